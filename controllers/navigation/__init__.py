"""Navigation: the own state between GNSS fixes (nav) and the camera's pose and pinhole model with its
ground geometry (camera_model, shared by the other blocks)."""
