"""The command line, called in-process through main()."""

import argparse
import importlib
import json
import re
from pathlib import Path

import pytest
from helpers.processes import free_port

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


def _run_logs(directory, starts_s, run_started=None):
    """One run in several log files (a dispatcher restarted), one file per start time;
    the run's start in their metadata when given, as the daemon writes it."""
    from dispatcher.recording.mcap_file import RUN_STARTED_KEY, Recorder

    t0 = 1_704_067_200_000_000_000  # 2024-01-01T00:00:00Z
    paths = []
    metadata = {RUN_STARTED_KEY: run_started} if run_started else None
    for start_s in starts_s:
        start = t0 + start_s * 10**9
        with Recorder.create_in(
            directory, "changji", metadata, clock=lambda start=start: start
        ) as rec:
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


def test_review_of_a_log_folder_of_several_runs_reviews_the_latest_and_says_so(tmp_path, capsys):
    """A dispatcher's --log-dir holds a run a day: read as one, their tracks and events
    were merged into one review."""
    monday = _run_logs(tmp_path, [0, 600], "2024-01-01T00:00:00+00:00")
    tuesday = _run_logs(tmp_path, [86_400], "2024-01-02T00:00:00+00:00")
    assert main(["review", str(tmp_path), "--json"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert out["log_start"] == "2024-01-02 00:00:00 UTC"
    assert out["log_end"] == "2024-01-02 00:00:00 UTC"
    assert "holds 2 runs; reviewing the latest" in captured.err
    assert all(p.name in captured.err for p in monday)
    # Files given by name are of one run, or named as two.
    assert main(["review", str(monday[0]), str(monday[1]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["log_end"] == "2024-01-01 00:10:00 UTC"
    assert main(["review", str(monday[1]), str(tuesday[0])]) == 2
    err = capsys.readouterr().err
    assert "different runs" in err and "2024-01-01" in err and "2024-01-02" in err


def test_a_log_that_holds_nothing_is_left_out_of_a_folders_review(tmp_path, capsys):
    """A dispatcher killed as it started leaves a log with the MCAP header alone: it was
    taken for the latest run (its start unknown) and the real run was not reviewed."""
    from dispatcher.recording.mcap_file import RUN_STARTED_KEY, Recorder

    first, restarted = _run_logs(tmp_path, [0, 600], "2024-01-01T00:00:00+00:00")
    (tmp_path / "changji-20231231-120000.mcap").write_bytes(first.read_bytes()[:120])
    # Killed after the metadata was written (it is flushed at once), a day later.
    later = 1_704_067_200_000_000_000 + 86_400 * 10**9
    metadata = {RUN_STARTED_KEY: "2024-01-02T00:00:00+00:00"}
    Recorder.create_in(tmp_path, "changji", metadata, clock=lambda: later).finish()
    assert main(["review", str(tmp_path), "--json"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert out["log_end"] == "2024-01-01 00:10:00 UTC" and out["source"] == str(tmp_path)
    assert "left out, as they hold nothing: changji-20231231-120000.mcap" in captured.err
    assert "changji-20240102-000000.mcap" in captured.err
    # A file of no bytes at all (killed as it was opened): left out too, not "is empty".
    (tmp_path / "changji-20231231-130000.mcap").write_bytes(b"")
    assert main(["review", str(tmp_path), "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["log_end"] == "2024-01-01 00:10:00 UTC"
    assert "changji-20231231-130000.mcap" in captured.err.split("left out, as they hold nothing")[1]


def test_review_of_an_empty_directory_is_a_clear_error(tmp_path, capsys):
    assert main(["review", str(tmp_path)]) == 2
    assert "holds no .mcap log" in capsys.readouterr().err


def test_every_package_is_installed_and_the_light_ones_stay_light():
    """pyproject lists its packages: none left out; a scenario, the link, the simulator and
    the command line's parser (`agrifleet sim|bridge`) load without the solver (numba), as a
    tractor's companion computer needs."""
    import subprocess
    import sys
    import tomllib

    root = Path(__file__).resolve().parents[1]
    listed = set(
        tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    )
    on_disk = {
        ".".join(p.parent.relative_to(root).parts)
        for top in ("agrifleet", "planner", "dispatcher", "sim_vehicles")
        for p in (root / top).rglob("__init__.py")
    }
    assert on_disk <= listed, on_disk - listed
    code = (
        "import sys, sim_vehicles, sim_vehicles.runner, sim_vehicles.mavlink_port, "
        "dispatcher.config.scenario, dispatcher.link.mission_protocol, dispatcher.tools.bridge, "
        "agrifleet, importlib; importlib.import_module('dispatcher.cli.main').build_parser(); "
        "assert 'numba' not in sys.modules and 'planner.solve' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


# --- version, plan --json, exit codes --------------------------------------------------

REPO = Path(__file__).resolve().parents[1]
TINY = DATA / "tiny.toml"


def test_version_comes_from_the_package_metadata(capsys):
    from importlib.metadata import version

    import pytest

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"agrifleet {version('agrifleet')}"


def test_plan_json_is_the_plan_document_alone_on_stdout(tmp_path, capsys):
    from dispatcher.mission.document import PlanDocument

    out = tmp_path / "plan"
    assert main(["plan", str(TINY), "--json", "--out", str(out), "--time-limit", "2"]) == 0
    captured = capsys.readouterr()
    doc = PlanDocument.from_json(captured.out)  # the whole of stdout is one document
    assert doc.plan_id == json.loads((out / "plan.json").read_text())["plan_id"]
    assert (doc.farm_id, len(doc.fields)) == ("tiny", 3)
    assert "wrote" in captured.err


def test_plan_wants_an_output_folder_or_json(capsys):
    assert main(["plan", str(TINY)]) == 2
    assert "give --out DIR" in capsys.readouterr().err


def test_the_farm_id_follows_the_fields_file(tmp_path, capsys):
    farm = tmp_path / "North farm.geojson"
    farm.write_text((DATA / "tiny-farm.geojson").read_text())
    args = ["plan", str(TINY), "--fields", str(farm), "--json", "--time-limit", "2"]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["farm_id"] == "North-farm"


def test_a_scenario_whose_own_farm_is_missing_plans_on_the_fields_given(tmp_path, capsys):
    """A scenario kept as a template for several farms: with --fields its own farm file is
    not read (it used to be, and a missing one stopped the plan)."""
    scenario = tmp_path / "template.toml"
    scenario.write_text(
        TINY.read_text().replace('farm = "tiny-farm.geojson"', 'farm = "not-here.geojson"')
    )
    farm = tmp_path / "North farm.geojson"
    farm.write_text((DATA / "tiny-farm.geojson").read_text())
    assert main(["plan", str(scenario), "--json", "--time-limit", "2"]) == 2
    assert "not-here.geojson" in capsys.readouterr().err
    args = ["plan", str(scenario), "--fields", str(farm), "--json", "--time-limit", "2"]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["farm_id"] == "North-farm"
    args += ["--id-field", "id"]
    assert main(args) == 0


def test_interrupted_exits_130(monkeypatch, capsys):
    cli = importlib.import_module("dispatcher.cli.main")  # the package's `main` is the function

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "cmd_review", interrupted)
    assert main(["review", "nothing.mcap"]) == 130
    assert "interrupted" in capsys.readouterr().err


def test_sigterm_interrupts_a_command_as_ctrl_c_does(monkeypatch, capsys):
    """`agrifleet plan` stopped by SIGTERM (a service manager, `timeout`) exits 130 as with
    Ctrl-C, not with the signal's 143; the handler is put back afterwards."""
    import os
    import signal
    import time

    cli = importlib.import_module("dispatcher.cli.main")
    before = signal.getsignal(signal.SIGTERM)

    def terminated(args):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)  # the handler raises long before
        return 0

    monkeypatch.setattr(cli, "cmd_review", terminated)
    assert main(["review", "nothing.mcap"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) is before

    # Inside the solver the interrupt comes out of a numba kernel's call back into Python
    # as a SystemError caused by it (a traceback and exit 1, with Ctrl-C too).
    def in_a_kernel(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise SystemError("returned a result with an exception set") from exc

    monkeypatch.setattr(cli, "cmd_review", in_a_kernel)
    assert main(["review", "nothing.mcap"]) == 130
    assert "interrupted" in capsys.readouterr().err


def test_the_router_has_no_mode_to_choose(capsys):
    """A router runs in router mode: `--mode peer` was offered and ended in a traceback."""
    with pytest.raises(SystemExit) as stop:
        main(["router", "--mode", "peer"])
    assert stop.value.code == 2
    assert "--mode" in capsys.readouterr().err


def test_exit_codes_are_documented_and_agree_with_the_code(capsys):
    """--help and the README list every exit code; the daemon's and the simulator's
    constants are the ones listed."""
    import pytest

    import sim_vehicles.__main__ as sim
    from dispatcher.daemon import server

    cli = importlib.import_module("dispatcher.cli.main")
    assert (server.EXIT_OK, server.EXIT_INCOMPLETE, server.EXIT_INTERRUPTED) == (
        cli.EXIT_OK,
        cli.EXIT_INCOMPLETE,
        cli.EXIT_INTERRUPTED,
    )
    assert (sim.EXIT_BAD_INPUT, sim.EXIT_LINK_DOWN) == (cli.EXIT_BAD_INPUT, cli.EXIT_LINK_DOWN)
    with pytest.raises(SystemExit):
        main(["--help"])
    help_text = capsys.readouterr().out
    readme = (REPO / "README.md").read_text()
    for code in cli.EXIT_CODES:
        assert f"\n  {code:<4} " in help_text
        assert f"| {code} |" in readme, f"README lists no exit code {code}"


def test_a_state_that_cannot_be_written_is_not_called_bad_input(monkeypatch, capsys):
    """A full disk while serve ran ended it with exit 2, "bad input", which it was not: the
    inputs were fine and the run resumes once there is room (exit 5 says so)."""
    cli = importlib.import_module("dispatcher.cli.main")
    from dispatcher.daemon.store import StoreWriteError

    def full(args):  # type: ignore[no-untyped-def]
        raise StoreWriteError("agrifleet.sqlite3: cannot write the dispatcher's state (full)")

    monkeypatch.setattr(cli, "cmd_serve", full)
    assert main(["serve", str(DATA / "tiny.toml"), "--unsigned"]) == cli.EXIT_STATE_UNWRITTEN == 5
    assert "cannot write the dispatcher's state" in capsys.readouterr().err


def test_every_option_has_help_text():
    import argparse

    from sim_vehicles.__main__ import build_parser as sim_parser

    cli = importlib.import_module("dispatcher.cli.main")
    missing = []

    def walk(parser: argparse.ArgumentParser, name: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for command, sub in action.choices.items():
                    walk(sub, f"{name} {command}")
            elif action.help is None:
                missing.append(f"{name} {'/'.join(action.option_strings) or action.dest}")

    walk(cli.build_parser(), "agrifleet")
    walk(sim_parser(), "agrifleet sim")
    assert not missing


def test_the_first_run_says_it_compiles_and_how_long(monkeypatch, capsys):
    """While numba compiles (a tiny function of the test's, standing for the solver's
    kernels) the command says so on stderr, then how long it took; warm says where the
    kernels are cached."""
    from numba import njit

    import planner.solve

    @njit
    def tiny(x):
        return x * 2

    monkeypatch.setattr(planner.solve, "warm_up", lambda: tiny(2))
    assert main(["warm"]) == 0
    out, err = capsys.readouterr()
    first, done = err.splitlines()
    assert first.startswith("compiling the solver's kernels once for this install (~")
    assert done.startswith("compiled in ") and done.endswith(" s; cached for the next runs")
    assert out.startswith("the solver's kernels are compiled and cached in ")


def test_a_cached_run_says_nothing_of_compiling(monkeypatch, capsys):
    import planner.solve

    monkeypatch.setattr(planner.solve, "warm_up", lambda: None)  # all loaded from the cache
    assert main(["warm"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert out.startswith("the solver's kernels were compiled already: loaded from ")


def test_sim_help_is_the_simulators(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["sim", "--help"])
    assert stop.value.code == 0
    assert "usage: agrifleet sim" in capsys.readouterr().out


def test_bad_numbers_and_unusable_paths_exit_2_naming_them(tmp_path, capsys):
    """--time-limit and --speedup are checked when parsed (a negative one was a traceback,
    0 meant the scenario's, 1e9 ran); a directory to write into that is a file is named."""
    for value in ("-5", "nan", "0", "1e9"):
        with pytest.raises(SystemExit) as stop:
            main(["plan", str(TINY), "--json", "--time-limit", value])
        assert stop.value.code == 2
        assert "argument --time-limit" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main(["demo", "--speedup", "-5", "--no-foxglove"])
    assert stop.value.code == 2 and "argument --speedup" in capsys.readouterr().err
    taken = tmp_path / "a file"
    taken.write_text("mine")
    # The directories to write into: named, before anything is planned or kept (plan --out
    # planned for its whole time limit, then said "File exists").
    data = tmp_path / "data"
    listen = ["--listen", f"tcp/127.0.0.1:{free_port()}"]  # (a demo beside may hold 7447)
    for argv, flag in (
        (["plan", str(TINY), "--out", str(taken)], "--out"),
        (["keys", str(TINY), "--keys", str(taken)], "--keys"),
        (["certs", str(TINY), "--tls", str(taken)], "--tls"),
        (
            [
                "serve",
                str(TINY),
                *listen,
                "--unsigned",
                "--data-dir",
                str(data),
                "--log-dir",
                str(taken),
            ],
            "--log-dir",
        ),  # fmt: skip
        (["serve", str(TINY), *listen, "--unsigned", "--data-dir", str(taken)], "--data-dir"),
        (["demo", str(TINY), "--no-foxglove", "--log-dir", str(taken)], "--log-dir"),
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{flag} {taken}: not a directory" in err and "planned" not in err, err
    assert not (data / "agrifleet.sqlite3").exists() and taken.read_text() == "mine"


def test_a_scenario_as_windows_and_other_languages_write_it(tmp_path, capsys):
    """A byte-order mark (Notepad), and a file name with spaces and letters beyond ASCII:
    the farm id is made of it (it was refused as a farm id)."""
    folder = tmp_path / "Ферма Ünï"
    folder.mkdir()
    scenario = folder / "моя ферма.toml"
    text = TINY.read_text().replace(
        'farm = "tiny-farm.geojson"', f'farm = "{DATA / "tiny-farm.geojson"}"'
    )
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith("farm_id"))
    scenario.write_text(text, encoding="utf-8-sig")
    assert main(["plan", str(scenario), "--json", "--time-limit", "1"]) == 0
    farm_id = json.loads(capsys.readouterr().out)["farm_id"]
    assert re.fullmatch(r"farm-[0-9a-f]{6}", farm_id), farm_id


def test_the_demo_gives_its_simulators_the_farm_it_was_given(tmp_path):
    """demo --fields FARM ran the dispatcher on FARM (farm id its name) and the simulators on
    the scenario's own farm (another farm id: every tractor "never came alive")."""
    from dispatcher.tools.bridge import add_bridge_arguments
    from dispatcher.tools.demo import sim_command
    from sim_vehicles.__main__ import build_parser

    farm = tmp_path / "North farm.geojson"
    cmd = sim_command(TINY, "v1", "tcp/127.0.0.1:7447", 10.0, fields=farm)
    assert cmd[cmd.index("--fields") + 1] == str(farm)
    assert "--fields" not in sim_command(TINY, "v1", "tcp/127.0.0.1:7447", 10.0)
    args = build_parser().parse_args([str(TINY), "--all", "--fields", str(farm)])
    assert args.fields == farm
    bridge = argparse.ArgumentParser()
    add_bridge_arguments(bridge)
    assert (
        bridge.parse_args(
            [
                str(TINY),
                "--vehicle",
                "v1",
                "--fields",
                str(farm),
                "--mavlink",
                "udpin:0.0.0.0:14550",
            ]
        ).fields
        == farm
    )


def test_minsum_is_an_objective_on_the_command_line_as_in_a_scenario(capsys):
    args = ["plan", str(TINY), "--objective", "minsum", "--json", "--time-limit", "1"]
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out)["objective"] == "distance"


def test_serve_on_a_port_another_process_listens_on_is_refused_before_planning(tmp_path, capsys):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        argv = ["serve", str(TINY), "--unsigned", "--listen", endpoint]
        assert main([*argv, "--data-dir", str(tmp_path / "data")]) == 2
    err = capsys.readouterr().err
    assert f"--listen {endpoint}: Address already in use" in err, err
    assert not (tmp_path / "data" / "agrifleet.sqlite3").exists()  # nothing planned or kept


def test_a_plot_file_is_a_picture_matplotlib_writes(capsys):
    """`review --plot out.txt` was a matplotlib traceback; `--plot out` wrote out.png and
    said "plot: out"."""
    from dispatcher.cli.main import figure_file

    assert figure_file("out") == Path("out.png")
    assert figure_file("a/map.PDF") == Path("a/map.PDF")
    with pytest.raises(SystemExit) as exc:
        main(["review", "nowhere", "--plot", "out.txt"])
    assert exc.value.code == 2
    assert "out.txt: not a picture format matplotlib writes" in capsys.readouterr().err


def test_a_stored_run_is_resumed_unless_the_plan_would_differ(tmp_path):
    """The fingerprint a stored run is resumed by: a comment, the [dispatcher] section or a
    time limit changed in the scenario refused the resume ("made from other inputs", only
    --fresh out: review); a field, a machine or the seed changed still refuse it."""
    import argparse
    import shutil

    from dispatcher.cli.main import inputs_fingerprint, load_scenario_args

    for name in ("tiny.toml", "tiny-farm.geojson"):
        shutil.copy(DATA / name, tmp_path / name)
    scenario_path = tmp_path / "tiny.toml"
    base = scenario_path.read_text()

    def fingerprint(text: str, seed: int | None = None, time_limit: float | None = None) -> str:
        scenario_path.write_text(text)
        args = argparse.Namespace(
            scenario=str(scenario_path),
            fields=None,
            machines=None,
            objective=None,
            seed=seed,
            time_limit=time_limit,
        )
        return inputs_fingerprint(load_scenario_args(args), args)

    first = fingerprint(base)
    assert fingerprint(base + "\n# a comment\n") == first
    # The same farm saved again (another layout of its JSON), a field renamed: the same
    # plan (the file's bytes refused the resume: an outside review)
    farm = tmp_path / "tiny-farm.geojson"
    drawn = json.loads(farm.read_text())
    farm.write_text(json.dumps(drawn, indent=4))
    assert fingerprint(base) == first
    drawn["features"][0]["properties"]["name"] = "Renamed"
    farm.write_text(json.dumps(drawn))
    assert fingerprint(base) == first
    assert fingerprint(base + "\n[dispatcher]\nlost_after_s = 9.0\n") == first
    assert fingerprint(base, time_limit=3.0) == first
    assert fingerprint(base, seed=7) != first
    seed = int(next(ln for ln in base.splitlines() if ln.startswith("seed")).split("=")[1])
    assert fingerprint(base, seed=seed) == first  # --seed as the scenario has it (a review)
    assert fingerprint(base.replace("road_fuel_lh = 3.0", "road_fuel_lh = 4.0", 1)) != first
    farm = tmp_path / "tiny-farm.geojson"
    farm.write_text(farm.read_text().replace("87.3007493", "87.30074", 2))  # field A narrower
    assert fingerprint(base) != first


def test_a_refused_resume_says_which_input_changed(tmp_path):
    """A refused resume said "its farm or the options changed since", whatever it was: an
    operator had to guess between the farm file, the fleet and the solver's settings. A run
    stored with each input's hash is refused naming the ones that changed; one stored with
    the bare fingerprint (before) still gets the general words."""
    import argparse
    import shutil
    from types import SimpleNamespace

    from dispatcher.cli.main import check_resumable, load_scenario_args, stored_fingerprint
    from dispatcher.daemon.store import StoreError

    for name in ("tiny.toml", "tiny-farm.geojson"):
        shutil.copy(DATA / name, tmp_path / name)
    scenario_path = tmp_path / "tiny.toml"
    base = scenario_path.read_text()
    farm = tmp_path / "tiny-farm.geojson"
    drawn = farm.read_text()

    def inputs(text: str = base, seed: int | None = None):  # type: ignore[no-untyped-def]
        scenario_path.write_text(text)
        args = argparse.Namespace(
            scenario=str(scenario_path), fields=None, machines=None, objective=None,
            seed=seed, time_limit=None,
        )  # fmt: skip
        scenario = load_scenario_args(args)
        return stored_fingerprint(scenario, args), scenario, args

    first, _, _ = inputs()
    run = SimpleNamespace(id=4, fingerprint=first, job=SimpleNamespace(plan_id="p"))

    def refusal(*changed) -> str:  # type: ignore[no-untyped-def]
        now, scenario, args = changed[0] if changed else inputs()
        with pytest.raises(StoreError) as info:
            check_resumable(run, now, scenario, args, tmp_path)
        return str(info.value)

    check_resumable(run, *inputs(), tmp_path)  # the same inputs: resumed
    assert "inputs: " in refusal(inputs(seed=7)) and "the seed changed since" in refusal(
        inputs(seed=7)
    )
    fleet = refusal(inputs(base.replace("road_fuel_lh = 3.0", "road_fuel_lh = 4.0", 1)))
    assert "the fleet changed since" in fleet and "farm" not in fleet.split("inputs:")[1]
    farm.write_text(drawn.replace("87.3007493", "87.30074", 2))  # field A narrower
    both = refusal(inputs(seed=7))
    assert "the farm (its fields, roads, gates or garage) and the seed changed since" in both
    farm.write_text(drawn)
    run.fingerprint = first.split()[0]  # stored before the inputs' hashes were kept
    assert "its farm or the options changed since" in refusal(inputs(seed=7))


def test_a_setting_an_upgrade_adds_at_its_default_keeps_a_stored_run_resumable(tmp_path):
    """The fleet and the solver's settings were hashed as their repr: an upgrade that adds a
    machine or solver setting (with a default) made every unfinished run "made from other
    inputs", and only --fresh went on (its fields worked again). Their values not at the
    defaults count; the fingerprint of runs stored before (the repr) is still accepted."""
    import argparse
    import dataclasses
    from types import SimpleNamespace

    from dispatcher.cli.main import check_resumable, inputs_fingerprint, load_scenario_args
    from dispatcher.config.scenario import SolverSettings
    from dispatcher.daemon.store import StoreError
    from planner.problem import Machine

    args = argparse.Namespace(
        scenario=str(DATA / "tiny.toml"),
        fields=None,
        machines=None,
        objective=None,
        seed=None,
        time_limit=None,
    )
    scenario = load_scenario_args(args)
    default = dataclasses.field(default=0.5)
    machine = dataclasses.make_dataclass(
        "Machine", [("new_setting", float, default)], bases=(Machine,), frozen=True
    )
    solver = dataclasses.make_dataclass(
        "SolverSettings", [("new_setting", float, default)], bases=(SolverSettings,), frozen=True
    )

    def upgraded(new_setting: float):  # type: ignore[no-untyped-def]
        vehicles = tuple(
            dataclasses.replace(
                v, machine=machine(**dataclasses.asdict(v.machine), new_setting=new_setting)
            )
            for v in scenario.vehicles
        )
        settings = solver(**dataclasses.asdict(scenario.solver), new_setting=new_setting)
        return dataclasses.replace(scenario, vehicles=vehicles, solver=settings)

    before = inputs_fingerprint(scenario, args)
    assert inputs_fingerprint(upgraded(0.5), args) == before
    assert inputs_fingerprint(upgraded(0.7), args) != before  # set: another plan
    # How runs stored before this were fingerprinted: changed by the upgrade alone.
    old = inputs_fingerprint(scenario, args, as_repr=True)
    assert old != before and inputs_fingerprint(upgraded(0.5), args, as_repr=True) != old

    def stored(fingerprint: str) -> SimpleNamespace:
        return SimpleNamespace(id=3, fingerprint=fingerprint, job=SimpleNamespace(plan_id="p"))

    now = inputs_fingerprint(upgraded(0.5), args)
    check_resumable(stored(before), now, upgraded(0.5), args, tmp_path)
    check_resumable(stored(old), before, scenario, args, tmp_path)  # by the version before
    by_bytes = inputs_fingerprint(scenario, args, file_bytes=True)  # to 2026-11-29 14:00
    assert by_bytes not in (before, old)
    check_resumable(stored(by_bytes), before, scenario, args, tmp_path)
    with pytest.raises(StoreError, match="unfinished run 3 .* made from other inputs"):
        check_resumable(stored(before), inputs_fingerprint(upgraded(0.7), args),
                        upgraded(0.7), args, tmp_path)  # fmt: skip
