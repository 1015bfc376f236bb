"""Test helpers (tests/helpers) import as ``helpers.*`` under pytest's importlib mode."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
