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
