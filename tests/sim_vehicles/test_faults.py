"""Fault injection in the simulator process: the stall signal, the stall in the serve loop,
and the ``--stall-after`` / ``--fail-after`` arguments."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Sequence
from pathlib import Path

import pytest

from dispatcher.config.scenario import Vehicle
from dispatcher.link import mavlink as mc
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
    ],
)
def test_bad_fault_arguments_exit_2_naming_the_flag(
    args: list[str], message: str, caplog: pytest.LogCaptureFixture
) -> None:
    assert main([str(SCENARIO), *args]) == EXIT_BAD_INPUT
    assert message in caplog.text
