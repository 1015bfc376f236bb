"""Test helpers (tests/helpers) import as ``helpers.*`` under pytest's importlib mode."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(autouse=True)
def _state_dir(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """The dispatcher's default data directory ($XDG_STATE_HOME/agrifleet/FARM) in a
    temporary folder, for this test and the processes it starts: no test resumes another's
    run or writes to the user's state."""
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("state")))
