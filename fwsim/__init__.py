"""fwsim: a flight-simulation harness around JSBSim.

The truth world (JSBSim airframe, target, gimbal, camera, sensors), the loop,
the logs and the command line live here; the flight software under test lives
in the sibling package ``controllers``.
"""
from pathlib import Path

__version__ = "0.1.0"

#: The project's root (holds ``aircraft/`` and ``scenarios/``), found from this
#: file so it does not depend on the working directory.
PROJECT_ROOT = Path(__file__).resolve().parent.parent
AIRCRAFT_DIR = PROJECT_ROOT / "aircraft"
SCENARIO_DIR = PROJECT_ROOT / "scenarios"
