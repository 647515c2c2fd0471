"""Phases: the mission's phase logic (the switch to the dive, the entry ring, the go-around)."""
