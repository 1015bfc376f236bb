"""Missions sent in windows (dispatcher/mission/window.py): how much a vehicle holds, the
top-up while it drives, and a re-plan that leaves what it holds alone."""

import dataclasses

import pytest
from helpers.daemon import daemon_for, feed, heartbeat, mission_current, running_events
from helpers.messages import from_vehicle

from dispatcher.daemon import events as ev
from dispatcher.daemon.state import FleetState, Phase
from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import Outcome
from dispatcher.mission.build import Mission
from dispatcher.mission.job import DispatchJob
from dispatcher.mission.window import FIELD_ENDS, ROUTE_ENDS, shortest, window

STATE_ACTIVE = mc.MISSION_STATE_ACTIVE


@pytest.mark.parametrize("size", [1, 5, 12, 20, 30])
def test_windows_end_after_a_field_and_cover_the_mission(dispatch, size):
    for m in dispatch.document.machines:
        items, held, ends = m.items, 1, []
        while held < len(items):
            nxt = window(items, held, size)
            assert nxt > held
            ends.append(nxt)
            held = nxt
        assert ends[-1] == len(items)
        for end in ends[:-1]:
            last = items[end - 1]
            # the first waypoint after the implement went up: a route may end there
            assert last.is_nav and last.role in ROUTE_ENDS
            before = [i.role for i in items[:end] if i.role in FIELD_ENDS or i.is_nav]
            assert FIELD_ENDS & set(before)
        # as many whole fields as fit, and never less than one
        first_field_end = next(k for k, i in enumerate(items) if i.role in FIELD_ENDS)
        assert ends[0] > first_field_end


def test_the_way_home_comes_last_and_no_windows_send_the_mission_whole(dispatch):
    items = dispatch.document.machines[0].items
    assert window(items, 1, 0) == len(items)
    last_field_end = max(k for k, i in enumerate(items) if i.role in FIELD_ENDS)
    # a window as big as the mission still ends after the last field, before the way home
    end = window(items, 1, len(items))
    assert last_field_end < end < len(items) and items[end - 1].role in ROUTE_ENDS
    assert window(items, end, 5) == len(items)


def windowed(dispatch, size=20):
    daemon = daemon_for(dispatch)
    daemon.config.window_items = size
    return daemon


def drive(daemon, vid, reached, now):
    """The vehicle started on its mission and reached item ``reached``."""
    v = daemon.state.vehicles[vid]
    for event in running_events(vid, reached):
        if isinstance(event, ev.UploadStarted):
            event = ev.UploadStarted(vid, 1, window(v.items, 1, daemon.config.window_items))
        daemon.state.apply(event, now)
    v.mode, v.armed = 10, True
    return v


def answer_read_back(daemon, vid, sysid, now):
    """The vehicle answers the daemon's read-back with what it holds (ours)."""
    link = daemon.links[vid]
    v = daemon.state.vehicles[vid]
    held = daemon.job.missions[vid].to_mavlink(255)[: v.held]
    count = mc.message(
        "MISSION_COUNT", target_system=255, target_component=190, count=len(held), mission_type=0
    )
    for msg in link.download.on_message(from_vehicle(count, sysid), now):
        assert msg.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK")
        if msg.get_type() == "MISSION_REQUEST_INT":
            assert msg.seq >= link.download.first  # only what the top-up added is read
    for item in held[link.download.first :]:
        link.download.on_message(from_vehicle(item, sysid), now)
    assert link.download.outcome is Outcome.DONE


def test_the_first_upload_sends_a_window(dispatch):
    daemon = windowed(dispatch)
    v = daemon.state.vehicles["v1"]
    for vid, veh in daemon.state.vehicles.items():
        daemon.state.apply(ev.VehicleSeen(vid), 0.0)
        feed(daemon.state, vid, from_vehicle(mc.peer_heartbeat(mc.MAV_TYPE_GROUND_ROVER), 11), 0.0)
        veh.system_status = mc.MAV_STATE_STANDBY
    daemon._advance("v1", 0.0)
    count = daemon.publishers["v1"].sent()[-1]
    assert count.get_type() == "MISSION_COUNT"
    assert count.count == v.held == window(v.items, 1, 20) < len(v.items)


@pytest.mark.parametrize("reached_lost", [0, 2])
@pytest.mark.parametrize("renumbered", [False, True])
def test_a_vehicle_near_the_end_of_its_window_is_topped_up_and_started_if_it_stopped(
    dispatch, reached_lost, renumbered
):
    """``reached_lost``: the last items' MISSION_ITEM_REACHED lost on the way; its autopilot
    says its mission is complete all the same, and it goes on at the first new item.
    ``renumbered``: watched as renumbered too (link/numbering.py): started once, by the
    top-up's end, not also by the watch."""
    daemon = windowed(dispatch)
    vid = "v1"
    v = drive(daemon, vid, 5, 0.0)
    held = v.held
    daemon._advance(vid, 1.0)  # planned_s: items 5..held-1 take longer than the lead at 1x
    assert daemon.links[vid].upload is None
    v.reached = v.current = held - 1  # at the end of its window: its mission complete
    feed(daemon.state, vid, mission_current(11, held - 1, held - 1, mc.MISSION_STATE_COMPLETE), 2.0)
    v.reached -= reached_lost
    assert daemon.state.stalled_for(v, 0.0, 100.0) is None  # waiting, not stalled
    daemon._advance(vid, 2.0)
    link = daemon.links[vid]
    assert link.upload is not None and link.topup_from == held
    assert v.held == window(v.items, held, 20) > held
    assert daemon.state.stalled_for(v, 0.0, 100.0) is None  # its next window on its way
    count = daemon.publishers[vid].sent()[-1]
    assert count.get_type() == "MISSION_COUNT" and count.count == v.held
    link.upload.outcome = Outcome.DONE  # every item asked for and sent
    daemon._advance(vid, 3.0)
    assert link.download is not None and link.download.first == held
    link.renumbered = renumbered
    answer_read_back(daemon, vid, 11, 3.5)
    sent = len(daemon.publishers[vid].sent())
    daemon._advance(vid, 4.0)
    assert link.topup_from is None and daemon.topups == [(vid, v.held)]
    # it stood at the end of its old window: HOLD (it is in AUTO), then on at the next item
    commands = [(m.command, m.param1, m.param2) for m in daemon.publishers[vid].sent()[sent:]]
    assert commands == [(mc.MAV_CMD_DO_SET_MODE, 1.0, 4.0)]
    assert v.phase is Phase.STARTING and link.start is not None
    assert link.start_item == held


def test_a_vehicle_heard_to_stand_at_its_old_windows_end_after_its_top_up_is_started_again(
    dispatch,
):
    """A lossy radio (CI, 30 % loss): the tractor drove the last items of its window while
    the top-up went up; its reports of the last item and of its mission's end were lost, so
    when the read-back ended it was taken to be driving. Its autopilot says it is complete
    at the end of its old window only afterwards (every second, with the longer total):
    started again then, at the first new item, not left standing for ever (the run waited
    240 s for it); once, not again while the start's news settles."""
    daemon = windowed(dispatch)
    daemon.config.topup_lead_s = 1e6  # its top-up due at once
    vid = "v1"
    v = drive(daemon, vid, 5, 0.0)
    held = v.held
    feed(daemon.state, vid, mission_current(11, held - 3, held - 1, STATE_ACTIVE), 1.0)
    daemon._advance(vid, 1.0)
    link = daemon.links[vid]
    assert link.upload is not None and link.topup_from == held
    link.upload.outcome = Outcome.DONE
    daemon._advance(vid, 2.0)
    answer_read_back(daemon, vid, 11, 2.5)
    daemon.config.topup_lead_s = 0.0  # its next window not yet due
    sent = len(daemon.publishers[vid].sent())
    daemon._advance(vid, 3.0)
    assert link.topup_from is None and link.start is None  # it drives, as far as is known
    assert daemon.publishers[vid].sent()[sent:] == []
    stands = mission_current(11, held - 1, v.held - 1, mc.MISSION_STATE_COMPLETE)
    feed(daemon.state, vid, stands, 4.0)
    assert v.at_window_end and daemon.state.stalled_for(v, 0.0, 100.0) is None
    daemon._advance(vid, 4.0)
    commands = [(m.command, m.param1, m.param2) for m in daemon.publishers[vid].sent()[sent:]]
    assert commands == [(mc.MAV_CMD_DO_SET_MODE, 1.0, 4.0)]  # HOLD, then on (in AUTO)
    assert link.start is not None and link.start_item == held
    assert daemon.window_waits == 1
    # started; its next report late: what it said before does not start it twice
    link.start.outcome = Outcome.DONE
    daemon.state.apply(ev.MissionStarted(vid, held), 5.0)
    sent = len(daemon.publishers[vid].sent())
    for now in (6.0, 8.0, 30.0):
        daemon._advance(vid, now)
    assert daemon.publishers[vid].sent()[sent:] == [] and daemon.window_waits == 1


def test_a_replan_that_leaves_the_window_alone_uploads_nothing_now(dispatch):
    state = FleetState(dispatch.document)
    vid = dispatch.document.machines[0].id
    for event in running_events(vid, 5):
        state.apply(event, 1.0)
    v = state.vehicles[vid]
    state.apply(ev.WindowExtended(vid, 20), 1.0)
    old = v.items
    # the new plan changes the route after the window only
    new_items = tuple(
        dataclasses.replace(i, x=i.x + 10) if k >= 25 else i for k, i in enumerate(old)
    )
    machine = dataclasses.replace(dispatch.document.machines[0], items=new_items)
    doc = dataclasses.replace(dispatch.document, machines=(machine,)).with_id()
    state.apply(ev.PlanReplaced(ev.FLEET, doc.plan_id, "test", doc.to_dict()), 2.0)
    assert v.phase is Phase.RUNNING and not v.switch and v.reached == 5
    assert v.items == new_items and v.held == 20
    # one that changes inside the window is switched (uploaded under way)
    inside = tuple(dataclasses.replace(i, x=i.x + 10) if k >= 10 else i for k, i in enumerate(old))
    machine = dataclasses.replace(machine, items=inside)
    doc = dataclasses.replace(dispatch.document, machines=(machine,)).with_id()
    state.apply(ev.PlanReplaced(ev.FLEET, doc.plan_id, "again", doc.to_dict()), 3.0)
    assert v.switch and v.route_from == 10


def test_a_vehicle_that_finished_while_re_planning_goes_on_after_its_mission(dispatch):
    """Done while the re-plan ran: a new plan that sends it on after its mission has it
    upload and start there, never again from item 1 (it would work its fields twice); one
    whose mission did not change stays done."""
    state = FleetState(dispatch.document)
    vid = dispatch.document.machines[0].id
    v = state.vehicles[vid]
    last = len(v.items) - 1
    for event in running_events(vid, last):
        state.apply(event, 1.0)
    assert v.phase is Phase.DONE
    same = dataclasses.replace(dispatch.document, plan_id="").with_id()
    state.apply(ev.PlanReplaced(ev.FLEET, same.plan_id, "unchanged", same.to_dict()), 2.0)
    assert v.phase is Phase.DONE and v.reached == last
    old = v.items
    more = tuple(dataclasses.replace(i, seq=len(old) + k) for k, i in enumerate(old[1:]))
    machine = dataclasses.replace(dispatch.document.machines[0], items=old + more)
    doc = dataclasses.replace(dispatch.document, machines=(machine,)).with_id()
    state.apply(ev.PlanReplaced(ev.FLEET, doc.plan_id, "more", doc.to_dict()), 3.0)
    assert v.phase is Phase.ALIVE and v.reached == last and v.resume_item == len(old)


def tracked_to_the_end_of_its_window(dispatch):
    """v1 driving its first window with the next one on its way (it holds the first), its
    track along it to its last item, no MISSION_ITEM_REACHED of that one: the daemon, v1,
    and how many items the first window holds."""
    daemon = windowed(dispatch)
    v = drive(daemon, "v1", 5, 0.0)
    held = v.held
    daemon.state.apply(ev.WindowExtended("v1", window(v.items, held, 20)), 1.0)
    feed(daemon.state, "v1", mission_current(11, held - 2, held - 1, mc.MISSION_STATE_ACTIVE), 5.0)
    for k in range(5, held):
        fix = mc.message(
            "GLOBAL_POSITION_INT", time_boot_ms=1000 * k, lat=v.items[k].x, lon=v.items[k].y,
            alt=0, relative_alt=0, vx=0, vy=0, vz=0, hdg=0,
        )  # fmt: skip
        feed(daemon.state, "v1", from_vehicle(fix, 11), 5.0 + 0.1 * k)
    return daemon, v, held


def test_the_end_of_the_window_held_is_read_from_mission_current_while_the_next_is_on_its_way(
    dispatch,
):
    """Its MISSION_ITEM_REACHED for the last item of its window lost, and the next window
    on its way (the vehicle still holds the old one): MISSION_CURRENT of the window it
    holds says it reached its end, so it waits there, not taken for stalled."""
    daemon, v, held = tracked_to_the_end_of_its_window(dispatch)
    vid = v.id
    assert v.held > held and v.held_before == held
    assert v.reached < held - 1  # no MISSION_ITEM_REACHED of its last item
    complete = mission_current(11, held - 1, held - 1, mc.MISSION_STATE_COMPLETE)
    feed(daemon.state, vid, complete, 9.0)
    assert v.reached == held - 1 and v.at_window_end
    assert daemon.state.stalled_for(v, 0.0, 100.0) is None


def test_a_vehicle_standing_complete_given_its_next_window_is_not_taken_to_have_driven_it(
    dispatch,
):
    """ArduPilot stands at the end of the window it held, its mission complete (MISSION_CURRENT
    seq = total = that item); once the next window is on board it still says complete, at
    the same seq, but with the longer mission's total (Rover 4.7 SITL: (4, 4, complete),
    then (4, 14, complete) after a longer upload). That is where it stands, not a claim to
    have driven the new window: counted so, the claim was doubted as the track never got
    there (a demo at 1 714x: four alarms, each at a wait at a window's end)."""
    daemon, v, held = tracked_to_the_end_of_its_window(dispatch)
    vid = v.id
    feed(daemon.state, vid, mission_current(11, held - 1, held - 1, mc.MISSION_STATE_COMPLETE), 9.0)
    assert v.reached == held - 1
    # the next window on board: complete still, at the item it stands at, of a longer mission
    stands = mission_current(11, held - 1, v.held - 1, mc.MISSION_STATE_COMPLETE)
    feed(daemon.state, vid, stands, 10.0)
    assert v.reached == held - 1 and v.mission_total == v.held - 1
    assert v.witness.claims == []  # nothing claimed beyond where it stands
    assert v.go_on_item == held and v.at_window_end


def test_a_driving_vehicles_new_route_goes_from_where_it_is_to_the_shortest_window(dispatch):
    """A vehicle re-planned deep in its mission is sent home and the items from the one it
    drives to, up to the first place a window of its new route may end (here the end of a
    field added to it): renumbered even when it may
    reach that item before the upload is on board (a top-up then sends the prefix), and
    sent on to it in the new numbers once acknowledged."""
    daemon = windowed(dispatch)
    daemon._outruns = lambda *args: False  # fast: it would get there before the upload
    vid = "v1"
    daemon.state.vehicles["v2"].phase = Phase.DONE
    v = drive(daemon, vid, 35, 0.0)
    daemon.state.apply(ev.WindowExtended(vid, len(v.items)), 0.5)
    running = heartbeat(11)
    running.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    feed(daemon.state, vid, running, 1.0)
    feed(daemon.state, vid, mission_current(11, 36, len(v.items) - 1, STATE_ACTIVE), 1.0)
    assert v.driving and v.current == 36
    link = daemon.links[vid]
    daemon._send_window(v, link, 1.5)  # a top-up: the prefix, as numbered before
    assert link.numbered == (1, v.held)
    # its new route: one more field (a copy of its second, moved), then on as before
    old = v.items
    extra = tuple(dataclasses.replace(i, x=i.x + 10) for i in old[18:38])
    new_items = old[:38] + tuple(
        dataclasses.replace(i, seq=38 + k) for k, i in enumerate(extra + old[38:])
    )
    machine = dataclasses.replace(dispatch.document.machines[0], items=new_items)
    doc = dataclasses.replace(dispatch.document, machines=(machine,)).with_id()
    mission = daemon.job.missions[vid]
    order = [*range(38), *range(18, 38), *range(38, len(old))]
    moved = [dataclasses.replace(mission.items[j], seq=k) for k, j in enumerate(order)]
    mission = Mission(vid, tuple(moved), tuple(mission.traces[j] for j in order))
    daemon.job = DispatchJob(doc, {**daemon.job.missions, vid: mission}, {})
    daemon.state.apply(ev.PlanReplaced(ev.FLEET, doc.plan_id, "test", doc.to_dict()), 2.0)
    assert v.switch and v.route_from == 38
    link.switch_from = v.route_from
    daemon._upload_switch(v, link, 2.0)
    assert v.held == window(new_items, 38, shortest(20)) < len(new_items)
    count = daemon.publishers[vid].sent()[-1]
    assert count.get_type() == "MISSION_COUNT" and count.count == 1 + v.held - 36
    assert link.numbered == (36, count.count)
    link.upload.outcome = Outcome.DONE
    daemon._advance(vid, 3.0)
    assert v.numbering.base == 36
    (sent,) = [m for m in daemon.publishers[vid].sent() if m.get_type() == "COMMAND_LONG"]
    assert sent.command == mc.MAV_CMD_DO_SET_MISSION_CURRENT and sent.param1 == 1.0


def run_at(v, rate):
    """The vehicle's clock heard running ``rate`` times the wall clock (its speedup)."""
    v.clock._first, v.clock._last_wall = (0.0, 0.0), 2.0
    v.clock.now = 2.0 * rate
    assert v.clock.rate == pytest.approx(rate)


@pytest.mark.parametrize(
    ("rate", "driving_to", "renumbered"),
    [
        (1.0, 39, False),  # on the road home: the whole prefix is there in time
        (2000.0, 39, True),  # the whole prefix would have it stand longer
        (2000.0, 36, False),  # to the end of its last swath: never a stop there
    ],
)
def test_a_top_up_is_renumbered_when_the_whole_prefix_would_stop_the_vehicle_longer(
    dispatch, rate, driving_to, renumbered
):
    """A driving vehicle due its next window, too close to the item it drives to for a
    renumbered upload to be on board first (it would stop there): on a slow clock the whole
    prefix is sent, in time before the end of its window; on a fast one (or a slow radio)
    the whole prefix would have it stand at the end of its window longer than the short
    upload has it stand at its item, and the top-up is renumbered; but not where it would
    stand with its implement down (the end of a swath: the implement is raised after it)."""
    daemon = windowed(dispatch)
    vid = "v1"
    v = drive(daemon, vid, driving_to - 1, 0.0)
    assert v.items[36].role == "swath_end" and v.items[39].role == "road"
    held = driving_to + 4
    daemon.state.apply(ev.WindowExtended(vid, held), 0.5)
    running = heartbeat(11)
    running.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    feed(daemon.state, vid, running, 1.0)
    feed(daemon.state, vid, mission_current(11, driving_to, held - 1, STATE_ACTIVE), 1.0)
    near = v.items[driving_to]  # a metre short of the item it drives to: it gets there first
    fix = mc.message(
        "GLOBAL_POSITION_INT", time_boot_ms=1000, lat=near.x + 90, lon=near.y, alt=0,
        relative_alt=0, vx=0, vy=0, vz=0, hdg=0,
    )  # fmt: skip
    feed(daemon.state, vid, from_vehicle(fix, 11), 1.0)
    assert v.driving and v.current == driving_to and v.lat is not None
    run_at(v, rate)
    daemon._upload_took[vid] = (0.1, 10)  # 100 items a second
    link = daemon.links[vid]
    link.topup_from = held
    daemon.state.apply(ev.WindowExtended(vid, len(v.items)), 1.5)
    assert not daemon._outruns(v, link, driving_to)
    daemon._send_window(v, link, 2.0)
    count = daemon.publishers[vid].sent()[-1]
    assert count.get_type() == "MISSION_COUNT"
    if rate == 1.0:  # the road to the window's end takes longer than the whole prefix
        assert daemon._left_s(v, held) > daemon._upload_s(v, len(v.items))
    if renumbered:  # home and the items from the one it drives to
        short = len(v.items) - driving_to + 1
        assert link.numbered == (driving_to, short) and count.count == short
    else:
        assert link.numbered == (1, len(v.items)) and count.count == len(v.items)
