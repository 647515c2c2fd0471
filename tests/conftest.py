import sys
from pathlib import Path

# tests/flight.py holds closed-loop helpers shared by several test files
sys.path.insert(0, str(Path(__file__).parent))

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def paper_typical(tmp_path_factory):
    """The paper mission flown whole on the typical sensors (the onboard INS between them and everything
    onboard), once per test session: its log path."""
    from fwsim import SCENARIO_DIR
    from fwsim.scenario.model import load_scenario
    from fwsim.sim.loop import run
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"sensors.profile": "typical"})
    result = run(scenario, text, tmp_path_factory.mktemp("paper_typical") / "paper_typical.mcap")
    assert result.status == "completed", result.reason
    return result.log_path
