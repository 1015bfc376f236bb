"""Fault injection in ``agrifleet demo``: the options and their checks, the fleet's share
of the work that triggers a fault, the injector, and one real run with a tractor's
simulator killed part-way."""

from __future__ import annotations

import io
import re
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import pytest

from dispatcher.cli.main import EXIT_BAD_INPUT
from dispatcher.cli.main import main as cli_main
from dispatcher.config.errors import ConfigError
from dispatcher.daemon.state import FieldState, Phase, SetOff, VehicleState
from dispatcher.mission.document import PlanDocument, PlannedItem
from dispatcher.recording.mcap_file import read_logs
from dispatcher.review.report import review_contents, review_table
from dispatcher.tools.demo import (
    MAX_AUTO_SPEEDUP,
    TARGET_WALL_S,
    DemoFaults,
    Fault,
    FaultInjector,
    LiveStatus,
    Supervisor,
    auto_speedup,
    demo_faults,
    describe_exit,
    fleet_share_done,
    sim_command,
)
from sim_vehicles.__main__ import build_parser as sim_parser
from sim_vehicles.impairment import Impairment

DATA = Path(__file__).parent / "data"
TINY = DATA / "tiny.toml"
VEHICLES = ("v1", "v2")


def test_fault_options_are_parsed_and_sorted_by_share() -> None:
    faults = demo_faults(
        VEHICLES,
        kill=["v2@0.3"],
        stall=["v1@0.05", "v2@1"],
        loss=0.3,
        duplicate=0.1,
        delay_ms=200,
        radio_seed=7,
    )
    assert faults.faults == (
        Fault("stall", "v1", 0.05),
        Fault("kill", "v2", 0.3),
        Fault("stall", "v2", 1.0),
    )
    assert faults.radio == Impairment(loss=0.3, duplicate=0.1, delay_s=0.2)
    assert faults.radio_seed == 7
    assert str(faults.faults[1]) == "v2 killed at 30 % of the work"
    assert faults.describe() == [
        "planned: v1 stalled at 5 % of the work",
        "planned: v2 killed at 30 % of the work",
        "planned: v2 stalled at 100 % of the work",
        "radio: loss 30 %, duplicates 10 %, delay up to 200 ms (every tractor, both ways)",
    ]
    assert demo_faults(VEHICLES) == DemoFaults()
    assert DemoFaults().describe() == []


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"kill": ["v3@0.3"]}, "--kill v3@0.3: no vehicle 'v3' in this run (vehicles: v1, v2)"),
        ({"stall": ["v1@1.5"]}, "--stall v1@1.5: the fraction of the work must be 0 to 1"),
        ({"kill": ["v1@-0.1"]}, "--kill v1@-0.1: the fraction of the work must be 0 to 1"),
        ({"kill": ["v1@half"]}, "--kill v1@half: the fraction of the work must be 0 to 1"),
        ({"kill": ["v1@nan"]}, "--kill v1@nan: the fraction of the work must be 0 to 1"),
        ({"kill": ["v1"]}, "--kill wants VEHICLE@FRACTION (e.g. v2@0.3), got 'v1'"),
        ({"stall": ["@0.3"]}, "--stall wants VEHICLE@FRACTION"),
        ({"loss": 1.0}, "--loss 1: a probability must be at least 0 and below 1"),
        ({"duplicate": -0.1}, "--duplicate -0.1: a probability must be at least 0 and below 1"),
        ({"delay_ms": 20000}, "--delay 20000: the delay must be 0 to 10000 ms"),
    ],
)
def test_bad_fault_options_are_config_errors_naming_flag_and_value(
    options: dict, message: str
) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        demo_faults(VEHICLES, **options)


def test_the_command_line_refuses_a_bad_fault_before_planning(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = cli_main(["demo", str(TINY), "--kill", "v9@0.3", "--log-dir", str(tmp_path / "logs")])
    assert code == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "agrifleet: error: --kill v9@0.3: no vehicle 'v9'" in err
    assert not (tmp_path / "logs").exists()  # nothing planned, nothing written
    code = cli_main(["demo", str(TINY), "--machines", "1", "--stall", "v2@0.5"])
    assert code == EXIT_BAD_INPUT  # --machines 1 leaves v2 out of the run
    assert "--stall v2@0.5: no vehicle 'v2' in this run (vehicles: v1)" in capsys.readouterr().err


def test_the_simulators_take_the_radio_options_the_demo_gives() -> None:
    radio = Impairment(loss=0.3, duplicate=0.1, delay_s=0.2)
    cmd = sim_command(TINY, "v2", "tcp/127.0.0.1:7447", 200.0, radio, radio_seed=5)
    assert cmd[1:3] == ["-m", "sim_vehicles"]
    args = sim_parser().parse_args(cmd[3:])
    assert (args.vehicle, args.connect, args.speedup) == (["v2"], ["tcp/127.0.0.1:7447"], 200.0)
    assert (args.loss, args.duplicate, args.delay, args.radio_seed) == (0.3, 0.1, 200.0, 5)
    plain = sim_parser().parse_args(sim_command(TINY, "v1", "tcp/127.0.0.1:7447", 50.0)[3:])
    assert (plain.loss, plain.duplicate, plain.delay) == (0.0, 0.0, 0.0)


@dataclass
class _Fleet:
    vehicles: dict[str, VehicleState]


def _fleet(phase: Phase = Phase.RUNNING, **reached: int) -> _Fleet:
    planned = {"v1": [0.0, 100.0, 200.0, 300.0], "v2": [0.0, 50.0, 100.0]}
    return _Fleet(
        {
            vid: VehicleState(
                vid, k + 1, (), planned[vid], phase=phase, reached=reached.get(vid, 0)
            )
            for k, vid in enumerate(planned)
        }
    )


def test_the_share_of_the_work_is_weighted_by_planned_time() -> None:
    assert fleet_share_done(_fleet()) == 0.0  # type: ignore[arg-type]
    assert fleet_share_done(_fleet(v1=1)) == pytest.approx(100 / 400)  # type: ignore[arg-type]
    assert fleet_share_done(_fleet(v1=3, v2=1)) == pytest.approx(350 / 400)  # type: ignore[arg-type]
    assert fleet_share_done(_fleet(v1=3, v2=2)) == 1.0  # type: ignore[arg-type]


@dataclass
class _Children:
    """A stand-in for the Supervisor: signals sent, exits to report."""

    alive: set[str] = field(default_factory=lambda: {"v1", "v2"})
    signals: list[tuple[str, int]] = field(default_factory=list)
    exits: list[tuple[str, int]] = field(default_factory=list)

    def send_signal(self, name: str, sig: int) -> bool:
        if name not in self.alive:
            return False
        self.signals.append((name, sig))
        if sig == signal.SIGKILL:
            self.alive.discard(name)
            self.exits.append((name, -signal.SIGKILL))
        return True

    def newly_exited(self) -> list[tuple[str, int]]:
        out, self.exits = self.exits, []
        return out


def test_the_injector_fires_each_fault_once_at_its_share_and_reports_exits() -> None:
    faults = demo_faults(VEHICLES, kill=["v2@0.3"], stall=["v1@0.5", "v2@0.6"])
    children = _Children()
    notes: list[str] = []
    injector = FaultInjector(faults, children, notes.append, clock=lambda: 12.0)  # type: ignore[arg-type]
    injector(_fleet(v1=1))  # type: ignore[arg-type]
    assert children.signals == [] and notes == []
    injector(_fleet(Phase.WAITING, v1=2))  # type: ignore[arg-type]  # not before it is heard
    assert children.signals == [] and notes == []
    injector(_fleet(v1=2))  # type: ignore[arg-type]  # 50 %: the kill (0.3) and the stall (0.5)
    injector(_fleet(v1=2))  # type: ignore[arg-type]  # nothing twice
    injector(_fleet(v1=3))  # type: ignore[arg-type]  # 75 %: v2 is gone, its stall is not done
    assert children.signals == [("v2", signal.SIGKILL), ("v1", signal.SIGUSR1)]
    assert notes == [
        "v2 killed at 30 % of the work (50 % done, 0.0 s into the run)",
        "v1 stalled at 50 % of the work (50 % done, 0.0 s into the run)",
        "v2's simulator exited (killed by SIGKILL, injected) at 50 % done, 0.0 s into the run;"
        " the run goes on without it",
        "v2 stalled at 60 % of the work: not done, its simulator had already exited",
    ]
    assert injector.events == notes and injector.pending == []
    assert injector.marks == {"v2": "killed", "v1": "stalled"}
    children.exits.append(("v1", 1))  # a simulator that dies of itself is reported too
    injector(_fleet(v1=3))  # type: ignore[arg-type]
    assert notes[-1].startswith("v1's simulator exited (exit code 1) at 75 % done")
    assert injector.marks == {"v2": "killed", "v1": "simulator exited"}


def test_exit_codes_in_words() -> None:
    assert describe_exit(1) == "exit code 1"
    assert describe_exit(-signal.SIGKILL) == "killed by SIGKILL"
    assert describe_exit(-200) == "killed by signal 200"


def test_the_supervisor_signals_a_child_by_name_and_reports_each_exit_once(
    tmp_path: Path,
) -> None:
    sleeper = [sys.executable, "-c", "import time; time.sleep(60)"]
    children = Supervisor.start([sleeper, sleeper], tmp_path, names=["v1", "v2"])
    try:
        assert children.newly_exited() == []
        assert children.send_signal("v2", signal.SIGKILL)
        children.procs[1].wait(10)
        assert children.newly_exited() == [("v2", -signal.SIGKILL)]
        assert children.newly_exited() == []
        assert not children.send_signal("v2", signal.SIGKILL)
        assert (tmp_path / "v1.log").exists() and (tmp_path / "v2.log").exists()
    finally:
        children.stop()
    assert all(p.poll() is not None for p in children.procs)


def _fields_done(output: str) -> tuple[int, int]:
    found = re.findall(r"fields done: (\d+)/(\d+)", output)
    assert found, output[-3000:]
    done, total = found[-1]
    return int(done), int(total)


def test_a_killed_simulator_does_not_stop_the_demo(tmp_path: Path) -> None:
    """v2's simulator is killed at 30 % of the work: the demo goes on, v1 does all its
    fields, the summary names v2 killed and lost with its fields not done, and the exit code
    is the dispatcher's (3 while a field is not done; 0 once re-planning does them)."""
    log_dir = tmp_path / "logs"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dispatcher.cli",
            "demo",
            str(TINY),
            "--speedup",
            "200",
            "--kill",
            "v2@0.3",
            "--log-dir",
            str(log_dir),
            "--time-limit",
            "1",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    try:
        output, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # the demo stops its simulators on the way out
            try:
                proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
    assert "fault injection: planned: v2 killed at 30 % of the work" in output, output
    live = [ln for ln in output.splitlines() if ln.startswith("! ")]
    assert any(ln.startswith("! v2 killed at 30 % of the work (") for ln in live), output
    exits = [ln for ln in live if "v2's simulator exited (killed by SIGKILL, injected)" in ln]
    assert len(exits) == 1, output  # said once
    summary = output[output.index("summary:") :]
    assert "v2's simulator exited (killed by SIGKILL, injected)" in summary
    (v1,) = [ln.strip() for ln in summary.splitlines() if ln.strip().startswith("v1:")]
    assert v1.startswith("v1: done, fields ") and "not done" not in v1, summary
    (v2,) = [ln.strip() for ln in summary.splitlines() if ln.strip().startswith("v2:")]
    assert v2.startswith("v2: lost, "), summary
    # v2's rest was planned again over v1: every field done, exit 0.
    assert "re-planning the rest of the work: v2 lost" in output, output
    done, total = _fields_done(output)
    assert done == total, summary
    assert proc.returncode == 0, output[-3000:]
    assert "log: " in output
    (endpoint,) = re.findall(r"simulating at \d+x on (tcp/\S+)", output)
    assert not _processes_with(endpoint), "a simulator outlived the demo"
    # Reviewed: v1's mission went on through the re-plan, which counts from where v1 was;
    # its planned fields and hours are of the whole mission (before: "fields 3/2", and a
    # vehicle that kept its mission "took 12 % more than planned", the re-plan's rest).
    review = review_contents(read_logs([log_dir]))
    v1r = review.vehicle("v1")
    assert sorted(v1r.fields_done) == sorted(v1r.fields_planned), review_table(review)
    assert v1r.planned_time_h > v1r.time_h / 2, review_table(review)
    assert review.planned_makespan_h == max(
        v.planned_time_h for v in review.vehicles if not v.left_out
    )
    # The summary's hours are the review's (one rule for setting off and finishing), and
    # so is its plan: v1's hours until the re-plan and the re-plan's for the rest.
    finished = re.search(r"finished after ([\d.]+) h \(planned ([\d.]+) h\)", v1)
    assert finished and float(finished[1]) == pytest.approx(v1r.time_h, abs=0.011), summary
    assert float(finished[2]) == pytest.approx(v1r.planned_time_h, abs=0.011), (summary, v1r)
    assert "the re-plan's for the rest" in summary


def _processes_with(word: str) -> list[int]:
    """Running processes with ``word`` in their command line (Linux /proc)."""
    out = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            args = cmdline.read_bytes().split(b"\0")
        except OSError:
            continue
        if word.encode() in args:
            out.append(int(cmdline.parent.name))
    return out


@dataclass
class _Farm:
    vehicles: dict[str, VehicleState]
    fields: dict[str, FieldState]


def _six_tractors(done: int) -> _Farm:
    """Six tractors with long ids on 15 fields, ``done`` of them done."""
    item = PlannedItem(0, "field-with-a-long-id", 0, "swath_end", 440000000, 873000000, 16)
    vehicles = {
        f"tractor-{k}": VehicleState(
            f"tractor-{k}",
            k + 1,
            (item, item),
            [0.0, 7200.0],
            phase=Phase.LOST,
            reached=1,
            sim_time_s=10_000.0 + k,
            started_at=5.0,
            last_seen=6.0,
            set_off=SetOff(at_s=9_999.0),
        )
        for k in range(6)
    }
    fields = {f"F{k}": FieldState(f"F{k}", "tractor-0") for k in range(15)}
    for f in list(fields.values())[:done]:
        f.status = "done"
    return _Farm(vehicles, fields)


def test_the_live_view_fits_80_columns_and_ends_on_the_final_state() -> None:
    out = io.StringIO()
    planned = {vid: 21.15 for vid in _six_tractors(0).vehicles}
    status = LiveStatus(1714.0, planned, stream=out, period_s=0.0)
    status.marks["tractor-1"] = "simulator exited"
    status(_six_tractors(10))  # type: ignore[arg-type]
    status.close(_six_tractors(15))  # type: ignore[arg-type]
    text = out.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 80, text
    assert "sim h" in text and "plan h" in text and "21.15" in text
    last = text[text.rindex("fields done") - 10 :]
    assert "15/15 fields done" in last and "lost (simulator" in text, text
    # Hours since each tractor set off (SetOff, the review's rule: its clock at 9 999 s).
    assert status.worked_s(_six_tractors(0).vehicles["tractor-0"]) == pytest.approx(1.0)


def test_the_live_views_plan_of_a_re_planned_tractor_is_its_hours_until_then_and_the_rest():
    """The review's rule: a tractor given a new mission by a re-plan is planned the hours
    it worked until the re-plan and what the re-plan gives it for the rest; one whose
    mission the re-plan left as it was keeps its figure."""
    farm = _six_tractors(0)
    planned = {vid: 21.15 for vid in farm.vehicles}
    status = LiveStatus(1714.0, planned, stream=io.StringIO(), period_s=0.0)

    def plan(plan_id: str, hours: float) -> PlanDocument:
        machines = [SimpleNamespace(id=vid, time_h=hours) for vid in farm.vehicles]
        return SimpleNamespace(plan_id=plan_id, machines=machines)  # type: ignore[return-value]

    status.follow_plans(farm, plan("first", 21.15))  # type: ignore[arg-type]
    v = farm.vehicles["tractor-0"]
    v.items = (*v.items, v.items[0])  # re-planned
    farm.vehicles["tractor-1"].items = tuple(farm.vehicles["tractor-1"].items)  # the same
    status.follow_plans(farm, plan("again", 2.0))  # type: ignore[arg-type]
    assert status.planned_h["tractor-0"] == pytest.approx(status.worked_s(v) / 3600 + 2.0)
    assert status.planned_h["tractor-1"] == 21.15
    v.sim_time_s += 3600.0  # the same plan seen again: nothing changes
    status.follow_plans(farm, plan("again", 2.0))  # type: ignore[arg-type]
    assert status.planned_h["tractor-0"] == pytest.approx(1.0 / 3600 + 2.0)


def test_the_default_speedup_fits_the_plan_into_the_target_but_not_faster_than_the_ceiling():
    def plan(hours: float, items: int = 2181):  # type: ignore[no-untyped-def]
        # the demo farm's busiest mission: 22.04 h over 2 180 items, 36.4 s an item
        machines = [SimpleNamespace(time_h=22.04, items=[None] * items)]
        return SimpleNamespace(
            plan=SimpleNamespace(makespan_h=hours), document=SimpleNamespace(machines=machines)
        )

    assert auto_speedup(plan(10.0)) == pytest.approx(10.0 * 3600.0 / TARGET_WALL_S)  # 800x
    assert auto_speedup(plan(0.001)) == 1.0  # never slower than real time
    assert auto_speedup(plan(40.0)) == MAX_AUTO_SPEEDUP  # 3 200x would make it late
    # Through a lossy, slow radio the uploads take longer in wall time: no faster than they
    # keep up, three items over the radio for each driven, 0.41 s each at 30 % and 200 ms.
    lossy = Impairment(loss=0.3, duplicate=0.1, delay_s=0.2)
    assert auto_speedup(plan(40.0), radio=lossy) == pytest.approx(36.38 / (3 * 0.4134), rel=1e-3)
    assert 25.0 < auto_speedup(plan(40.0), radio=lossy) < 35.0
    # a light loss does not hold the demo back; a longer item to drive allows more
    assert auto_speedup(plan(40.0), radio=Impairment(loss=0.05)) == MAX_AUTO_SPEEDUP
    assert auto_speedup(plan(40.0, items=1001), radio=lossy) > auto_speedup(plan(40.0), radio=lossy)
    assert auto_speedup(plan(40.0), radio=Impairment()) == MAX_AUTO_SPEEDUP
