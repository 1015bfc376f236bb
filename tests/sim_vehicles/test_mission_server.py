"""The mission server against ArduPilot-style exchanges, every message through a frame.

Each test is an exchange as ArduPilot's MissionItemProtocol.cpp plays it: what the ground
station sends, at which link time, and what the vehicle must answer.
"""

from __future__ import annotations

import pytest
from helpers.mavlink_wire import HOME, Wire, only, types

from dispatcher.link import mavlink as mc
from dispatcher.mission.build import Mission
from sim_vehicles.mission_server import (
    RE_REQUEST_S,
    UPLOAD_TIMEOUT_S,
    MissionServer,
    RequestMessage,
)


def make_server(
    request: RequestMessage = "MISSION_REQUEST_INT", running: bool = False
) -> MissionServer:
    return MissionServer(lambda: HOME, is_running=lambda: running, request_message=request)


def send(
    server: MissionServer, wire: Wire, msg: mc.MAVLinkMessage, now: float = 0.0
) -> list[mc.MAVLinkMessage]:
    """One ground-station message in, the vehicle's answers out (both through frames)."""
    return wire.down(server.on_message(wire.up(msg), now))


def count_msg(
    wire: Wire, count: int, mission_type: int = mc.MAV_MISSION_TYPE_MISSION
) -> mc.MAVLinkMessage:
    return wire.mission_msg("MISSION_COUNT", count=count, mission_type=mission_type)


def items_of(mission: Mission, wire: Wire) -> list[mc.MAVLinkMessage]:
    return mission.to_mavlink(wire.vehicle_system)


def upload(server: MissionServer, wire: Wire, items: list[mc.MAVLinkMessage]) -> int:
    """A clean upload; the final MISSION_ACK result."""
    replies = send(server, wire, count_msg(wire, len(items)))
    for _ in range(len(items)):
        (request,) = only(replies, "MISSION_REQUEST_INT", "MISSION_REQUEST")
        replies = send(server, wire, items[request.seq])
    (ack,) = only(replies, "MISSION_ACK")
    return int(ack.type)


def assert_ack(
    reply: mc.MAVLinkMessage, result: int, mission_type: int = mc.MAV_MISSION_TYPE_MISSION
) -> None:
    assert reply.get_type() == "MISSION_ACK"
    assert (reply.type, reply.mission_type) == (result, mission_type)
    assert (reply.target_system, reply.target_component) == (255, 190)
    assert (reply.get_srcSystem(), reply.get_srcComponent()) == (7, 1)


@pytest.mark.parametrize("request_kind", ["MISSION_REQUEST_INT", "MISSION_REQUEST"])
def test_full_upload_pulls_every_item_in_order_then_accepts(
    wire: Wire, mission: Mission, request_kind: RequestMessage
) -> None:
    server = make_server(request_kind)
    items = items_of(mission, wire)
    replies = send(server, wire, count_msg(wire, len(items)))
    for seq, item in enumerate(items):
        assert types(replies) == [request_kind]
        request = replies[0]
        assert (request.seq, request.mission_type) == (seq, mc.MAV_MISSION_TYPE_MISSION)
        assert (request.target_system, request.target_component) == (255, 190)
        assert server.receiving
        replies = send(server, wire, item, now=0.1 * seq)
    assert types(replies) == ["STATUSTEXT", "MISSION_ACK"]
    assert replies[0].text == "Flight plan received"
    assert_ack(replies[1], mc.MAV_MISSION_ACCEPTED)
    assert not server.receiving
    stored = server.items
    assert len(stored) == len(mission)
    for got, want in zip(stored, mission.items, strict=True):
        assert (got.seq, got.frame, got.command, got.x, got.y) == (
            want.seq,
            want.frame,
            want.command,
            want.x,
            want.y,
        )
        assert (got.param1, got.param2, got.param3, got.param4) == (
            want.param1,
            want.param2,
            want.param3,
            want.param4,
        )


def test_out_of_sequence_item_is_refused_and_the_transfer_goes_on(
    wire: Wire, mission: Mission
) -> None:
    server = make_server()
    items = items_of(mission, wire)
    send(server, wire, count_msg(wire, len(items)))
    send(server, wire, items[0], now=0.1)  # vehicle now asks for item 1
    (reply,) = send(server, wire, items[2], now=0.2)
    assert_ack(reply, mc.MAV_MISSION_INVALID_SEQUENCE)
    assert server.receiving
    # ArduPilot does not ask again at once: its 1 s re-request does.
    assert server.on_tick(0.2 + RE_REQUEST_S / 2) == []
    (request,) = wire.down(server.on_tick(0.1 + RE_REQUEST_S + 0.01))
    assert (request.get_type(), request.seq) == ("MISSION_REQUEST_INT", 1)
    replies = send(server, wire, items[1], now=1.2)
    assert only(replies, "MISSION_REQUEST_INT")[0].seq == 2
    for item in items[2:]:
        replies = send(server, wire, item, now=1.3)
    assert_ack(only(replies, "MISSION_ACK")[0], mc.MAV_MISSION_ACCEPTED)


def test_timeout_re_requests_every_second_then_cancels_after_eight(
    wire: Wire, mission: Mission
) -> None:
    server = make_server()
    items = items_of(mission, wire)
    send(server, wire, count_msg(wire, len(items)), now=10.0)
    send(server, wire, items[0], now=10.5)  # last item received at 10.5, item 1 asked
    assert server.on_tick(11.5) == []  # not *more* than 1 s yet
    request_times: list[float] = []
    now = 11.5
    while server.receiving:
        now = round(now + 0.25, 2)
        replies = wire.down(server.on_tick(now))
        request_times += [now for r in replies if r.get_type() == "MISSION_REQUEST_INT"]
        assert all(r.seq == 1 for r in only(replies, "MISSION_REQUEST_INT"))
    *_, text, cancelled = replies
    # re-asked 1 s (one tick, 0.25 s, later than "more than 1 s") after each request
    assert request_times == [11.75, 13.0, 14.25, 15.5, 16.75, 18.0]
    assert text.text == "Mission upload timeout"
    assert_ack(cancelled, mc.MAV_MISSION_OPERATION_CANCELLED)
    assert now == 10.5 + UPLOAD_TIMEOUT_S + 0.25  # first tick more than 8 s after the item
    # The transfer is over: a late item is an error; ArduPilot kept what it had received.
    (late,) = send(server, wire, items[1], now=19.0)
    assert_ack(late, mc.MAV_MISSION_ERROR)
    assert server.count == 1


def test_a_re_requested_item_completes_the_upload(wire: Wire, mission: Mission) -> None:
    server = make_server()
    items = items_of(mission, wire)
    send(server, wire, count_msg(wire, len(items)), now=0.0)
    (request,) = wire.down(server.on_tick(1.01))  # item 0 lost: asked again
    assert request.seq == 0
    replies = send(server, wire, items[0], now=1.1)
    for item in items[1:]:
        replies = send(server, wire, item, now=1.2)
    assert_ack(only(replies, "MISSION_ACK")[0], mc.MAV_MISSION_ACCEPTED)


def test_download_round_trip(wire: Wire, mission: Mission) -> None:
    server = make_server()
    items = items_of(mission, wire)
    assert upload(server, wire, items) == mc.MAV_MISSION_ACCEPTED
    (count,) = send(server, wire, wire.mission_msg("MISSION_REQUEST_LIST"))
    assert (count.get_type(), count.count) == ("MISSION_COUNT", len(items))
    assert (count.target_system, count.target_component) == (255, 190)
    downloaded = []
    for seq in range(count.count):
        (item,) = send(server, wire, wire.mission_msg("MISSION_REQUEST_INT", seq=seq))
        assert (item.get_type(), item.seq) == ("MISSION_ITEM_INT", seq)
        downloaded.append(item)
    # Item 0 is the vehicle's own home in MAV_FRAME_GLOBAL, the rest as uploaded.
    assert (downloaded[0].x, downloaded[0].y, downloaded[0].frame) == (
        HOME.x,
        HOME.y,
        mc.MAV_FRAME_GLOBAL,
    )
    for got, sent in zip(downloaded[1:], items[1:], strict=True):
        assert (got.command, got.frame, got.x, got.y, got.param1, got.param2) == (
            sent.command,
            sent.frame,
            sent.x,
            sent.y,
            sent.param1,
            sent.param2,
        )
    # The ground station's final ACK needs no answer.
    assert send(server, wire, wire.mission_msg("MISSION_ACK", type=mc.MAV_MISSION_ACCEPTED)) == []


def test_legacy_messages_both_ways(wire: Wire, mission: Mission) -> None:
    server = make_server("MISSION_REQUEST")
    items = items_of(mission, wire)
    replies = send(server, wire, count_msg(wire, len(items)))
    for item in items:
        assert types(replies) == ["MISSION_REQUEST"]
        legacy = wire.mission_msg(
            "MISSION_ITEM",
            seq=item.seq,
            frame=mc.float_frame(item.frame),
            command=item.command,
            current=0,
            autocontinue=1,
            param1=item.param1,
            param2=item.param2,
            param3=item.param3,
            param4=item.param4,
            x=item.x / 1e7,
            y=item.y / 1e7,
            z=0.0,
        )
        replies = send(server, wire, legacy)
    assert_ack(replies[-1], mc.MAV_MISSION_ACCEPTED)
    for stored, sent in zip(server.items[1:], items[1:], strict=True):
        # float32 lat/lon on the wire: within ~1 m, not exact (why MISSION_ITEM_INT exists)
        assert abs(stored.x - sent.x) <= 100 and abs(stored.y - sent.y) <= 100
    (reply,) = send(server, wire, wire.mission_msg("MISSION_REQUEST", seq=2))
    assert reply.get_type() == "MISSION_ITEM"
    assert reply.x == pytest.approx(items[2].x / 1e7, abs=1e-5)


def test_count_zero_clears_the_mission(wire: Wire, mission: Mission) -> None:
    server = make_server()
    assert upload(server, wire, items_of(mission, wire)) == mc.MAV_MISSION_ACCEPTED
    replies = send(server, wire, count_msg(wire, 0))
    assert_ack(only(replies, "MISSION_ACK")[0], mc.MAV_MISSION_ACCEPTED)
    assert server.count == 0 and not server.receiving
    (count,) = send(server, wire, wire.mission_msg("MISSION_REQUEST_LIST"))
    assert count.count == 0
    # home can always be read; anything else is past the end
    (home,) = send(server, wire, wire.mission_msg("MISSION_REQUEST_INT", seq=0))
    assert home.x == HOME.x
    educate, error = send(server, wire, wire.mission_msg("MISSION_REQUEST_INT", seq=1))
    assert (educate.get_type(), educate.count) == ("MISSION_COUNT", 0)
    assert_ack(error, mc.MAV_MISSION_ERROR)


@pytest.mark.parametrize("mission_type", [mc.MAV_MISSION_TYPE_FENCE, mc.MAV_MISSION_TYPE_RALLY])
def test_other_mission_types_are_unsupported(wire: Wire, mission_type: int) -> None:
    server = make_server()
    for name, fields in (
        ("MISSION_COUNT", {"count": 3}),
        ("MISSION_REQUEST_LIST", {}),
        ("MISSION_CLEAR_ALL", {}),
    ):
        (reply,) = send(server, wire, wire.mission_msg(name, mission_type=mission_type, **fields))
        assert_ack(reply, mc.MAV_MISSION_UNSUPPORTED, mission_type)
    # ArduPilot ignores an item request for a type it has no protocol for
    assert (
        send(
            server, wire, wire.mission_msg("MISSION_REQUEST_INT", seq=0, mission_type=mission_type)
        )
        == []
    )
    assert not server.receiving


def test_count_while_busy_denied_to_others_restarts_for_the_uploader(
    wire: Wire, mission: Mission
) -> None:
    server = make_server()
    items = items_of(mission, wire)
    send(server, wire, count_msg(wire, len(items)))
    send(server, wire, items[0])
    other = Wire(7, gcs_system=200, gcs_component=1)
    (denied,) = wire.down(server.on_message(other.up(count_msg(other, 3)), 0.5))
    assert (denied.type, denied.target_system) == (mc.MAV_MISSION_DENIED, 200)
    # downloads are refused while receiving, too
    (busy,) = send(server, wire, wire.mission_msg("MISSION_REQUEST_LIST"))
    assert_ack(busy, mc.MAV_MISSION_DENIED)
    (busy,) = send(server, wire, wire.mission_msg("MISSION_CLEAR_ALL"))
    assert_ack(busy, mc.MAV_MISSION_ERROR)
    (restart,) = send(server, wire, count_msg(wire, len(items)))
    assert (restart.get_type(), restart.seq) == ("MISSION_REQUEST_INT", 0)


def test_item_without_upload_and_bad_items(wire: Wire, mission: Mission) -> None:
    server = make_server()
    items = items_of(mission, wire)
    (reply,) = send(server, wire, items[0])
    assert_ack(reply, mc.MAV_MISSION_ERROR)
    send(server, wire, count_msg(wire, 3))
    send(server, wire, items[0])
    bad = wire.mission_msg(
        "MISSION_ITEM_INT",
        seq=1,
        frame=items[2].frame,
        command=mc.MAV_CMD_NAV_WAYPOINT,
        current=0,
        autocontinue=1,
        param1=0.0,
        param2=0.0,
        param3=0.0,
        param4=0.0,
        x=950_000_000,
        y=items[2].y,
        z=0.0,
    )
    (reply,) = send(server, wire, bad)
    assert_ack(reply, mc.MAV_MISSION_INVALID_PARAM5_X)
    assert not server.receiving  # a bad item ends the upload


def test_too_many_items(wire: Wire) -> None:
    server = MissionServer(lambda: HOME, max_items=10)
    replies = send(server, wire, count_msg(wire, 11))
    assert_ack(only(replies, "MISSION_ACK")[0], mc.MAV_MISSION_NO_SPACE)
    assert not server.receiving


def test_clear_all(wire: Wire, mission: Mission) -> None:
    server = make_server()
    upload(server, wire, items_of(mission, wire))
    changes = server.changes
    (reply,) = send(server, wire, wire.mission_msg("MISSION_CLEAR_ALL"))
    assert_ack(reply, mc.MAV_MISSION_ACCEPTED)
    assert server.count == 0 and server.changes > changes
    running = make_server(running=True)
    upload(running, wire, items_of(mission, wire))
    (reply,) = send(running, wire, wire.mission_msg("MISSION_CLEAR_ALL"))
    assert_ack(reply, mc.MAV_MISSION_ERROR)  # AP_Mission::clear refuses while running
    assert running.count == len(mission)


def test_new_upload_truncates_at_once(wire: Wire, mission: Mission) -> None:
    """ArduPilot truncates on MISSION_COUNT and overwrites in place."""
    server = make_server()
    items = items_of(mission, wire)
    upload(server, wire, items)
    send(server, wire, count_msg(wire, 4))
    assert server.count == 4  # old items 0..3 until the new ones arrive
    send(server, wire, items[0])
    assert server.count == 4 and server.receiving
