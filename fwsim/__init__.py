"""fwsim: a flight-simulation harness around JSBSim.

The truth world (JSBSim airframe, target, gimbal, camera, sensors), the loop,
the logs and the command line live here; the flight software under test lives
in the sibling package ``controllers``.

From Python (docs/guide/api.md)::

    import fwsim
    flight = fwsim.fly("scenarios/autopilot_checkout.yaml", duration_s=10)
    flight.metrics["flight_time_s"], flight.log_path

``import fwsim`` stays light: JSBSim, CasADi and the flight software are
imported by the first :func:`fly` or :func:`batch`.
"""
from pathlib import Path

__version__ = "0.1.0"

#: The project's root (holds ``aircraft/`` and ``scenarios/``), found from this
#: file so it does not depend on the working directory.
PROJECT_ROOT = Path(__file__).resolve().parent.parent
AIRCRAFT_DIR = PROJECT_ROOT / "aircraft"
SCENARIO_DIR = PROJECT_ROOT / "scenarios"

from fwsim.sim.api import Flight, batch, fly  # noqa: E402 - (standard library only until called)

__all__ = ["fly", "batch", "Flight", "PROJECT_ROOT", "AIRCRAFT_DIR", "SCENARIO_DIR", "__version__"]
