"""ArduPilot Rover SITL, the dispatcher and the bridge as real processes, for the tests
against the real autopilot (tests/test_sitl.py) and the SITL benchmark.

The autopilot binary is looked up in ``$AGRIFLEET_ARDUROVER``, else in
``../shared/sitl/ardurover`` beside the repository; :func:`find_ardurover` returns None
when there is none, and the tests skip with that reason. Every process listens on
loopback only: SITL instance ``K`` takes TCP ports 5760 + 10 K (SERIAL0, where the bridge
connects) and 5762 + 10 K (SERIAL1, a second MAVLink port the tests use to change a
parameter); the dispatcher listens for Zenoh on a free port with multicast scouting off.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from helpers.processes import Processes, free_port, log_of, status_reader, wait_for

__all__ = [
    "ARDUROVER",
    "Processes",
    "Sitl",
    "find_ardurover",
    "free_port",
    "log_of",
    "needs_ardurover",
    "status_reader",
    "wait_for",
]

REPO = Path(__file__).resolve().parents[2]
SITL_ENV = "AGRIFLEET_ARDUROVER"
SHARED_SITL = REPO.parent / "shared" / "sitl"
HOME = (44.0003, 87.2995)  # the SITL farm's garage (tests/data/sitl-farm.geojson)

# What docs/bridge.md asks an ArduPilot Rover for, under this firmware's parameter names,
# plus what the test farm's machine needs (tests/data/sitl.toml).
PARAMS: dict[str, float] = {
    "MAV_SYSID": 1,
    "MAV_GCS_SYSID": 255,
    "MAV1_POSITION": 10,
    "MAV1_EXT_STAT": 2,
    "MAV1_EXTRA3": 1,
    "WP_RADIUS": 1.0,
    "WP_SPEED": 3.33,
    "CRUISE_SPEED": 3.33,
    "TURN_RADIUS": 3.0,
    "FS_GCS_ENABLE": 1,  # the dispatcher sends a ground-station HEARTBEAT at 1 Hz
    "SERVO9_FUNCTION": 0,
}


def find_ardurover() -> Path | None:
    """The ArduPilot Rover SITL binary, or None."""
    named = os.environ.get(SITL_ENV)
    for candidate in ([Path(named)] if named else []) + [SHARED_SITL / "ardurover"]:
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    return None


ARDUROVER = find_ardurover()
needs_ardurover = pytest.mark.skipif(
    ARDUROVER is None,
    reason=f"no ArduPilot Rover SITL binary: set {SITL_ENV} or put it at {SHARED_SITL}/ardurover",
)
"""The mark of a test module that runs ArduPilot SITL (``pytestmark = needs_ardurover``)."""


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


FIRST_INSTANCE = 20
WORKER_BLOCK = 50
"""Instance numbers each pytest-xdist worker searches (gwN from FIRST_INSTANCE + N times
this): two workers starting SITL at the same moment both found instance 20 free, and the
second SITL could not take its ports."""


def free_instance() -> int:
    """A SITL instance number whose TCP ports (5760..5763 + 10 K) are free, in this test
    worker's own block."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    first = FIRST_INSTANCE + WORKER_BLOCK * (int(worker) if worker.isdigit() else 0)
    for k in range(first, first + WORKER_BLOCK):
        if all(_port_free(5760 + 10 * k + d) for d in range(4)):
            return k
    raise RuntimeError("no free SITL instance number")


@dataclass
class Sitl:
    """One ArduPilot Rover SITL process, its eeprom in ``workdir``."""

    binary: Path
    workdir: Path
    speedup: float = 10.0
    instance: int = field(default_factory=free_instance)
    params: Mapping[str, float] = field(default_factory=lambda: dict(PARAMS))
    proc: subprocess.Popen[bytes] | None = None
    starts: int = 0

    @property
    def port(self) -> int:
        return 5760 + 10 * self.instance

    @property
    def url(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def start(
        self, *, wipe: bool = False, home: tuple[float, float] | None = None, heading: float = 0
    ) -> None:
        """Start (or restart, on the same eeprom) the autopilot; it finishes booting once
        the bridge connects to SERIAL0."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        extra = self.workdir / "agrifleet-test.parm"
        # The dispatcher's ground-station heartbeat comes once a wall second, that is every
        # `speedup` seconds of the autopilot's time: the GCS failsafe's timeout (5 s on a
        # tractor) is stretched by the same factor.
        params = {"FS_GCS_TIMEOUT": min(5.0 * self.speedup, 120.0), **self.params}
        extra.write_text("".join(f"{k} {v:g}\n" for k, v in params.items()))
        lat, lon = home or HOME
        args = [
            str(self.binary),
            "--model",
            "rover",
            "--speedup",
            f"{self.speedup:g}",
            "--defaults",
            f"{self.binary.parent / 'rover.parm'},{extra}",
            "--home",
            f"{lat:.7f},{lon:.7f},500,{heading:.0f}",
            "-I",
            str(self.instance),
        ]
        if wipe:
            args.append("--wipe")
        self.starts += 1
        log = open(self.workdir / f"sitl-{self.starts}.out", "wb")  # noqa: SIM115
        self.proc = subprocess.Popen(
            args, cwd=self.workdir, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL
        )
        log.close()
        wait_for(f"SITL on port {self.port}", lambda: not _port_free(self.port), 20.0)

    def freeze(self) -> None:
        """SIGSTOP: the autopilot stops where it is (until killed or continued)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGSTOP)

    def kill(self) -> None:
        """kill -9: the autopilot dies as on a power cut (its eeprom stays)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)

    def set_param(
        self, name: str, value: float, timeout_s: float = 20.0, key: bytes | None = None
    ) -> None:
        """Set a parameter over SERIAL1, as a second ground station would (its frames
        signed with ``key``, if given)."""
        from pymavlink import mavutil

        link = mavutil.mavlink_connection(
            f"tcp:127.0.0.1:{self.port + 2}", source_system=254, source_component=190
        )
        if key is not None:
            link.setup_signing(key, sign_outgoing=True)
        try:
            deadline = time.monotonic() + timeout_s
            link.wait_heartbeat(timeout=timeout_s)
            while time.monotonic() < deadline:
                link.mav.param_set_send(
                    link.target_system,
                    1,
                    name.encode(),
                    float(value),
                    mavutil.mavlink.MAV_PARAM_TYPE_REAL32,
                )
                msg = link.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
                if msg is not None and msg.param_id == name and abs(msg.param_value - value) < 1e-3:
                    return
            raise AssertionError(f"SITL did not confirm {name} = {value}")
        finally:
            link.close()
