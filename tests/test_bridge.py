"""The bridge between a MAVLink autopilot and Zenoh, and the simulated tractor's MAVLink port.

Unit tests drive the filter, the rate limiter and the heartbeat presence with a made-up
clock. Process tests run on loopback with free ports, multicast scouting off: our simulated
tractor listening on a MAVLink TCP port as SITL does, ``python -m dispatcher.tools.bridge`` and
either the dispatcher or a test Zenoh peer. They wait on conditions and always stop what
they started.
"""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
from helpers import messages
from helpers.mavlink_wire import Wire
from helpers.messages import from_vehicle
from helpers.processes import keys_for

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import load_scenario
from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.recording.mcap_file import read_log
from dispatcher.tools.bridge import (
    DEFAULT_RATE_LIMITS,
    AutopilotFilter,
    HeartbeatPresence,
    _Bridge,
    parse_rates,
    run_bridge,
)
from sim_vehicles.__main__ import main as sim_main
from sim_vehicles.mavlink_port import run_mavlink

SCENARIO = Path(__file__).parent / "data" / "tiny.toml"
SYSTEM = 11  # v1 in tiny.toml
TIMEOUT_S = 15.0


def free_port(kind: socket.SocketKind = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


# --- unit: what goes to the dispatcher ----------------------------------------------------
def vehicle_msg(name: str, system: int = SYSTEM, component: int = 1, **fields: object):
    """A message as if received from (system, component)."""
    return mc.Codec(system, component).decode_one(
        mc.Codec(system, component).encode(mc.message(name, **fields))
    )


def position(t_ms: int = 0):
    return from_vehicle(messages.position(t_ms), SYSTEM)


def mission_current(seq: int):
    return vehicle_msg("MISSION_CURRENT", seq=seq, total=10, mission_state=3, mission_mode=1)


def reached(seq: int):
    return vehicle_msg("MISSION_ITEM_REACHED", seq=seq)


def request(seq: int):
    return vehicle_msg(
        "MISSION_REQUEST", target_system=255, target_component=190, seq=seq, mission_type=0
    )


def passed(flt: AutopilotFilter, make: Callable[[int], object], hz: float, seconds: float) -> int:
    """How many of ``hz * seconds`` messages, evenly spaced, the filter lets through."""
    n = round(hz * seconds)
    return sum(flt.admit(make(i), i / hz) for i in range(n))


def test_filter_keeps_the_autopilots_own_messages_of_the_forwarded_types() -> None:
    flt = AutopilotFilter(SYSTEM)
    assert flt.admit(request(0), 0.0)
    assert not flt.admit(vehicle_msg("MISSION_ITEM_REACHED", system=12, seq=1), 0.0)
    assert not flt.admit(vehicle_msg("MISSION_ITEM_REACHED", component=154, seq=1), 0.0)
    attitude = vehicle_msg(
        "ATTITUDE", time_boot_ms=0, roll=0, pitch=0, yaw=0, rollspeed=0, pitchspeed=0, yawspeed=0
    )
    assert not flt.admit(attitude, 0.0)
    assert flt.counts == {"forwarded": 1, "other_source": 2, "other_type": 1}


def test_telemetry_is_bounded_but_the_protocol_and_progress_never_are() -> None:
    flt = AutopilotFilter(SYSTEM)
    # 50 Hz positions for 10 s: 10 Hz pass (plus the burst of 2 at the start).
    assert passed(flt, position, 50.0, 10.0) in range(99, 104)
    # 10 Hz positions with jitter all pass: the bucket absorbs it.
    flt = AutopilotFilter(SYSTEM)
    times = [i / 10.0 + (0.03 if i % 2 else -0.03) for i in range(1, 100)]
    assert all(flt.admit(position(i), t) for i, t in enumerate(times))
    # A burst of 1000 protocol messages in one millisecond: every one passes.
    assert passed(flt, request, 1e6, 1e-3) == 1000
    assert passed(flt, reached, 1e6, 1e-3) == 1000


def test_a_changed_mission_current_always_passes() -> None:
    flt = AutopilotFilter(SYSTEM)
    same = [flt.admit(mission_current(3), i / 100.0) for i in range(100)]  # 100 Hz, 1 s
    assert sum(same) <= DEFAULT_RATE_LIMITS["MISSION_CURRENT"] + 2
    changes = [flt.admit(mission_current(seq), 1.0 + seq / 1000.0) for seq in range(4, 40)]
    assert all(changes)


def test_rate_limits_are_checked() -> None:
    assert parse_rates(["global_position_int=5"])["GLOBAL_POSITION_INT"] == 5.0
    assert parse_rates(["VFR_HUD=1"])["VFR_HUD"] == 1.0  # forwards one more type
    for bad, match in [
        ("MISSION_ACK=1", "never rate-limited"),
        ("NOT_A_MESSAGE=1", "not a MAVLink message"),
        ("GLOBAL_POSITION_INT=0", "rate > 0"),
        ("GLOBAL_POSITION_INT", "rate > 0"),
    ]:
        with pytest.raises(ConfigError, match=match):
            parse_rates([bad])


def test_presence_follows_the_heartbeat() -> None:
    presence = HeartbeatPresence(timeout_s=3.0)
    assert not presence.present(0.0)
    presence.on_heartbeat(1.0)
    assert presence.present(1.0) and presence.present(4.0)
    assert not presence.present(4.1)
    presence.on_heartbeat(10.0)
    assert presence.present(10.5)


def test_mavlink1_frames_are_packed_again_as_mavlink2_with_their_ids_and_sequence() -> None:
    mav = mc.mavlink2.MAVLink(None, srcSystem=SYSTEM, srcComponent=1)
    mav.seq = 42
    v1 = mc.message("MISSION_ITEM_REACHED", seq=7).pack(mav, force_mavlink1=True)
    assert v1[0] == 0xFE
    msg = mc.Codec(255, 190).decode_one(v1)
    assert msg is not None
    frame = mc.mavlink2_frame(msg)
    again = mc.Codec(255, 190).decode_one(frame)
    assert frame[0] == 0xFD and again is not None
    assert (again.get_srcSystem(), again.get_srcComponent(), again.get_seq()) == (SYSTEM, 1, 42)
    assert again.get_type() == "MISSION_ITEM_REACHED" and again.seq == 7
    v2 = mc.Codec(SYSTEM, 1).encode(mc.message("MISSION_ITEM_REACHED", seq=7))
    assert mc.mavlink2_frame(mc.Codec(255, 190).decode_one(v2)) == v2  # as it came


def test_bad_input_is_refused_before_anything_opens() -> None:
    scenario = load_scenario(SCENARIO)
    for url in ("tcp:nohost", "zenoh:x", "/dev/ttyUSB0,fast"):
        with pytest.raises(ValueError, match="MAVLink URL"):
            mc.check_mavlink_url(url)
    mc.check_mavlink_url("/dev/serial/by-path/pci-0000:00:14.0-usb-0:2:1.0-port0,57600")
    with pytest.raises(ConfigError, match="unknown machine 'v9'"):
        run_bridge(scenario, "v9", "tcp:127.0.0.1:5760", wire.ZenohOptions())
    with pytest.raises(ValueError, match="tcpin:, udpin: or udpout:"):
        run_mavlink(scenario, "v1", "tcp:127.0.0.1:5760")
    assert sim_main([str(SCENARIO), "--all", "--mavlink", "tcpin:127.0.0.1:5760"]) == 2


# --- the simulated tractor on a MAVLink socket, in-process --------------------------------
def test_simulated_tractor_answers_on_a_udp_mavlink_port() -> None:
    scenario = load_scenario(SCENARIO)
    port = free_port(socket.SOCK_DGRAM)
    stop = threading.Event()
    codes: list[int] = []
    sim = threading.Thread(
        target=lambda: codes.append(
            run_mavlink(scenario, "v1", f"udpin:127.0.0.1:{port}", speedup=50.0, stop=stop)
        )
    )
    sim.start()
    gcs = mc.Codec(wire.DISPATCHER_SYSTEM_ID, wire.DISPATCHER_COMPONENT_ID)
    link = mc.open_mavlink(f"udpout:127.0.0.1:{port}")
    arm = Wire(SYSTEM).command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    heard: list[mc.MAVLinkMessage] = []
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while not any(m.get_type() == "COMMAND_ACK" for m in heard):
            assert time.monotonic() < deadline, [m.get_type() for m in heard]
            link.write(gcs.encode(arm))  # UDP: the simulator answers whoever spoke last
            time.sleep(0.05)
            heard += link.receive()
    finally:
        stop.set()
        sim.join(TIMEOUT_S)
        link.close()
    assert codes == [0]
    ack = next(m for m in heard if m.get_type() == "COMMAND_ACK")
    assert ack.result == mc.MAV_RESULT_ACCEPTED and ack.target_system == 255
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in heard} == {(SYSTEM, 1)}
    assert all(m.get_msgbuf()[0] == 0xFD for m in heard)  # MAVLink 2


# --- real processes ------------------------------------------------------------------------
class Children:
    """Processes a test starts (``python -m MODULE ...``); all stopped at the end."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen[str]] = []

    def start(self, module: str, *args: str, capture: bool = False) -> subprocess.Popen[str]:
        out = subprocess.PIPE if capture else subprocess.DEVNULL
        proc = subprocess.Popen(
            [sys.executable, "-m", module, *args], stdout=out, stderr=out, text=True
        )
        self.procs.append(proc)
        return proc

    def sim(self, mavlink_port: int, *extra: str) -> subprocess.Popen[str]:
        url = f"tcpin:127.0.0.1:{mavlink_port}"
        return self.start(
            "sim_vehicles",
            str(SCENARIO),
            "--vehicle",
            "v1",
            "--mavlink",
            url,
            "--keys",
            keys_for(SCENARIO),
            *extra,
        )

    def bridge(self, mavlink_port: int, zenoh_port: int, *extra: str) -> subprocess.Popen[str]:
        return self.start(
            "dispatcher.tools.bridge",
            str(SCENARIO),
            "--vehicle",
            "v1",
            "--mavlink",
            f"tcp:127.0.0.1:{mavlink_port}",
            "--connect",
            f"tcp/127.0.0.1:{zenoh_port}",
            "--keys",
            keys_for(SCENARIO),
            *extra,
            capture=True,
        )

    @staticmethod
    def terminate(proc: subprocess.Popen[str]) -> tuple[int, str]:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=TIMEOUT_S)
        return proc.returncode, (out or "") + (err or "")

    def stop_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()


@pytest.fixture
def children() -> Iterator[Children]:
    group = Children()
    yield group
    group.stop_all()


def test_dispatcher_completes_the_plan_through_the_bridge(children: Children, tmp_path) -> None:
    """dispatcher -> Zenoh -> bridge -> MAVLink TCP -> simulated autopilot, and back."""
    zport, mport = free_port(), free_port()
    dispatcher = children.start(
        "dispatcher.cli",
        "serve",
        str(SCENARIO),
        "--listen",
        f"tcp/127.0.0.1:{zport}",
        "--log-dir",
        str(tmp_path),
        "--time-limit",
        "1",
        "--machines",
        "1",
        "--keys",
        keys_for(SCENARIO),
        capture=True,
    )
    children.sim(mport, "--speedup", "400")
    children.bridge(mport, zport)
    out, err = dispatcher.communicate(timeout=60)
    assert dispatcher.returncode == 0, err[-3000:]
    last = out.strip().splitlines()[-1]
    assert last.startswith("log: "), out
    log = read_log(Path(last[5:]))
    status = log.on("agrifleet/tiny/dispatcher/status")[-1].decode_json()
    assert {f["status"] for f in status["fields"].values()} == {"done"}
    assert sorted(status["vehicles"]["v1"]["fields_done"]) == ["A", "B", "C"]
    from_vehicle = log.on("agrifleet/tiny/vehicle/v1/mavlink/from")
    assert from_vehicle
    codec = mc.Codec(255, 190)
    for record in from_vehicle:  # one MAVLink 2 frame per sample, from the autopilot
        assert record.data[0] == 0xFD
        msg = codec.decode_one(record.data)
        assert msg is not None and (msg.get_srcSystem(), msg.get_srcComponent()) == (SYSTEM, 1)


class ZenohWatch:
    """A test Zenoh peer: the vehicle's liveliness events and frames, with a condition."""

    def __init__(self, session: zenoh.Session) -> None:
        self.cond = threading.Condition()
        self.tokens: list[zenoh.SampleKind] = []
        self.frames: list[bytes] = []
        self._entities = [
            session.liveliness().declare_subscriber(wire.vehicle_alive("tiny", "v1"), self._token),
            session.declare_subscriber(wire.vehicle_from("tiny", "v1"), self._frame),
        ]

    def _token(self, sample: zenoh.Sample) -> None:
        with self.cond:
            self.tokens.append(sample.kind)
            self.cond.notify_all()

    def _frame(self, sample: zenoh.Sample) -> None:
        with self.cond:
            self.frames.append(sample.payload.to_bytes())
            self.cond.notify_all()

    def wait(self, what: str, predicate: Callable[[], bool]) -> None:
        with self.cond:
            assert self.cond.wait_for(predicate, TIMEOUT_S), f"timed out waiting for {what}"

    def types(self) -> list[str]:
        decoded = map(mc.Codec(255, 190).decode_one, self.frames)
        return [m.get_type() for m in decoded if m is not None]

    def wait_tokens(self, *kinds: zenoh.SampleKind) -> None:
        self.wait(f"liveliness {kinds}", lambda: self.tokens[: len(kinds)] == list(kinds))

    def close(self) -> None:
        for entity in self._entities:
            entity.undeclare()


def test_the_token_follows_the_autopilot_heartbeat_and_the_link_comes_back(
    children: Children,
) -> None:
    put, delete = zenoh.SampleKind.PUT, zenoh.SampleKind.DELETE
    zport, mport = free_port(), free_port()
    test_peer = wire.ZenohOptions(mode="peer", listen=(f"tcp/127.0.0.1:{zport}",))
    with zenoh.open(test_peer.config()) as session:
        watch = ZenohWatch(session)
        try:
            bridge = children.bridge(mport, zport, "--heartbeat-timeout", "1")
            sim = children.sim(mport)
            watch.wait_tokens(put)
            watch.wait("a heartbeat", lambda: "HEARTBEAT" in watch.types())
            # The autopilot freezes (its TCP link stays up): no heartbeat, the token goes;
            # it thaws: the token is back, on the same link.
            sim.send_signal(signal.SIGSTOP)
            try:
                watch.wait_tokens(put, delete)
            finally:
                sim.send_signal(signal.SIGCONT)
            watch.wait_tokens(put, delete, put)
            # The autopilot reboots: the link drops, the bridge opens it again, token back.
            assert children.terminate(sim)[0] == 0
            watch.wait_tokens(put, delete, put, delete)
            children.sim(mport)
            watch.wait_tokens(put, delete, put, delete, put)
            # SIGTERM: the bridge undeclares and exits cleanly.
            code, output = children.terminate(bridge)
            assert code == 0, output
            watch.wait_tokens(put, delete, put, delete, put, delete)
            assert len(watch.tokens) == 6
            assert "links_opened=2" in output, output
        finally:
            watch.close()


def test_another_autopilots_heartbeat_is_named_once() -> None:
    """An autopilot whose MAV_SYSID is not the fleet file's system_id: its HEARTBEAT is
    told apart (once), a ground station's and our own autopilot's are not."""

    def heartbeat(system: int, component: int = 1, autopilot: int = mc.MAV_AUTOPILOT_ARDUPILOTMEGA):
        fields = {"type": mc.MAV_TYPE_GROUND_ROVER, "base_mode": 0, "custom_mode": 0}
        fields |= {"system_status": 3, "mavlink_version": 3, "autopilot": autopilot}
        return vehicle_msg("HEARTBEAT", system, component, **fields)

    flt = AutopilotFilter(SYSTEM)
    assert flt.stranger(heartbeat(SYSTEM)) is None
    assert flt.stranger(heartbeat(1)) == (1, 1)
    assert flt.stranger(heartbeat(1)) is None  # said once
    assert flt.stranger(heartbeat(255, 190, mc.MAV_AUTOPILOT_INVALID)) is None  # a GCS
    assert flt.stranger(vehicle_msg("SYSTEM_TIME", 2, time_unix_usec=0, time_boot_ms=0)) is None
    assert not flt.admit(heartbeat(1), 0.0)  # and it is not forwarded


def test_once_the_autopilot_signs_an_unsigned_frame_on_its_link_is_dropped_not_signed(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The bridge signs what the autopilot sends unsigned: anyone on its link (a second
    radio, a UDP sender, a shared router) claiming the autopilot's ids got reports to the
    dispatcher signed with the tractor's key, taken as genuine. Once the autopilot is seen
    signing with that key, its link takes only signed frames."""
    key = bytes(range(32))
    vehicle = load_scenario(SCENARIO).vehicles[0]

    class Link:
        verified_with: bytes | None = None

        def verify_with(self, key: bytes) -> None:
            self.verified_with = key

    bridge = _Bridge("f", vehicle, "udpin:x", AutopilotFilter(SYSTEM), HeartbeatPresence(),
                     1.0, False, key=key)  # fmt: skip
    bridge.link = link = Link()  # type: ignore[assignment]

    def heard(codec: mc.Codec):  # type: ignore[no-untyped-def]
        frame = codec.encode(mc.message("MISSION_ITEM_REACHED", seq=42))
        return mc.Codec(255, 190).decode_one(frame)  # as the link parses it: unchecked

    stranger, autopilot = mc.Codec(SYSTEM, 1), mc.Codec(SYSTEM, 1, key=key)
    assert bridge._signed_as_it_should(heard(stranger))  # an autopilot that does not sign
    assert not bridge.autopilot_signs
    forged = mc.Codec(SYSTEM, 1, key=bytes(32))  # signed, with another key
    assert bridge._signed_as_it_should(heard(forged)) and not bridge.autopilot_signs
    # (passed on, the dispatcher refuses it; counted and said: an autopilot that holds a
    # key replaced since signed with it, and nothing said why the tractor stood)
    assert bridge.stats["from_autopilot_other_key"] == 1
    assert bridge._signed_as_it_should(heard(autopilot))
    assert bridge.autopilot_signs and link.verified_with == key
    assert not bridge._signed_as_it_should(heard(stranger))
    assert bridge.stats["from_autopilot_unsigned_dropped"] == 1
    assert "signed with a key other than" in caplog.text and "USB port" in caplog.text
    plain = _Bridge("f", vehicle, "udpin:x", AutopilotFilter(SYSTEM), HeartbeatPresence(), 1.0,
                    False)  # fmt: skip
    assert plain._signed_as_it_should(heard(stranger))  # no key: its link is trusted
    for b in (bridge, plain):
        b._wake_r.close()
        b._wake_w.close()


def test_unsigned_frames_a_signing_autopilots_link_refuses_are_counted_and_said(caplog) -> None:
    """Once the link checks signatures (pymavlink), it drops an unsigned frame itself:
    the bridge's count and warning saw none of them, and an autopilot that lost its key
    (a reflash) went silent with no word why."""
    key = bytes(range(32))
    vehicle = load_scenario(SCENARIO).vehicles[0]
    port = free_port(socket.SOCK_DGRAM)
    bridge = _Bridge("f", vehicle, f"udpin:127.0.0.1:{port}", AutopilotFilter(SYSTEM),
                     HeartbeatPresence(), 1.0, False, key=key)  # fmt: skip
    bridge.link = mc.open_mavlink(f"udpin:127.0.0.1:{port}", SYSTEM, 191)

    class Publisher:
        frames: list[bytes] = []

        def put(self, frame: bytes) -> None:
            self.frames.append(frame)

    bridge.publisher = Publisher()  # type: ignore[assignment]
    autopilot, stranger = mc.Codec(SYSTEM, 1, key=key), mc.Codec(SYSTEM, 1)
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

    def send(codec: mc.Codec, seq: int) -> None:
        sender.sendto(
            codec.encode(mc.message("MISSION_ITEM_REACHED", seq=seq)), ("127.0.0.1", port)
        )

    def until(what: Callable[[], bool]) -> None:
        deadline = time.monotonic() + TIMEOUT_S
        while not what():
            assert time.monotonic() < deadline
            bridge._from_autopilot(time.monotonic())
            time.sleep(0.01)

    try:
        send(autopilot, 1)
        until(lambda: bridge.autopilot_signs)
        with caplog.at_level("WARNING", logger="dispatcher.tools.bridge"):
            for seq in range(2, 5):
                send(stranger, seq)
            send(autopilot, 5)
            until(lambda: len(Publisher.frames) == 2)
            until(lambda: bridge.stats["from_autopilot_unsigned_dropped"] == 3)
        # (said at the first drop: the three may come in one read or more)
        assert re.search(r"dropped [123] unsigned frame\(s\) on the link", caplog.text)
        assert "its key lost in a reflash" in caplog.text
        taken = [mc.Codec(255, 190, key=key).decode_one(f) for f in Publisher.frames]
        assert [m.seq for m in taken if m is not None] == [1, 5]
    finally:
        sender.close()
        bridge._close_link()
        bridge._wake_r.close()
        bridge._wake_w.close()
