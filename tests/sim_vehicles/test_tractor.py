"""The simulated tractor in simulated time, spoken to through real MAVLink frames."""

from __future__ import annotations

import math

import pytest
from helpers.mavlink_wire import Wire, only, types
from pyproj import Geod

from dispatcher.config.scenario import Vehicle
from dispatcher.link import mavlink as mc
from dispatcher.mission.build import Mission
from sim_vehicles.tractor import MissionState, Mode, RoverParams, SimTractor

GEOD = Geod(ellps="WGS84")
CUSTOM = float(mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)


def send(tractor: SimTractor, wire: Wire, msg: mc.MAVLinkMessage) -> list[mc.MAVLinkMessage]:
    return wire.down(tractor.handle(wire.up(msg), tractor.sim_time))


def texts(messages: list[mc.MAVLinkMessage]) -> list[str]:
    return [mc.statustext(m) for m in messages if m.get_type() == "STATUSTEXT"]


def upload(tractor: SimTractor, wire: Wire, mission: Mission) -> None:
    items = mission.to_mavlink(wire.vehicle_system)
    replies = send(tractor, wire, wire.mission_msg("MISSION_COUNT", count=len(items)))
    while not only(replies, "MISSION_ACK"):
        (request,) = only(replies, "MISSION_REQUEST", "MISSION_REQUEST_INT")
        replies = send(tractor, wire, items[request.seq])
    assert only(replies, "MISSION_ACK")[0].type == mc.MAV_MISSION_ACCEPTED


def ack_of(replies: list[mc.MAVLinkMessage], command: int) -> int:
    (ack,) = only(replies, "COMMAND_ACK")
    assert ack.command == command
    assert (ack.target_system, ack.target_component) == (255, 190)
    return int(ack.result)


def arm_and_start(tractor: SimTractor, wire: Wire) -> list[mc.MAVLinkMessage]:
    arm = send(tractor, wire, wire.command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    assert ack_of(arm, mc.MAV_CMD_COMPONENT_ARM_DISARM) == mc.MAV_RESULT_ACCEPTED
    start = send(tractor, wire, wire.command_long(mc.MAV_CMD_MISSION_START))
    assert ack_of(start, mc.MAV_CMD_MISSION_START) == mc.MAV_RESULT_ACCEPTED
    return start


def leg_times(mission: Mission, road_speed_ms: float) -> list[float]:
    """Arrival time at each navigation item, driving its straight legs at the speeds its
    DO_CHANGE_SPEED items set (the reference the tractor must meet)."""
    speed, t = road_speed_ms, 0.0
    here = mission.items[0]
    arrivals = []
    for item in mission.items[1:]:
        if item.command == mc.MAV_CMD_DO_CHANGE_SPEED:
            speed = item.param2
        elif item.command == mc.MAV_CMD_NAV_WAYPOINT:
            _, _, dist = GEOD.inv(here.lon, here.lat, item.lon, item.lat)
            t += dist / speed
            arrivals.append(t)
            here = item
    return arrivals


def sphere_time(mission: Mission, road_speed_ms: float) -> float:
    """The whole mission's time on a sphere of radius 6371 km (a check on the geodesics)."""
    speed, t, here = road_speed_ms, 0.0, mission.items[0]
    for item in mission.items[1:]:
        if item.command == mc.MAV_CMD_DO_CHANGE_SPEED:
            speed = item.param2
        elif item.command == mc.MAV_CMD_NAV_WAYPOINT:
            p1, p2 = math.radians(here.lat), math.radians(item.lat)
            dl = math.radians(item.lon - here.lon)
            h = math.sin((p2 - p1) / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
            t += 2 * 6371e3 * math.asin(math.sqrt(h)) / speed
            here = item
    return t


def heartbeat_of(tractor: SimTractor) -> mc.MAVLinkMessage:
    (hb,) = only(tractor.heartbeat(tractor.sim_time), "HEARTBEAT")
    return hb


@pytest.mark.parametrize("step_s", [0.5, 37.0, 1e6])
@pytest.mark.parametrize("done", ["stop", "hold"])
def test_drives_a_real_mission_to_the_end(
    vehicle: Vehicle,
    home_lonlat: tuple[float, float],
    mission: Mission,
    wire: Wire,
    step_s: float,
    done: str,
) -> None:
    tractor = SimTractor(vehicle, home_lonlat, params=RoverParams(mission_done=done))  # type: ignore[arg-type]
    upload(tractor, wire, mission)
    events = arm_and_start(tractor, wire)
    while tractor.mission_state is not MissionState.COMPLETE:
        assert tractor.sim_time < 1e4, "the mission never ends"
        events += wire.down(tractor.advance(step_s))

    # every item after home reported, in order, once
    reached = [m.seq for m in only(events, "MISSION_ITEM_REACHED")]
    assert reached == list(range(1, len(mission)))

    # each waypoint reached is followed by a position fix exactly there, at the right time
    expected = iter(leg_times(mission, vehicle.machine.road_speed_kmh / 3.6))
    for i, msg in enumerate(events):
        if msg.get_type() != "MISSION_ITEM_REACHED":
            continue
        item = mission.items[msg.seq]
        if item.command != mc.MAV_CMD_NAV_WAYPOINT:
            continue
        fix = events[i + 1]
        assert fix.get_type() == "GLOBAL_POSITION_INT"
        _, _, miss = GEOD.inv(fix.lon / 1e7, fix.lat / 1e7, item.lon, item.lat)
        assert miss < 0.5
        assert (fix.lat, fix.lon) == (item.x, item.y)
        assert fix.time_boot_ms == pytest.approx(next(expected) * 1000.0, abs=1.0)

    # total time is distance / speed, leg by leg: 3 swaths of ~160 m and 2 turns of 6 m
    # at 1 m/s, ~170 m of road out and ~270 m back at 10 km/h; a sphere agrees with the
    # ellipsoid to 0.5 %
    total = leg_times(mission, vehicle.machine.road_speed_kmh / 3.6)[-1]
    assert total == pytest.approx(sphere_time(mission, 10 / 3.6), rel=5e-3)
    assert total == pytest.approx(3 * 160 + 2 * 6 + (170 + 270) / (10 / 3.6), rel=0.01)
    last_fix = only(events, "GLOBAL_POSITION_INT")[-1]
    assert last_fix.time_boot_ms == pytest.approx(total * 1000.0, abs=1.0)
    assert (tractor.lat, tractor.lon) == (mission.items[-1].lat, mission.items[-1].lon)

    # the end: ArduPilot's "Mission Complete", then stopped in AUTO or switched to HOLD
    assert "Mission Complete" in [m.text for m in only(events, "STATUSTEXT")]
    final = only(events, "MISSION_CURRENT")[-1]
    assert (final.seq, final.total) == (len(mission) - 1, len(mission) - 1)
    assert final.mission_state == mc.MISSION_STATE_COMPLETE
    hb = heartbeat_of(tractor)
    if done == "hold":
        assert tractor.mode is Mode.HOLD
        assert (hb.custom_mode, hb.system_status) == (Mode.HOLD, mc.MAV_STATE_STANDBY)
        assert final.mission_mode == 0
    else:
        assert tractor.mode is Mode.AUTO
        assert (hb.custom_mode, hb.system_status) == (Mode.AUTO, mc.MAV_STATE_ACTIVE)
        assert final.mission_mode == 1
    assert not tractor.implement_down
    later = tractor.telemetry(tractor.sim_time + 60.0)[-1]
    assert (later.lat, later.lon, later.vx, later.vy) == (
        mission.items[-1].x,
        mission.items[-1].y,
        0,
        0,
    )


def test_speeds_and_implement_along_the_way(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat)
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    assert tractor.speed_ms == pytest.approx(10 / 3.6, rel=1e-6)  # item 1: road speed
    arrivals = leg_times(mission, 10 / 3.6)
    tractor.advance(arrivals[0] - 1.0)  # on the road, short of the field
    assert not tractor.implement_down and tractor.current_seq == 2
    (fix,) = tractor.telemetry(tractor.sim_time)
    speed = math.hypot(fix.vx, fix.vy) / 100.0
    assert speed == pytest.approx(10 / 3.6, abs=0.01)
    tractor.advance(10.0)  # along the first swath: work speed, implement down
    assert tractor.implement_down and tractor.speed_ms == 1.0 and tractor.current_seq == 5
    assert tractor.servo_pwm == {9: 1900}
    (fix,) = tractor.telemetry(tractor.sim_time)
    assert (fix.vx, fix.vy, fix.hdg) == (0, 100, 9000)  # due east at 1 m/s
    tractor.advance(arrivals[-2] + 1.0 - tractor.sim_time)  # off the field, going home
    assert not tractor.implement_down and tractor.servo_pwm == {9: 1100}


def test_ardupilot_style_reporting_of_servo_items(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    """ArduPilot itself sends no MISSION_ITEM_REACHED for DO_SET_SERVO (AP_Mission
    completes it without the vehicle's verify callback)."""
    tractor = SimTractor(vehicle, home_lonlat, params=RoverParams(report_all_items=False))
    upload(tractor, wire, mission)
    events = arm_and_start(tractor, wire) + tractor.advance(1e6)
    servo = {i.seq for i in mission.items if i.command == mc.MAV_CMD_DO_SET_SERVO}
    reached = [m.seq for m in only(events, "MISSION_ITEM_REACHED")]
    assert reached == [s for s in range(1, len(mission)) if s not in servo]


def test_refusals_as_ardupilot(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat)
    set_mode = mc.MAV_CMD_DO_SET_MODE
    # no mission: AUTO cannot be entered, by mode change or by MISSION_START
    replies = send(tractor, wire, wire.command_long(set_mode, CUSTOM, Mode.AUTO))
    assert ack_of(replies, set_mode) == mc.MAV_RESULT_FAILED
    assert "No Mission. Can't set AUTO." in [m.text for m in only(replies, "STATUSTEXT")]
    replies = send(tractor, wire, wire.command_long(mc.MAV_CMD_MISSION_START))
    assert ack_of(replies, mc.MAV_CMD_MISSION_START) == mc.MAV_RESULT_FAILED
    assert tractor.mode is Mode.HOLD
    upload(tractor, wire, mission)
    # first/last item of MISSION_START are not supported
    replies = send(tractor, wire, wire.command_long(mc.MAV_CMD_MISSION_START, 2.0, 5.0))
    assert ack_of(replies, mc.MAV_CMD_MISSION_START) == mc.MAV_RESULT_DENIED
    # only custom modes; unknown and unsimulated modes fail
    replies = send(tractor, wire, wire.command_long(set_mode, 0.0, Mode.AUTO))
    assert ack_of(replies, set_mode) == mc.MAV_RESULT_DENIED
    for number in (2, Mode.FOLLOW, 99):
        replies = send(tractor, wire, wire.command_long(set_mode, CUSTOM, number))
        assert ack_of(replies, set_mode) == mc.MAV_RESULT_FAILED
    # arming: 1 arms (again: still accepted), 0 disarms, anything else is unsupported
    arm = mc.MAV_CMD_COMPONENT_ARM_DISARM
    for p1, result, armed in (
        (0.5, mc.MAV_RESULT_UNSUPPORTED, False),
        (1.0, mc.MAV_RESULT_ACCEPTED, True),
        (1.0, mc.MAV_RESULT_ACCEPTED, True),
        (0.0, mc.MAV_RESULT_ACCEPTED, False),
    ):
        assert ack_of(send(tractor, wire, wire.command_long(arm, p1)), arm) == result
        assert tractor.armed is armed
    # speed changes only where a mode has a speed to change
    speed = mc.MAV_CMD_DO_CHANGE_SPEED
    replies = send(tractor, wire, wire.command_long(speed, mc.SPEED_TYPE_GROUNDSPEED, 2.0))
    assert ack_of(replies, speed) == mc.MAV_RESULT_FAILED  # in HOLD
    replies = send(tractor, wire, wire.command_long(speed, mc.SPEED_TYPE_CLIMB_SPEED, 2.0))
    assert ack_of(replies, speed) == mc.MAV_RESULT_DENIED
    replies = send(tractor, wire, wire.command_long(mc.MAV_CMD_DO_FENCE_ENABLE, 1.0))
    assert ack_of(replies, mc.MAV_CMD_DO_FENCE_ENABLE) == mc.MAV_RESULT_UNSUPPORTED


def test_auto_while_disarmed_waits_and_arming_sets_off(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat)
    upload(tractor, wire, mission)
    replies = send(tractor, wire, wire.command_long(mc.MAV_CMD_DO_SET_MODE, CUSTOM, Mode.AUTO))
    assert ack_of(replies, mc.MAV_CMD_DO_SET_MODE) == mc.MAV_RESULT_ACCEPTED
    (current,) = only(replies, "MISSION_CURRENT")
    assert (current.seq, current.mission_state, current.mission_mode) == (
        2,
        mc.MISSION_STATE_ACTIVE,
        1,
    )
    tractor.advance(120.0)
    assert (tractor.lat, tractor.lon) == (home_lonlat[1], home_lonlat[0])
    hb = heartbeat_of(tractor)
    assert hb.base_mode == (mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mc.MAV_MODE_FLAG_GUIDED_ENABLED)
    send(tractor, wire, wire.command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1.0))
    tractor.advance(10.0)
    _, _, moved = GEOD.inv(home_lonlat[0], home_lonlat[1], tractor.lon, tractor.lat)
    assert moved == pytest.approx(10 * 10 / 3.6, rel=1e-6)
    assert heartbeat_of(tractor).base_mode & mc.MAV_MODE_FLAG_SAFETY_ARMED


def test_hold_then_auto_resumes_the_leg_at_the_speed_it_had(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    """MIS_RESTART = 0 resumes; entering AUTO keeps the speed the mission set (ArduPilot
    4.7 SITL, put back in AUTO after its failsafe: on at the work speed, not WP_SPEED)."""
    tractor = SimTractor(vehicle, home_lonlat)
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    tractor.advance(leg_times(mission, 10 / 3.6)[0] + 20.0)  # on the first swath
    assert (tractor.current_seq, tractor.speed_ms) == (5, 1.0)
    replies = send(tractor, wire, wire.command_long(mc.MAV_CMD_DO_SET_MODE, CUSTOM, Mode.HOLD))
    assert only(replies, "MISSION_CURRENT")[0].mission_state == mc.MISSION_STATE_NOT_STARTED
    here = (tractor.lat, tractor.lon)
    tractor.advance(300.0)
    assert (tractor.lat, tractor.lon) == here
    send(tractor, wire, wire.command_long(mc.MAV_CMD_DO_SET_MODE, CUSTOM, Mode.AUTO))
    assert (tractor.current_seq, tractor.mission_state) == (5, MissionState.RUNNING)
    assert tractor.speed_ms == 1.0
    events = tractor.advance(1e5)
    assert [m.seq for m in only(events, "MISSION_ITEM_REACHED")] == list(range(5, len(mission)))


def test_restart_a_finished_mission_with_do_set_mission_current(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat)  # stays in AUTO at the end
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    tractor.advance(1e5)
    assert tractor.mission_state is MissionState.COMPLETE and tractor.mode is Mode.AUTO
    # MISSION_START in AUTO changes nothing (the mode is already AUTO) ...
    send(tractor, wire, wire.command_long(mc.MAV_CMD_MISSION_START))
    assert tractor.mission_state is MissionState.COMPLETE
    # ... DO_SET_MISSION_CURRENT with reset runs it again
    cmd = mc.MAV_CMD_DO_SET_MISSION_CURRENT
    replies = send(tractor, wire, wire.command_long(cmd, 1.0, 1.0))
    assert ack_of(replies, cmd) == mc.MAV_RESULT_ACCEPTED
    assert [m.seq for m in only(replies, "MISSION_ITEM_REACHED")] == [1]
    assert tractor.mission_state is MissionState.RUNNING
    events = tractor.advance(1e5)
    assert [m.seq for m in only(events, "MISSION_ITEM_REACHED")] == list(range(2, len(mission)))
    replies = send(tractor, wire, wire.command_long(cmd, float(len(mission))))
    assert ack_of(replies, cmd) == mc.MAV_RESULT_DENIED


def test_set_mode_message_and_rtl(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat)
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    tractor.advance(60.0)
    set_mode = mc.message(
        "SET_MODE",
        target_system=wire.vehicle_system,
        base_mode=mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        custom_mode=Mode.RTL,
    )
    replies = send(tractor, wire, set_mode)
    assert ack_of(replies, 11) == mc.MAV_RESULT_ACCEPTED  # ArduPilot acks SET_MODE as "11"
    assert tractor.mode is Mode.RTL
    _, _, away = GEOD.inv(home_lonlat[0], home_lonlat[1], tractor.lon, tractor.lat)
    events = tractor.advance(away / (10 / 3.6) + 1.0)
    (fix,) = only(events, "GLOBAL_POSITION_INT")
    assert (fix.lat, fix.lon) == (round(home_lonlat[1] * 1e7), round(home_lonlat[0] * 1e7))
    assert fix.time_boot_ms == pytest.approx((60.0 + away / (10 / 3.6)) * 1000, abs=1)
    assert heartbeat_of(tractor).custom_mode == Mode.RTL


def test_heartbeat_time_and_addressing(
    vehicle: Vehicle, home_lonlat: tuple[float, float], wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat, unix_epoch_s=1_700_000_000.0)
    hb, system_time, current = tractor.heartbeat(12.345)
    assert (hb.type, hb.autopilot) == (mc.MAV_TYPE_GROUND_ROVER, mc.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert (hb.base_mode, hb.custom_mode) == (mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, Mode.HOLD)
    assert hb.system_status == mc.MAV_STATE_STANDBY
    assert system_time.time_boot_ms == 12345
    assert system_time.time_unix_usec == 1_700_000_012_345_000
    assert (current.mission_state, current.total) == (mc.MISSION_STATE_NO_MISSION, 0)
    (fix,) = wire.down(tractor.telemetry(20.0))
    assert (fix.time_boot_ms, fix.lat, fix.lon) == (
        20000,
        round(home_lonlat[1] * 1e7),
        round(home_lonlat[0] * 1e7),
    )
    assert (fix.get_srcSystem(), fix.get_srcComponent()) == (7, mc.MAV_COMP_ID_AUTOPILOT1)
    # addressed to someone else: ignored; to everyone (0): answered
    other = Wire(8)
    assert (
        tractor.handle(other.up(other.command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)), 20.0)
        == []
    )
    broadcast = wire.command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    broadcast.target_system = 0
    assert types(send(tractor, wire, broadcast)) == ["COMMAND_ACK"]


def test_breakdown_silences_and_stops_the_vehicle(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat, fail_after_s=30.0)
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    assert tractor.advance(20.0) == [] and not tractor.failed
    tractor.advance(100.0)
    assert tractor.failed
    _, _, moved = GEOD.inv(home_lonlat[0], home_lonlat[1], tractor.lon, tractor.lat)
    assert moved == pytest.approx(30.0 * 10 / 3.6, rel=1e-6)  # stopped when it broke
    assert tractor.heartbeat(200.0) == []
    assert tractor.telemetry(200.0) == []
    assert send(tractor, wire, wire.command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)) == []
    assert tractor.on_link_tick(1000.0) == []


def test_a_dead_uplink_hears_nothing_until_it_comes_back(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    """``deaf_until_s``: no command is heard (nor answered) until then, and the vehicle
    reports as ever meanwhile; from then on it hears and answers."""
    tractor = SimTractor(vehicle, home_lonlat, deaf_until_s=30.0)
    arm = wire.command_long(mc.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    tractor.advance(10.0)
    assert send(tractor, wire, arm) == [] and not tractor.armed
    assert tractor.heartbeat(10.0) and tractor.telemetry(10.0)
    assert send(tractor, wire, wire.mission_msg("MISSION_COUNT", count=3)) == []
    tractor.advance(31.0)
    upload(tractor, wire, mission)
    assert ack_of(send(tractor, wire, arm), mc.MAV_CMD_COMPONENT_ARM_DISARM) == (
        mc.MAV_RESULT_ACCEPTED
    )
    with pytest.raises(ValueError, match="deaf_until_s"):
        SimTractor(vehicle, home_lonlat, deaf_until_s=-1.0)


def test_broken_from_boot_never_speaks(vehicle: Vehicle, home_lonlat: tuple[float, float]) -> None:
    tractor = SimTractor(vehicle, home_lonlat, fail_after_s=0.0)
    assert tractor.heartbeat(0.0) == [] and tractor.failed


def test_mission_set_current_message_moves_the_next_start(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat)
    upload(tractor, wire, mission)
    set_current = mc.message(
        "MISSION_SET_CURRENT",
        target_system=wire.vehicle_system,
        target_component=wire.vehicle_component,
        seq=6,
    )
    replies = send(tractor, wire, set_current)
    (current,) = only(replies, "MISSION_CURRENT")
    assert (current.seq, current.mission_state) == (6, mc.MISSION_STATE_NOT_STARTED)
    events = arm_and_start(tractor, wire) + tractor.advance(1e5)
    assert [m.seq for m in only(events, "MISSION_ITEM_REACHED")] == list(range(6, len(mission)))


def test_params_are_checked() -> None:
    with pytest.raises(ValueError, match="initial_mode"):
        RoverParams(initial_mode=Mode.AUTO)
    with pytest.raises(ValueError, match="mission_done"):
        RoverParams(mission_done="loiter")  # type: ignore[arg-type]


def test_the_ground_station_failsafe_holds_where_the_heartbeats_stopped(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(vehicle, home_lonlat, params=RoverParams(gcs_failsafe_s=5.0))
    gcs_beat = mc.peer_heartbeat(mc.MAV_TYPE_GCS)
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    tractor.advance(20.0)  # no ground station heard yet: no failsafe
    assert tractor.mode == Mode.AUTO
    for _ in range(10):  # heard every 4 s: driving on
        send(tractor, wire, gcs_beat)
        tractor.advance(4.0)
    assert tractor.mode == Mode.AUTO
    send(tractor, wire, gcs_beat)
    heard_at, seq = tractor.sim_time, tractor.current_seq
    events = wire.down(tractor.advance(60.0))
    assert tractor.mode == Mode.HOLD and tractor.armed
    assert "GCS Failsafe" in texts(events)
    (beat,) = only(wire.down(tractor.heartbeat(tractor.sim_time)), "HEARTBEAT")
    assert beat.system_status == mc.MAV_STATE_CRITICAL  # as SITL says it in the failsafe
    lat, lon = tractor.lat, tractor.lon
    tractor.advance(100.0)  # it stands where the failsafe stopped it, 5 s after the last
    assert (tractor.lat, tractor.lon) == (lat, lon)
    back = send(tractor, wire, gcs_beat)  # the ground station is back
    assert [t for t in texts(back) if "Failsafe" in t] == ["GCS Failsafe Cleared"]
    back = send(tractor, wire, gcs_beat)  # said once
    assert not [t for t in texts(back) if "Failsafe" in t]
    (beat,) = only(wire.down(tractor.heartbeat(tractor.sim_time)), "HEARTBEAT")
    assert beat.system_status == mc.MAV_STATE_STANDBY
    tractor.advance(10.0)  # it stays in HOLD (the ground station starts it again)
    assert tractor.mode == Mode.HOLD and tractor.current_seq >= seq
    assert heard_at + 5.0 <= tractor.sim_time
    with pytest.raises(ValueError, match="gcs_failsafe_s"):
        RoverParams(gcs_failsafe_s=0.0)


@pytest.mark.parametrize("how", ["stall_after_s", "stall()"])
def test_a_stalled_vehicle_stands_still_armed_in_auto_and_keeps_reporting(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire, how: str
) -> None:
    tractor = SimTractor(
        vehicle, home_lonlat, stall_after_s=30.0 if how == "stall_after_s" else None
    )
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    wire.down(tractor.advance(30.0))
    if how == "stall()":
        tractor.stall()
    wire.down(tractor.advance(1e-9 if how == "stall()" else 0.0))
    assert tractor.stalled and not tractor.failed
    _, _, moved = GEOD.inv(home_lonlat[0], home_lonlat[1], tractor.lon, tractor.lat)
    assert moved == pytest.approx(30.0 * 10 / 3.6, rel=1e-6)  # stopped where it stalled
    lat, lon, seq = tractor.lat, tractor.lon, tractor.current_seq
    events: list[mc.MAVLinkMessage] = []
    for _ in range(100):  # 1000 s: long enough for the whole mission
        events += wire.down(tractor.advance(10.0))
        events += wire.down(tractor.heartbeat(tractor.sim_time))
        events += wire.down(tractor.telemetry(tractor.sim_time))
    assert not only(events, "MISSION_ITEM_REACHED")
    assert (tractor.lat, tractor.lon, tractor.current_seq) == (lat, lon, seq)
    assert tractor.mission_state is MissionState.RUNNING
    beats = only(events, "HEARTBEAT")
    assert len(beats) == 100
    assert all(hb.custom_mode == Mode.AUTO for hb in beats)
    assert all(hb.base_mode & mc.MAV_MODE_FLAG_SAFETY_ARMED for hb in beats)
    currents = only(events, "MISSION_CURRENT")
    assert {(m.seq, m.mission_state) for m in currents} == {(seq, mc.MISSION_STATE_ACTIVE)}
    positions = only(events, "GLOBAL_POSITION_INT")
    assert len(positions) == 100
    assert {(p.lat, p.lon, p.vx, p.vy) for p in positions} == {
        (round(lat * 1e7), round(lon * 1e7), 0, 0)
    }
    # The autopilot still answers: it can be told to hold and to go home (where it stays).
    hold = send(tractor, wire, wire.command_long(mc.MAV_CMD_DO_SET_MODE, CUSTOM, Mode.HOLD))
    assert ack_of(hold, mc.MAV_CMD_DO_SET_MODE) == mc.MAV_RESULT_ACCEPTED
    assert tractor.mode == Mode.HOLD


def test_a_stall_comes_in_time_order_with_the_ground_station_failsafe(
    vehicle: Vehicle, home_lonlat: tuple[float, float], mission: Mission, wire: Wire
) -> None:
    tractor = SimTractor(
        vehicle, home_lonlat, params=RoverParams(gcs_failsafe_s=50.0), stall_after_s=20.0
    )
    upload(tractor, wire, mission)
    arm_and_start(tractor, wire)
    send(tractor, wire, mc.peer_heartbeat(mc.MAV_TYPE_GCS))
    wire.down(tractor.advance(500.0))  # stalls at 20 s, fails safe to HOLD at 50 s
    assert tractor.stalled and tractor.mode == Mode.HOLD
    _, _, moved = GEOD.inv(home_lonlat[0], home_lonlat[1], tractor.lon, tractor.lat)
    assert moved == pytest.approx(20.0 * 10 / 3.6, rel=1e-6)
    with pytest.raises(ValueError, match="stall_after_s"):
        SimTractor(vehicle, home_lonlat, stall_after_s=-1.0)
