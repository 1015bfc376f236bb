"""`agrifleet demo`: the whole job on one machine, nothing to install.

Plans the scenario, starts the dispatcher (Zenoh peer listening on loopback), starts one
simulated tractor process per machine connected to it, shows live progress, and exits 0
when every field is done. Child processes are always stopped, also on failure or Ctrl-C.

Fault injection (:class:`DemoFaults`): a tractor's simulator killed (SIGKILL) or its
tractor stalled (SIGUSR1) once the fleet has done a share of its planned work, and every
radio impaired. A simulator that exits early is reported, once, and the run goes on: the
dispatcher sees that tractor lost and the run ends as the dispatcher decides.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any, Literal

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import DEMO_SCENARIO
from dispatcher.daemon.server import DaemonConfig, Dispatcher
from dispatcher.daemon.state import FleetState, Phase, VehicleState
from dispatcher.daemon.store import Store
from dispatcher.link import wire
from dispatcher.link.keys import read_keys, write_keys
from dispatcher.link.signals import stop_on_signals
from dispatcher.mission.document import PlanDocument, PlannedItem
from dispatcher.mission.plan import DispatchPlan
from dispatcher.recording.address import DEFAULT_PORT as DEFAULT_LIVE_PORT
from dispatcher.tools.replan import replanner_for
from sim_vehicles.impairment import Impairment

log = logging.getLogger(__name__)

DEFAULT_SCENARIO = DEMO_SCENARIO
TARGET_WALL_S = 45.0  # the default speedup fits the planned makespan into this
MAX_AUTO_SPEEDUP = 1200.0
"""The default speedup's ceiling: a longer plan takes longer than ``TARGET_WALL_S`` (the
default scenario's 21.4 h take ~70 s). The mission protocol and the top-ups of a window run
in wall time, so a second a tractor waits for them is ``speedup`` seconds of its simulated
time, and on two cores the simulators and the links fall behind. The default scenario on
this project's two-core machine (benchmarks/RESULTS.md, 2026-11-27 08:20): at 1 000x and
1 400x every tractor finished within 3 % of its planned time, no waits at a window's end,
no upload retries; at 1 714x (what fits 45 s) the two with the longest missions (2 166 and
2 277 items) waited at 2 to 4 of their windows' ends and finished 10-20 % late, with up to
36 upload retries (16-31 % before the top-ups were renumbered to spare a prefix that cannot
be sent in time, ``Dispatcher._stops_sooner``). 1 200x leaves a margin for a slower
machine. Until 2026-11-27 the ceiling was 1 800x, chosen from runs whose simulator drove on
at road speed after each start at a window's end (d67da2c), which hid the waits."""
RADIO_ITEM_S = (0.26, 0.76, 3.8)
"""Seconds one item of a mission upload takes through an impaired radio, from its loss p and
its delay spread D (seconds): ``a p² / (1 − p) + b D + c p D``, these the a, b, c fitted to
the transfer benchmark (benchmarks/RESULTS.md, 2026-11-28 04:45 and 2026-11-29 12:30; 200
items, medians): 30 % loss and no delay 0.027 s an item, no loss and 0–200 ms late 0.15 s,
both 0.41 s; 20 % loss and 20 ms 0.045 s (the fit 0.043 s). A late frame overtakes the one
before it and ArduPilot takes only the item it expects, so the delay counts most."""
UPLOAD_ITEMS_PER_ITEM = 3.0
"""Items sent or read over the radio for each item of a mission driven: its upload, its
read-back and what a top-up sends again (the demo's windows, docs/link.md)."""
FAULT_CHECK_PERIOD_S = 0.1
"""How often (wall seconds) the share of the work is looked at when faults are planned (the
dispatcher's progress callback, ``progress_period_s``: its status period, 1 s, is 200
simulated seconds at 200x; the status itself is still published once a second)."""


def free_port(preferred: int = wire.DEFAULT_PORT) -> int:
    """``preferred`` if a listener can have it on loopback, else any free port."""
    for port in (preferred, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            # As the listeners do (zenoh, the Foxglove server): a port whose last connections
            # wait out TIME_WAIT (the previous run's) can be listened on; one listened on cannot.
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(s.getsockname()[1])
    raise RuntimeError("no free TCP port on 127.0.0.1")


def _port_or_say(preferred: int, what: str) -> int:
    """``preferred`` if it is free, else a free port, said loudly (on stderr): an outside
    tool looking at the documented port would see nothing."""
    port = free_port(preferred)
    if port != preferred:
        print(
            f"WARNING: port {preferred} on 127.0.0.1 is taken by another program: the {what} "
            f"of this demo is on port {port} instead. Outside tools must use port {port}.",
            file=sys.stderr,
            flush=True,
        )
    return port


def auto_speedup(
    dispatch: DispatchPlan, target_wall_s: float = TARGET_WALL_S, radio: Impairment | None = None
) -> float:
    """The speedup that runs the plan in ``target_wall_s``, within [1, MAX_AUTO_SPEEDUP];
    through an impaired ``radio``, not faster than its uploads keep up with the tractors:
    the simulated seconds an item takes to drive (on average, in the mission where that is
    least) over UPLOAD_ITEMS_PER_ITEM times what an item takes through the radio
    (RADIO_ITEM_S). Faster, the tractors wait at their windows' ends while their simulated
    hours run on (30 % loss and 200 ms: at 196x, the ceiling of before, the first windows
    took 61–173 s and t6 was at 26.5 h of a 14.25 h plan after 10 min; at 1 200x not a
    field in 240 s)."""
    ceiling = MAX_AUTO_SPEEDUP
    if radio is not None and radio.active:
        a, b, c = RADIO_ITEM_S
        p, d = radio.loss, radio.delay_s
        item_s = a * p * p / (1.0 - p) + b * d + c * p * d
        drive_s = [
            m.time_h * 3600.0 / (len(m.items) - 1)
            for m in dispatch.document.machines
            if len(m.items) > 1 and m.time_h > 0
        ]
        if item_s > 0 and drive_s:
            ceiling = min(ceiling, min(drive_s) / (UPLOAD_ITEMS_PER_ITEM * item_s))
    return min(max(1.0, dispatch.plan.makespan_h * 3600.0 / target_wall_s), max(ceiling, 1.0))


@dataclass
class Supervisor:
    """Child processes started together and always stopped together, each by a name (its
    output goes to ``<log_dir>/<name>.log``)."""

    procs: list[subprocess.Popen[bytes]]
    names: list[str] = field(default_factory=list)
    _reported: set[str] = field(default_factory=set)

    @classmethod
    def start(
        cls,
        commands: Sequence[Sequence[str]],
        log_dir: Path,
        names: Sequence[str] | None = None,
    ) -> Supervisor:
        """Start ``commands``, named ``names`` (default: each command's last word)."""
        names = list(names) if names is not None else [Path(cmd[-1]).name for cmd in commands]
        procs: list[subprocess.Popen[bytes]] = []
        log_dir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        try:
            for name, cmd in zip(names, commands, strict=True):
                out = open(log_dir / f"{name}.log", "ab")  # noqa: SIM115
                procs.append(
                    subprocess.Popen(
                        list(cmd),
                        stdout=out,
                        stderr=subprocess.STDOUT,
                        stdin=subprocess.DEVNULL,
                        env=env,
                    )
                )
                out.close()
        except BaseException:
            cls(procs).stop()
            raise
        return cls(procs, names)

    def send_signal(self, name: str, sig: int) -> bool:
        """Send ``sig`` to the process ``name``; False if it has already exited."""
        proc = self.procs[self.names.index(name)]
        if proc.poll() is not None:
            return False
        proc.send_signal(sig)
        return True

    def newly_exited(self) -> list[tuple[str, int]]:
        """Processes that exited since the last call: (name, return code), each once."""
        out = []
        for name, proc in zip(self.names, self.procs, strict=True):
            code = proc.poll()
            if code is not None and name not in self._reported:
                self._reported.add(name)
                out.append((name, code))
        return out

    def stop(self, timeout_s: float = 5.0) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + timeout_s
        for p in self.procs:
            try:
                p.wait(max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def sim_command(
    scenario: Path,
    vehicle: str,
    endpoint: str,
    speedup: float,
    radio: Impairment | None = None,
    radio_seed: int = 1,
    keys_dir: Path | None = None,
    fields: Path | None = None,
) -> list[str]:
    """``python -m sim_vehicles`` for one tractor (with every fault-injection option);
    signed with the keys of ``keys_dir``, else unsigned; on the farm file ``fields`` when
    the demo was given one (its farm id and garage, as the dispatcher's)."""
    cmd = [
        sys.executable,
        "-m",
        "sim_vehicles",
        str(scenario),
        *(("--fields", str(fields)) if fields is not None else ()),
        "--connect",
        endpoint,
        "--speedup",
        f"{speedup:.3f}",
        "--vehicle",
        vehicle,
        "--exit-with-parent",  # none left on the port by a demo killed with -9
        str(os.getpid()),
        *(("--keys", str(keys_dir)) if keys_dir is not None else ("--unsigned",)),
    ]
    if radio is not None and radio.active:
        cmd += [
            "--loss",
            f"{radio.loss:g}",
            "--duplicate",
            f"{radio.duplicate:g}",
            "--delay",
            f"{radio.delay_s * 1000.0:g}",
            "--radio-seed",
            str(radio_seed),
        ]
    return cmd


FaultAction = Literal["kill", "stall"]
FAULT_SIGNALS: dict[FaultAction, int] = {"kill": signal.SIGKILL, "stall": signal.SIGUSR1}
_DONE_WORDS: dict[FaultAction, str] = {"kill": "killed", "stall": "stalled"}


@dataclass(frozen=True)
class Fault:
    """``action`` on ``vehicle``'s simulator once the fleet has done ``at_share`` (0..1) of
    its planned work: "kill" is SIGKILL to the process, "stall" SIGUSR1 (the tractor
    stands still, armed in AUTO, and keeps reporting)."""

    action: FaultAction
    vehicle: str
    at_share: float

    def __str__(self) -> str:
        return f"{self.vehicle} {_DONE_WORDS[self.action]} at {100 * self.at_share:g} % of the work"


@dataclass(frozen=True)
class DemoFaults:
    """What the demo injects: faults at shares of the work, and an impaired radio for
    every tractor, both ways (random numbers seeded with ``radio_seed``)."""

    faults: tuple[Fault, ...] = ()
    radio: Impairment = Impairment()
    radio_seed: int = 1

    def describe(self) -> list[str]:
        """One line per planned fault, and the radio's if it is impaired."""
        lines = [f"planned: {f}" for f in self.faults]
        if self.radio.active:
            lines.append(f"radio: {self.radio} (every tractor, both ways)")
        return lines


def parse_fault(action: FaultAction, text: str, vehicles: Sequence[str]) -> Fault:
    """``VEHICLE@FRACTION`` (``--kill``/``--stall``) as a :class:`Fault`; ConfigError names
    the flag and the value."""
    flag = f"--{action}"
    vid, sep, share = text.rpartition("@")
    if not sep or not vid:
        raise ConfigError(f"{flag} wants VEHICLE@FRACTION (e.g. v2@0.3), got {text!r}")
    try:
        at_share = float(share)
    except ValueError:
        at_share = float("nan")
    if not 0.0 <= at_share <= 1.0:
        raise ConfigError(f"{flag} {text}: the fraction of the work must be 0 to 1, got {share!r}")
    if vid not in vehicles:
        raise ConfigError(
            f"{flag} {text}: no vehicle {vid!r} in this run (vehicles: {', '.join(vehicles)})"
        )
    return Fault(action, vid, at_share)


def demo_faults(
    vehicles: Sequence[str],
    kill: Sequence[str] = (),
    stall: Sequence[str] = (),
    loss: float = 0.0,
    duplicate: float = 0.0,
    delay_ms: float = 0.0,
    radio_seed: int = 1,
) -> DemoFaults:
    """The demo's fault options checked against the run's ``vehicles``; ConfigError names
    the flag and the value at fault."""
    faults = [parse_fault("kill", text, vehicles) for text in kill]
    faults += [parse_fault("stall", text, vehicles) for text in stall]
    for flag, value in (("--loss", loss), ("--duplicate", duplicate)):
        if not 0.0 <= value < 1.0:
            raise ConfigError(f"{flag} {value:g}: a probability must be at least 0 and below 1")
    if not 0.0 <= delay_ms <= 10_000.0:
        raise ConfigError(f"--delay {delay_ms:g}: the delay must be 0 to 10000 ms")
    radio = Impairment(loss=loss, duplicate=duplicate, delay_s=delay_ms / 1000.0)
    return DemoFaults(tuple(sorted(faults, key=lambda f: f.at_share)), radio, radio_seed)


def fleet_share_done(state: FleetState) -> float:
    """The fleet's share of its planned work done, weighted by planned time: the planned
    time to each vehicle's last item reached over the planned time of every mission."""
    total = sum(v.planned_s[-1] for v in state.vehicles.values() if v.planned_s)
    if total <= 0.0:
        return 1.0
    done = sum(v.planned_s[v.reached] for v in state.vehicles.values() if v.planned_s)
    return min(done / total, 1.0)


def describe_exit(code: int) -> str:
    """A process's return code in words: "exit code 1", "killed by SIGKILL"."""
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class FaultInjector:
    """Fires the faults as the work gets done and reports simulators that exit early, once
    each; what it did is kept in ``events`` (for the summary) and passed to ``notify``."""

    def __init__(
        self,
        faults: DemoFaults,
        children: Supervisor,
        notify: Callable[[str], None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.pending = list(faults.faults)
        self.children = children
        self.notify = notify
        self.clock = clock
        self.started = clock()
        self.events: list[str] = []
        self.marks: dict[str, str] = {}  # vehicle id -> what happened to it, for the live view
        self._injected: dict[str, FaultAction] = {}

    def __call__(self, state: FleetState) -> None:
        share = fleet_share_done(state)
        # Not before the dispatcher has heard the vehicle: its simulator has set up its
        # signal handlers by then (SIGUSR1 would end a process that has none yet).
        due = [
            f
            for f in self.pending
            if f.at_share <= share and state.vehicles[f.vehicle].phase is not Phase.WAITING
        ]
        for fault in due:
            self.pending.remove(fault)
            if self.children.send_signal(fault.vehicle, FAULT_SIGNALS[fault.action]):
                self._injected[fault.vehicle] = fault.action
                self.marks[fault.vehicle] = _DONE_WORDS[fault.action]
                self._note(f"{fault} ({100 * share:.0f} % done, {self._elapsed()})")
            else:
                self._note(f"{fault}: not done, its simulator had already exited")
        for vid, code in self.children.newly_exited():
            why = ", injected" if self._injected.get(vid) == "kill" else ""
            self.marks[vid] = "killed" if why else "simulator exited"
            self._note(
                f"{vid}'s simulator exited ({describe_exit(code)}{why}) at "
                f"{100 * share:.0f} % done, {self._elapsed()}; the run goes on without it"
            )

    def _elapsed(self) -> str:
        return f"{self.clock() - self.started:.1f} s into the run"

    def _note(self, text: str) -> None:
        self.events.append(text)
        self.notify(text)


class LiveStatus:
    """The demo's live view, 80 columns: per tractor its field, the share of its mission
    done, its simulated hours and the plan's, its state; above, the fields done and the
    simulated time. Redrawn in place on a terminal, printed every ``period_s`` otherwise.
    Times marked "sim" are the tractors' simulated clocks; "wall" is the real time."""

    WIDTH = 80

    def __init__(
        self,
        speedup: float,
        planned_h: dict[str, float],
        stream: IO[str] | None = None,
        period_s: float = 5.0,
    ) -> None:
        from rich.console import Console

        self.speedup = speedup
        self.planned_h = planned_h  # each tractor's planned hours, as its last plan says
        self._plan_id: str | None = None  # of the plan last followed (follow_plans)
        self._missions: dict[str, tuple[PlannedItem, ...]] = {}  # each tractor's under it
        self.period_s = period_s
        self.marks: dict[str, str] = {}  # vehicle id -> a fault it has (see FaultInjector)
        self.console = Console(file=stream or sys.stdout, width=self.WIDTH, highlight=False)
        self.started = time.monotonic()
        self._live: Any = None
        self._last = -math.inf

    def note(self, text: str) -> None:
        """A line of news (a fault injected, a simulator gone), at once, above the view."""
        self.console.print(f"! {text}", markup=False, soft_wrap=True)

    def worked_s(self, v: VehicleState) -> float:
        """Simulated seconds since ``v`` set off (the review's rule, :class:`SetOff`), to
        the end of its mission if it is done."""
        if v.set_off.at_s is None:
            return 0.0
        end = v.finished_s if v.finished_s is not None else v.sim_time_s
        return max(end - v.set_off.at_s, 0.0)

    def follow_plans(self, state: FleetState, document: PlanDocument) -> None:
        """The plan the dispatcher follows now is ``document``: a tractor whose mission a
        re-plan changed is planned the hours it worked until the re-plan and the re-plan's
        for the rest (the review's rule). The dispatcher publishes its status, and so
        calls this, as it adopts a re-plan."""
        if document.plan_id == self._plan_id:
            return
        first, self._plan_id = self._plan_id is None, document.plan_id
        for m in document.machines:
            v = state.vehicles.get(m.id)
            if v is None:
                continue
            seen, self._missions[m.id] = self._missions.get(m.id), v.items
            if first or seen is None or v.items == seen:
                continue
            self.planned_h[m.id] = self.worked_s(v) / 3600 + m.time_h

    def render(self, state: FleetState) -> Any:
        from rich import box
        from rich.table import Table

        done = sum(f.status == "done" for f in state.fields.values())
        sim_h = max((self.worked_s(v) for v in state.vehicles.values()), default=0.0) / 3600
        table = Table(
            title=f"{done}/{len(state.fields)} fields done · sim {sim_h:.2f} h at "
            f"{self.speedup:.0f}x · wall {time.monotonic() - self.started:.0f} s",
            box=box.SIMPLE_HEAD,
            title_justify="left",
        )
        table.add_column("tractor")
        table.add_column("field")
        table.add_column("done", justify="right")
        table.add_column("sim h", justify="right")
        table.add_column("plan h", justify="right")
        table.add_column("state")
        for v in state.vehicles.values():
            mark = f" ({self.marks[v.id]})" if v.id in self.marks else ""
            planned = self.planned_h.get(v.id)
            table.add_row(
                v.id,
                v.current_field or "-",
                f"{100 * v.share_done:.0f} %",
                f"{self.worked_s(v) / 3600:.2f}",
                "-" if planned is None else f"{planned:.2f}",
                f"{v.phase.value}{mark}",
            )
        return table

    def __call__(self, state: FleetState) -> None:
        now = time.monotonic()
        if self.console.is_terminal:
            if now - self._last < 0.25:
                return
            self._last = now
            if self._live is None:
                from rich.live import Live

                self._live = Live(console=self.console, auto_refresh=False)
                self._live.start()
            self._live.update(self.render(state), refresh=True)
        elif now - self._last >= self.period_s:
            self._last = now
            self.console.print(self.render(state))

    def close(self, state: FleetState) -> None:
        """Show the final state (what the summary then tells) and stop redrawing."""
        if self._live is not None:
            self._live.update(self.render(state), refresh=True)
            self._live.stop()
            self._live = None
        else:
            self.console.print(self.render(state))


@dataclass
class DemoResult:
    """How the demo ended: the dispatcher's exit code, the finished dispatcher, and what
    was injected or went wrong on the way (one line each, in order)."""

    code: int
    daemon: Dispatcher
    events: list[str]
    faults: DemoFaults
    status: LiveStatus | None = None  # the live view, with each tractor's hours


def run_demo(
    scenario_path: Path,
    dispatch: DispatchPlan,
    speedup: float | None,
    log_dir: Path,
    heartbeat_timeout_s: float = 10.0,
    faults: DemoFaults | None = None,
    foxglove: tuple[str, int] | None = None,
    fields: Path | None = None,
) -> DemoResult:
    """Run the demo with ``faults`` injected; a simulator that exits early is reported and
    the run goes on (the dispatcher sees its tractor lost). Returns the dispatcher's exit
    code with what happened, for the summary. ``foxglove``: serve the run live to Foxglove
    there (the default port taken: any free one, said loudly). ``fields``: the farm file
    the demo was given (``--fields``), which the simulators are given too."""
    faults = faults or DemoFaults()
    for fault in faults.faults:
        if fault.vehicle not in dispatch.missions:
            raise ConfigError(f"--{fault.action} names {fault.vehicle!r}, which has no mission")
    speed = speedup or auto_speedup(dispatch, radio=faults.radio)
    endpoint = f"tcp/127.0.0.1:{_port_or_say(wire.DEFAULT_PORT, 'zenoh endpoint')}"
    if foxglove is not None and foxglove[1] == DEFAULT_LIVE_PORT:
        foxglove = (foxglove[0], _port_or_say(DEFAULT_LIVE_PORT, "Foxglove live view"))
    print(
        f"plan {dispatch.plan_id}: {len(dispatch.missions)} tractors, "
        f"{len(dispatch.plan.farm.fields)} fields, planned makespan "
        f"{dispatch.plan.makespan_h:.2f} h\nsimulating at {speed:.0f}x on {endpoint}",
        flush=True,
    )
    print(
        f"sim: simulated time; the tractors' clocks run {speed:.0f}x "
        f"(a planned hour takes {3600 / speed:.1f} s)",
        flush=True,
    )
    for line in faults.describe():
        print(f"fault injection: {line}", flush=True)
    # The demo keeps its state beside its logs, and always starts a new run.
    farm_id = dispatch.document.farm_id
    store = Store.open(log_dir / "state" / farm_id, farm_id, option="--log-dir")
    store.abandon_unfinished()
    job = dispatch.job()
    started = time.time()
    store.begin_run(job, fingerprint="demo", started=started)
    # Throwaway signing keys, one per tractor, for this demo only (beside its logs).
    keys_dir = log_dir / "keys" / dispatch.document.farm_id
    write_keys(keys_dir, list(dispatch.missions), replace=True)
    keys = read_keys(keys_dir, list(dispatch.missions))
    planned_h = {m.id: m.time_h for m in dispatch.document.machines}
    printer = LiveStatus(speed, planned_h)
    config = DaemonConfig(
        job=job,
        store=store,
        zenoh=wire.dispatcher_options((endpoint,)),
        log_dir=log_dir,
        heartbeat_timeout_s=heartbeat_timeout_s,
        stall_after_s=dispatch.scenario.watch.stall_after_s,
        lost_grace_s=dispatch.scenario.watch.lost_grace_s,
        alive_timeout_s=dispatch.scenario.watch.alive_after_s,
        window_items=dispatch.scenario.watch.window_items,
        topup_lead_s=dispatch.scenario.watch.topup_lead_s,
        on_progress=printer,
        replanner=replanner_for(dispatch.scenario, dispatch, started=started),
        keys=keys,
        foxglove=foxglove,
    )
    if faults.faults:
        config.progress_period_s = FAULT_CHECK_PERIOD_S
    daemon = Dispatcher(config)
    injector: FaultInjector | None = None

    def progress(state: FleetState) -> None:
        if injector is not None:
            injector(state)
        printer.follow_plans(state, daemon.job.document)
        printer(state)

    config.on_progress = progress
    restore_signals = stop_on_signals(daemon.should_exit, "stopping the demo")
    children: Supervisor | None = None
    try:
        daemon.startup()
        if daemon.live is not None:
            print(
                f"live view: in Foxglove, Open connection > Foxglove WebSocket > "
                f"{daemon.live.url} (docs/foxglove.md)",
                flush=True,
            )
        vids = list(dispatch.missions)
        children = Supervisor.start(
            [
                sim_command(
                    scenario_path,
                    vid,
                    endpoint,
                    speed,
                    faults.radio,
                    faults.radio_seed,
                    keys_dir,
                    fields,
                )
                for vid in vids
            ],
            log_dir / "sim",
            names=vids,
        )
        injector = FaultInjector(faults, children, printer.note)
        printer.marks = injector.marks
        code = daemon.main_loop()
    finally:
        printer.close(daemon.state)
        if children is not None:
            children.stop()
        daemon.shutdown()
        store.close()
        restore_signals()
    events = list(injector.events) if injector is not None else []
    if injector is not None:
        events += [f"{f}: not reached" for f in injector.pending]
    return DemoResult(code, daemon, events, faults, printer)


def summary(daemon: Dispatcher, result: DemoResult | None = None) -> str:
    """The end of the run: per vehicle, fields done and not done, its simulated hours
    beside the plan's (the plan table's figure); what was injected."""
    state = daemon.state
    status = result.status if result is not None else None
    lines = ["", "summary: (simulated hours, from when each tractor set off)"]
    if status is not None and daemon.replans:
        lines.append(
            "  (planned, of a tractor re-planned: the hours it worked until the re-plan and "
            "the re-plan's for the rest, as the review counts)"
        )
    for v in state.vehicles.values():
        not_done = [f.id for f in state.fields.values() if f.vehicle == v.id and f.status != "done"]
        if status is not None:
            worked_s, planned = status.worked_s(v), status.planned_h.get(v.id, 0.0)
        else:  # without the live view: the tractor's own clock, the mission's planned time
            end = v.finished_s if v.finished_s is not None else v.sim_time_s
            worked_s, planned = end, (v.planned_s[-1] / 3600 if v.planned_s else 0.0)
        lines.append(
            f"  {v.id}: {v.phase.value}, fields {' '.join(v.fields_done) or '-'}"
            + (f", not done {' '.join(not_done)}" if not_done else "")
            + f", {'finished after ' if v.finished_s is not None else ''}"
            f"{worked_s / 3600:.2f} h (planned {planned:.2f} h)"
            + (f", upload retries {v.upload_retries}" if v.upload_retries else "")
            + (f", {v.error}" if v.error else "")
        )
    done = sum(f.status == "done" for f in state.fields.values())
    lines.append(f"  fields done: {done}/{len(state.fields)}")
    if status is not None:
        lines.append(f"  the run took {time.monotonic() - status.started:.0f} s of wall time")
    if daemon.upload_started is not None and daemon.all_acknowledged is not None:
        lines.append(
            f"  every mission acknowledged {daemon.all_acknowledged - daemon.upload_started:.2f} s "
            "(wall) after the first upload began"
        )
    if result is not None:
        if result.faults.radio.active:
            lines.append(f"  radio: {result.faults.radio} (every tractor, both ways)")
        lines += [f"  {event}" for event in result.events]
    return "\n".join(lines)
