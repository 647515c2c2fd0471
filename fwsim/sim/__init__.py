"""The loop that flies a scenario, the Python API, and the block timers behind ``fwsim bench``."""
