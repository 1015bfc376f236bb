"""Fault injection in the simulator process: the stall signal, the stall in the serve loop,
and the ``--stall-after`` / ``--fail-after`` / ``--deaf-until`` arguments."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

import pytest
import zenoh

from dispatcher.config.scenario import Vehicle
from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from sim_vehicles.__main__ import EXIT_BAD_INPUT, main, parse_fail_after
from sim_vehicles.runner import serve_vehicles, stall_on_signal
from sim_vehicles.tractor import SimTractor

SCENARIO = Path(__file__).resolve().parents[1] / "data" / "tiny.toml"


def test_sigusr1_sets_the_stall_flag_and_the_old_handler_comes_back() -> None:
    before = signal.getsignal(signal.SIGUSR1)
    stall = threading.Event()
    restore = stall_on_signal(stall)
    try:
        os.kill(os.getpid(), signal.SIGUSR1)
        assert stall.wait(5.0)
    finally:
        restore()
    assert signal.getsignal(signal.SIGUSR1) == before


def test_stall_signal_off_the_main_thread_does_nothing() -> None:
    results: list[object] = []

    def install() -> None:
        restore = stall_on_signal(threading.Event())
        results.append(signal.getsignal(signal.SIGUSR1))
        restore()

    before = signal.getsignal(signal.SIGUSR1)
    worker = threading.Thread(target=install)
    worker.start()
    worker.join()
    assert results == [before]


class _Link:
    def __init__(self, tractor: SimTractor) -> None:
        self.tractor = tractor
        self.sent: list[mc.MAVLinkMessage] = []

    def send(self, messages: Sequence[mc.MAVLinkMessage]) -> None:
        self.sent += messages


def test_the_serve_loop_stalls_every_vehicle_once_the_flag_is_set(
    vehicle: Vehicle, home_lonlat: tuple[float, float]
) -> None:
    links = [_Link(SimTractor(vehicle, home_lonlat)) for _ in range(2)]
    stop, stall = threading.Event(), threading.Event()
    calls = 0

    def receive(timeout_s: float) -> list[tuple[int, mc.MAVLinkMessage]]:
        nonlocal calls
        calls += 1
        if calls == 3:
            assert not any(link.tractor.stalled for link in links)
            stall.set()
        if calls == 6:
            stop.set()
        return []

    serve_vehicles(links, receive, stop, speedup=1.0, telemetry_hz=10.0, stall=stall)
    assert all(link.tractor.stalled for link in links)
    assert all(any(m.get_type() == "HEARTBEAT" for m in link.sent) for link in links)


def test_stall_after_is_parsed_and_checked_like_fail_after() -> None:
    assert parse_fail_after(["v1:12.5", "v2:0"], "--stall-after") == {"v1": 12.5, "v2": 0.0}
    for bad in ("v1", "v1:-3", ":5", "v1:soon"):
        with pytest.raises(ValueError, match=f"--stall-after wants ID:SECONDS.*{bad}"):
            parse_fail_after([bad], "--stall-after")


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--vehicle", "v1", "--stall-after", "v2:10"], "--stall-after names v2"),
        (["--vehicle", "v1", "--stall-after", "v1:x"], "--stall-after wants ID:SECONDS"),
        (["--vehicle", "v1", "--fail-after", "v2:10"], "--fail-after names v2"),
        (
            ["--vehicle", "v1", "--stall-after", "v1:10", "--mavlink", "tcpin:127.0.0.1:5760"],
            "--stall-after works on Zenoh only",
        ),
        (["--vehicle", "v1", "--deaf-until", "v2:10"], "--deaf-until names v2"),
        (["--vehicle", "v1", "--deaf-until", "v1"], "--deaf-until wants ID:SECONDS"),
        # An infinite speed-up overflowed a clock (a traceback), one tractor twice ran two
        # sessions of one system id (review).
        (["--vehicle", "v1", "--speedup", "inf"], "must be finite and > 0, not inf"),
        (["--vehicle", "v1", "--vehicle", "v1"], "--vehicle v1 given more than once"),
        (
            ["--vehicle", "v1", "--deaf-until", "v1:10", "--mavlink", "tcpin:127.0.0.1:5760"],
            "--deaf-until works on Zenoh only",
        ),
    ],
)
def test_bad_fault_arguments_exit_2_naming_the_flag(
    args: list[str], message: str, caplog: pytest.LogCaptureFixture
) -> None:
    assert main([str(SCENARIO), *args]) == EXIT_BAD_INPUT
    assert message in caplog.text


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_sigusr1_stalls_a_simulator_process_which_keeps_reporting() -> None:
    """The signal the demo sends for ``--stall``: the process lives on, heartbeats go on."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    beats = threading.Semaphore(0)
    codec = mc.Codec(wire.DISPATCHER_SYSTEM_ID, wire.DISPATCHER_COMPONENT_ID)

    def on_frame(sample: zenoh.Sample) -> None:
        msg = codec.decode_one(sample.payload.to_bytes())
        if msg is not None and msg.get_type() == "HEARTBEAT":
            beats.release()

    with zenoh.open(wire.ZenohOptions(mode="peer", listen=(endpoint,)).config()) as session:
        frames = session.declare_subscriber(wire.vehicle_from("tiny", "v1"), on_frame)
        proc = subprocess.Popen(
            [sys.executable, "-m", "sim_vehicles", str(SCENARIO), "--vehicle", "v1"]
            + ["--connect", endpoint, "--speedup", "20", "--unsigned"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
        )
        try:
            assert beats.acquire(timeout=20), "no heartbeat from the simulator"
            proc.send_signal(signal.SIGUSR1)
            for _ in range(2):  # heartbeats go on after the stall
                assert beats.acquire(timeout=5), "heartbeats stopped after SIGUSR1"
            assert proc.poll() is None
            proc.send_signal(signal.SIGTERM)
            output, _ = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
            frames.undeclare()
    assert proc.returncode == 0, output
    assert "stalled at t=" in output
