"""`agrifleet demo`: the whole job on one machine, nothing to install.

Plans the scenario, starts the dispatcher (Zenoh peer listening on loopback), starts one
simulated tractor process per machine connected to it, shows live progress, and exits 0
when every field is done. Child processes are always stopped, also on failure or Ctrl-C.
"""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

from dispatcher.daemon.server import DaemonConfig, Dispatcher
from dispatcher.daemon.state import FleetState
from dispatcher.daemon.store import Store
from dispatcher.link import wire
from dispatcher.link.signals import stop_on_signals
from dispatcher.mission.plan import DispatchPlan

log = logging.getLogger(__name__)

# The demo farm ships with agrifleet (config/ in a checkout).
DEFAULT_SCENARIO = Path(str(files("agrifleet_config") / "changji.toml"))
TARGET_WALL_S = 45.0  # the default speedup fits the planned makespan into this


def free_port(preferred: int = 7447) -> int:
    """``preferred`` if nothing listens on it on loopback, else any free port."""
    for port in (preferred, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(s.getsockname()[1])
    raise RuntimeError("no free TCP port on 127.0.0.1")


def auto_speedup(dispatch: DispatchPlan, target_wall_s: float = TARGET_WALL_S) -> float:
    return max(1.0, dispatch.plan.makespan_h * 3600.0 / target_wall_s)


@dataclass
class Supervisor:
    """Child processes started together and always stopped together."""

    procs: list[subprocess.Popen[bytes]]

    @classmethod
    def start(cls, commands: Sequence[Sequence[str]], log_dir: Path) -> Supervisor:
        procs = []
        log_dir.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        try:
            for cmd in commands:
                out = open(log_dir / f"{Path(cmd[-1]).name}.log", "ab")  # noqa: SIM115
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
        return cls(procs)

    def failed(self) -> list[int]:
        return [p.returncode for p in self.procs if p.poll() not in (None, 0)]

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


def sim_command(scenario: Path, vehicle: str, endpoint: str, speedup: float) -> list[str]:
    return [
        sys.executable,
        "-m",
        "dispatcher.cli",
        "sim",
        str(scenario),
        "--connect",
        endpoint,
        "--speedup",
        f"{speedup:.3f}",
        "--vehicle",
        vehicle,
    ]


class ProgressPrinter:
    """Live progress per tractor: current field, share of its mission done, ETA (sim)."""

    def __init__(self, speedup: float, period_s: float = 3.0, stream=None) -> None:  # type: ignore[no-untyped-def]
        self.speedup = speedup
        self.period_s = period_s
        self.stream = stream or sys.stdout
        self._last = 0.0

    def __call__(self, state: FleetState) -> None:
        now = time.monotonic()
        if now - self._last < self.period_s:
            return
        self._last = now
        done = sum(f.status == "done" for f in state.fields.values())
        parts = []
        for v in state.vehicles.values():
            field = v.current_field or "-"
            parts.append(
                f"{v.id} {v.phase.value:<9} {field:<4} {100 * v.share_done:5.1f}% "
                f"eta {v.eta_s / 3600:5.2f} h"
            )
        print(
            f"[{done}/{len(state.fields)} fields] " + " | ".join(parts),
            file=self.stream,
            flush=True,
        )


def run_demo(
    scenario_path: Path,
    dispatch: DispatchPlan,
    speedup: float | None,
    log_dir: Path,
    heartbeat_timeout_s: float = 10.0,
) -> tuple[int, Dispatcher]:
    """Run the demo; returns the exit code and the finished dispatcher (for the summary)."""
    speed = speedup or auto_speedup(dispatch)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    print(
        f"plan {dispatch.plan_id}: {len(dispatch.missions)} tractors, "
        f"{len(dispatch.plan.farm.fields)} fields, planned makespan "
        f"{dispatch.plan.makespan_h:.2f} h; simulating at {speed:.0f}x on {endpoint}",
        flush=True,
    )
    # The demo keeps its state beside its logs, and always starts a new run.
    store = Store.open(log_dir, dispatch.document.farm_id)
    store.abandon_unfinished()
    job = dispatch.job()
    store.begin_run(job, fingerprint="demo")
    config = DaemonConfig(
        job=job,
        store=store,
        zenoh=wire.dispatcher_options((endpoint,)),
        log_dir=log_dir,
        heartbeat_timeout_s=heartbeat_timeout_s,
        on_progress=ProgressPrinter(speed),
    )
    daemon = Dispatcher(config)
    children: Supervisor | None = None
    printer = config.on_progress

    def progress(state: FleetState) -> None:
        if children is not None and children.failed():
            print(f"a simulated tractor exited early; see {log_dir / 'sim'}", file=sys.stderr)
            daemon.should_exit.set()
        if printer is not None:
            printer(state)

    config.on_progress = progress
    restore_signals = stop_on_signals(daemon.should_exit, "stopping the demo")
    try:
        daemon.startup()
        children = Supervisor.start(
            [sim_command(scenario_path, vid, endpoint, speed) for vid in dispatch.missions],
            log_dir / "sim",
        )
        code = daemon.main_loop()
    finally:
        if children is not None:
            children.stop()
        daemon.shutdown()
        store.close()
        restore_signals()
    return code, daemon


def summary(daemon: Dispatcher) -> str:
    state = daemon.state
    lines = ["", "summary:"]
    for v in state.vehicles.values():
        lines.append(
            f"  {v.id}: {v.phase.value}, fields {' '.join(v.fields_done) or '-'}, "
            f"{'finished after ' if v.finished_s is not None else ''}"
            f"{(v.finished_s if v.finished_s is not None else v.sim_time_s) / 3600:.2f} h "
            f"(planned {v.planned_s[-1] / 3600:.2f} h), upload retries {v.upload_retries}"
            + (f", {v.error}" if v.error else "")
        )
    done = sum(f.status == "done" for f in state.fields.values())
    lines.append(f"  fields done: {done}/{len(state.fields)}")
    if daemon.upload_started is not None and daemon.all_acknowledged is not None:
        lines.append(
            f"  every mission acknowledged {daemon.all_acknowledged - daemon.upload_started:.2f} s "
            "after the first upload began"
        )
    return "\n".join(lines)
