"""docs/api.md runs: its Python blocks in order, as the cells of a notebook, on the small
test farm in place of the demo farm (the page is the same with either; the test is faster)."""

import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "api.md"
DATA = Path(__file__).parent / "data"


def test_the_api_page_runs_as_a_notebook(tmp_path, monkeypatch, capsys):
    cells = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)
    assert len(cells) >= 4
    import agrifleet

    monkeypatch.setattr(agrifleet, "DEMO_SCENARIO", DATA / "tiny.toml")
    monkeypatch.chdir(tmp_path)  # the page writes its files where it runs
    namespace: dict[str, object] = {}
    for k, cell in enumerate(cells):
        exec(compile(cell, f"{DOC}, block {k + 1}", "exec"), namespace)
    out = capsys.readouterr().out
    assert "makespan" in out and "2 routes;" in out
    assert (tmp_path / "map.png").stat().st_size > 0
    assert (tmp_path / "plan.geojson").exists()
    written = sorted(p.suffix for p in (tmp_path / "out" / "plan").iterdir())
    assert written == [
        ".geojson",
        ".json",
        ".kml",
        ".plan",
        ".plan",
        ".png",
        ".waypoints",
        ".waypoints",
    ]


def test_the_api_says_which_argument_is_bad():
    """docs/api.md promises a ConfigError naming what is at fault; a negative time limit
    was a ValueError, a seed of 'a' another, machines '2' a TypeError (review)."""
    import pytest

    import agrifleet
    from dispatcher.config.errors import ConfigError

    for kwargs, said in [
        ({"time_limit_s": -1}, r"plan_farm\(time_limit_s=-1\): seconds from 0\.1"),
        ({"seed": "a"}, r"plan_farm\(seed='a'\): a whole number"),
        ({"machines": "2"}, r"plan_farm\(machines='2'\): a whole number"),
        ({"machines": 0}, r"plan_farm\(machines=0\): at least 1"),
    ]:
        with pytest.raises(ConfigError, match=said):
            agrifleet.plan_farm(**kwargs)
