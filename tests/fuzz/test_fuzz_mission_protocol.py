"""Fuzzing both sides of the mission protocol with well-formed but arbitrary messages.

The ground station's exchanges (dispatcher.link.mission_protocol: MissionUpload,
MissionDownload, CommandSequence) and the simulated vehicle's MissionServer
(sim_vehicles.mission_server) are fed random sequences of protocol messages — requests for
any item, acknowledgements of any kind, counts of any size, garbage items, from any system
and component, every one through a real MAVLink 2 frame — and the clock. No exception may
escape; a transfer succeeds only when the real exchange did; a frame that fits no step is
counted (``Stats.stray``); the server's stored mission changes only by the steps of an
upload (ArduPilot's: a count truncates it, each item in sequence from the uploader replaces
one) or MISSION_CLEAR_ALL, never by garbage, and a completed upload leaves exactly its items.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from helpers.mavlink_wire import HOME, Wire
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import (
    Command,
    CommandSequence,
    MissionDownload,
    MissionUpload,
    Outcome,
    start_mission_commands,
)
from sim_vehicles.mission_server import MissionServer

FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

VEHICLE = (21, mc.MAV_COMP_ID_AUTOPILOT1)
GCS = (255, 190)

# ----------------------------------------------------------------------------- messages

senders = st.one_of(
    st.sampled_from([GCS, VEHICLE, (254, 190), (21, 191), (1, 1), (22, 1)]),
    st.tuples(st.integers(1, 255), st.integers(0, 255)),
)
small = st.one_of(st.integers(0, 6), st.integers(0, 65535))
mission_types = st.sampled_from([0, 0, 0, 0, 1, 2, 255])
targets = st.one_of(
    st.sampled_from([VEHICLE, GCS, (0, 0)]), st.tuples(st.integers(0, 255), st.integers(0, 255))
)
floats = st.floats(width=32)
results = st.one_of(st.sampled_from([0, 0, 0, 1, 2, 4, 5, 13]), st.integers(0, 255))


def _item_fields(draw: st.DrawFn) -> dict[str, object]:
    return {
        "seq": draw(small),
        "frame": draw(st.sampled_from([0, 3, 5, 6, 2, 255])),
        "command": draw(st.sampled_from([16, 178, 183, 181, 203, 0, 65535])),
        "current": draw(st.sampled_from([0, 0, 1, 2, 3, 255])),
        "autocontinue": draw(st.integers(0, 255)),
        "param1": draw(floats),
        "param2": draw(floats),
        "param3": draw(floats),
        "param4": draw(floats),
        "z": draw(floats),
    }


@st.composite
def protocol_message(draw: st.DrawFn) -> tuple[tuple[int, int], mc.MAVLinkMessage]:
    """(sender, message): a mission-protocol message (or a COMMAND_ACK, a HEARTBEAT) with
    any field values its type can carry."""
    kind = draw(
        st.sampled_from(
            [
                "MISSION_REQUEST_INT",
                "MISSION_REQUEST",
                "MISSION_ACK",
                "MISSION_COUNT",
                "MISSION_ITEM_INT",
                "MISSION_ITEM",
                "MISSION_REQUEST_LIST",
                "MISSION_CLEAR_ALL",
                "COMMAND_ACK",
                "HEARTBEAT",
            ]
        )
    )
    target_system, target_component = draw(targets)
    address = {"target_system": target_system, "target_component": target_component}
    mtype = draw(mission_types)
    if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
        msg = mc.message(kind, **address, seq=draw(small), mission_type=mtype)
    elif kind == "MISSION_ACK":
        msg = mc.message(kind, **address, type=draw(results), mission_type=mtype)
    elif kind == "MISSION_COUNT":
        msg = mc.message(kind, **address, count=draw(small), mission_type=mtype)
    elif kind == "MISSION_ITEM_INT":
        xy = st.one_of(st.integers(-(2**31), 2**31 - 1), st.sampled_from([440000000, 873000000]))
        msg = mc.message(
            kind, **address, **_item_fields(draw), x=draw(xy), y=draw(xy), mission_type=mtype
        )
    elif kind == "MISSION_ITEM":
        msg = mc.message(
            kind,
            **address,
            **_item_fields(draw),
            x=draw(floats),
            y=draw(floats),
            mission_type=mtype,
        )
    elif kind in ("MISSION_REQUEST_LIST", "MISSION_CLEAR_ALL"):
        msg = mc.message(kind, **address, mission_type=mtype)
    elif kind == "COMMAND_ACK":
        command = draw(st.sampled_from([176, 176, 400, 224, 224, 0, 65535]))
        msg = mc.message(kind, command=command, result=draw(results))
    else:
        msg = mc.peer_heartbeat(mc.MAV_TYPE_GCS)
    return draw(senders), msg


def framed(sender: tuple[int, int], msg: mc.MAVLinkMessage) -> mc.MAVLinkMessage:
    """``msg`` as it arrives from ``sender``: through a MAVLink 2 frame (ids, float32)."""
    decoded = mc.Codec(240, 1).decode_one(mc.Codec(*sender).encode(msg))
    assert decoded is not None
    return decoded


events = st.lists(
    st.one_of(protocol_message(), st.floats(0.0, 12.0).map(lambda dt: ("tick", dt))),
    max_size=40,
)


def mission(n: int) -> list[mc.MAVLinkMessage]:
    return [
        mc.mission_item_int(
            target_system=VEHICLE[0],
            target_component=VEHICLE[1],
            seq=k,
            frame=mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            command=mc.MAV_CMD_NAV_WAYPOINT,
            current=0,
            autocontinue=1,
            param1=0.0,
            param2=float(k),
            param3=0.0,
            param4=0.0,
            x=440000000 + 10 * k,
            y=873000000 + 7 * k,
            z=0.0,
        )
        for k in range(n)
    ]


def protocol_frame(msg: mc.MAVLinkMessage) -> bool:
    return msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK") and (
        getattr(msg, "mission_type", 0) == mc.MAV_MISSION_TYPE_MISSION
    )


# ----------------------------------------------------------------------------- client alone


@FUZZ
@given(n=st.integers(0, 6), feed=events)
@example(
    n=2,
    feed=[
        (
            GCS,
            mc.message(
                "MISSION_ACK", target_system=255, target_component=190, type=0, mission_type=0
            ),
        )
    ],
)
@example(  # the same request twice at once (a radio's duplicate): neither answered nor counted
    n=1,
    feed=[
        (VEHICLE, mc.message("MISSION_REQUEST_INT", target_system=255, target_component=190,
                             seq=0, mission_type=0)),
    ] * 2,
)  # fmt: skip
def test_an_upload_fed_anything_never_raises_and_counts_strays(n, feed):
    up = MissionUpload(mission(n), VEHICLE[0])
    now = 0.0
    up.start(now)
    for step in feed:
        if step[0] == "tick":
            now += step[1]
            out = up.on_tick(now)
            assert all(m.get_type() in ("MISSION_COUNT", "MISSION_ITEM_INT") for m in out)
            continue
        msg = framed(*step)
        before, status = up.stats.stray, up.outcome
        out = up.on_message(msg, now)
        if status is not Outcome.RUNNING:
            assert out == [] and up.stats.stray == before
            continue
        if msg.get_srcSystem() != VEHICLE[0] or msg.get_srcComponent() != VEHICLE[1]:
            # from anyone but the vehicle: nothing done, counted when of the protocol
            assert out == [] and up.outcome is Outcome.RUNNING
            assert up.stats.stray == before + protocol_frame(msg)
        elif protocol_frame(msg):  # answered, the upload done, or counted
            assert out or up.outcome is Outcome.DONE or up.stats.stray == before + 1
        if up.outcome is Outcome.DONE:
            assert msg.get_type() == "MISSION_ACK" and msg.type == mc.MAV_MISSION_ACCEPTED
    assert up.outcome in (Outcome.RUNNING, Outcome.DONE, Outcome.FAILED)


MISSION_FRAMES = {
    "MISSION_COUNT",
    "MISSION_ITEM_INT",
    "MISSION_ITEM",
    "MISSION_REQUEST_INT",
    "MISSION_REQUEST",
    "MISSION_ACK",
}


@FUZZ
@given(feed=events)
def test_a_download_fed_anything_never_raises_and_counts_strays(feed):
    down = MissionDownload(VEHICLE[0])
    now = 0.0
    down.start(now)
    for step in feed:
        if step[0] == "tick":
            now += step[1]
            out = down.on_tick(now)
            assert all(m.get_type() in ("MISSION_REQUEST_LIST", "MISSION_REQUEST_INT") for m in out)
            continue
        msg = framed(*step)
        before, status, count = down.stats.stray, down.outcome, down.count
        out = down.on_message(msg, now)
        if status is not Outcome.RUNNING:
            assert out == [] and down.stats.stray == before
            continue
        of_protocol = msg.get_type() in MISSION_FRAMES and msg.mission_type == 0
        if not of_protocol:  # a HEARTBEAT, a COMMAND_ACK, another mission type: not stray
            assert out == [] and down.stats.stray == before and down.count == count
        elif (msg.get_srcSystem(), msg.get_srcComponent()) != VEHICLE:
            assert out == [] and down.stats.stray == before + 1 and down.count == count
        else:  # a step (a request, or the final ACK) or counted
            assert out or down.stats.stray == before + 1
    if down.outcome is Outcome.DONE:
        assert down.count == len(down.items)
        assert [int(m.seq) for m in down.items] == list(range(len(down.items)))


@FUZZ
@given(feed=events, in_auto=st.booleans())
@example(feed=[((22, 1), mc.message("COMMAND_ACK", command=224, result=0))], in_auto=False)
def test_a_command_sequence_fed_anything_never_raises_nor_takes_others_acks(feed, in_auto):
    commands = start_mission_commands(3, in_auto=in_auto)
    seq = CommandSequence(commands, VEHICLE[0], refusal_window_s=5.0)
    now = 0.0
    seq.start(now)
    for step in feed:
        if step[0] == "tick":
            now += step[1]
            out = seq.on_tick(now)
            assert all(m.get_type() == "COMMAND_LONG" for m in out)
            continue
        msg = framed(*step)
        index = seq._index
        seq.on_message(msg, now)
        if (msg.get_srcSystem(), msg.get_srcComponent()) != VEHICLE:
            assert seq._index == index and seq.outcome is not Outcome.DONE or index == len(commands)
    assert seq.outcome in (Outcome.RUNNING, Outcome.DONE, Outcome.FAILED)


def test_an_empty_command_sequence_is_done_at_once():
    seq = CommandSequence([], VEHICLE[0])
    assert seq.start(0.0) == [] and seq.outcome is Outcome.DONE
    assert seq.on_tick(10.0) == []
    ack = mc.message("COMMAND_ACK", command=400, result=0)
    assert seq.on_message(framed(VEHICLE, ack), 1.0) == []
    assert CommandSequence([Command(400, (1.0,))], VEHICLE[0]).start(0.0)


# ----------------------------------------------------------------------------- both sides


@dataclass
class Link:
    """Client and server through frames, with losses, duplicates and foreign frames."""

    lose: set[int]
    twice: set[int]
    junk: dict[int, list[tuple[tuple[int, int], mc.MAVLinkMessage]]]

    def run(self, client, server: MissionServer, limit_s: float = 200.0) -> None:  # type: ignore[no-untyped-def]
        wire = Wire(VEHICLE[0])
        now, sent = 0.0, 0
        to_vehicle = client.start(now)
        step = 0
        while client.outcome is Outcome.RUNNING and now < limit_s:
            step += 1
            to_gcs = []
            for msg in to_vehicle:
                sent += 1
                if sent in self.lose:
                    continue
                for _ in range(1 + (sent in self.twice)):
                    to_gcs += server.on_message(wire.up(msg), now)
            to_vehicle = []
            # frames of other systems and components on the same radio, at any point
            arriving = [framed(s, m) for s, m in self.junk.get(step, [])]
            for msg in wire.down(to_gcs):
                sent += 1
                if sent not in self.lose:
                    arriving += [msg] * (1 + (sent in self.twice))
            for msg in arriving:
                to_vehicle += client.on_message(msg, now)
            now += 0.25
            to_vehicle += client.on_tick(now)
            to_vehicle_late = server.on_tick(now)
            for msg in wire.down(to_vehicle_late):
                to_vehicle += client.on_message(msg, now)


foreign = protocol_message().filter(lambda sm: sm[0] != VEHICLE)
links = st.builds(
    Link,
    lose=st.sets(st.integers(1, 60), max_size=12),
    twice=st.sets(st.integers(1, 60), max_size=6),
    junk=st.dictionaries(st.integers(1, 40), st.lists(foreign, min_size=1, max_size=3)),
)
ACCEPTED_FROM_ELSEWHERE = (
    (22, 1),
    mc.message("MISSION_ACK", target_system=255, target_component=190, type=0, mission_type=0),
)


def stored(server: MissionServer) -> list[tuple[int, int, int, float]]:
    return [(it.seq, it.x, it.y, it.param2) for it in server.items]


def sent_items(items: list[mc.MAVLinkMessage]) -> list[tuple[int, int, int, float]]:
    return [(m.seq, m.x, m.y, m.param2) for m in items]


@FUZZ
@given(n=st.integers(1, 6), link=links)
# The last item lost on its way, and another system's MISSION_ACK(ACCEPTED) meanwhile.
@example(
    n=3, link=Link(lose={7}, twice=set(), junk={k: [ACCEPTED_FROM_ELSEWHERE] for k in range(30)})
)
def test_an_upload_succeeds_only_when_the_vehicle_has_the_mission(n, link):
    server = MissionServer(lambda: HOME, request_message="MISSION_REQUEST_INT")
    up = MissionUpload(mission(n), VEHICLE[0])
    link.run(up, server)
    event(f"upload {up.outcome.value}")
    if up.outcome is Outcome.DONE:
        assert not server.receiving
        assert stored(server) == sent_items(mission(n))


@FUZZ
@given(n=st.integers(0, 6), link=links)
@example(
    n=4,
    link=Link(
        lose=set(),
        twice=set(),
        junk={
            1: [
                (
                    (22, 1),
                    mc.message(
                        "MISSION_COUNT",
                        target_system=255,
                        target_component=190,
                        count=1,
                        mission_type=0,
                    ),
                )
            ]
        },
    ),
)
def test_a_download_succeeds_only_with_the_vehicle_s_mission(n, link):
    server = MissionServer(lambda: HOME, request_message="MISSION_REQUEST_INT")
    up = MissionUpload(mission(n), VEHICLE[0])
    Link(set(), set(), {}).run(up, server)
    assert up.outcome is Outcome.DONE or n == 0
    down = MissionDownload(VEHICLE[0])
    link.run(down, server)
    event(f"download {down.outcome.value}")
    if down.outcome is Outcome.DONE:  # what the vehicle holds (item 0: its home)
        want = [] if n == 0 else [(0, HOME.x, HOME.y, HOME.param2)] + stored(server)[1:]
        assert [(m.seq, m.x, m.y, m.param2) for m in down.items] == want


# ----------------------------------------------------------------------------- server alone

DIGICAM_1E30 = mc.message(
    "MISSION_ITEM",
    target_system=21,
    target_component=1,
    seq=1,
    frame=0,
    command=mc.MAV_CMD_DO_DIGICAM_CONTROL,
    current=0,
    autocontinue=1,
    param1=0,
    param2=0,
    param3=0,
    param4=0,
    x=1e30,
    y=0.0,
    z=0,
    mission_type=0,
)


@st.composite
def uploads_among_garbage(draw: st.DrawFn) -> list:
    """Uploads as a ground station makes them (a count, then items 0, 1, ... with any
    content, now and then a wrong seq or another sender), between random messages and
    ticks: so that uploads do run and complete among the garbage."""
    out = draw(events)
    for _ in range(draw(st.integers(1, 3))):
        sender = draw(senders)
        n = draw(st.integers(0, 5))
        script = [
            (sender, mc.message("MISSION_COUNT", target_system=21, target_component=1, count=n))
        ]
        for k in range(n):
            # mostly as a ground station would, now and then not
            who = draw(st.sampled_from([sender] * 7 + [draw(senders)]))
            seq = draw(st.sampled_from([k] * 7 + [draw(small)]))
            kind = draw(st.sampled_from(["MISSION_ITEM_INT", "MISSION_ITEM_INT", "MISSION_ITEM"]))
            fields = {
                **_item_fields(draw),
                "seq": seq,
                "current": draw(st.sampled_from([0, 0, 1, 2, 3])),
            }
            if kind == "MISSION_ITEM_INT":
                x = draw(st.one_of(st.integers(-(2**31), 2**31 - 1), st.just(440000000 + k)))
                y = draw(st.one_of(st.integers(-(2**31), 2**31 - 1), st.just(873000000 + k)))
            else:
                x = draw(st.one_of(floats, st.just(44.0 + k / 1e5)))
                y = draw(st.one_of(floats, st.just(87.3)))
            script.append(
                (who, mc.message(kind, target_system=21, target_component=1, x=x, y=y, **fields))
            )
        at = draw(st.integers(0, len(out)))
        # the script in order, garbage and ticks between its steps
        for k, step in enumerate(script):
            out.insert(min(at + k * 2, len(out)), step)
    return out


def snapshot(server: MissionServer) -> tuple:
    up = server._upload
    where = None if up is None else (up.dest_system, up.dest_component, up.next_seq, up.last_seq)
    return server.items, server.changes, where


@FUZZ
@given(
    feed=uploads_among_garbage(),
    running=st.booleans(),
    request=st.sampled_from(["MISSION_REQUEST", "MISSION_REQUEST_INT"]),
)
@example(
    feed=[
        (
            GCS,
            mc.message(
                "MISSION_COUNT", target_system=21, target_component=1, count=2, mission_type=0
            ),
        ),
        (
            GCS,
            mc.message(
                "MISSION_ITEM",
                target_system=21,
                target_component=1,
                seq=0,
                frame=0,
                command=203,
                current=0,
                autocontinue=1,
                param1=0,
                param2=0,
                param3=0,
                param4=0,
                x=math.nan,
                y=math.inf,
                z=0,
                mission_type=0,
            ),
        ),
    ],
    running=False,
    request="MISSION_REQUEST",
)
@example(  # a camera item whose x is no int32: stored, it could not be sent back
    feed=[
        (GCS, mc.message("MISSION_COUNT", target_system=21, target_component=1, count=2)),
        (GCS, HOME.message(21, 1)),
        (GCS, DIGICAM_1E30),
        (GCS, mc.message("MISSION_REQUEST", target_system=21, target_component=1, seq=1)),
        (GCS, mc.message("MISSION_REQUEST_INT", target_system=21, target_component=1, seq=1)),
    ],
    running=False,
    request="MISSION_REQUEST",
)
def test_the_server_changes_its_mission_only_by_an_upload(feed, running, request):
    server = MissionServer(lambda: HOME, is_running=lambda: running, request_message=request)
    now = 0.0
    uploads: dict[tuple[int, int], list[tuple]] = {}  # what each uploader had stored
    for step in feed:
        if step[0] == "tick":
            now += step[1]
            before = snapshot(server)
            server.on_tick(now)
            assert snapshot(server)[:2] == before[:2]  # a timeout changes no item
            continue
        msg = framed(*step)
        sender = (msg.get_srcSystem(), msg.get_srcComponent())
        items, changes, upload = snapshot(server)
        replies = server.on_message(msg, now)
        new_items, new_changes, new_upload = snapshot(server)
        kind = msg.get_type()
        mission_type = getattr(msg, "mission_type", 0)
        for reply in replies:  # answers go to the sender (STATUSTEXT has no address)
            mc.Codec(*VEHICLE).encode(reply)  # and fit their frames
            if hasattr(reply, "target_system"):
                assert (reply.target_system, reply.target_component) == sender
        if new_items == items:
            assert new_changes == changes or kind == "MISSION_COUNT"
        else:
            assert mission_type == mc.MAV_MISSION_TYPE_MISSION
            if kind == "MISSION_COUNT":  # ArduPilot truncates at once
                assert upload is None or upload[:2] == sender
                assert new_items == items[: int(msg.count)]
            elif kind == "MISSION_CLEAR_ALL":
                assert upload is None and not running and new_items == ()
            else:  # one item, in sequence, from the uploader, in its place
                assert kind in ("MISSION_ITEM_INT", "MISSION_ITEM")
                assert upload is not None and upload[:2] == sender
                assert int(msg.seq) == upload[2] and msg.current not in (2, 3)
                k = int(msg.seq)
                assert new_items[:k] == items[:k] and new_items[k + 1 :] == items[k + 1 :]
                assert new_items[k].seq == k and new_items[k].command == msg.command
                uploads.setdefault(sender, []).append(new_items[k])
                event("server: an item stored")
        if upload is not None and upload[:2] != sender and kind != "MISSION_CLEAR_ALL":
            assert new_upload == upload  # someone else cannot end or move an upload
        if kind == "MISSION_COUNT" and new_upload is not None:
            uploads[sender] = []
        completed = any(
            r.get_type() == "MISSION_ACK" and r.type == mc.MAV_MISSION_ACCEPTED for r in replies
        )
        item = kind in ("MISSION_ITEM_INT", "MISSION_ITEM")
        if completed and item and upload is not None and upload[:2] == sender and not new_upload:
            # A complete upload: the stored mission is exactly its items.
            event("server: an upload completed")
            assert list(server.items) == uploads[sender]
