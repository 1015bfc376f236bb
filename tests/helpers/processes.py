"""agrifleet processes a test starts (``python -m dispatcher.cli ...`` or ``python -m
sim_vehicles ...``), each with its output in a file, all stopped at the end; free ports,
waiting on a condition, the dispatcher's status and its log path."""

from __future__ import annotations

import atexit
import contextlib
import functools
import json
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import zenoh

from dispatcher.link import wire
from dispatcher.mission.document import PlanDocument, PlannedItem

if TYPE_CHECKING:
    from helpers.sitl import Sitl


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(
    what: str,
    predicate: Callable[[], bool],
    timeout_s: float,
    explain: Callable[[], str] | None = None,
) -> None:
    """Poll ``predicate`` until it holds; on time-out fail with ``explain()`` (what the
    processes said) in the message."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    why = f"\n{explain()}" if explain is not None else ""
    raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}{why}")


def keys_for(scenario: Path, folder: Path | None = None) -> str:
    """MAVLink signing keys for the fleet of ``scenario`` in ``folder`` (default: one
    folder for the whole test session), made as `agrifleet keys` makes them, once: every
    process a test starts signs with them, as on a farm."""
    from dispatcher.config.scenario import load_scenario
    from dispatcher.link.keys import write_keys

    if folder is None:
        folder = _session_keys()
    write_keys(folder, [v.id for v in load_scenario(scenario).vehicles])
    return str(folder)


@functools.cache
def _session_keys() -> Path:
    folder = Path(tempfile.mkdtemp(prefix="agrifleet-test-keys-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)  # removed with the session
    return folder / "keys"


class Processes:
    """agrifleet processes a test starts (``python -m dispatcher.cli ...``); all stopped
    at the end."""

    def __init__(self, workdir: Path) -> None:
        self.workdir = workdir
        self.procs: list[subprocess.Popen[str]] = []

    def keys(self, scenario: Path) -> str:
        """The test's MAVLink signing keys for the fleet of ``scenario``."""
        return keys_for(scenario, self.workdir / "keys")

    def start(self, name: str, *args: str, module: str = "dispatcher.cli") -> subprocess.Popen[str]:
        out = open(self.workdir / f"{name}-{len(self.procs)}.out", "w")  # noqa: SIM115
        proc = subprocess.Popen(
            [sys.executable, "-m", module, *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
        )
        out.close()
        proc.output_path = out.name  # type: ignore[attr-defined]
        self.procs.append(proc)
        return proc

    def serve(
        self,
        scenario: Path,
        port: int,
        log_dir: Path,
        *extra: str,
        endpoint: Sequence[str] | None = None,
    ) -> subprocess.Popen[str]:
        """``agrifleet serve`` listening on loopback ``port`` (or with the ``endpoint``
        options given instead: a router's client, a TLS listener)."""
        return self.start(
            "serve",
            "serve",
            str(scenario),
            *(endpoint if endpoint is not None else ("--listen", f"tcp/127.0.0.1:{port}")),
            "--log-dir",
            str(log_dir),
            "--keys",
            self.keys(scenario),
            *extra,
        )

    def bridge(
        self, scenario: Path, vehicle: str, sitl: Sitl, port: int, *extra: str
    ) -> subprocess.Popen[str]:
        return self.start(
            "bridge",
            "bridge",
            str(scenario),
            "--vehicle",
            vehicle,
            "--mavlink",
            sitl.url,
            "--connect",
            f"tcp/127.0.0.1:{port}",
            "--keys",
            self.keys(scenario),
            *extra,
        )

    def sim(
        self,
        scenario: Path,
        port: int,
        speedup: float,
        *vehicles: str,
        extra: tuple[str, ...] = (),
        scheme: str = "tcp",
    ) -> subprocess.Popen[str]:
        """Simulated tractors (``python -m sim_vehicles``) connected to the dispatcher
        (``scheme`` "tls" with ``--tls DIR`` in ``extra``)."""
        args = [str(scenario), "--connect", f"{scheme}/127.0.0.1:{port}"]
        args += ["--speedup", f"{speedup:g}"]
        args += ["--keys", self.keys(scenario)]
        for v in vehicles:
            args += ["--vehicle", v]
        return self.start("sim", *args, *extra, module="sim_vehicles")

    @staticmethod
    def output(proc: subprocess.Popen[str]) -> str:
        return Path(proc.output_path).read_text()  # type: ignore[attr-defined]

    def report(self, sitl: Sitl | None = None, chars: int = 2500) -> str:
        """The end of every process's output (and the autopilot's), for a failed test."""
        parts = []
        for p in self.procs:
            state = "running" if p.poll() is None else f"exit {p.returncode}"
            name = " ".join(str(a) for a in list(p.args)[2:4])  # type: ignore[arg-type]
            parts.append(f"--- {name} ({state}) ---\n{self.output(p)[-chars:]}")
        if sitl is not None:
            for out in sorted(sitl.workdir.glob("sitl-*.out")):
                parts.append(f"--- {out.name} ---\n{out.read_text(errors='replace')[-chars:]}")
        return "\n".join(parts)

    def stop_all(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def log_of(output: str) -> Path:
    lines = [ln for ln in output.splitlines() if ln.startswith("log: ")]
    assert lines, output[-3000:]
    return Path(lines[-1][5:])


@contextlib.contextmanager
def status_reader(port: int, farm: str) -> Iterator[Callable[[], dict]]:
    """A function that asks the dispatcher's status queryable (``{}`` until it answers)."""
    conf = wire.client_options((f"tcp/127.0.0.1:{port}",)).config()
    with zenoh.open(conf) as session:
        yield status_asker(session, farm)


def planned_items(port: int, farm: str, vehicle: str) -> tuple[PlannedItem, ...]:
    """``vehicle``'s mission items in the dispatcher's current plan (its plan queryable)."""
    conf = wire.client_options((f"tcp/127.0.0.1:{port}",)).config()
    with zenoh.open(conf) as session:
        for reply in session.get(wire.dispatcher_plan(farm), timeout=5.0):
            if reply.ok is not None:
                doc = PlanDocument.from_json(reply.ok.payload.to_bytes())
                return next(m.items for m in doc.machines if m.id == vehicle)
    raise AssertionError(f"no plan of {farm} from the dispatcher on port {port}")


def status_asker(session: zenoh.Session, farm: str) -> Callable[[], dict]:
    """A function that asks the dispatcher's status queryable through ``session`` (``{}``
    until it answers)."""

    def ask() -> dict:
        for reply in session.get(wire.dispatcher_status(farm), timeout=2.0):
            if reply.ok is not None:
                doc = json.loads(reply.ok.payload.to_string())
                if doc:
                    return dict(doc)
        return {}

    return ask


def wait_for_share(
    status: Callable[[], dict],
    vehicles: Sequence[str],
    share: float,
    timeout_s: float,
    explain: Callable[[], str] | None = None,
) -> None:
    """Wait until every one of ``vehicles`` has done ``share`` of its mission (the
    dispatcher's status, ``status_reader``)."""
    seen: dict = {}

    def there() -> bool:
        seen.update(status().get("vehicles", {}))
        return all(seen.get(v, {}).get("share_done", 0.0) >= share for v in vehicles)

    wait_for(f"{', '.join(vehicles)} at {100 * share:g} %", there, timeout_s, explain)
