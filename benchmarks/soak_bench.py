"""Soak: a big fleet on a big farm for minutes, with tractors killed and stalled at random
and lossy radios; the dispatcher must re-plan and finish the farm.

The dispatcher runs in this process (its CPU and memory are this process's), with its
re-planner, as `agrifleet serve` has it; the tractors run as `python -m sim_vehicles`
processes, a few tractors each (a kill or a stall hits a whole process). Reported: faults
injected, re-plans, seconds from a loss to the new plan and to every changed mission
acknowledged (median, max; goal < 3 s), fields not done at the end and of those the lost
ones, in no working vehicle's route (goal 0), segments (swaths, headland edges) worked
twice or never (goal 0), as the fleet state counts them, dispatcher CPU and memory at the
start and at the end. Faults come once every tractor has started (a fault during the first
uploads only delays the start) or from 30 % of the wall time on (the first uploads through a
lossy radio can take longer), 30-60 s apart, until half the wall time, to a third of the
simulator processes at most (a farm cannot be finished in the time by what is left of a
fleet that lost most of its tractors: that measures the fleet, not the dispatcher); the
planned makespan is fitted to ``fit`` of the wall time (40 % by default: the first uploads
through lossy radios take minutes). Which processes fail, how and when, and the radios'
random frames follow ``seed`` (`AGRIFLEET_SOAK_SEED` for `benchmarks/run.py soak`, default
1); `AGRIFLEET_SOAK_LOGS=DIR` keeps the run's logs and scenario in DIR.
"""

from __future__ import annotations

import os
import random
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from benchmarks.dispatcher_bench import _grid_farm, _keys, _plan, _scenario, _stop, free_port

SOAK_DISPATCHER = "\n[dispatcher]\nlost_after_s = 10\nstall_after_s = 120\nlost_grace_s = 10\n"


FAULTS_FROM = 0.3
"""Share of the wall time after which faults come even if not every tractor drives yet."""


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def bench_soak(
    vehicles: int = 30,
    fields: int = 200,
    minutes: float = 10.0,
    per_process: int = 3,
    loss: float = 0.2,
    seed: int = 1,
    fit: float = 0.4,
    gap_s: tuple[float, float] = (30.0, 60.0),
    fault_share: float = 1 / 3,
) -> str:
    """Run the soak (module doc). Faults hit up to ``fault_share`` of the simulator
    processes, in the first half of the time: the farm is sized (``fit``: the share of the
    wall time the first plan takes) so that the rest of the fleet can still finish it."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.state import GONE
    from dispatcher.link import wire
    from dispatcher.tools.replan import replanner_for

    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        farm = _grid_farm(folder, fields)
        scenario_path = _scenario(
            folder, farm, vehicles, 6.0, 20.0
        )  # not measured: room on a loaded machine
        scenario_path.write_text(scenario_path.read_text() + SOAK_DISPATCHER)
        dispatch = _plan(scenario_path)
        wall_s = minutes * 60.0
        speedup = max(1.0, dispatch.plan.makespan_h * 3600.0 / (fit * wall_s))
        port = free_port()
        daemon = Dispatcher(
            DaemonConfig(
                job=dispatch.job(),
                zenoh=wire.dispatcher_options((f"tcp/127.0.0.1:{port}",)),
                log_dir=folder / "logs",
                heartbeat_timeout_s=dispatch.scenario.watch.lost_after_s,
                stall_after_s=dispatch.scenario.watch.stall_after_s,
                lost_grace_s=dispatch.scenario.watch.lost_grace_s,
                window_items=dispatch.scenario.watch.window_items,
                alive_timeout_s=120.0,
                on_progress=lambda state: None,
                replanner=replanner_for(dispatch.scenario, dispatch, started=time.time()),
                keys=_keys(scenario_path),
            )
        )
        ids = [v.id for v in dispatch.scenario.vehicles]
        groups = [ids[k : k + per_process] for k in range(0, len(ids), per_process)]
        procs = []
        figures: dict[str, object] = {"faults": []}
        cpu0 = rss0 = 0.0
        daemon.startup()
        try:
            for group in groups:
                cmd = [sys.executable, "-m", "sim_vehicles", str(scenario_path)]
                for vid in group:
                    cmd += ["--vehicle", vid]
                cmd += ["--connect", f"tcp/127.0.0.1:{port}", "--speedup", f"{speedup:g}"]
                cmd += ["--loss", str(loss), "--radio-seed", str(rng.randrange(1000))]
                procs.append(
                    subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                )
            started = time.monotonic()

            def inject() -> None:
                nonlocal cpu0, rss0
                # Faults once every tractor drives, or from FAULTS_FROM of the time on (the
                # first uploads through a lossy radio can take most of it).
                while (
                    not daemon.should_exit.is_set()
                    and time.monotonic() - started < FAULTS_FROM * wall_s
                    and any(v.started_at is None for v in list(daemon.state.vehicles.values()))
                ):
                    time.sleep(1.0)
                if all(v.started_at is not None for v in list(daemon.state.vehicles.values())):
                    figures["driving_s"] = time.monotonic() - started
                usage = resource.getrusage(resource.RUSAGE_SELF)
                cpu0, rss0 = usage.ru_utime + usage.ru_stime, _rss_mb()
                alive = list(range(len(procs)))
                faults_left = max(1, int(fault_share * len(procs)))
                while time.monotonic() - started < 0.5 * wall_s and faults_left > 0:
                    faults_left -= 1
                    time.sleep(rng.uniform(*gap_s))
                    if daemon.should_exit.is_set():
                        return
                    k = alive.pop(rng.randrange(len(alive)))
                    kind = rng.choice(["kill", "stall"])
                    procs[k].send_signal(signal.SIGKILL if kind == "kill" else signal.SIGUSR1)
                    figures["faults"].append((kind, groups[k]))  # type: ignore[attr-defined]
                deadline = started + wall_s
                while time.monotonic() < deadline and not daemon.should_exit.is_set():
                    time.sleep(1.0)
                daemon.should_exit.set()  # out of time

            thread = threading.Thread(target=inject, daemon=True)
            thread.start()
            code = daemon.main_loop()
            took = time.monotonic() - started
        finally:
            for p in procs:
                _stop(p)
            daemon.shutdown()
        usage = resource.getrusage(resource.RUSAGE_SELF)
        cpu1, rss1 = usage.ru_utime + usage.ru_stime, _rss_mb()
        not_done = [f.id for f in daemon.state.fields.values() if f.status != "done"]
        # Lost: not done, and no vehicle still at work has it in its route.
        working = {
            v.id for v in daemon.state.vehicles.values() if v.phase not in GONE and not v.retired
        }
        planned = {fid for m in daemon.job.document.machines if m.id in working for fid in m.fields}
        lost = [fid for fid in not_done if fid not in planned]
        twice = sum(len(f.worked_twice) for f in daemon.state.fields.values())
        never = sum(len(f.never_worked) for f in daemon.state.fields.values())
        segments = sum(f.segments for f in daemon.state.fields.values())
        keep = os.environ.get("AGRIFLEET_SOAK_LOGS")
        if keep:  # for a look afterwards: agrifleet review DIR/logs/...
            shutil.copytree(folder, keep, dirs_exist_ok=True)
    faults = figures["faults"]
    plan_s = [r[1] for r in daemon.replans]
    acked_s = [r[2] for r in daemon.replans if r[2] is not None]

    fault_list = ", ".join(f"{kind} {'+'.join(group)}" for kind, group in faults)  # type: ignore[attr-defined]

    driving_s = figures.get("driving_s")
    driving = f"{driving_s:.0f}" if isinstance(driving_s, float) else "not all before the faults"

    def stat(values: list[float]) -> str:
        return f"{statistics.median(values):.2f} / {max(values):.2f}" if values else "–"

    lines = [
        f"### Soak: {vehicles} tractors ({per_process} per simulator process), {fields} fields, "
        f"{minutes:g} min wall at {speedup:.0f}x, {100 * loss:g} % frame loss each way, "
        f"missions in windows of {dispatch.scenario.watch.window_items or 'all'} items, "
        f"fault seed {seed}",
        "",
        "| faults | re-plans | loss → new plan s (median / max) | loss → all acked s "
        "(median / max) | fields not done / lost | segments twice / never (of all) | exit "
        "| all started after s | dispatcher CPU s | RSS MB start → end "
        "| top-ups (items; waited at a window's end) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        f"| {len(faults)} ({fault_list}) "
        f"| {len(daemon.replans)} | {stat(plan_s)} | {stat(acked_s)} ({len(acked_s)} of "
        f"{len(daemon.replans)}) | {len(not_done)} / {len(lost)} "
        f"| {twice} / {never} ({segments}) | {code} "
        f"| {driving} | {cpu1 - cpu0:.0f} over "
        f"{took:.0f} s | {rss0:.0f} → {rss1:.0f} "
        f"| {len(daemon.topups)} ({sum(n for _, n in daemon.topups)}; {daemon.window_waits}) |",
        "",
        "Goals: loss → all acked < 3 s; fields lost 0 (not done, and in no working vehicle's "
        "route); segments twice 0. A kill or a stall hits every tractor of one simulator "
        "process; CPU and memory from when all have started.",
        "",
    ]
    return "\n".join(lines)
