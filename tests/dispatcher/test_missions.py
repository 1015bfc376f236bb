"""Missions: layout, traces, validation, MAVLink round trip, .waypoints and .plan files."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink import mavwp

from dispatcher.config.scenario import Implement
from dispatcher.link import mavlink as mc
from dispatcher.mission.build import (
    FieldVisit,
    LatLon,
    Mission,
    MissionError,
    MissionSpec,
    Trace,
    build_mission,
    implement_set_before,
)
from dispatcher.mission.files import qgc_plan, write_qgc_plan, write_waypoints

GARAGE = LatLon(52.0000000, 5.0000000)
SERVO = Implement(kind="servo", channel=9, pwm_down=1900, pwm_up=1100)

# Field "north": three swaths, each starting away from where the last one ended
# (a turn waypoint is needed). Field "south": the second swath starts 5 mm from where
# the first ended, so its start is not repeated.
NORTH = FieldVisit(
    field_id="north",
    swaths=(
        (LatLon(52.0010000, 5.0010000), LatLon(52.0010000, 5.0030000)),
        (LatLon(52.0010500, 5.0030000), LatLon(52.0010500, 5.0010000)),
        (LatLon(52.0011000, 5.0010000), LatLon(52.0011000, 5.0030000)),
    ),
)
SOUTH = FieldVisit(
    field_id="south",
    swaths=(
        (LatLon(51.9990000, 5.0020000), LatLon(51.9990000, 5.0040000)),
        (LatLon(51.9990000, 5.00400007), LatLon(51.9989500, 5.0020000)),
    ),
)


def make_spec(**changes: object) -> MissionSpec:
    """The two-field spec, with ``changes`` applied."""
    values: dict[str, object] = {
        "machine_id": "tractor-7",
        "home": GARAGE,
        "road_speed_kmh": 18.0,
        "work_speed_kmh": 7.2,
        "implement": SERVO,
        "visits": (NORTH, SOUTH),
    }
    values.update(changes)
    return MissionSpec(**values)  # type: ignore[arg-type]


@pytest.fixture
def mission() -> Mission:
    return build_mission(make_spec())


def roles(mission: Mission) -> list[str]:
    return [trace.role for trace in mission.traces]


def index_of(mission: Mission, role: str, field_id: str | None) -> int:
    for index, trace in enumerate(mission.traces):
        if trace.role == role and trace.field_id == field_id:
            return index
    raise AssertionError(f"no {role} item for field {field_id!r}")


# --- layout ---------------------------------------------------------------------------


def test_sequence_numbers_are_contiguous_from_zero(mission: Mission) -> None:
    assert [item.seq for item in mission.items] == list(range(len(mission)))
    assert len(mission.traces) == len(mission.items)


def test_expected_layout(mission: Mission) -> None:
    assert roles(mission) == [
        "home", "speed",
        "transit", "speed", "implement_down",
        "swath_end", "swath_start", "swath_end", "swath_start", "swath_end",
        "implement_up", "speed",
        "transit", "speed", "implement_down",
        "swath_end", "swath_end",
        "implement_up", "speed",
        "return",
    ]  # fmt: skip


def test_item_zero_is_home_at_the_garage(mission: Mission) -> None:
    home, trace = mission.item_for_seq(0)
    assert trace == Trace(None, None, "home")
    assert home.command == mc.MAV_CMD_NAV_WAYPOINT
    assert home.frame == mc.MAV_FRAME_GLOBAL
    assert (home.x, home.y, home.z) == (520000000, 50000000, 0.0)


def test_mission_ends_back_at_the_garage(mission: Mission) -> None:
    last, trace = mission.item_for_seq(len(mission) - 1)
    assert trace.role == "return"
    assert last.command == mc.MAV_CMD_NAV_WAYPOINT
    assert (last.x, last.y) == (520000000, 50000000)


def test_waypoints_are_relative_alt_int_on_the_ground(mission: Mission) -> None:
    for item in mission.items[1:]:
        if item.is_waypoint:
            assert item.frame == mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
            assert item.z == 0.0
        else:
            assert item.frame == mc.MAV_FRAME_MISSION
            assert (item.x, item.y, item.z) == (0, 0, 0.0)
        assert item.autocontinue == 1
        assert item.mission_type == mc.MAV_MISSION_TYPE_MISSION


def test_speeds_change_road_work_road(mission: Mission) -> None:
    speeds = [item for item in mission.items if item.command == mc.MAV_CMD_DO_CHANGE_SPEED]
    assert [item.param2 for item in speeds] == pytest.approx([5.0, 2.0, 5.0, 2.0, 5.0])
    for item in speeds:
        assert item.param1 == mc.SPEED_TYPE_GROUNDSPEED
        assert item.param3 == -1.0
    # The road speed is set before leaving the garage, the work speed after each entry.
    assert mission.items[1].command == mc.MAV_CMD_DO_CHANGE_SPEED
    for field_id in ("north", "south"):
        entry = index_of(mission, "transit", field_id)
        assert mission.items[entry + 1].param2 == pytest.approx(2.0)


@pytest.mark.parametrize("field_id", ["north", "south"])
def test_implement_down_before_first_swath_and_up_after_last(
    mission: Mission, field_id: str
) -> None:
    swath_items = [
        index
        for index, trace in enumerate(mission.traces)
        if trace.field_id == field_id and trace.role in ("swath_start", "swath_end")
    ]
    down = index_of(mission, "implement_down", field_id)
    up = index_of(mission, "implement_up", field_id)
    entry = index_of(mission, "transit", field_id)
    assert entry < down < min(swath_items)
    assert max(swath_items) < up
    assert mission.items[up + 1].command == mc.MAV_CMD_DO_CHANGE_SPEED  # back to road speed
    assert mission.items[up + 1].param2 == pytest.approx(5.0)


def test_every_waypoint_traces_to_field_and_swath(mission: Mission) -> None:
    visits = {visit.field_id: visit for visit in (NORTH, SOUTH)}
    for item, trace in zip(mission.items[1:-1], mission.traces[1:-1], strict=True):
        if not item.is_waypoint:
            continue
        assert trace.field_id is not None and trace.swath_index is not None
        start, end = visits[trace.field_id].swaths[trace.swath_index]
        point = end if trace.role == "swath_end" else start
        assert item.x == round(point.lat * 1e7)
        assert item.y == round(point.lon * 1e7)


def test_each_swath_end_appears_once_in_driving_order(mission: Mission) -> None:
    for visit in (NORTH, SOUTH):
        ends = [
            trace.swath_index
            for trace in mission.traces
            if trace.field_id == visit.field_id and trace.role == "swath_end"
        ]
        assert ends == list(range(len(visit.swaths)))


def test_servo_implement(mission: Mission) -> None:
    down = mission.items[index_of(mission, "implement_down", "north")]
    up = mission.items[index_of(mission, "implement_up", "north")]
    assert down.command == up.command == mc.MAV_CMD_DO_SET_SERVO
    assert (down.param1, down.param2) == (9.0, 1900.0)
    assert (up.param1, up.param2) == (9.0, 1100.0)


def test_relay_implement() -> None:
    mission = build_mission(make_spec(implement=Implement(kind="relay", channel=2)))
    down = mission.items[index_of(mission, "implement_down", "south")]
    up = mission.items[index_of(mission, "implement_up", "south")]
    assert down.command == up.command == mc.MAV_CMD_DO_SET_RELAY
    assert (down.param1, down.param2) == (2.0, 1.0)
    assert (up.param1, up.param2) == (2.0, 0.0)


def test_no_fields_drives_nowhere_but_home() -> None:
    mission = build_mission(make_spec(visits=()))
    assert roles(mission) == ["home", "speed", "return"]


# North with planned turns: after swath 0 a two-point turn, after swath 1 a hop.
TURN_0 = (LatLon(52.0010100, 5.0031000), LatLon(52.0010400, 5.0031000))
NORTH_TURNING = dataclasses.replace(NORTH, turns=(TURN_0, ()))
APPROACH = (LatLon(52.0003000, 5.0002000), LatLon(52.0006000, 5.0008000))
HOME_ROAD = (LatLon(51.9995000, 5.0010000),)


def test_layout_with_turns_and_road_points() -> None:
    mission = build_mission(
        make_spec(
            visits=(dataclasses.replace(NORTH_TURNING, approach=APPROACH), SOUTH),
            return_path=HOME_ROAD,
        )
    )
    assert roles(mission) == [
        "home", "speed",
        "road", "road", "transit", "speed", "implement_down",
        "swath_end",
        "implement_raise", "turn", "turn", "swath_start", "implement_lower", "swath_end",
        "implement_raise", "swath_start", "implement_lower", "swath_end",
        "implement_up", "speed",
        "transit", "speed", "implement_down",
        "swath_end", "swath_end",  # south has no planned turns: the implement stays down
        "implement_up", "speed",
        "road",
        "return",
    ]  # fmt: skip
    traces = mission.traces
    assert [t.field_id for t in traces[2:4]] == ["north", "north"]
    assert traces[-2] == Trace(None, None, "road")
    raise_, lower = mission.items[8], mission.items[12]
    assert (raise_.param1, raise_.param2) == (9.0, 1100.0)  # implement up for the turn
    assert (lower.param1, lower.param2) == (9.0, 1900.0)  # down again on the next swath
    turn_points = [
        (it.x, it.y) for it, t in zip(mission.items, traces, strict=True) if t.role == "turn"
    ]
    assert turn_points == [(round(p.lat * 1e7), round(p.lon * 1e7)) for p in TURN_0]
    assert {t.swath_index for t in traces if t.role == "turn"} == {1}
    # the first lowering and the last raising stay the field's start and finish
    roles_north = [t.role for t in traces if t.field_id == "north"]
    assert roles_north.count("implement_down") == roles_north.count("implement_up") == 1


def test_the_implement_set_before_an_item_is_by_the_last_lowering_or_raising() -> None:
    """What a resumed mission sets the implement to before it sets off
    (``start_mission_commands``: an autopilot that rebooted does not run the item that
    lowered it again, and in a field without planned turns nothing lowers it to the end)."""
    mission = build_mission(
        make_spec(
            visits=(dataclasses.replace(NORTH_TURNING, approach=APPROACH), SOUTH),
            return_path=HOME_ROAD,
        )
    )
    rs = roles(mission)
    setting = [
        (k, mission.items[k].param2)
        for k, r in enumerate(rs)
        if r in ("implement_down", "implement_lower", "implement_raise", "implement_up")
    ]
    assert [p for _, p in setting] == [1900.0, 1100.0] * 4  # down, up: north 3, south 1
    for seq in range(len(mission)):
        last = [k for k, _ in setting if k < seq]
        assert implement_set_before(mission.traces, seq) == (last[-1] if last else None), seq
    # South has no planned turns: after its first swath's end the implement is still down.
    south_end = rs.index("swath_end", rs.index("implement_down", rs.index("implement_up")))
    k = implement_set_before(mission.traces, south_end + 1)
    assert mission.items[k].param2 == 1900.0


def test_a_via_point_at_the_place_of_a_waypoint_beside_it_is_not_sent_twice() -> None:
    """A plan of the demo farm had 122 pairs of waypoints 0-5 cm apart: a turn beginning at
    its swath's end and ending 3 cm from the next start, a road ending at the field's entry,
    a road point at the garage. The swath's and the field's waypoints stay: the mission is
    the one without those via points."""
    north = NORTH.swaths
    near_start = LatLon(north[1][0].lat + 3e-7, north[1][0].lon)  # 3.3 cm from swath 1's start
    turn = (north[0][1], *TURN_0, near_start)
    doubled = dataclasses.replace(NORTH, turns=(turn, ()), approach=(*APPROACH, north[0][0]))
    plain = dataclasses.replace(NORTH, turns=(TURN_0, ()), approach=APPROACH)
    mission = build_mission(make_spec(visits=(doubled,), return_path=(*HOME_ROAD, GARAGE)))
    assert mission == build_mission(make_spec(visits=(plain,), return_path=HOME_ROAD))
    places = [(it.x, it.y) for it in mission.items if it.command == mc.MAV_CMD_NAV_WAYPOINT]
    assert all(a != b for a, b in itertools.pairwise(places))


def test_road_points_are_waypoints_at_road_speed() -> None:
    mission = build_mission(
        make_spec(visits=(dataclasses.replace(NORTH, approach=APPROACH),), return_path=HOME_ROAD)
    )
    road = [it for it, t in zip(mission.items, mission.traces, strict=True) if t.role == "road"]
    assert [(it.x, it.y) for it in road] == [
        (round(p.lat * 1e7), round(p.lon * 1e7)) for p in (*APPROACH, *HOME_ROAD)
    ]
    assert all(it.command == mc.MAV_CMD_NAV_WAYPOINT for it in road)
    first_road = roles(mission).index("road")
    assert mission.items[first_road - 1].param2 == pytest.approx(5.0)  # road speed


def test_item_for_seq_out_of_range(mission: Mission) -> None:
    with pytest.raises(IndexError, match="tractor-7"):
        mission.item_for_seq(len(mission))
    with pytest.raises(IndexError):
        mission.item_for_seq(-1)


# --- validation -----------------------------------------------------------------------


def with_swath(swath: tuple[LatLon, LatLon]) -> tuple[FieldVisit, ...]:
    return (NORTH, dataclasses.replace(SOUTH, swaths=(SOUTH.swaths[0], swath)))


@pytest.mark.parametrize(
    ("changes", "field_id", "message"),
    [
        ({"machine_id": ""}, None, "machine id"),
        ({"home": LatLon(91.0, 5.0)}, None, "garage .* latitude"),
        ({"home": LatLon(52.0, -180.5)}, None, "garage .* longitude"),
        ({"home": LatLon(float("nan"), 5.0)}, None, "latitude"),
        ({"road_speed_kmh": 0.0}, None, "road_speed_kmh"),
        ({"work_speed_kmh": -3.0}, None, "work_speed_kmh"),
        ({"work_speed_kmh": float("inf")}, None, "work_speed_kmh"),
        ({"implement": Implement("hydraulic", 1)}, None, "implement kind"),
        ({"implement": Implement("servo", 0)}, None, "servo channel"),
        ({"implement": Implement("servo", 33)}, None, "servo channel"),
        ({"implement": Implement("relay", 16)}, None, "relay number"),
        ({"implement": Implement("relay", -1)}, None, "relay number"),
        ({"implement": Implement("servo", 9, pwm_down=2300)}, None, "pwm_down"),
        ({"implement": Implement("servo", 9, pwm_up=700)}, None, "pwm_up"),
        ({"visits": (NORTH, dataclasses.replace(SOUTH, swaths=()))}, "south", "no swaths"),
        ({"visits": (NORTH, NORTH)}, "north", "visited twice"),
        ({"visits": (dataclasses.replace(NORTH, field_id=" "),)}, None, "no field id"),
        (
            {"visits": with_swath((LatLon(51.999, 5.002), LatLon(95.0, 5.002)))},
            "south",
            "swath 1 end latitude",
        ),
        (
            {"visits": with_swath((LatLon(51.999, 185.0), LatLon(51.999, 5.002)))},
            "south",
            "swath 1 start longitude",
        ),
        (
            {"visits": with_swath((LatLon(51.999, 5.002), LatLon(51.999, 5.002)))},
            "south",
            "zero length",
        ),
        (
            {"visits": (dataclasses.replace(NORTH, turns=((), (), ())),)},
            "north",
            "3 turn paths for 2 moves",
        ),
        (
            {"visits": (dataclasses.replace(NORTH, turns=((LatLon(99.0, 5.0),),)),)},
            "north",
            "turn point after swath 0 latitude",
        ),
        (
            {"visits": (dataclasses.replace(NORTH, approach=(LatLon(52.0, 190.0),)),)},
            "north",
            "road point 0 before the field longitude",
        ),
        ({"return_path": (LatLon(-95.0, 5.0),)}, None, "road point 0 back to the garage"),
    ],
)
def test_bad_spec_raises_mission_error(
    changes: dict[str, object], field_id: str | None, message: str
) -> None:
    with pytest.raises(MissionError, match=message) as caught:
        make_spec(**changes)
    error = caught.value
    assert isinstance(error, ValueError)
    assert error.field_id == field_id
    if changes.get("machine_id") != "":
        assert error.machine_id == "tractor-7"
        assert "'tractor-7'" in str(error)
    if field_id is not None:
        assert f"field {field_id!r}" in str(error)


def test_relay_ignores_pwm_values() -> None:
    relay = Implement(kind="relay", channel=0, pwm_down=0, pwm_up=0)
    build_mission(make_spec(implement=relay))


# --- MAVLink --------------------------------------------------------------------------


def test_to_mavlink_round_trips_through_the_codec(mission: Mission) -> None:
    messages = mission.to_mavlink(target_system=3, target_component=1)
    assert len(messages) == len(mission)
    sender, receiver = mc.Codec(255, 190), mc.Codec(3, 1)
    stream = b"".join(sender.encode(msg) for msg in messages)
    decoded = receiver.decode(stream)
    assert len(decoded) == len(mission)
    for msg, item in zip(decoded, mission.items, strict=True):
        assert msg.get_type() == "MISSION_ITEM_INT"
        assert (msg.target_system, msg.target_component) == (3, 1)
        assert msg.get_srcSystem() == 255
        for name in (
            "seq", "frame", "command", "current", "autocontinue",
            "param1", "param2", "param3", "param4", "x", "y", "z", "mission_type",
        ):  # fmt: skip
            assert getattr(msg, name) == getattr(item, name), name


@given(
    lat=st.floats(min_value=-90.0, max_value=90.0, allow_nan=False),
    lon=st.floats(min_value=-180.0, max_value=180.0, allow_nan=False),
)
def test_mission_item_int_encode_decode_round_trip(lat: float, lon: float) -> None:
    msg = mc.mission_item_int(
        target_system=1,
        target_component=mc.MAV_COMP_ID_AUTOPILOT1,
        seq=7,
        frame=mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        command=mc.MAV_CMD_NAV_WAYPOINT,
        current=0,
        autocontinue=1,
        param1=0.0,
        param2=0.0,
        param3=0.0,
        param4=0.0,
        x=round(lat * 1e7),
        y=round(lon * 1e7),
        z=0.0,
    )
    frame = mc.Codec(255, 190).encode(msg)
    assert frame[0] == 0xFD  # MAVLink 2
    (decoded,) = mc.Codec(1, 1).decode(frame)
    assert decoded.get_type() == "MISSION_ITEM_INT"
    assert (decoded.x, decoded.y) == (round(lat * 1e7), round(lon * 1e7))
    assert abs(decoded.x / 1e7 - lat) <= 0.5e-7 + 1e-12
    assert abs(decoded.y / 1e7 - lon) <= 0.5e-7 + 1e-12
    assert (decoded.seq, decoded.frame, decoded.command) == (7, 6, 16)


def test_codec_sequence_numbers_increment_and_wrap() -> None:
    codec = mc.Codec(255, 190)
    msg = build_mission(make_spec()).to_mavlink(1)[0]
    seqs = [codec.encode(msg)[4] for _ in range(258)]
    assert seqs[:3] == [0, 1, 2]
    assert seqs[255:] == [255, 0, 1]


@given(
    garbage=st.lists(st.binary(max_size=40), min_size=3, max_size=3),
    seqs=st.lists(st.integers(min_value=0, max_value=65535), min_size=2, max_size=2),
)
def test_codec_decode_skips_garbage(garbage: list[bytes], seqs: list[int]) -> None:
    sender = mc.Codec(255, 190)
    items = build_mission(make_spec()).to_mavlink(1)
    frames = [sender.encode(with_seq(items[2], seq=seq)) for seq in seqs]
    data = garbage[0] + frames[0] + garbage[1] + frames[1] + garbage[2]
    receiver = mc.Codec(1, 1)
    decoded = receiver.decode(data)
    got = [msg.seq for msg in decoded if msg.get_type() == "MISSION_ITEM_INT"]
    assert got == seqs


def test_codec_completes_a_frame_split_across_calls() -> None:
    frame = mc.Codec(255, 190).encode(build_mission(make_spec()).to_mavlink(1)[5])
    receiver = mc.Codec(1, 1)
    assert receiver.decode(b"\x01\x02" + frame[:9]) == []
    (msg,) = receiver.decode(frame[9:])
    assert msg.seq == 5
    receiver.reset()
    assert receiver.decode(frame[:20]) == []
    receiver.reset()
    assert receiver.decode(frame[20:]) == []


def test_codec_rejects_a_corrupted_frame() -> None:
    frame = bytearray(mc.Codec(255, 190).encode(build_mission(make_spec()).to_mavlink(1)[0]))
    frame[15] ^= 0xFF
    assert mc.Codec(1, 1).decode(bytes(frame)) == []


def test_codec_checks_ids() -> None:
    with pytest.raises(ValueError, match="system id"):
        mc.Codec(0, 1)
    with pytest.raises(ValueError, match="component id"):
        mc.Codec(1, 256)


def with_seq(msg: mc.MissionItemIntMessage, seq: int) -> mc.MissionItemIntMessage:
    """A MISSION_ITEM_INT like ``msg`` with another seq."""
    return mc.mission_item_int(
        target_system=msg.target_system,
        target_component=msg.target_component,
        seq=seq,
        frame=msg.frame,
        command=msg.command,
        current=msg.current,
        autocontinue=msg.autocontinue,
        param1=msg.param1,
        param2=msg.param2,
        param3=msg.param3,
        param4=msg.param4,
        x=msg.x,
        y=msg.y,
        z=msg.z,
    )


# --- files ----------------------------------------------------------------------------


def test_waypoints_file_round_trips_through_mavwp(mission: Mission, tmp_path: Path) -> None:
    path = tmp_path / "tractor-7.waypoints"
    write_waypoints(mission, path)
    assert path.read_text(encoding="utf-8").splitlines()[0] == "QGC WPL 110"

    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(mission)
    for item in mission.items:
        wp = loader.wp(item.seq)
        assert wp.seq == item.seq
        assert wp.command == item.command
        assert wp.frame == mc.float_frame(item.frame)
        assert wp.current == item.current
        assert wp.autocontinue == item.autocontinue
        assert abs(wp.x - item.x / 1e7) <= 1e-7
        assert abs(wp.y - item.y / 1e7) <= 1e-7
        assert wp.z == item.z
        assert (wp.param1, wp.param2, wp.param3, wp.param4) == (
            item.param1,
            item.param2,
            item.param3,
            item.param4,
        )


def test_waypoints_frames_are_the_float_ones(mission: Mission, tmp_path: Path) -> None:
    path = tmp_path / "m.waypoints"
    write_waypoints(mission, path)
    lines = path.read_text(encoding="utf-8").splitlines()[1:]
    assert len(lines) == len(mission)
    frames = {int(line.split("\t")[2]) for line in lines}
    assert frames == {
        mc.MAV_FRAME_GLOBAL,
        mc.MAV_FRAME_MISSION,
        mc.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    }
    assert all(len(line.split("\t")) == 12 for line in lines)


def test_qgc_plan_structure(mission: Mission, tmp_path: Path) -> None:
    path = tmp_path / "tractor-7.plan"
    write_qgc_plan(mission, path)
    plan = json.loads(path.read_text(encoding="utf-8"))
    assert plan == qgc_plan(mission)

    assert plan["fileType"] == "Plan"
    assert plan["version"] == 1
    assert plan["groundStation"] == "QGroundControl"
    assert plan["geoFence"] == {"circles": [], "polygons": [], "version": 2}
    assert plan["rallyPoints"] == {"points": [], "version": 2}

    body = plan["mission"]
    assert body["version"] == 2
    assert body["firmwareType"] == 3  # MAV_AUTOPILOT_ARDUPILOTMEGA
    assert body["vehicleType"] == 10  # MAV_TYPE_GROUND_ROVER
    assert body["globalPlanAltitudeMode"] == 1
    assert body["cruiseSpeed"] == pytest.approx(5.0)
    assert body["hoverSpeed"] == pytest.approx(2.0)
    assert body["plannedHomePosition"] == [52.0, 5.0, 0.0]

    # Home travels as plannedHomePosition; QGroundControl re-inserts it as item 0.
    items = body["items"]
    assert len(items) + 1 == len(mission)
    for entry, item in zip(items, mission.items[1:], strict=True):
        assert set(entry) == {"autoContinue", "command", "doJumpId", "frame", "params", "type"}
        assert entry["type"] == "SimpleItem"
        assert entry["autoContinue"] is True
        assert entry["command"] == item.command
        assert entry["doJumpId"] == item.seq
        assert entry["frame"] == mc.float_frame(item.frame)
        assert len(entry["params"]) == 7
        assert entry["params"][:4] == [item.param1, item.param2, item.param3, item.param4]
        assert entry["params"][4] == pytest.approx(item.x / 1e7, abs=1e-9)
        assert entry["params"][5] == pytest.approx(item.y / 1e7, abs=1e-9)
        assert entry["params"][6] == 0.0


def test_the_speed_before_an_item_is_that_of_the_last_change_before_it(mission: Mission) -> None:
    """What a resumed mission is to drive at (link/mission_protocol.py
    ``start_mission_commands``: AUTO starts at WP_SPEED)."""
    speeds = [
        (item.seq, item.param2)
        for item in mission.items
        if item.command == mc.MAV_CMD_DO_CHANGE_SPEED
    ]
    assert len(speeds) >= 2 and speeds[0][0] == 1
    assert mission.speed_before(1) is None  # nothing before the first change
    ends = [*(s for s, _ in speeds[1:]), len(mission)]
    for (seq, speed), after in zip(speeds, ends, strict=True):
        for n in (seq + 1, after - 1):
            if seq < n < len(mission):
                assert mission.speed_before(n) == speed
