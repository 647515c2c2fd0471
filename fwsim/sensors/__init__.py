"""What the aircraft can know: onboard sensor models and the ray-cast camera with its detector."""
