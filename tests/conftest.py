import sys
from pathlib import Path

# tests/flight.py holds closed-loop helpers shared by several test files
sys.path.insert(0, str(Path(__file__).parent))
