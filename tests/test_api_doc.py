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
