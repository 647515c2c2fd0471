"""The simulated world (truth side): JSBSim airframe, ship, gimbal, meshes, timed events."""
