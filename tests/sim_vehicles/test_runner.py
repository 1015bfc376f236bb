"""The runner in-process: a test Zenoh peer listens on a free loopback port, the runner
connects to it from a thread; everything waits on conditions, never on fixed sleeps."""

from __future__ import annotations

import contextlib
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import load_scenario
from dispatcher.link import mavlink as mc
from dispatcher.link import wire as contract
from sim_vehicles.runner import run

SCENARIO = Path(__file__).resolve().parents[2] / "config" / "changji.toml"
TIMEOUT_S = 10.0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


class Inbox:
    """What the test peer hears, with a condition to wait on."""

    def __init__(self) -> None:
        self.cond = threading.Condition()
        self.messages: list[mc.MAVLinkMessage] = []
        self.tokens: list[tuple[str, zenoh.SampleKind]] = []
        self._codec = mc.Codec(contract.DISPATCHER_SYSTEM_ID, contract.DISPATCHER_COMPONENT_ID)

    def on_frame(self, sample: zenoh.Sample) -> None:
        msg = self._codec.decode_one(sample.payload.to_bytes())
        if msg is not None:
            with self.cond:
                self.messages.append(msg)
                self.cond.notify_all()

    def on_token(self, sample: zenoh.Sample) -> None:
        with self.cond:
            self.tokens.append((str(sample.key_expr), sample.kind))
            self.cond.notify_all()

    def wait(self, what: str, predicate: Callable[[], bool]) -> None:
        with self.cond:
            assert self.cond.wait_for(predicate, TIMEOUT_S), f"timed out waiting for {what}"

    def first(self, kind: str, **fields: int) -> mc.MAVLinkMessage | None:
        for m in self.messages:
            if m.get_type() == kind and all(getattr(m, k) == v for k, v in fields.items()):
                return m
        return None

    def count_from(self, system_id: int, kind: str | None = None) -> int:
        return sum(
            1
            for m in self.messages
            if m.get_srcSystem() == system_id and (kind is None or m.get_type() == kind)
        )


def test_runner_lives_on_zenoh_and_serves_an_upload() -> None:
    """t1 is served; t2 breaks down at once (fault injection): token, but no messages."""
    scenario = load_scenario(SCENARIO)
    vehicle, broken = scenario.vehicle("t1"), scenario.vehicle("t2")
    farm = scenario.farm_id
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    inbox = Inbox()
    stop = threading.Event()
    codes: list[int] = []
    alive_key = contract.vehicle_alive(farm, vehicle.id)
    broken_key = contract.vehicle_alive(farm, broken.id)

    test_side = contract.ZenohOptions(mode="peer", listen=(endpoint,))
    with zenoh.open(test_side.config()) as session:
        tokens = session.liveliness().declare_subscriber(
            contract.vehicle_alive(farm, "*"), inbox.on_token
        )
        frames = session.declare_subscriber(contract.vehicle_from(farm, "*"), inbox.on_frame)
        to_vehicle = session.declare_publisher(contract.vehicle_to(farm, vehicle.id))
        sim = threading.Thread(
            target=lambda: codes.append(
                run(
                    scenario,
                    [vehicle.id, broken.id],
                    contract.ZenohOptions(mode="peer", connect=(endpoint,)),
                    speedup=50.0,
                    telemetry_hz=20.0,
                    stop=stop,
                    fail_after={broken.id: 0.0},
                )
            ),
            name="sim-runner",
        )
        sim.start()
        try:
            inbox.wait(
                "the liveliness tokens",
                lambda: all(
                    (key, zenoh.SampleKind.PUT) in inbox.tokens for key in (alive_key, broken_key)
                ),
            )
            inbox.wait(
                "two heartbeats", lambda: inbox.count_from(vehicle.system_id, "HEARTBEAT") >= 2
            )
            assert inbox.count_from(broken.system_id) == 0
            hb = inbox.first("HEARTBEAT")
            assert hb is not None
            assert (hb.get_srcSystem(), hb.get_srcComponent()) == (
                vehicle.system_id,
                mc.MAV_COMP_ID_AUTOPILOT1,
            )
            assert (hb.type, hb.autopilot) == (
                mc.MAV_TYPE_GROUND_ROVER,
                mc.MAV_AUTOPILOT_ARDUPILOTMEGA,
            )
            inbox.wait("a position", lambda: inbox.first("GLOBAL_POSITION_INT") is not None)

            gcs = mc.Codec(contract.DISPATCHER_SYSTEM_ID, contract.DISPATCHER_COMPONENT_ID)
            items = three_items(vehicle.system_id, scenario.farm.garage_lonlat)
            to_vehicle.put(
                gcs.encode(
                    mc.message(
                        "MISSION_COUNT",
                        target_system=vehicle.system_id,
                        target_component=mc.MAV_COMP_ID_AUTOPILOT1,
                        count=len(items),
                        mission_type=mc.MAV_MISSION_TYPE_MISSION,
                    )
                )
            )
            for seq, item in enumerate(items):
                inbox.wait(f"the request for item {seq}", requested(inbox, seq))
                to_vehicle.put(gcs.encode(item))
            inbox.wait("the mission ack", lambda: inbox.first("MISSION_ACK") is not None)
            ack = inbox.first("MISSION_ACK")
            assert ack is not None and ack.type == mc.MAV_MISSION_ACCEPTED
            assert (ack.target_system, ack.target_component) == (
                contract.DISPATCHER_SYSTEM_ID,
                contract.DISPATCHER_COMPONENT_ID,
            )
        finally:
            stop.set()
            sim.join(TIMEOUT_S)
        assert not sim.is_alive()
        assert codes == [0]
        inbox.wait(
            "the tokens to go",
            lambda: all(
                (key, zenoh.SampleKind.DELETE) in inbox.tokens for key in (alive_key, broken_key)
            ),
        )
        assert inbox.count_from(broken.system_id) == 0
        tokens.undeclare()
        frames.undeclare()
        to_vehicle.undeclare()


def requested(inbox: Inbox, seq: int) -> Callable[[], bool]:
    """Whether the vehicle has asked for item ``seq`` (ArduPilot's MISSION_REQUEST, or INT)."""
    return lambda: any(
        m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT") and m.seq == seq
        for m in inbox.messages
    )


def three_items(system_id: int, garage_lonlat: tuple[float, float]) -> list[mc.MAVLinkMessage]:
    """Home, a speed, one waypoint 100 m north of the garage."""
    lon, lat = garage_lonlat

    def item(
        seq: int, command: int, frame: int, p2: float = 0.0, x: int = 0, y: int = 0
    ) -> mc.MAVLinkMessage:
        return mc.mission_item_int(
            target_system=system_id,
            target_component=mc.MAV_COMP_ID_AUTOPILOT1,
            seq=seq,
            frame=frame,
            command=command,
            current=0,
            autocontinue=1,
            param1=0.0,
            param2=p2,
            param3=0.0,
            param4=0.0,
            x=x,
            y=y,
            z=0.0,
        )

    return [
        item(
            0, mc.MAV_CMD_NAV_WAYPOINT, mc.MAV_FRAME_GLOBAL, x=round(lat * 1e7), y=round(lon * 1e7)
        ),
        item(1, mc.MAV_CMD_DO_CHANGE_SPEED, mc.MAV_FRAME_MISSION, p2=2.0),
        item(
            2,
            mc.MAV_CMD_NAV_WAYPOINT,
            mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            x=round((lat + 0.0009) * 1e7),
            y=round(lon * 1e7),
        ),
    ]


def test_unknown_vehicle_is_refused() -> None:
    scenario = load_scenario(SCENARIO)
    with pytest.raises(ConfigError, match="unknown machine 'nope'"):
        run(scenario, ["nope"], contract.ZenohOptions(), stop=threading.Event())


def test_command_line_process_stops_cleanly_on_sigterm() -> None:
    scenario = load_scenario(SCENARIO)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    alive_key = contract.vehicle_alive(scenario.farm_id, "t2")
    inbox = Inbox()
    with zenoh.open(contract.ZenohOptions(mode="peer", listen=(endpoint,)).config()) as session:
        tokens = session.liveliness().declare_subscriber(alive_key, inbox.on_token)
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "sim_vehicles",
                str(SCENARIO),
                "--vehicle",
                "t2",
                "--connect",
                endpoint,
                "--speedup",
                "20",
                "--unsigned",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        try:
            inbox.wait(
                "the process's token", lambda: (alive_key, zenoh.SampleKind.PUT) in inbox.tokens
            )
            proc.send_signal(signal.SIGTERM)
            output, _ = proc.communicate(timeout=TIMEOUT_S)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert proc.returncode == 0, output
        assert "simulator stopped" in output
        inbox.wait("the token to go", lambda: (alive_key, zenoh.SampleKind.DELETE) in inbox.tokens)
        tokens.undeclare()


def test_a_simulator_started_with_exit_with_parent_ends_when_its_parent_is_killed():
    """A demo killed with -9 left its simulators running, connected to its port (the next
    demo there could hear them: an outside review). ``--exit-with-parent`` (the demo's) ends
    one with its parent, however that ends."""
    import os
    import time

    if not sys.platform.startswith("linux"):
        pytest.skip("PR_SET_PDEATHSIG is Linux's")
    port = free_port()
    sim = [
        sys.executable, "-m", "sim_vehicles", str(SCENARIO), "--vehicle", "t1",
        "--listen", f"tcp/127.0.0.1:{port}", "--unsigned",
    ]  # fmt: skip
    parent = subprocess.Popen(
        [sys.executable, "-c", "import os, subprocess, sys, time; "
         f"p = subprocess.Popen({sim!r} + ['--exit-with-parent', str(os.getpid())]); "
         "print(p.pid, flush=True); time.sleep(120)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())

        def running() -> bool:
            try:
                return "Z" not in Path(f"/proc/{child}/stat").read_text().split()[2]
            except FileNotFoundError:
                return False

        def listening() -> bool:
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", port)) == 0

        deadline = time.monotonic() + 3 * TIMEOUT_S
        while time.monotonic() < deadline and running() and not listening():
            time.sleep(0.1)
        assert running() and listening()  # up: its parent may go now
        parent.kill()  # SIGKILL: nothing of the parent's own runs
        parent.wait()
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline and running():
            time.sleep(0.1)
        assert not running(), "the simulator outlived its parent"
    finally:
        parent.kill()
        parent.wait()
        if parent.stdout is not None:
            parent.stdout.close()
        with contextlib.suppress(ProcessLookupError, UnboundLocalError):
            os.kill(child, signal.SIGKILL)
