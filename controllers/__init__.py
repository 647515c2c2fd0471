"""Flight software under test: the paper's algorithms.

Nothing in this package may import the truth side of the harness (JSBSim,
``fwsim.world.airframe``, ``fwsim.sim.loop``, ...). It sees only measurements.
"""
