"""The command line, called in-process through main()."""

import json
from pathlib import Path

from dispatcher.cli.main import main

DATA = Path(__file__).parent / "data"


def test_mtsp_json_is_one_object_with_the_contract_keys(capsys):
    code = main(["mtsp", str(DATA / "eil51.tsp"), "-m", "3", "--generations", "50", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {
        "instance",
        "salesmen",
        "objective",
        "algorithm",
        "distance",
        "cost",
        "routes",
        "elapsed_s",
    }
    assert out["instance"] == "eil51" and out["salesmen"] == 3
    nodes = sorted(n for route in out["routes"] for n in route)
    assert nodes == list(range(2, 52))  # every city once, depot 1 excluded
    assert len(out["routes"]) == 3


def test_mtsp_readable_summary_and_minmax(capsys):
    code = main(
        [
            "mtsp",
            str(DATA / "att48.tsp"),
            "-m",
            "2",
            "--objective",
            "minmax",
            "--algorithm",
            "ga",
            "--generations",
            "20",
            "--distance",
            "tsplib",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "att48: 2 salesmen, minmax by ga, tsplib distances" in out
    assert "salesman 2:" in out


def test_bad_tsplib_file_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "broken.tsp"
    bad.write_text("DIMENSION : 2\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n2 zz 1\n")
    assert main(["mtsp", str(bad), "-m", "1"]) == 2
    err = capsys.readouterr().err
    assert "broken.tsp:5" in err


def test_bench_paper_fleet_table(capsys):
    assert main(["bench", "paper", "--tables", "8", "--runs", "1", "--generations", "20"]) == 0
    out = capsys.readouterr().out
    assert "| 8 | 4 | GA |" in out and "| 8 | 4 | IGHOA |" in out
    assert "OUR positions" in out


def _run_logs(directory, starts_s):
    """One run in several log files (a dispatcher restarted), one file per start time."""
    from dispatcher.recording.mcap_file import Recorder

    t0 = 1_704_067_200_000_000_000  # 2024-01-01T00:00:00Z
    paths = []
    for start_s in starts_s:
        start = t0 + start_s * 10**9
        with Recorder.create_in(directory, "changji", clock=lambda start=start: start) as rec:
            rec.record_status({"vehicles": {}}, start + 1)
            rec.record_log("info", f"started at {start_s}", start + 2)
        paths.append(rec.path)
    return paths


def test_review_reads_several_logs_as_one_run(tmp_path, capsys):
    first, restarted = _run_logs(tmp_path, [0, 600])
    assert main(["review", str(restarted), str(first), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["farm_id"], out["complete"]) == ("changji", True)
    assert out["log_start"] == "2024-01-01 00:00:00 UTC"
    assert out["log_end"] == "2024-01-01 00:10:00 UTC"  # the second file's end
    assert out["source"] == f"{first} (+1 more)"


def test_review_reads_a_directory_and_names_a_file_cut_short(tmp_path, capsys):
    _, last = _run_logs(tmp_path, [0, 600])
    last.write_bytes(last.read_bytes()[:-100])  # the restarted dispatcher was killed
    (tmp_path / "plan.json").write_text("{}")  # not a log: left out
    assert main(["review", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["source"] == str(tmp_path) and out["complete"] is False
    assert last.name in out["problem"]
    assert main(["review", str(tmp_path)]) == 0  # the table too
    assert capsys.readouterr().out.strip()


def test_review_of_an_empty_directory_is_a_clear_error(tmp_path, capsys):
    assert main(["review", str(tmp_path)]) == 2
    assert "holds no .mcap log" in capsys.readouterr().err


def test_every_package_is_installed_and_the_light_ones_stay_light():
    """pyproject lists its packages: none left out; a scenario, the link and the simulator
    load without the solver (numba), as a tractor's companion computer needs."""
    import subprocess
    import sys
    import tomllib

    root = Path(__file__).resolve().parents[1]
    listed = set(
        tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    on_disk = {
        ".".join(p.parent.relative_to(root).parts)
        for top in ("planner", "dispatcher", "sim_vehicles")
        for p in (root / top).rglob("__init__.py")
    }
    assert on_disk <= listed, on_disk - listed
    code = (
        "import sys, sim_vehicles, sim_vehicles.runner, sim_vehicles.mavlink_port, "
        "dispatcher.config.scenario, dispatcher.link.mission_protocol, dispatcher.tools.bridge; "
        "assert 'numba' not in sys.modules and 'planner.solve' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
