"""Progress counts only when the vehicle's own track bears it out (issue 11 §3)."""

from __future__ import annotations

from helpers.messages import position

from dispatcher.daemon import events as ev
from dispatcher.daemon.plausibility import (
    FALLBACK_SPEED_MS,
    REACH_M,
    WAIT_REPORTS,
    WAIT_S,
    ProgressWitness,
    top_speed_ms,
)
from dispatcher.daemon.state import FleetState, Phase
from dispatcher.link import mavlink as mc
from dispatcher.mission.document import PlannedItem

LAT0, LON0 = 44.0, 87.3
M_PER_DEG_LAT = 111_195.0


def item(seq: int, north_m: float, role: str = "swath_end", positioned: bool = True):
    lat = LAT0 + north_m / M_PER_DEG_LAT
    x, y = (round(lat * 1e7), round(LON0 * 1e7)) if positioned else (0, 0)
    return PlannedItem(seq, "F1", seq, role, x, y, 16)


# Home, then waypoints every 100 m north, with a speed change (no position) after item 2.
MISSION = (
    item(0, 0.0, "home"),
    item(1, 100.0),
    item(2, 200.0),
    item(3, 0.0, "speed", positioned=False),
    item(4, 300.0),
    item(5, 400.0),
    item(6, 500.0),
)


def at(north_m: float) -> tuple[float, float]:
    return LAT0 + north_m / M_PER_DEG_LAT, LON0


def reached(events):
    return [e.seq for e in events if isinstance(e, ev.ItemReached)]


def doubted(events):
    return [e for e in events if isinstance(e, ev.ProgressDoubted)]


def witness() -> ProgressWitness:
    w = ProgressWitness()
    w.follow(MISSION, 0)
    return w


def test_a_claim_the_track_bears_out_counts_at_once_or_when_the_fix_comes():
    w = witness()
    for north in (0.0, 50.0, 100.0):
        assert w.observe("v", *at(north), 1.0) == []
    assert reached(w.claim("v", 1, 10.0, False, "MISSION_ITEM_REACHED", 1.0)) == [1]
    # The claim comes before the fix that shows the vehicle there: it waits for it.
    assert w.claim("v", 2, 20.0, False, "MISSION_ITEM_REACHED", 2.0) == []
    assert reached(w.observe("v", *at(199.0), 2.1)) == [2]
    # Item 3 has no position: it passes with item 2.
    assert reached(w.claim("v", 3, 20.0, False, "MISSION_CURRENT", 2.2)) == [3]


def test_a_jump_to_the_last_item_far_from_the_track_is_an_alarm_and_counts_nothing():
    w = witness()
    w.observe("v", *at(0.0), 0.0)
    assert w.claim("v", 6, 5.0, False, "MISSION_ITEM_REACHED", 1.0) == []
    out: list[ev.Event] = []
    for k in range(WAIT_REPORTS):
        out += w.observe("v", *at(60.0), 1.0 + WAIT_S * (k + 1) / WAIT_REPORTS)
    assert reached(out) == []
    [alarm] = doubted(out)
    assert (alarm.seq, alarm.item, alarm.source) == (6, 1, "MISSION_ITEM_REACHED")
    assert alarm.distance_m == 40.0  # at 60 m, 40 m short of item 1 (100 m north)
    # The genuine progress that follows still counts.
    assert reached(w.observe("v", *at(100.0), 5.0) + w.claim("v", 1, 6.0, False, "R", 5.0)) == [1]


def test_one_item_cut_between_fixes_passes_unseen_but_a_parallel_track_passes_nothing():
    w = witness()
    for north in range(0, 220, 20):
        w.observe("v", *at(north), 0.0)
    assert w.passed == 3  # items 1, 2 and the speed change after 2
    # A track 100 m east of the line of items, fixes 20 m apart: it passes none of them.
    east = 100.0 / (M_PER_DEG_LAT * 0.719)
    for north in range(220, 620, 20):
        lat, lon = at(north)
        w.observe("v", lat, lon + east, 1.0)
    assert w.passed == 3
    # One item cut between two fixes far apart is passed when the next one is seen.
    w = witness()
    for north in (0.0, 100.0, 200.0, 250.0, 400.0):  # item 4 (300 m) between fixes
        w.observe("v", *at(north), 2.0)
    assert w.passed == 5


def test_reach_is_documented_and_a_near_miss_within_it_counts():
    w = witness()
    w.observe("v", *at(100.0 - REACH_M + 1.0), 0.0)
    assert w.passed == 1


def test_fleet_state_keeps_the_alarm_and_counts_no_field(dispatch):
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    v.phase = Phase.RUNNING
    home = v.items[0]
    forged = mc.message("MISSION_ITEM_REACHED", seq=len(v.items) - 1)
    events = state.on_message("v1", forged, 1.0)
    for k in range(WAIT_REPORTS):
        events += state.on_message("v1", position(1_000 * k, home.x, home.y), 2.0 + k)
    for e in events:
        state.apply(e, 20.0)
    assert v.reached == 0 and v.alarms == 1 and v.phase is Phase.RUNNING
    assert all(f.status == "pending" for f in state.fields.values())
    assert "not counted" in state.status_doc()["alarms"][0]


def test_after_a_gap_in_its_reports_a_vehicle_is_believed_as_far_as_it_could_drive():
    # A zigzag of swaths 100 m long east-west, 60 m apart.
    east = 1.0 / (M_PER_DEG_LAT * 0.719)
    zigzag = [item(0, 0.0, "home")]
    for k in range(1, 21):
        lat, lon = at(60.0 * ((k + 1) // 2))
        x = round(lat * 1e7)
        y = round((lon + (100.0 * east if k % 4 in (2, 3) else 0.0)) * 1e7)
        zigzag.append(PlannedItem(k, "F1", k, "swath_end", x, y, 16))
    w = ProgressWitness()
    w.follow(tuple(zigzag), 0)
    assert w.top_speed_ms == FALLBACK_SPEED_MS  # the mission sets no speed
    w.observe("v", *at(0.0), 0.0, clock_s=0.0)
    far = zigzag[15]
    # A second of its clock later it cannot have driven 1.9 km of swaths: nothing passes.
    w.observe("v", far.lat, far.lon, 1.0, clock_s=1.0)
    assert w.passed == 0
    assert w.claim("v", 15, 1.0, True, "MISSION_CURRENT", 1.0) == []
    # Five minutes of its clock later it can: everything up to where it is now passes.
    assert reached(w.observe("v", far.lat, far.lon, 2.0, clock_s=300.0)) == [15]
    assert w.passed == 15  # not beyond where it is, though it had the time


def test_the_top_speed_is_the_fastest_speed_change_of_the_mission():
    fast = PlannedItem(3, None, None, "speed", 0, 0, mc.MAV_CMD_DO_CHANGE_SPEED, 1.0, 8.0)
    slow = PlannedItem(4, None, None, "speed", 0, 0, mc.MAV_CMD_DO_CHANGE_SPEED, 1.0, 2.0)
    assert top_speed_ms((*MISSION, fast, slow)) == 8.0


def test_a_position_of_0_0_is_no_position(dispatch):
    # An autopilot without a GPS fix reports 0, 0: the vehicle stays where it was heard.
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    home = v.items[0]
    state.on_message("v1", position(1_000, home.x, home.y), 1.0)
    state.on_message("v1", position(2_000), 2.0)
    assert (v.lat, v.lon) == (home.lat, home.lon)
    assert v.sim_time_s == 2.0  # its clock still counts
