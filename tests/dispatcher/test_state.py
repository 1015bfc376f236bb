"""The dispatcher's state through losses of link: vehicles resume where they were."""

import dataclasses
import json
import time
from pathlib import Path

import pytest
from helpers.daemon import (
    Pub,
    daemon_for,
    deliver,
    feed,
    heartbeat,
    mission_current,
    running_events,
)
from helpers.messages import command_ack, from_vehicle, position, track

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import load_scenario
from dispatcher.daemon import events as ev
from dispatcher.daemon.state import FleetState, Phase, SetOff
from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import Outcome
from dispatcher.mission.build import IMPLEMENT_LOWERED, IMPLEMENT_RAISED
from dispatcher.mission.plan import write_plan_files

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.mark.parametrize("phase", [Phase.UPLOADING, Phase.STARTING, Phase.RUNNING])
def test_a_vehicle_lost_for_a_moment_resumes_its_phase(dispatch, phase):
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    v.phase = phase
    state.apply(ev.VehicleLost("v1", "liveliness token dropped"), 10.0)
    assert v.phase is Phase.LOST
    assert not state.finished(12.0, lost_grace_s=30.0)  # not given up yet
    state.apply(ev.VehicleSeen("v1"), 14.0)
    assert v.phase is phase and v.lost_s == pytest.approx(4.0) and v.error == ""
    state.apply(ev.VehicleLost("v1", "heartbeats stopped"), 20.0)
    feed(state, "v1", heartbeat(11), 21.0)  # frames again: the link is back
    assert v.phase is phase and v.lost_s == pytest.approx(5.0)


def test_a_vehicle_lost_for_good_ends_the_run_after_the_grace(dispatch):
    state = FleetState(dispatch.document)
    state.vehicles["v2"].phase = Phase.DONE
    state.vehicles["v1"].phase = Phase.RUNNING
    state.apply(ev.VehicleLost("v1", "heartbeats stopped"), 100.0)
    assert not state.finished(120.0, lost_grace_s=30.0)
    assert state.finished(131.0, lost_grace_s=30.0)


def test_replanning_into_the_same_folder_leaves_no_stale_mission(dispatch, tmp_path):
    """The missions of a machine the earlier plan there had are gone; mission files that
    no plan of ours wrote (the user's own) are kept."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "plan.json").write_text(
        '{"machines": [{"id": "old-tractor"}, {"id": "v1"}, {"id": "../outside"}]}'
    )
    (tmp_path / "outside.plan").write_text("{}")  # not ours to delete, whatever plan.json says
    (out / "old-tractor.waypoints").write_text("QGC WPL 110\n")
    (out / "old-tractor.plan").write_text("{}")
    (out / "north field by hand.waypoints").write_text("QGC WPL 110\n")
    write_plan_files(dispatch, out)
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "map.png",
        "north field by hand.waypoints",
        "plan.geojson",
        "plan.json",
        "plan.kml",
        "v1.plan",
        "v1.waypoints",
        "v2.plan",
        "v2.waypoints",
    ]
    assert (tmp_path / "outside.plan").exists()


@pytest.mark.parametrize(("key", "value"), [("farm_id", "north#2"), ("id", "JD 6R/1")])
def test_ids_that_zenoh_or_files_would_misread_are_refused(tmp_path, key, value):
    text = (
        (DATA / "tiny.toml")
        .read_text()
        .replace('farm = "tiny-farm.geojson"', f'farm = "{DATA / "tiny-farm.geojson"}"')
    )
    if key == "farm_id":
        text = text.replace('farm_id = "tiny"', f'farm_id = "{value}"')
    else:
        text = text.replace('id = "v1"', f'id = "{value}"')
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="letters, digits") as err:
        load_scenario(path)
    assert str(path) in str(err.value)


def booting(sysid):
    msg = heartbeat(sysid)
    msg.system_status, msg.custom_mode = mc.MAV_STATE_BOOT, 16  # INITIALISING
    return msg


def test_a_failed_upload_is_tried_again_from_the_count_after_a_pause(dispatch):
    """Three uploads, then the vehicle is failed, and its work goes to the others (a
    re-plan is asked for), as a vehicle's that cannot be started does."""
    from dispatcher.link.mission_protocol import Outcome

    daemon = daemon_for(dispatch)
    daemon.config.replanner = lambda state, cancel: daemon.job  # wanted, not run here
    for vid, v in daemon.state.vehicles.items():
        daemon.state.apply(ev.VehicleSeen(vid), 0.0)
        feed(daemon.state, vid, heartbeat(v.system_id), 0.0)
    daemon._advance("v1", 0.0)
    first = daemon.links["v1"].upload
    assert daemon.state.vehicles["v1"].phase is Phase.UPLOADING and first is not None
    now = 1.0
    for attempt, pause in ((2, 2.0), (3, 4.0)):
        daemon.links["v1"].upload._fail("no answer")
        daemon._advance("v1", now)
        assert daemon.links["v1"].upload is None  # backing off
        daemon._advance("v1", now + pause - 0.1)
        assert daemon.links["v1"].upload is None
        now += pause
        daemon._advance("v1", now)
        assert daemon.state.vehicles["v1"].upload_attempts == attempt
        assert daemon.links["v1"].upload.outcome is Outcome.RUNNING
    daemon.links["v1"].upload._fail("no answer")
    daemon._advance("v1", now + 10.0)
    v1 = daemon.state.vehicles["v1"]
    assert v1.phase is Phase.FAILED and "after 3 attempts" in v1.error
    types = [m.get_type() for m in daemon.publishers["v1"].sent()]
    assert types.count("MISSION_COUNT") == 3
    assert daemon._replan_reason.startswith("v1 could not be given its mission (upload failed")


def test_a_booting_autopilot_gets_its_mission_once_it_is_ready(dispatch):
    daemon = daemon_for(dispatch)
    for vid, v in daemon.state.vehicles.items():
        daemon.state.apply(ev.VehicleSeen(vid), 0.0)
        feed(daemon.state, vid, booting(v.system_id), 0.0)
    daemon._tick(0.5)
    assert daemon.links["v1"].upload is None
    assert [m.get_type() for m in daemon.publishers["v1"].sent()] == ["HEARTBEAT"]  # the GCS's
    feed(daemon.state, "v1", heartbeat(11), 1.0)  # STANDBY/ACTIVE: booted
    daemon._advance("v1", 1.0)
    assert daemon.links["v1"].upload is not None
    assert daemon.publishers["v1"].sent()[-1].get_type() == "MISSION_COUNT"


def statustext(sysid, text, severity=mc.MAV_SEVERITY_CRITICAL):
    return mc.Codec(sysid, 1).decode_one(
        mc.Codec(sysid, 1).encode(
            mc.message("STATUSTEXT", severity=severity, text=text.encode(), id=0, chunk_seq=0)
        )
    )


def test_an_arm_refusal_carries_the_autopilots_reason(dispatch):
    from dispatcher.link.mission_protocol import Outcome

    daemon = daemon_for(dispatch)
    v = daemon.state.vehicles["v1"]
    hold = heartbeat(11)
    hold.custom_mode = 4
    daemon.state.apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", hold, 0.0)
    daemon._start(v, daemon.links["v1"], 0.0)
    start = daemon.links["v1"].start
    sent = daemon.publishers["v1"].sent()
    assert [(m.command, m.param1, m.param2) for m in sent] == [
        (mc.MAV_CMD_DO_SET_MISSION_CURRENT, 1.0, 0.0)  # never a reset (param2 = 1)
    ]
    # Before arming, the implement up, as the mission has it before its first field.
    before_arm = [c.command for c in start.commands]
    before_arm = before_arm[: before_arm.index(mc.MAV_CMD_COMPONENT_ARM_DISARM)]
    assert before_arm == [mc.MAV_CMD_DO_SET_MISSION_CURRENT, mc.MAV_CMD_DO_SET_SERVO]
    accept(start, 0.1, until=mc.MAV_CMD_COMPONENT_ARM_DISARM)
    start.on_message(ack(mc.MAV_CMD_COMPONENT_ARM_DISARM, mc.MAV_RESULT_FAILED), 0.2)
    text = "Arm: Battery 1 below minimum arming voltage"
    feed(daemon.state, "v1", statustext(11, text), 0.25)
    daemon._advance("v1", 0.3)
    assert text in v.error and "ARM_DISARM refused" in v.error
    assert daemon.state.status_doc()["vehicles"]["v1"]["autopilot_says"] == [text]
    start.outcome, start.reason = Outcome.FAILED, "MAV_CMD_COMPONENT_ARM_DISARM refused"
    daemon._advance("v1", 70.0)
    assert v.phase is Phase.FAILED and text in v.error


def test_a_start_unanswered_on_a_vehicle_still_heard_is_tried_again_then_failed(dispatch):
    """A bad radio loses every copy of a start command or of its answer: the vehicle is
    still heard, so the start is tried again (3 attempts in all), then failed."""
    daemon, v, link = starting_v1(dispatch, 0.0)
    now = 0.0
    for attempt in (1, 2, 3):
        start = link.start
        accept(start, now, until=mc.MAV_CMD_COMPONENT_ARM_DISARM)
        now = unanswered(daemon, start, now)  # every ARM and every answer lost
        assert start.outcome is Outcome.FAILED and start.unanswered
        feed(daemon.state, "v1", held(11), now)  # but the vehicle is heard
        daemon._advance("v1", now)
        if attempt < 3:
            assert link.start is not start and v.phase is Phase.STARTING, attempt
    assert v.phase is Phase.FAILED and "no COMMAND_ACK for MAV_CMD_COMPONENT_ARM_DISARM" in v.error
    firsts = [
        m
        for m in daemon.publishers["v1"].sent()
        if m.get_type() == "COMMAND_LONG" and m.command == mc.MAV_CMD_DO_SET_MISSION_CURRENT
    ]
    assert len(firsts) == 3  # each attempt from the first command


def test_a_start_unanswered_on_a_vehicle_not_heard_since_fails_at_once(dispatch):
    daemon, v, link = starting_v1(dispatch, 1.0)
    now = unanswered(daemon, link.start, 1.0)
    daemon._advance("v1", now)
    assert v.phase is Phase.FAILED and "no COMMAND_ACK" in v.error


def test_a_started_mission_gives_the_next_start_its_attempts_again(dispatch):
    daemon, v, link = starting_v1(dispatch, 0.0)
    link.start._fail("no COMMAND_ACK")
    link.start.unanswered = True
    feed(daemon.state, "v1", held(11), 0.5)
    daemon._advance("v1", 0.5)
    assert link.starts == 1 and v.phase is Phase.STARTING
    accept(link.start, 0.6)
    daemon._advance("v1", 0.7)
    assert v.phase is Phase.RUNNING and link.starts == 0


def test_a_tractor_that_could_not_be_started_is_asked_again_and_rejoins_once_it_answers(
    dispatch,
):
    """Its work given to the others, a vehicle failed for want of answers is told to HOLD
    while it is heard (not when it is not), PROBE_PERIOD_S after the last time went
    unanswered; once it acknowledges, it hears us again, and a re-plan is asked for to give
    it work, as for one back from a loss."""
    from dispatcher.daemon.server import PROBE_PERIOD_S

    daemon, v, link = starting_v1(dispatch, 0.0)
    daemon.config.replanner = lambda state, cancel: daemon.job  # wanted, not run here
    now = unanswered(daemon, link.start, 0.0)
    while v.phase is not Phase.FAILED:
        feed(daemon.state, "v1", held(11), now)
        daemon._advance("v1", now)
        if link.start.outcome is Outcome.RUNNING:
            now = unanswered(daemon, link.start, now)
    assert daemon._replan_reason.startswith("v1 could not be started")
    daemon._replan_reason = ""
    v.retired = True  # what the re-plan does to a vehicle it leaves out

    def holds():
        return commands_to(daemon, "v1", 11).count((mc.MAV_CMD_DO_SET_MODE, 1.0))

    before = holds()
    now += daemon.config.heartbeat_timeout_s + 1.0
    daemon._advance("v1", now)  # its last HEARTBEAT is old: not heard
    assert holds() == before
    feed(daemon.state, "v1", held(11), now)
    daemon._advance("v1", now)
    assert holds() == before + 1 and link.hold.outcome is Outcome.RUNNING
    probe = link.hold
    now = unanswered(daemon, probe, now)
    assert probe.outcome is Outcome.FAILED
    feed(daemon.state, "v1", held(11), now)
    daemon._advance("v1", now)  # it went unanswered: the next in PROBE_PERIOD_S
    assert holds() == before + 1 + probe.max_retries and link.hold is None
    feed(daemon.state, "v1", held(11), now + PROBE_PERIOD_S - 0.5)
    daemon._advance("v1", now + PROBE_PERIOD_S - 0.5)
    assert link.hold is None
    now += PROBE_PERIOD_S
    feed(daemon.state, "v1", held(11), now)
    daemon._advance("v1", now)
    assert link.hold is not probe and v.phase is Phase.FAILED
    link.hold.on_message(ack(mc.MAV_CMD_DO_SET_MODE, mc.MAV_RESULT_ACCEPTED), now + 0.5)
    daemon._advance("v1", now + 0.6)
    assert v.phase is Phase.ALIVE and not v.error and v.retired
    daemon._advance("v1", now + 0.7)
    assert daemon._replan_reason == "v1 back"


def starting_v1(dispatch, now):
    """A daemon that has just asked v1, in HOLD and disarmed, to start its mission."""
    daemon = daemon_for(dispatch)
    v = daemon.state.vehicles["v1"]
    daemon.state.apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", held(11), 0.0)
    link = daemon.links["v1"]
    daemon._start(v, link, now)
    return daemon, v, link


def accept(start, now, until=None):
    """Acknowledge ``start``'s commands in order, up to ``until`` (that one not), or all."""
    for cmd in [c.command for c in start.commands]:
        if cmd == until:
            return
        start.on_message(ack(cmd, mc.MAV_RESULT_ACCEPTED), now)


def unanswered(daemon, start, now):
    """Every resend of ``start``'s current command goes unanswered: the time it fails."""
    for _ in range(start.max_retries + 1):
        now += start.timeout_s
        daemon._send("v1", start.on_tick(now))
    return now


def held(sysid):
    """A HEARTBEAT of a vehicle in HOLD, disarmed."""
    msg = heartbeat(sysid)
    msg.custom_mode = 4
    return msg


def ack(command, result):
    return from_vehicle(command_ack(command, result), 11)


def position_of_v1(t_ms):
    return position(t_ms, 440003000, 872995000)


def rebooted_v1(dispatch, reached, at=None, back_at=None):
    """A daemon whose v1 rebooted while driving, ``reached`` its last item reached, and has
    come back (MANUAL, disarmed, holding our mission) at the garage, or at ``at`` (lat,
    lon * 1e7; where it says it is after the reboot: ``back_at``, if given): the commands
    it was sent since."""
    daemon = daemon_for(dispatch)
    v = daemon.state.vehicles["v1"]
    x, y = at or (440003000, 872995000)
    back_x, back_y = back_at or (x, y)
    daemon.state.vehicles["v2"].phase = Phase.DONE
    running = heartbeat(11)
    running.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    daemon.state.apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", running, 0.0)
    v.phase = Phase.RUNNING
    feed(daemon.state, "v1", position(500_000, x, y), 1.0)
    daemon.state.apply(ev.ItemReached("v1", reached, v.sim_time_s), 1.5)
    feed(daemon.state, "v1", position(3_000, back_x, back_y), 2.0)  # its clock started again
    assert v.needs_restart and v.reboots == 1 and not v.ready
    assert v.sim_time_s >= 500.0  # the run's time does not go back
    daemon._tick(2.1)
    commands = [m for m in daemon.publishers["v1"].sent() if m.get_type() == "COMMAND_LONG"]
    assert not commands  # still booting
    manual = heartbeat(11)
    manual.custom_mode = 0  # MANUAL, disarmed: how ArduPilot comes back
    feed(daemon.state, "v1", manual, 3.0)
    total = mc.message(
        "MISSION_CURRENT", seq=0, total=len(v.items) - 1, mission_state=2, mission_mode=0
    )
    feed(daemon.state, "v1", total, 3.0)
    assert v.off_auto_since is None  # expected, not a failsafe
    daemon._advance("v1", 3.1)
    sent = [m for m in daemon.publishers["v1"].sent() if m.get_type() == "COMMAND_LONG"]
    return daemon, v, sent


def at_item(dispatch, seq):
    """Where v1's mission item ``seq`` is (lat, lon * 1e7)."""
    item = daemon_for(dispatch).state.vehicles["v1"].items[seq]
    return item.x, item.y


def test_a_reboot_while_driving_is_armed_again_and_resumed_after_the_last_item(dispatch):
    _, v, sent = rebooted_v1(dispatch, 7, at_item(dispatch, 7))
    assert (sent[0].command, sent[0].param1, sent[0].param2) == (
        mc.MAV_CMD_DO_SET_MISSION_CURRENT,
        8.0,
        0.0,
    )
    assert v.phase is Phase.STARTING and v.reached == 7


def test_a_reboot_in_a_field_sets_the_implement_as_the_mission_has_it_there(dispatch, caplog):
    """The item that lowered the implement is behind the item it resumes at, and the
    rebooted autopilot's outputs are at their boot values: the implement is set before it
    arms (with the mission's output and setting), or it would drive on with it up."""
    daemon = daemon_for(dispatch)
    items = daemon.state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role == "implement_down")
    end = next(k for k in range(down, len(items)) if items[k].role == "swath_end")
    at = (items[end].x, items[end].y)  # where it stopped: at the swath's end
    daemon, v, _ = rebooted_v1(dispatch, end, at)
    start = daemon.links["v1"].start.commands
    lowering = v.items[down]
    assert [c.command for c in start[:4]] == [
        mc.MAV_CMD_DO_SET_MISSION_CURRENT,
        lowering.command,
        mc.MAV_CMD_COMPONENT_ARM_DISARM,
        mc.MAV_CMD_DO_SET_MODE,
    ]
    assert start[0].params[0] == end + 1
    start_lowered = (lowering.param1, lowering.param2)
    assert start[1].params == start_lowered
    # Back somewhere else (a simulator started again in the garage): it would drive there
    # with the implement down. The field has no planned turns: its lines are driven one
    # after another with the implement down, lowered once before the first. So from the
    # end of the line before, the implement up, and lowered by our command once it is past
    # that item (the lowering is behind: the mission does not lower it again).
    with caplog.at_level("WARNING"):
        daemon, v, _ = rebooted_v1(dispatch, end)
    link = daemon.links["v1"]
    start = link.start.commands
    raising = next(it for it in v.items[end + 1 :] if it.role in IMPLEMENT_RAISED)
    assert start[0].params[0] == end
    assert start[1].params == (raising.param1, raising.param2) != start_lowered
    assert f"from item {end}, where the leg starts" in caplog.text

    def heading_to(seq, now):
        feed(daemon.state, "v1", mc.message("MISSION_CURRENT", seq=seq, total=len(v.items) - 1,
                                            mission_state=3, mission_mode=1), now)  # fmt: skip
        daemon._advance("v1", now)

    daemon._start(v, link, 3.12)  # the same start again (unanswered though heard)
    assert link.start_item == end and link.start.commands[0].params[0] == end
    heading_to(end + 1, 3.15)  # (a report from before our start took: past the item)
    accept(link.start, 3.2)
    daemon._advance("v1", 3.3)
    assert v.phase is Phase.RUNNING and link.lower is None
    heading_to(end + 1, 3.4)
    assert link.lower is None  # not seen heading to the line's end yet
    heading_to(end, 3.5)
    assert link.lower is None  # on its way back to the line's end
    feed(daemon.state, "v1", driving_heartbeat(11), 8.9)
    feed(daemon.state, "v1", position(9_000, items[end].x, items[end].y), 8.9)
    heading_to(end + 1, 9.0)  # past it: on along the line
    assert link.lower is not None and [c.params for c in link.lower.commands] == [start_lowered]
    assert commands_to(daemon, "v1", 11)[-1] == (lowering.command, lowering.param1)
    # Before any field: up, as the mission has it there.
    daemon, _, _ = rebooted_v1(dispatch, 1)
    start = daemon.links["v1"].start.commands
    assert start[1].params == (raising.param1, raising.param2) and start[1].optional


def test_a_lowering_after_a_start_at_the_lines_start_needs_no_report_of_heading_there(dispatch):
    """Started back at the line's start from close by, the reports of it heading there
    (MISSION_CURRENT at that item) all lost on a lossy radio: seen there, started, it
    counts as having headed there, and is lowered once it is past it."""
    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role == "implement_down")
    end = next(k for k in range(down, len(items)) if items[k].role == "swath_end")
    daemon, v, _ = rebooted_v1(dispatch, end)  # back in the garage
    link = daemon.links["v1"]
    assert link.lower_after == (end, down, False)
    feed(daemon.state, "v1", mission_current(11, end + 1, len(v.items) - 1, 3), 3.15)
    accept(link.start, 3.2)
    daemon._advance("v1", 3.3)
    daemon._advance("v1", 3.4)  # still where it was (the garage)
    assert v.phase is Phase.RUNNING and link.lower_after == (end, down, False)
    feed(daemon.state, "v1", driving_heartbeat(11), 8.9)
    feed(daemon.state, "v1", position(9_000, *at_item(dispatch, end)), 8.9)
    daemon._advance("v1", 8.95)
    assert link.lower_after == (end, down, True) and link.lower is None
    feed(daemon.state, "v1", mission_current(11, end + 1, len(v.items) - 1, 3), 9.0)
    daemon._advance("v1", 9.1)
    assert link.lower is not None
    assert commands_to(daemon, "v1", 11)[-1] == (items[down].command, items[down].param1)


@pytest.mark.parametrize("plan", ["dispatch", "dispatch_turning"])
def test_a_reboot_off_a_swath_goes_back_to_where_the_swath_starts(plan, request, caplog):
    """Stopped along a swath and back somewhere else (moved with the implement down, or a
    simulator started again in the garage): sent on to the swath's end with the implement
    up, it would leave the swath unworked. It starts where the swath starts instead, the
    implement up, and the mission lowers it there (a field's first swath, or one after a
    turn); on the swath, it goes on there."""
    dispatch = request.getfixturevalue(plan)
    items = daemon_for(dispatch).state.vehicles["v1"].items
    raised = {(it.param1, it.param2) for it in items if it.role in IMPLEMENT_RAISED}
    lowerings = [k for k, it in enumerate(items) if it.role in IMPLEMENT_LOWERED]
    roles = {items[k].role for k in lowerings}
    assert roles == ({"implement_down"} if plan == "dispatch" else IMPLEMENT_LOWERED)
    for down in lowerings:
        start_at = max(k for k in range(down) if items[k].x or items[k].y)
        assert items[start_at].role in ("transit", "swath_start"), items[start_at].role
        # Reached the swath's start, the items after it, or the lowering: on its way along
        # the swath (to its end, or to the items before the lowering, then the end).
        for reached in range(start_at, down + 1):
            caplog.clear()
            with caplog.at_level("WARNING"):
                daemon, v, _ = rebooted_v1(dispatch, reached)
            start = daemon.links["v1"].start.commands
            assert start[0].params[0] == start_at, (down, reached)
            assert start[1].params in raised and v.start_from == start_at
            assert f"from item {start_at}, where the leg starts" in caplog.text
        # Stopped on the swath: on from there, the implement down.
        at = (items[start_at].x, items[start_at].y)
        daemon, v, _ = rebooted_v1(dispatch, down, at)
        start = daemon.links["v1"].start.commands
        assert start[0].params[0] == down + 1
        assert start[1].params == (items[down].param1, items[down].param2)


def test_a_rebooted_autopilot_is_started_again_once_it_says_where_it_is(dispatch):
    """Where it stood before the reboot says nothing of where it is after (a simulator
    starts again in its garage, a tractor may have been towed): the item it starts at and
    the implement depend on it, so the start waits for a position heard since."""
    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role == "implement_down")
    # On the swath when it rebooted, back with no fix yet.
    daemon, v, sent = rebooted_v1(dispatch, down, (items[down].x, items[down].y), (0, 0))
    assert not sent and v.needs_restart and v.where is None
    feed(daemon.state, "v1", position(4_000, 440003000, 872995000), 4.0)  # in the garage
    daemon._advance("v1", 4.1)
    start = daemon.links["v1"].start.commands
    start_at = max(k for k in range(down) if items[k].x or items[k].y)
    assert start[0].params[0] == start_at  # back where the swath starts


def test_a_rebooted_autopilot_with_no_fix_has_its_work_re_planned_and_is_asked_again_once_it_has(
    dispatch, caplog
):
    """A rebooted tractor that never says where it is (no GPS fix: ArduPilot drives no
    mission without one) does not keep its fields undone to the end of the run: its start
    fails, its work goes to the others, and it is asked whether it hears us once it says
    where it is (then it rejoins, given work from there)."""
    from dispatcher.daemon.server import FIX_TIMEOUT_S

    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role == "implement_down")
    daemon, v, sent = rebooted_v1(dispatch, down, (items[down].x, items[down].y), (0, 0))
    daemon.config.replanner = lambda state, cancel: daemon.job  # wanted, not run here
    now = 4.0
    with caplog.at_level("INFO"):
        while v.phase is Phase.RUNNING and now < 3.1 + FIX_TIMEOUT_S + 5.0:
            feed(daemon.state, "v1", position(int(now * 1000), 0, 0), now)  # no fix
            daemon._advance("v1", now)
            now += 1.0
    assert v.phase is Phase.FAILED and "no position in" in v.error
    assert now > 3.1 + FIX_TIMEOUT_S and not commands_to(daemon, "v1", 11)
    assert daemon._replan_reason.startswith("v1 could not be started")
    assert caplog.text.count("start failed: no position in") == 1
    v.retired = True  # the re-plan gave its work to the others
    daemon._advance("v1", now)
    assert not commands_to(daemon, "v1", 11)  # not asked before it says where it is
    feed(daemon.state, "v1", position(int(now * 1000), 440003000, 872995000), now)
    daemon._advance("v1", now + 0.1)
    hold = daemon.links["v1"].hold
    assert hold is not None and [c.command for c in hold.commands][:1] == [mc.MAV_CMD_DO_SET_MODE]
    hold.on_message(ack(mc.MAV_CMD_DO_SET_MODE, mc.MAV_RESULT_ACCEPTED), now + 0.2)
    daemon._advance("v1", now + 0.3)
    assert v.phase is Phase.ALIVE and not v.needs_restart  # to rejoin with a new mission


def test_a_rebooted_autopilot_with_no_fix_and_nobody_to_take_its_work_is_waited_for(
    dispatch, caplog
):
    """Its work would go nowhere (the others gone, or nothing re-plans): failing it would
    leave its work undone and it stranded; it is waited for, the operator told why every
    FIX_TIMEOUT_S, and started once it says where it is."""
    from dispatcher.daemon.server import FIX_TIMEOUT_S

    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role == "implement_down")
    daemon, v, sent = rebooted_v1(dispatch, down, (items[down].x, items[down].y), (0, 0))
    daemon.config.replanner = lambda state, cancel: daemon.job
    for other in daemon.state.vehicles.values():
        if other is not v:
            other.phase = Phase.FAILED
    now = 4.0
    with caplog.at_level("WARNING"):
        while now < 3.1 + 2.5 * FIX_TIMEOUT_S:
            feed(daemon.state, "v1", position(int(now * 1000), 0, 0), now)  # no fix
            daemon._advance("v1", now)
            now += 1.0
    assert v.phase is Phase.RUNNING and v.needs_restart and not commands_to(daemon, "v1", 11)
    assert caplog.text.count("v1: still no position since its autopilot rebooted") == 2
    assert "no other tractor can take it" in caplog.text
    placed = next(k for k in range(down, 0, -1) if items[k].x)  # where its line starts
    feed(daemon.state, "v1", position(int(now * 1000), *at_item(dispatch, placed)), now)
    daemon._advance("v1", now)
    assert daemon.links["v1"].start is not None and v.phase is Phase.STARTING


def test_where_a_vehicle_is_is_forgotten_when_its_autopilot_reboots(dispatch):
    """Told by its clock or by a booting HEARTBEAT (before its clock tells): the position
    heard before the reboot is no longer where it is; the next one with a fix is."""
    for reboot in (position(1_000, 0, 0), booting(11)):
        state = FleetState(dispatch.document)
        v = state.vehicles["v1"]
        feed(state, "v1", heartbeat(11), 0.0)
        feed(state, "v1", position(500_000, 440003000, 872995000), 1.0)
        assert v.where == (44.0003, 87.2995)
        feed(state, "v1", reboot, 2.0)
        assert v.where is None, reboot
        feed(state, "v1", position(2_000, 440004000, 872995000), 3.0)
        assert v.where == (44.0004, 87.2995)


def daemon_driving_v1(dispatch, reached):
    """A daemon whose v1 drives its mission, ``reached`` its last item reached."""
    daemon = daemon_for(dispatch)
    daemon.state.vehicles["v2"].phase = Phase.DONE
    for event in running_events("v1", reached):
        daemon._apply(event, 0.0)
    feed(daemon.state, "v1", driving_heartbeat(11), 0.0)
    return daemon


def holding(sysid):
    """A HEARTBEAT of a vehicle in HOLD, armed (how a failsafe or the operator stops it)."""
    msg = heartbeat(sysid)
    msg.custom_mode, msg.base_mode = 4, mc.MAV_MODE_FLAG_SAFETY_ARMED
    msg.system_status = mc.MAV_STATE_STANDBY  # Rover's in HOLD
    return msg


@pytest.mark.parametrize(
    ("said", "cleared"),
    [
        ("GCS Failsafe", "GCS Failsafe Cleared"),  # Rover 4.6, the simulator
        ("Radio Failsafe", "GCS Failsafe Cleared"),  # the same, named by the radio's check
        # Rover 4.7; "Cleared" lost on the radio, and the CRITICAL heartbeats too
        ("Failsafe trigger: GCS", None),
        # The failsafe and its CRITICAL heartbeats not heard (the dispatcher frozen 20 s:
        # an outside review's fleet then stood in HOLD for good, "left to the operator")
        (None, "GCS Failsafe Cleared"),
    ],
)
def test_a_vehicle_held_by_its_ground_station_failsafe_goes_on_once_it_hears_us(
    dispatch, said, cleared
):
    daemon = daemon_driving_v1(dispatch, 7)
    v = daemon.state.vehicles["v1"]
    if said is not None:
        feed(daemon.state, "v1", statustext(11, said, mc.MAV_SEVERITY_WARNING), 10.0)
    in_failsafe = holding(11)
    if cleared is not None and said is not None:
        in_failsafe.system_status = mc.MAV_STATE_CRITICAL  # ArduPilot's, until it hears us
    feed(daemon.state, "v1", in_failsafe, 10.0)
    daemon._advance("v1", 10.1)
    assert not commands_to(daemon, "v1", 11)  # the failsafe holds until a beat of ours
    if cleared is not None:
        feed(daemon.state, "v1", statustext(11, cleared, mc.MAV_SEVERITY_INFO), 10.9)
        daemon._advance("v1", 10.95)
        if said is not None:
            assert not commands_to(daemon, "v1", 11)  # its heartbeat says critical yet
            feed(daemon.state, "v1", holding(11), 11.0)
    else:
        feed(daemon.state, "v1", holding(11), 12.9)
        daemon._advance("v1", 12.95)
        assert not commands_to(daemon, "v1", 11)  # heard for less than 3 s yet
        feed(daemon.state, "v1", holding(11), 13.0)
    daemon._advance("v1", 13.1)
    # From the item after the last one reached (then arm, AUTO: each once this one's ACK
    # is in).
    assert commands_to(daemon, "v1", 11) == [(mc.MAV_CMD_DO_SET_MISSION_CURRENT, 8.0)]
    assert v.phase is Phase.STARTING
    v.phase, daemon.links["v1"].start = Phase.RUNNING, None  # started, and in HOLD again:
    daemon.publishers["v1"].frames.clear()  # not for the same failsafe
    feed(daemon.state, "v1", holding(11), 14.0)
    daemon._advance("v1", 20.0)
    assert not commands_to(daemon, "v1", 11)


def test_a_failsafe_whose_text_was_lost_is_told_by_the_heartbeat(dispatch):
    """Rover's HEARTBEAT says CRITICAL in its radio, ground-station and EKF failsafes and
    STANDBY in HOLD once the failsafe is over: that says it when the texts are lost."""
    daemon = daemon_driving_v1(dispatch, 7)
    in_failsafe = holding(11)
    in_failsafe.system_status = mc.MAV_STATE_CRITICAL
    feed(daemon.state, "v1", in_failsafe, 10.0)
    daemon._advance("v1", 10.5)
    assert not commands_to(daemon, "v1", 11)
    feed(daemon.state, "v1", holding(11), 11.0)  # it heard us: STANDBY
    daemon._advance("v1", 11.1)
    assert commands_to(daemon, "v1", 11) == [(mc.MAV_CMD_DO_SET_MISSION_CURRENT, 8.0)]


@pytest.mark.parametrize("heard", ["holding", "stopped in AUTO", "running", "no work left"])
def test_a_tractor_heard_but_deaf_to_the_start_has_its_work_re_planned(dispatch, heard):
    """Held by its ground-station failsafe, heard, but none of our commands reaches it (a
    dead uplink): the start fails after its attempts, and its work goes to the others as
    a lost one's does, instead of standing undone to the end of the run. So too for one
    armed in AUTO whose mission stopped (at the end of its window). One heard running its
    mission took the start after all (the answers were what got lost), and one with no
    field left to work has no work to give: no re-plan."""
    daemon = daemon_driving_v1(dispatch, 7)
    daemon.config.replanner = lambda state, cancel: daemon.job  # wanted, not run here
    v = daemon.state.vehicles["v1"]
    if heard == "no work left":
        for f in daemon.state.fields.values():
            f.status = "done"
        daemon.state.fields["other"] = dataclasses.replace(f, id="other", status="planned")
    in_failsafe = holding(11)
    in_failsafe.system_status = mc.MAV_STATE_CRITICAL
    feed(daemon.state, "v1", in_failsafe, 10.0)
    state = mc.MISSION_STATE_COMPLETE if heard == "stopped in AUTO" else mc.MISSION_STATE_ACTIVE
    now = 11.0
    while v.phase is not Phase.FAILED and now < 300.0:
        in_auto = heard in ("stopped in AUTO", "running") and now > 12
        feed(daemon.state, "v1", driving_heartbeat(11) if in_auto else holding(11), now)
        if in_auto:
            feed(daemon.state, "v1", mission_current(11, 8, len(v.items) - 1, state), now)
        for machine in daemon.links["v1"].exchanges():
            if machine is not None and machine.outcome is Outcome.RUNNING:
                machine.on_tick(now)
        daemon._advance("v1", now)
        now += 0.5
    assert v.phase is Phase.FAILED and "start failed" in v.error
    assert len(commands_to(daemon, "v1", 11)) >= daemon.config.start_attempts
    if heard in ("running", "no work left"):
        assert daemon._replan_reason == ""
    else:
        assert daemon._replan_reason.startswith("v1 could not be started (start failed")


def test_an_ekf_failsafe_or_an_old_critical_is_left_to_the_operator(dispatch):
    daemon = daemon_driving_v1(dispatch, 7)
    in_failsafe = holding(11)
    in_failsafe.system_status = mc.MAV_STATE_CRITICAL
    feed(daemon.state, "v1", statustext(11, "EKF failsafe", mc.MAV_SEVERITY_CRITICAL), 10.0)
    feed(daemon.state, "v1", in_failsafe, 10.0)
    feed(daemon.state, "v1", holding(11), 11.0)
    daemon._advance("v1", 15.0)
    assert not commands_to(daemon, "v1", 11)  # its position was not to be trusted
    other = daemon_driving_v1(dispatch, 7)
    critical_in_auto = driving_heartbeat(11)
    critical_in_auto.system_status = mc.MAV_STATE_CRITICAL  # FS_GCS_ENABLE 2: drives on
    feed(other.state, "v1", critical_in_auto, 10.0)
    feed(other.state, "v1", driving_heartbeat(11), 11.0)
    feed(other.state, "v1", holding(11), 12.0)  # then the operator holds it
    for now in (13.0, 18.0):
        feed(other.state, "v1", holding(11), now)
        other._advance("v1", now)
    assert not commands_to(other, "v1", 11)


def test_a_vehicle_its_failsafe_holds_is_not_given_up(dispatch):
    """Its failsafe may outlast the grace (a top-up under way on a lossy radio holds the
    start back: a 50 %-loss run ended without it): the run waits for it, and says why it
    stands; for one the operator stopped too (it may be put back in AUTO: a run that ended
    then left it without our heartbeats, so its GCS failsafe held it)."""
    import types

    daemon = daemon_driving_v1(dispatch, 7)
    state = daemon.state
    # A transfer under way (a top-up's read-back): nothing is started meanwhile.
    daemon.links["v1"].download = types.SimpleNamespace(
        outcome=Outcome.RUNNING, on_tick=lambda now: []
    )
    feed(state, "v1", statustext(11, "GCS Failsafe", mc.MAV_SEVERITY_WARNING), 10.0)
    for now in (10.0, 16.0, 45.0):
        feed(state, "v1", holding(11), now)
        daemon._tick(now)
    assert "held by its failsafe (GCS Failsafe)" in state.vehicles["v1"].error
    assert not commands_to(daemon, "v1", 11)
    assert not state.finished(45.0, lost_grace_s=30.0)
    operator = daemon_driving_v1(dispatch, 7)
    for now in (10.0, 16.0, 45.0):
        feed(operator.state, "v1", holding(11), now)
        operator._tick(now)
    assert operator.state.vehicles["v1"].error == "left AUTO: mode 4, armed"
    assert operator.state.vehicles["v1"].operator_hold
    assert not operator.state.finished(45.0, lost_grace_s=30.0)


def test_a_vehicle_the_operator_stopped_is_left_alone(dispatch):
    daemon = daemon_driving_v1(dispatch, 7)
    feed(daemon.state, "v1", statustext(11, "GCS Failsafe", mc.MAV_SEVERITY_WARNING), 1.0)
    feed(daemon.state, "v1", statustext(11, "GCS Failsafe Cleared", mc.MAV_SEVERITY_INFO), 2.0)
    daemon._advance("v1", 2.1)  # a failsafe over while it drove on in AUTO: nothing to do
    feed(daemon.state, "v1", holding(11), 30.0)  # the operator put it in HOLD, long after
    for now in (31.0, 36.0, 45.0):
        feed(daemon.state, "v1", holding(11), now)
        daemon._tick(now)
    assert not commands_to(daemon, "v1", 11)
    assert daemon.state.vehicles["v1"].error.startswith("left AUTO")


def test_a_vehicle_left_in_auto_is_put_in_hold_before_its_next_start(dispatch):
    from dispatcher.link.mission_protocol import start_mission_commands

    cmds = start_mission_commands(1, in_auto=True)
    assert [c.command for c in cmds] == [
        mc.MAV_CMD_DO_SET_MODE,
        mc.MAV_CMD_DO_SET_MISSION_CURRENT,
        mc.MAV_CMD_COMPONENT_ARM_DISARM,
        mc.MAV_CMD_DO_SET_MODE,
    ]
    assert cmds[0].params[1] == 4.0 and cmds[-1].params[1] == 10.0


def test_a_running_vehicle_out_of_auto_is_flagged_and_waited_for(dispatch):
    state = FleetState(dispatch.document)
    state.vehicles["v2"].phase = Phase.DONE
    v = state.vehicles["v1"]
    v.phase = Phase.RUNNING
    hold = heartbeat(11)
    hold.custom_mode = 4  # HOLD: a failsafe or the operator stopped it
    feed(state, "v1", hold, 10.0)
    assert v.off_auto_since == 10.0 and not state.finished(20.0, lost_grace_s=30.0)
    assert state.status_doc()["vehicles"]["v1"]["stopped_outside_auto"] is True
    assert not state.finished(41.0, lost_grace_s=30.0)
    auto = heartbeat(11)
    auto.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    feed(state, "v1", auto, 42.0)  # back in AUTO and armed
    assert v.off_auto_since is None and not state.finished(43.0, lost_grace_s=30.0)


def test_a_fields_start_stays_its_first_visits_when_its_rest_is_begun_after_a_replan(dispatch):
    """A review: the rest of a field begun again after a re-plan moved its start there (a
    field worked 5.8-14.0 h was shown 10.8-14.0 h in the review's order and the Gantt)."""
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    v.phase = Phase.RUNNING
    down = next(s for s, t in enumerate(v.items) if t.role == "implement_down")
    first_end = next(s for s, t in enumerate(v.items) if t.role == "swath_end")
    fid = v.items[down].field_id
    state.apply(ev.ItemReached("v1", down, 100.0), 1.0)
    state.apply(ev.ItemReached("v1", first_end, 300.0), 2.0)
    assert state.fields[fid].started_s == 100.0
    state._item_done(v, down, 900.0, reported=True)  # its rest's lowering, later
    assert state.fields[fid].started_s == 100.0


def test_a_field_starts_at_its_entry_when_the_implement_item_is_not_reported(dispatch):
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    v.phase = Phase.RUNNING
    entry = next(s for s, t in enumerate(v.items) if t.role == "transit" and t.field_id)
    first_end = next(s for s, t in enumerate(v.items) if t.role == "swath_end")
    fid = v.items[entry].field_id
    state.apply(ev.ItemReached("v1", entry, 100.0), 1.0)
    assert state.fields[fid].status == "working" and state.fields[fid].started_s == 100.0
    state.apply(ev.ItemReached("v1", first_end, 300.0), 2.0)  # ArduPilot skips DO items
    assert state.fields[fid].started_s == 100.0  # not moved to the end of the first swath


def resumed_daemon(dispatch, tmp_path, stored):
    """A daemon restarted on a store that holds ``stored`` events of the plan's run."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.store import Store

    store = Store.open(tmp_path, "tiny")
    job = dispatch.job()
    store.begin_run(job, "x")
    for event in stored:
        store.append(event, 0.0)
    store.commit()
    run = store.unfinished_run()
    daemon = Dispatcher(DaemonConfig(job=job, store=store, resume=run))
    daemon.publishers = {vid: Pub() for vid in dispatch.missions}
    daemon._resume_run(run)
    return daemon


def test_a_restarted_daemon_counts_the_time_lost_before_it_stopped(dispatch, tmp_path):
    """The store keeps each event's wall time; the daemon runs on its monotonic clock: the
    time lost before the restart came out 0 (the two clocks subtracted, floored at 0)."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.store import Store

    store = Store.open(tmp_path, "tiny")
    job = dispatch.job()
    store.begin_run(job, "x")
    start = time.time() - 100.0
    for event in running_events("v1", 2):
        store.append(event, start)
    store.append(ev.VehicleLost("v1", "liveliness token dropped"), start + 10.0)
    store.append(ev.VehicleSeen("v2"), start + 40.0)  # its last event before it stopped
    store.commit()
    run = store.unfinished_run()
    daemon = Dispatcher(DaemonConfig(job=job, store=store, resume=run))
    daemon.publishers = {vid: Pub() for vid in dispatch.missions}
    daemon._resume_run(run)
    assert daemon.state.vehicles["v1"].lost_s == pytest.approx(30.0)


def read_back(daemon, vid, sysid, items=None):
    """The daemon asks the vehicle for its mission; the vehicle answers with ``items``
    (default: the plan's mission)."""
    link = daemon.links[vid]
    daemon._advance(vid, 0.1)
    assert link.download is not None, "no MISSION_REQUEST_LIST"
    items = items if items is not None else daemon.job.missions[vid].to_mavlink(255)
    count = mc.message(
        "MISSION_COUNT", target_system=255, target_component=190, count=len(items), mission_type=0
    )
    link.download.on_message(from_vehicle(count, sysid), 0.2)
    for item in items:
        link.download.on_message(from_vehicle(item, sysid), 0.2)
    daemon._advance(vid, 0.3)


def commands_to(daemon, vid, system):
    return [
        (m.command, m.param1)
        for m in daemon.publishers[vid].sent(system)
        if m.get_type() == "COMMAND_LONG"
    ]


def test_after_a_restart_nothing_is_sent_before_the_vehicle_says_where_it_is(dispatch, tmp_path):
    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", 7))
    v = daemon.state.vehicles["v1"]
    assert v.phase is Phase.WAITING and v.resuming and v.reached == 7 and v.acked
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    daemon._advance("v1", 0.1)
    assert not commands_to(daemon, "v1", 11) and v.phase is Phase.ALIVE


def test_a_vehicle_still_driving_its_mission_is_kept_and_caught_up(dispatch, tmp_path):
    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", 7))
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    driving = heartbeat(11)
    driving.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    feed(daemon.state, "v1", driving, 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    feed(daemon.state, "v1", mission_current(11, 12, len(v.items) - 1, 3), 0.0)  # ACTIVE
    read_back(daemon, "v1", 11)
    assert v.phase is Phase.RUNNING and not v.resuming
    assert v.reached == 11  # items 8..11 were reached while the dispatcher was down
    assert not commands_to(daemon, "v1", 11)  # left as it is
    kinds = [k for _, k in daemon.store.rows("SELECT vehicle, kind FROM events") if _ == "v1"]
    assert kinds[-2:] == ["item_reached", "mission_started"]


def test_items_reached_meanwhile_are_caught_up_at_the_vehicles_clock_once_heard(dispatch, tmp_path):
    """After a restart the vehicle told its mission before its clock: the items it reached
    meanwhile took 0 s (its clock not heard yet). It goes on once its clock is heard, or,
    if that does not come, RESUME_ASK_S later as before."""
    from dispatcher.daemon.server import RESUME_ASK_S

    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", 7))
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", driving_heartbeat(11), 0.0)
    feed(daemon.state, "v1", mission_current(11, 12, len(v.items) - 1, 3), 0.0)  # ACTIVE
    daemon._advance("v1", 0.1)
    assert daemon.links["v1"].download is None and v.resuming  # its clock not heard yet
    feed(daemon.state, "v1", position(500_000), 0.2)
    read_back(daemon, "v1", 11)
    assert v.reached == 11 and not v.resuming
    rows = daemon.store.rows("SELECT vehicle, kind, body FROM events")
    caught = [json.loads(b) for vid, k, b in rows if vid == "v1" and k == "item_reached"][-1]
    assert caught["seq"] == 11 and caught["clock_s"] == 500.0
    # Never heard: it goes on RESUME_ASK_S later, as before.
    late = resumed_daemon(dispatch, tmp_path / "late", running_events("v1", 7))
    w = late.state.vehicles["v1"]
    late._apply(ev.VehicleSeen("v1"), 0.0)
    feed(late.state, "v1", driving_heartbeat(11), 0.0)
    feed(late.state, "v1", mission_current(11, 12, len(w.items) - 1, 3), 0.0)
    late._advance("v1", 0.1)
    late._advance("v1", 0.2 + RESUME_ASK_S)
    assert late.links["v1"].download is not None


def resumed_driving_v1(dispatch, tmp_path, current, at):
    """A daemon restarted while v1 drove to item ``current``, standing at ``at`` (lat, lon
    * 1e7): its mission read back, kept."""
    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", current - 1))
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", driving_heartbeat(11), 0.0)
    feed(daemon.state, "v1", position(1_000, *at), 0.0)
    feed(daemon.state, "v1", mission_current(11, current, len(v.items) - 1, 3), 0.0)
    read_back(daemon, "v1", 11)
    assert v.phase is Phase.RUNNING and not v.resuming
    return daemon, v


def test_a_vehicle_kept_driving_after_a_restart_has_its_implement_as_its_mission_has_it(
    dispatch, tmp_path
):
    """We may have started it back at the start of its line with the implement up, the
    lowering still to come, which the restarted process does not know: where its mission
    has the implement down it is lowered once it is on the leg (a lowering again is nothing
    to an implement already down); where the mission has it up, nothing is sent."""
    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role in IMPLEMENT_LOWERED)
    end = next(k for k in range(down, len(items)) if items[k].role == "swath_end")
    lowering = items[down]
    daemon, _ = resumed_driving_v1(dispatch, tmp_path / "a", end, at_item(dispatch, end))
    assert commands_to(daemon, "v1", 11) == [(lowering.command, lowering.param1)]
    before = next(k for k in range(1, down) if items[k].x)  # on its way to the field
    daemon, _ = resumed_driving_v1(dispatch, tmp_path / "b", before, at_item(dispatch, before))
    assert not commands_to(daemon, "v1", 11)
    # On its way to the line's start from elsewhere: once it is past it.
    daemon, v = resumed_driving_v1(dispatch, tmp_path / "c", end, at_item(dispatch, 0))
    assert not commands_to(daemon, "v1", 11)
    feed(daemon.state, "v1", position(9_000, *at_item(dispatch, end)), 9.0)
    feed(daemon.state, "v1", mission_current(11, end + 1, len(v.items) - 1, 3), 9.0)
    daemon._advance("v1", 9.0)
    assert commands_to(daemon, "v1", 11) == [(lowering.command, lowering.param1)]


def test_a_lowering_unanswered_is_sent_again_and_one_refused_is_said(dispatch, tmp_path, caplog):
    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role in IMPLEMENT_LOWERED)
    end = next(k for k in range(down, len(items)) if items[k].role == "swath_end")
    daemon, v = resumed_driving_v1(dispatch, tmp_path / "a", end, at_item(dispatch, end))
    link = daemon.links["v1"]
    now = 1.0
    for attempt in range(1, daemon.config.start_attempts + 1):
        assert link.lower is not None and link.lowerings == attempt
        now = unanswered(daemon, link.lower, now)
        with caplog.at_level("WARNING"):
            daemon._advance("v1", now)
    assert link.lower is None and link.lower_after is None
    assert "the implement's lowering failed (no COMMAND_ACK" in caplog.text
    caplog.clear()
    daemon, v = resumed_driving_v1(dispatch, tmp_path / "b", end, at_item(dispatch, end))
    link = daemon.links["v1"]
    lower = link.lower
    lower.on_message(ack(items[down].command, mc.MAV_RESULT_DENIED), 1.0)
    with caplog.at_level("WARNING"):
        daemon._advance("v1", 1.1)
    assert link.lower is None and link.lower_after is None and link.lowerings == 1
    assert "the implement's lowering failed (MAV_CMD_DO_SET_SERVO refused" in caplog.text


@pytest.mark.parametrize(
    "then", ["past the raising", "into the next swath", "out of AUTO", "lost a moment"]
)
@pytest.mark.parametrize("plan", ["dispatch", "dispatch_turning"])
def test_a_lowering_under_way_no_longer_right_where_it_drives_is_stopped(
    plan, request, tmp_path, then
):
    """The lowering goes unanswered (a lossy radio) while the vehicle drives on past the
    item that raises the implement (onto the road, or into a turn), or is taken out of
    AUTO: no more of it (it would lower the implement there). Driving on, it is sent the
    mission's raising, in case one of ours reached it after the mission raised it, once a
    late answer to the lowering can no longer pass for the raising's, and until the mission
    sets the implement again (the next swath's lowering). Out of AUTO (the operator's, a
    failsafe), lowered once it drives there again. Lost for a moment (it may drive on
    meanwhile): the lowering goes on."""
    dispatch = request.getfixturevalue(plan)
    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role in IMPLEMENT_LOWERED)
    up = next(k for k in range(down, len(items)) if items[k].role in IMPLEMENT_RAISED)
    road = next(k for k in range(up + 1, len(items)) if items[k].x)
    again = next((k for k in range(road, len(items)) if items[k].role in IMPLEMENT_LOWERED), None)
    line = None if again is None else next(k for k in range(again + 1, len(items)) if items[k].x)
    daemon, v = resumed_driving_v1(dispatch, tmp_path, up - 1, at_item(dispatch, up - 1))
    link = daemon.links["v1"]
    lowering = link.lower
    assert lowering is not None and lowering.outcome is Outcome.RUNNING
    if then == "past the raising":
        feed(daemon.state, "v1", position(2_000, *at_item(dispatch, road)), 2.0)
        feed(daemon.state, "v1", mission_current(11, road, len(v.items) - 1, 3), 2.0)
    elif then == "into the next swath":  # its reports skipped the turn: nothing to raise
        if line is None:
            return
        feed(daemon.state, "v1", position(2_000, *at_item(dispatch, line)), 2.0)
        feed(daemon.state, "v1", mission_current(11, line, len(v.items) - 1, 3), 2.0)
    elif then == "out of AUTO":
        feed(daemon.state, "v1", held(11), 2.0)
    else:
        daemon._apply(ev.VehicleLost("v1", "liveliness token dropped"), 2.0)
    before = len(commands_to(daemon, "v1", 11))
    daemon._advance("v1", 2.1)
    if then == "lost a moment":
        assert link.lower is lowering and link.lower_after is not None
        return
    assert link.lower is None and len(commands_to(daemon, "v1", 11)) == before
    if then == "into the next swath":
        assert link.lower_after is None
        daemon._advance("v1", 2.1 + lowering.timeout_s + 0.1)
        assert link.lower is None and len(commands_to(daemon, "v1", 11)) == before
        return
    if then == "out of AUTO":  # lowered when it drives there again
        assert link.lower_after is not None
        feed(daemon.state, "v1", driving_heartbeat(11), 5.0)
        daemon._advance("v1", 5.1)
        assert link.lower is not None and link.lowerings == 2
        assert commands_to(daemon, "v1", 11)[before:] == [(items[down].command, items[down].param1)]
        return
    # Its raising once an answer to our lowering can no longer pass for the raising's.
    assert link.lower_after is None
    daemon._advance("v1", 2.1 + lowering.timeout_s + 0.1)
    raising = link.lower
    assert raising is not None and link.raising == up
    assert commands_to(daemon, "v1", 11)[before:] == [(items[up].command, items[up].param1)]
    if line is None:  # on the road home: answered, done
        raising.on_message(ack(items[up].command, mc.MAV_RESULT_ACCEPTED), 4.0)
        daemon._advance("v1", 4.1)
        assert link.lower is None and link.raising is None
        return
    # Unanswered into the next swath, which its mission lowers the implement for: no more.
    feed(daemon.state, "v1", position(5_000, *at_item(dispatch, line)), 5.0)
    feed(daemon.state, "v1", mission_current(11, line, len(v.items) - 1, 3), 5.0)
    daemon._advance("v1", 5.1)
    assert link.lower is None and link.raising is None


@pytest.mark.parametrize("plan", ["dispatch", "dispatch_turning"])
def test_a_lowering_answered_before_the_report_that_the_mission_raised_it_is_raised_again(
    plan, request, tmp_path
):
    """Its lowering's answer comes, then its MISSION_CURRENT (about once a second) says it
    is past the mission's raising: the lowering may have come after it, and the raising is
    sent again. Reports still on the legs with the implement down for a while: nothing."""
    from dispatcher.daemon.server import LOWER_WATCH_S

    dispatch = request.getfixturevalue(plan)
    items = daemon_for(dispatch).state.vehicles["v1"].items
    down = next(k for k, it in enumerate(items) if it.role in IMPLEMENT_LOWERED)
    up = next(k for k in range(down, len(items)) if items[k].role in IMPLEMENT_RAISED)
    road = next(k for k in range(up + 1, len(items)) if items[k].x)
    for late in (True, False):
        daemon, v = resumed_driving_v1(
            dispatch, tmp_path / str(late), up - 1, at_item(dispatch, up - 1)
        )
        link = daemon.links["v1"]
        link.lower.on_message(ack(items[down].command, mc.MAV_RESULT_ACCEPTED), 1.0)
        daemon._advance("v1", 1.1)
        before = len(commands_to(daemon, "v1", 11))
        assert link.lower is None and link.lower_after is None and link.watch is not None
        at = 1.9 if late else 1.1 + LOWER_WATCH_S + 1.0
        feed(daemon.state, "v1", position(int(at * 1000), *at_item(dispatch, road)), at)
        feed(daemon.state, "v1", mission_current(11, road, len(v.items) - 1, 3), at)
        daemon._advance("v1", at + 0.1)
        sent = commands_to(daemon, "v1", 11)[before:]
        assert sent == ([(items[up].command, items[up].param1)] if late else [])


def test_a_stopped_vehicle_goes_on_from_the_item_it_was_heading_to(dispatch, tmp_path):
    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", 7))
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    holding = heartbeat(11)
    holding.custom_mode, holding.base_mode = 4, mc.MAV_MODE_FLAG_SAFETY_ARMED  # failsafe HOLD
    feed(daemon.state, "v1", holding, 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    feed(daemon.state, "v1", mission_current(11, 9, len(v.items) - 1, 2), 0.0)
    read_back(daemon, "v1", 11)
    assert v.phase is Phase.STARTING and v.reached == 8
    assert commands_to(daemon, "v1", 11)[0] == (mc.MAV_CMD_DO_SET_MISSION_CURRENT, 9.0)


def test_a_vehicle_that_finished_meanwhile_is_done_and_parked(dispatch, tmp_path):
    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", 7))
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", heartbeat(11), 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    last = len(v.items) - 1
    feed(daemon.state, "v1", mission_current(11, last, last, 5), 0.0)  # COMPLETE
    read_back(daemon, "v1", 11)
    assert v.phase is Phase.DONE and sorted(v.fields_done) == sorted(
        dispatch.document.machine("v1").fields
    )
    daemon._advance("v1", 0.2)
    assert commands_to(daemon, "v1", 11)[0][0] == mc.MAV_CMD_DO_SET_MODE  # HOLD, then disarm


def test_a_vehicle_standing_at_its_windows_end_with_the_next_on_board_goes_on_from_there(
    dispatch, tmp_path
):
    """It stood at the end of its first window, its mission complete, and had its next
    window on board when the dispatcher died: it says complete at the item it stands at,
    with the longer mission's total (as ArduPilot does). The new window is not taken as
    driven: it goes on at its first item."""
    from dispatcher.mission.window import window

    items = dispatch.document.machine("v1").items
    first = window(items, 1, 20)
    second = window(items, first, 20)
    assert first < second <= len(items)
    stored = [
        ev.VehicleSeen("v1"),
        ev.UploadStarted("v1", 1, first),
        ev.UploadAcked("v1"),
        ev.StartRequested("v1", 1),
        ev.MissionStarted("v1", 1),
        ev.ItemReached("v1", first - 1, 100.0),
        ev.WindowExtended("v1", second),
    ]
    daemon = resumed_daemon(dispatch, tmp_path, stored)
    v = daemon.state.vehicles["v1"]
    assert v.held == second and v.reached == first - 1
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", heartbeat(11), 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    stands = mission_current(11, first - 1, second - 1, mc.MISSION_STATE_COMPLETE)
    feed(daemon.state, "v1", stands, 0.0)
    read_back(daemon, "v1", 11, daemon.job.missions["v1"].to_mavlink(255)[:second])
    assert v.reached == first - 1  # nothing of the new window counted
    assert v.phase is Phase.STARTING and daemon.links["v1"].start_item == first


@pytest.mark.parametrize("held", ["shorter", "mixed"])
def test_an_upload_cut_by_the_crash_is_made_again_before_going_on(dispatch, tmp_path, held):
    stored = running_events("v1", 7)[:2]  # upload started, never acknowledged
    daemon = resumed_daemon(dispatch, tmp_path, stored)
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", heartbeat(11), 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    ours = daemon.job.missions["v1"].to_mavlink(255)
    if held == "shorter":  # the autopilot kept what it had received
        feed(daemon.state, "v1", mission_current(11, 0, len(ours) - 4, 2), 0.0)
        daemon._advance("v1", 0.1)
    else:  # as long as ours, but the end is an older mission's (ArduPilot replaces in place)
        feed(daemon.state, "v1", mission_current(11, 0, len(ours) - 1, 2), 0.0)
        older = list(ours)
        older[-2] = from_vehicle(ours[-2], 11)
        older[-2].x += 100
        read_back(daemon, "v1", 11, older)
    assert v.phase is Phase.UPLOADING
    sent = [m.get_type() for m in daemon.publishers["v1"].sent(11)]
    assert "MISSION_COUNT" in sent


def test_an_acknowledgement_lost_in_the_crash_is_found_by_reading_the_mission_back(
    dispatch, tmp_path
):
    stored = running_events("v1", 7)[:2]  # the vehicle acked; the dispatcher died first
    daemon = resumed_daemon(dispatch, tmp_path, stored)
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", heartbeat(11), 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    feed(daemon.state, "v1", mission_current(11, 0, len(v.items) - 1, 2), 0.0)
    read_back(daemon, "v1", 11)
    assert v.acked and v.phase is Phase.STARTING  # no second upload
    sent = [m.get_type() for m in daemon.publishers["v1"].sent(11)]
    assert "MISSION_COUNT" not in sent and "MISSION_REQUEST_LIST" in sent


def test_progress_lost_on_the_link_is_read_from_mission_current(dispatch):
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    last = len(v.items) - 1
    for event in running_events("v1", 3)[:5]:
        state.apply(event, 10.0)  # started at t = 10 s
    assert v.phase is Phase.RUNNING
    # Still on its way from before the start: an earlier mission, complete.
    stale = mission_current(11, last, last, mc.MISSION_STATE_COMPLETE)
    feed(state, "v1", stale, 10.5)
    assert v.reached == 0
    for fix in track(v.items, 1, 8):
        feed(state, "v1", fix, 12.0)
    feed(state, "v1", mission_current(11, 9, last, mc.MISSION_STATE_ACTIVE), 13.0)
    assert v.reached == 8  # the MISSION_ITEM_REACHED of items 1..8 were lost
    for fix in track(v.items, 9, last):
        feed(state, "v1", fix, 19.0)
    feed(state, "v1", mission_current(11, last, last, mc.MISSION_STATE_COMPLETE), 20.0)
    assert v.phase is Phase.DONE and sorted(v.fields_done) == sorted(
        dispatch.document.machine("v1").fields
    )


def test_a_restart_that_drove_to_the_end_before_its_ack_is_done_when_it_says_complete(dispatch):
    """A lossy radio: started again at one of its last items, the vehicle drove them and
    said "complete" before the ACK of its AUTO came through; its MISSION_ITEM_REACHED were
    all lost and it never said "active" after the start. The run waited for ever (a CI run
    of tests/test_lossy_link.py); complete at the last item it holds, past the start, is
    done."""
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    last = len(v.items) - 1
    for event in running_events("v1", last - 3):
        state.apply(event, 10.0)
    state.apply(ev.StartRequested("v1", last - 2), 20.0)
    state.apply(ev.MissionStarted("v1", last - 2), 20.0)
    assert v.phase is Phase.RUNNING and not v.active_seen
    for fix in track(v.items, last - 2, last):
        feed(state, "v1", fix, 21.0)
    feed(state, "v1", mission_current(11, last, last, mc.MISSION_STATE_COMPLETE), 20.5)
    assert v.phase is Phase.RUNNING  # within the settling time: maybe from before the start
    feed(state, "v1", mission_current(11, last, last, mc.MISSION_STATE_COMPLETE), 23.0)
    assert v.phase is Phase.DONE


def driving_heartbeat(sysid):
    msg = heartbeat(sysid)
    msg.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    return msg


def test_a_vehicle_that_gets_nowhere_in_auto_is_lost_held_and_back_when_it_moves(dispatch):
    daemon = daemon_for(dispatch)
    daemon.config.stall_after_s = 60.0
    v = daemon.state.vehicles["v1"]
    daemon.state.vehicles["v2"].phase = Phase.DONE
    for event in running_events("v1", 3)[:5]:
        daemon._apply(event, 0.0)
    feed(daemon.state, "v1", driving_heartbeat(11), 0.0)
    feed(daemon.state, "v1", position(10_000, 440000000, 873000000), 0.1)
    feed(daemon.state, "v1", position(50_000, 440001000, 873000000), 0.2)  # 11 m on
    daemon._tick(0.3)
    assert v.phase is Phase.RUNNING
    feed(daemon.state, "v1", position(100_000, 440001001, 873000000), 0.4)  # 0.01 m in 50 s
    daemon._tick(0.5)
    assert v.phase is Phase.RUNNING  # 50 s of its time: not yet
    feed(daemon.state, "v1", position(115_000, 440001000, 873000001), 0.6)
    daemon._tick(0.7)
    assert v.phase is Phase.RUNNING  # 65 s of its time, but 0.5 s of ours: a fast simulator
    feed(daemon.state, "v1", position(116_000, 440001000, 873000001), 5.6)
    daemon._tick(5.7)
    assert v.phase is Phase.LOST and v.stalled and v.error.startswith("stalled")
    hold = [m for m in daemon.publishers["v1"].sent() if m.get_type() == "COMMAND_LONG"]
    assert (hold[-1].command, hold[-1].param2) == (mc.MAV_CMD_DO_SET_MODE, 4)  # HOLD
    feed(daemon.state, "v1", driving_heartbeat(11), 5.8)
    assert v.phase is Phase.LOST  # heard, but still nowhere
    feed(daemon.state, "v1", position(120_000, 440002000, 873000001), 5.9)  # it moves
    assert v.phase is Phase.RUNNING and not v.stalled


def test_the_dispatcher_table_of_a_scenario_sets_when_a_vehicle_is_lost(tmp_path):
    text = (
        (DATA / "tiny.toml")
        .read_text()
        .replace('farm = "tiny-farm.geojson"', f'farm = "{DATA / "tiny-farm.geojson"}"')
    )
    path = tmp_path / "s.toml"
    path.write_text(text + "\n[dispatcher]\nlost_after_s = 8\nstall_after_s = 90.5\n")
    watch = load_scenario(path).watch
    assert (watch.lost_after_s, watch.stall_after_s, watch.lost_grace_s) == (8.0, 90.5, 30.0)
    path.write_text(text + "\n[dispatcher]\nstal_after_s = 9\n")
    with pytest.raises(ConfigError, match=r"unknown key\(s\) in \[dispatcher\]: stal_after_s"):
        load_scenario(path)
    path.write_text(text + "\n[dispatcher]\nlost_after_s = -1\n")
    with pytest.raises(ConfigError, match="dispatcher.lost_after_s must be a positive"):
        load_scenario(path)


def test_a_vehicle_that_went_past_its_kept_part_carries_on_and_is_not_restarted(dispatch):
    """A re-plan keeps the first items of a driving vehicle's mission; when it has gone
    beyond them by the time the new plan comes, it is still driving: it switches to the new
    mission (from the kept part's end), never starts it again from item 1."""
    state = FleetState(dispatch.document)
    vid = dispatch.document.machines[0].id
    for event in running_events(vid, 30):
        state.apply(event, 1.0)
    v = state.vehicles[vid]
    old = v.items
    cut = 20
    new_items = tuple(
        dataclasses.replace(i, seq=k, x=i.x + 10) if k > cut else i for k, i in enumerate(old)
    )
    machine = dataclasses.replace(dispatch.document.machines[0], items=new_items)
    doc = dataclasses.replace(dispatch.document, machines=(machine,)).with_id()
    state.apply(ev.PlanReplaced(ev.FLEET, doc.plan_id, "test", doc.to_dict()), 2.0)
    assert v.phase is Phase.RUNNING and v.switch
    assert v.route_from == cut + 1 and v.reached == cut
    # the same mission again: it goes on as it is, nothing to upload
    v.switch, v.acked = False, True
    doc2 = dataclasses.replace(doc, plan_id="").with_id()
    state.apply(ev.PlanReplaced(ev.FLEET, doc2.plan_id, "again", doc2.to_dict()), 3.0)
    assert not v.switch and v.acked and v.route_from == cut + 1


def test_a_tractor_past_its_kept_part_is_sent_on_as_soon_as_its_new_mission_is_on_board(
    dispatch,
):
    # Re-planned while driving: its new mission keeps items up to 4, the new route begins
    # at 5; the upload done, it has driven on to item 9 of the old mission meanwhile. It
    # now drives item 9 of the new mission (an autopilot keeps its index): it is sent to
    # where its new route goes on before the read-back, not after.
    daemon, sent = switched_past_its_kept_part(dispatch, mc.MISSION_STATE_ACTIVE)
    link, v = daemon.links["v1"], daemon.state.vehicles["v1"]
    kinds = [m.get_type() for m in sent]
    assert kinds[:2] == ["COMMAND_LONG", "MISSION_REQUEST_LIST"], kinds
    assert sent[0].command == mc.MAV_CMD_DO_SET_MISSION_CURRENT
    assert sent[0].param1 == link.join and link.join >= 5
    assert v.reached == link.join - 1
    assert v.old_items is None  # the new mission is on board


def switched_past_its_kept_part(dispatch, mission_state):
    """v1 re-planned while driving (its new route begins at item 5), on at item 9 of its
    old mission, its MISSION_CURRENT state ``mission_state``; its new mission uploaded:
    the daemon and the frames it sent."""
    from dispatcher.link.mission_protocol import MissionUpload, Outcome

    daemon = daemon_for(dispatch)
    v = daemon.state.vehicles["v1"]
    for event in running_events("v1", 8):
        daemon.state.apply(event, 0.0)
    v.mode, v.armed, v.mission_state = 10, True, mission_state  # AUTO, armed
    v.current, v.switch, v.old_items, v.route_from = 9, True, v.items, 5
    link = daemon.links["v1"]
    link.switch_from = 5
    link.upload = MissionUpload(daemon.job.missions["v1"].to_mavlink(v.system_id), v.system_id)
    link.upload.outcome = Outcome.DONE
    daemon._advance("v1", 1.0)
    return daemon, daemon.publishers["v1"].sent()


def test_a_tractor_stopped_at_the_end_of_its_window_is_started_again_at_its_join(dispatch):
    # It had reached the end of the window it held and stood there, mission complete (a
    # soak: the item set current alone left it standing, taken for stalled 12 s later).
    daemon, sent = switched_past_its_kept_part(dispatch, mc.MISSION_STATE_COMPLETE)
    link = daemon.links["v1"]
    commands = [(m.command, m.param1, m.param2) for m in sent if m.get_type() == "COMMAND_LONG"]
    assert [c[0] for c in commands] == [mc.MAV_CMD_DO_SET_MODE]  # HOLD first, then the rest
    assert commands[0][2] == 4  # Rover HOLD
    start = link.start.commands
    assert start[1].command == mc.MAV_CMD_DO_SET_MISSION_CURRENT
    assert start[1].params[0] == link.join and link.join >= 5
    assert start[2].optional  # the implement as the mission has it at the join
    assert start[3].command == mc.MAV_CMD_COMPONENT_ARM_DISARM
    assert start[4].params[1] == 10  # then AUTO
    # and the speed in force there (AUTO starts at WP_SPEED)
    speed = daemon.job.missions["v1"].speed_before(link.join)
    assert speed is not None and start[5].command == mc.MAV_CMD_DO_CHANGE_SPEED
    assert start[5].params[:2] == (1.0, speed)
    assert daemon.state.vehicles["v1"].phase is Phase.STARTING


def driving_v1(dispatch, reached):
    """A fleet state with v1 armed in AUTO, driving its mission, ``reached`` its item."""
    state = FleetState(dispatch.document)
    for event in running_events("v1", reached):
        state.apply(event, 0.0)
    v = state.vehicles["v1"]
    v.mode, v.armed = 10, True  # AUTO, armed
    return state, v


def test_a_tractor_standing_still_while_its_new_mission_comes_is_not_stalled(dispatch):
    # An autopilot truncates its mission at MISSION_COUNT: one past the new mission's length
    # stands still, mission complete, until it is sent on. Neither a stall nor progress.
    state, v = driving_v1(dispatch, 8)
    v.sim_time_s, v.progress_s, v.progress_wall = 1_000.0, 100.0, 0.0
    v.switch, v.old_items = True, v.items
    assert state.stalled_for(v, 60.0, 50.0) is None
    last = len(v.items) - 1
    done = mission_current(v.system_id, last, last, mc.MISSION_STATE_COMPLETE)
    assert state.on_message("v1", done, 51.0) == []
    state.apply(ev.SwitchUploaded("v1"), 52.0)
    state.apply(ev.UploadAcked("v1"), 53.0)
    assert state.stalled_for(v, 60.0, 54.0) is None  # its stall clock starts again
    v.sim_time_s = 1_100.0
    assert state.stalled_for(v, 60.0, 60.0) == 100.0


def test_a_left_out_tractor_asks_to_rejoin_when_it_is_back_not_when_it_failed(dispatch):
    # A vehicle failed for good (a start never acknowledged) is left out of every plan:
    # taking it for "back" re-planned for ever (47 times in a soak).
    daemon = daemon_for(dispatch)
    v = daemon.state.vehicles["v1"]
    v.retired, v.phase = True, Phase.FAILED
    daemon._advance("v1", 1.0)
    assert daemon._replan_reason == ""
    v.phase = Phase.RUNNING  # heard again after it was lost
    daemon._advance("v1", 2.0)
    assert daemon._replan_reason == "v1 back"


def test_a_stopped_mission_goes_on_after_what_its_autopilot_says_it_completed(dispatch):
    # The last items' MISSION_ITEM_REACHED lost: going on after the last one counted would
    # work those items again; MISSION_CURRENT (complete at item 9) says where it stands.
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    for event in running_events("v1", 5):
        state.apply(event, 0.0)
    assert v.go_on_item == v.resume_item == 6
    v.current, v.mission_state = 9, mc.MISSION_STATE_COMPLETE
    assert v.go_on_item == 10
    v.mission_state = mc.MISSION_STATE_ACTIVE  # driving to item 9: nothing said of it yet
    assert v.go_on_item == 6


def test_a_tractor_at_the_end_of_its_kept_part_holds_until_its_new_route_is_on_board(dispatch):
    # Two 20 %-loss soaks: a switch upload of ~750 items took over a minute; meanwhile the
    # tractor drove its old mission past the kept part into a field the re-plan had given
    # to another, and the field was worked twice.
    from dispatcher.link.mission_protocol import MissionUpload

    daemon = daemon_for(dispatch)
    v, link = daemon.state.vehicles["v1"], daemon.links["v1"]
    for event in running_events("v1", 3):
        daemon.state.apply(event, 0.0)
    v.mode, v.armed, v.mission_state = 10, True, mc.MISSION_STATE_ACTIVE
    v.current, v.switch, v.old_items, v.old_reached, v.route_from = 4, True, v.items, 3, 5
    link.switch_from = 5
    link.upload = MissionUpload(daemon.job.missions["v1"].to_mavlink(v.system_id), v.system_id)
    daemon._advance("v1", 1.0)
    assert link.hold is None  # still on its kept part
    feed(daemon.state, "v1", mission_current(11, 5, len(v.items) - 1, 2), 1.1)
    daemon._advance("v1", 1.2)
    commands = [m for m in daemon.publishers["v1"].sent() if m.get_type() == "COMMAND_LONG"]
    assert (commands[-1].command, commands[-1].param2) == (mc.MAV_CMD_DO_SET_MODE, 4)  # HOLD
    assert v.held_for_route
    holding = heartbeat(11)
    holding.custom_mode, holding.base_mode = 4, mc.MAV_MODE_FLAG_SAFETY_ARMED
    feed(daemon.state, "v1", holding, 1.3)
    assert v.off_auto_since is None  # our doing: not a failsafe
    link.upload.outcome = Outcome.DONE
    read_back(daemon, "v1", 11)
    assert v.phase is Phase.STARTING and not v.switch
    first = link.start.commands[0]
    assert (first.command, first.params[0]) == (mc.MAV_CMD_DO_SET_MISSION_CURRENT, 5)
    daemon._apply(ev.MissionStarted("v1", 5), 2.0)
    assert not v.held_for_route


def test_the_end_of_the_kept_part_counts_when_the_first_report_is_beyond_it(dispatch):
    # A soak: the reports of the kept part's last items lost, the first one heard was of
    # the old mission past it; those last items (three swaths) were counted by neither.
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    for event in running_events("v1", 2):
        state.apply(event, 0.0)
    v.switch, v.old_items, v.old_reached, v.route_from = True, v.items, 2, 6
    state.apply(ev.ItemReached("v1", 7, 200.0), 1.0)
    assert v.reached == 5 and v.old_reached == 7
    ends = [k for k in range(3, 6) if v.items[k].role == "swath_end"]
    for k in ends:
        item = v.items[k]
        assert state.fields[item.field_id].passes.get(item.segment) == 1


def test_a_re_plan_that_gives_a_tractor_the_mission_on_its_way_leaves_that_upload_going(
    dispatch,
):
    # A soak under 20 % loss: each re-plan began a switch upload of 600 items again,
    # though the tractor's new mission was the same; with a re-plan every 40 s it never
    # ended, the tractor held at the end of its kept part for 280 s.
    from dispatcher.link.mission_protocol import MissionUpload
    from dispatcher.mission.job import DispatchJob

    daemon = daemon_for(dispatch)
    daemon.publishers["plan"] = Pub()
    v = daemon.state.vehicles["v1"]
    for event in running_events("v1", 3):
        daemon.state.apply(event, 0.0)
    v.switch, v.old_items, v.old_reached, v.route_from = True, v.items, 3, 5
    link = daemon.links["v1"]
    link.switch_from = 5
    link.upload = upload = MissionUpload(daemon.job.missions["v1"].to_mavlink(11), 11)
    job = daemon.job
    again = DispatchJob(dataclasses.replace(job.document, plan_id="").with_id(), job.missions, {})
    assert "v1" in daemon._adopt(again, "v2 lost", 1.0)  # its mission is still to be acked
    assert daemon.links["v1"] is link and link.upload is upload and v.switch
    moved = tuple(dataclasses.replace(i, x=i.x + 5) if i.seq > 6 else i for i in v.items)
    machine = dataclasses.replace(job.document.machine("v1"), items=moved)
    changed = dataclasses.replace(job.document, machines=(machine,), plan_id="").with_id()
    daemon._adopt(DispatchJob(changed, job.missions, {}), "v3 lost", 2.0)
    assert daemon.links["v1"] is not link  # a new mission: uploaded anew


def test_a_lowering_still_to_come_on_the_part_a_re_plan_keeps_is_kept(dispatch):
    """Started back at a line's start with the implement up, its lowering to be sent once
    it is past it, then re-planned while driving: the part it keeps is the same, so is the
    lowering still to come, and it is sent there; one on the part the new route replaces
    is not."""
    from dispatcher.mission.job import DispatchJob

    job = dispatch.job()
    items = job.document.machine("v1").items
    down = next(k for k, it in enumerate(items) if it.role in IMPLEMENT_LOWERED)
    line = next(k for k in range(down + 1, len(items)) if items[k].role == "swath_end")
    cut = line + 2  # the new route from after the line
    moved = tuple(dataclasses.replace(i, x=i.x + 5) if i.seq > cut else i for i in items)
    machine = dataclasses.replace(job.document.machine("v1"), items=moved)
    changed = dataclasses.replace(job.document, machines=(machine,), plan_id="").with_id()
    for pending, kept in ((line - 1, True), (cut + 2, False)):
        daemon = daemon_for(dispatch)
        daemon.publishers["plan"] = Pub()
        v = daemon.state.vehicles["v1"]
        for event in running_events("v1", 2):
            daemon.state.apply(event, 0.0)
        v.mode, v.armed = 10, True  # AUTO, armed
        daemon.links["v1"].lower_after = (pending, down, True)
        daemon._adopt(DispatchJob(changed, job.missions, {}), "v2 lost", 1.0)
        assert v.switch and v.route_from == cut + 1
        link = daemon.links["v1"]
        assert link.lower_after == ((pending, down, True) if kept else None)
        if kept:  # on along the line: lowered
            feed(daemon.state, "v1", position(2_000, *at_item(dispatch, line)), 2.0)
            feed(daemon.state, "v1", mission_current(11, line, len(v.items) - 1, 3), 2.0)
            daemon._advance("v1", 2.1)
            assert link.lower is not None
            assert commands_to(daemon, "v1", 11)[-1] == (items[down].command, items[down].param1)


def test_a_tractor_whose_autopilot_says_its_window_is_complete_is_not_stalled(dispatch):
    # The demo at 2367x through a 10 %-loss radio: the report of the window's last item was
    # lost, and MISSION_CURRENT's "complete" was doubted (positions too far apart), so the
    # state had it one item short of the end; 5 s of wall time later it was "stalled".
    state, v = driving_v1(dispatch, 3)
    state.apply(ev.UploadStarted("v1", 2, 8), 0.0)
    state.apply(ev.UploadAcked("v1"), 0.0)
    state.apply(ev.WindowExtended("v1", 12), 0.0)  # a top-up under way: 8 -> 12 items
    v.phase, v.reached = Phase.RUNNING, 6
    v.sim_time_s, v.progress_s, v.progress_wall = 1_000.0, 100.0, 0.0
    assert state.stalled_for(v, 60.0, 50.0) == 900.0  # one short, still "driving"
    v.current, v.mission_total = 7, 7  # at item 7, the last it holds
    v.mission_state = mc.MISSION_STATE_COMPLETE
    assert v.at_window_end and state.stalled_for(v, 60.0, 50.0) is None
    v.current, v.mission_state = 5, mc.MISSION_STATE_ACTIVE  # really standing mid-window
    assert state.stalled_for(v, 60.0, 50.0) == 900.0
    # At the last item of its old window, "active" heading there: its "complete" may be
    # lost, it may wait there for its next window. Heading on to the first new item (it
    # holds it) and getting nowhere: stuck on the way, stalled, not waiting for ever.
    v.reached, v.mission_total = 7, 11
    v.current = 7
    assert v.at_window_end and state.stalled_for(v, 60.0, 50.0) is None
    v.current = 8
    assert not v.at_window_end and state.stalled_for(v, 60.0, 50.0) == 900.0


def test_a_mission_driven_to_its_end_before_the_start_was_acknowledged_counts(dispatch):
    # CI, 30 % loss: the ACK for AUTO came after the tractor had driven its last items and
    # said its mission was complete (never "active" once started): the last item's report
    # lost, the run waited for it until the test timed out.
    state, v = driving_v1(dispatch, 3)
    last = len(v.items) - 1
    state.apply(ev.StartRequested("v1", last - 2), 10.0)
    state.apply(ev.ItemReached("v1", last - 2, 200.0), 10.5)  # its reports while starting
    state.apply(ev.ItemReached("v1", last - 1, 210.0), 10.6)
    state.apply(ev.MissionStarted("v1", last - 2), 11.0)
    assert v.reached == last - 1 and v.phase is Phase.RUNNING
    for k, item in enumerate(v.items[last - 1 :]):  # its track there
        feed(state, "v1", position(211_000 + 1_000 * k, item.x, item.y), 11.1 + 0.1 * k)
    done = mission_current(v.system_id, last, last, mc.MISSION_STATE_COMPLETE)
    for t in (11.5, 14.0):
        for event in state.on_message("v1", done, t):
            state.apply(event, t)
    assert v.phase is Phase.DONE


SET_CURRENT = mc.MAV_CMD_DO_SET_MISSION_CURRENT


def test_renumbered_under_way_and_stopped_at_the_item_driven_from_memory_it_goes_on(dispatch):
    """A driving vehicle sent its mission from item ``base`` on (link/numbering.py) that
    reached the item it drove to from memory before the set-current came: it stands there,
    its mission complete in the old numbers. That is its progress (not the whole window),
    it is not taken for stalled, and it is started again after it, in the new numbers."""
    daemon = daemon_for(dispatch)
    v = daemon.state.vehicles["v1"]
    daemon.state.vehicles["v2"].phase = Phase.DONE
    n = len(v.items)
    assert n > 30, n
    driven = n - 3  # it drives to the plan's item n - 3, its own n - 3 too (base 1)
    base = driven - 20  # renumbered: the new mission ends well before that index
    count = n - base + 1  # home and the plan's items base .. n - 1
    running = heartbeat(11)
    running.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    for event in running_events("v1", driven - 1):
        daemon.state.apply(event, 0.0)
    feed(daemon.state, "v1", running, 0.0)
    feed(daemon.state, "v1", mission_current(11, driven, n - 1, mc.MISSION_STATE_ACTIVE), 1.0)
    assert v.current == driven
    # Acknowledged: the daemon reads it in the new numbers from now on.
    daemon.state.apply(ev.MissionNumbered("v1", base, count), 1.1)
    link = daemon.links["v1"]
    link.renumbered = True
    # Its reports of the item it drove to come in the old numbers, past the new count.
    done = mission_current(11, driven, count - 1, mc.MISSION_STATE_COMPLETE)
    feed(daemon.state, "v1", from_vehicle(mc.message("MISSION_ITEM_REACHED", seq=driven), 11), 2.0)
    feed(daemon.state, "v1", done, 2.0)
    assert v.current == driven and v.mission_total == n - 1
    assert not v.current_of_last_upload and v.at_window_end
    daemon._advance("v1", 2.1)
    assert link.start is not None and link.start.outcome is Outcome.RUNNING
    (item,) = [c.params[0] for c in link.start.commands if c.command == SET_CURRENT]
    assert item == driven + 1  # the plan's numbers; sent as the vehicle's driven + 1 - base + 1


def stopped(sysid):
    """A HEARTBEAT of a vehicle in HOLD and disarmed: how the operator parks it."""
    msg = holding(sysid)
    msg.base_mode = 0
    return msg


def test_a_vehicle_the_operator_stopped_and_rebooted_is_not_armed_until_put_back_in_auto(
    dispatch,
):
    """The operator holds and disarms a driving tractor and power-cycles its autopilot two
    seconds later (before "left AUTO" is said): it is not armed or started by us. Put back
    in AUTO and armed by the operator (ArduPilot then drives its mission from item 1), it
    is sent on from the item after the last one reached."""
    daemon = daemon_driving_v1(dispatch, 7)
    v = daemon.state.vehicles["v1"]
    at = at_item(dispatch, 7)  # where it stopped (off its leg it would go back to the leg's start)
    deliver(daemon, "v1", position(500_000, *at), 0.5)
    deliver(daemon, "v1", stopped(11), 1.0)
    deliver(daemon, "v1", position(501_000, *at), 1.5)  # its clock runs on, stopped
    daemon._tick(1.6)
    deliver(daemon, "v1", position(2_000, *at), 3.0)  # rebooted
    assert v.reboots == 1 and v.operator_hold and v.needs_restart
    total = mc.message("MISSION_CURRENT", seq=0, total=len(v.items) - 1, mission_state=2)
    for now in (4.0, 10.0, 40.0, 400.0):
        deliver(daemon, "v1", stopped(11), now)
        deliver(daemon, "v1", total, now)
        daemon._tick(now)
    assert not commands_to(daemon, "v1", 11)
    assert not daemon.state.finished(400.0, lost_grace_s=30.0)  # waited for
    deliver(daemon, "v1", driving_heartbeat(11), 401.0)  # the operator: AUTO, armed
    daemon._tick(401.0)
    assert not v.operator_hold
    daemon._tick(401.1)
    # Started again: HOLD first (it is in AUTO), then item 8, arm, AUTO.
    assert v.phase is Phase.STARTING and daemon.links["v1"].start_item == 8
    assert commands_to(daemon, "v1", 11) == [(mc.MAV_CMD_DO_SET_MODE, 1.0)]


def test_a_hold_longer_than_the_stall_limit_is_no_stall_once_back_in_auto(dispatch):
    """The operator holds a tractor for 100 s of its own time (the stall limit is 60 s),
    then puts it back in AUTO: it drives on, neither told to HOLD nor given up."""
    daemon = daemon_driving_v1(dispatch, 7)
    daemon.config.stall_after_s = 60.0
    v = daemon.state.vehicles["v1"]
    deliver(daemon, "v1", position_of_v1(500_000), 0.5)
    for k in range(11):  # 100 s of its clock, 10 s of wall time
        deliver(daemon, "v1", holding(11), 1.0 + k)
        deliver(daemon, "v1", position_of_v1(501_000 + 10_000 * k), 1.0 + k)
        daemon._tick(1.0 + k)
    assert v.operator_hold and v.error.startswith("left AUTO")
    for now in (12.0, 14.0, 16.0):  # still where it was: its first metres take a while
        deliver(daemon, "v1", driving_heartbeat(11), now)
        deliver(daemon, "v1", position_of_v1(602_000 + round(1000 * (now - 12.0))), now)
        daemon._tick(now)
    assert v.phase is Phase.RUNNING and not v.operator_hold and not v.stalled
    assert not commands_to(daemon, "v1", 11)


def test_after_a_restart_a_vehicle_the_operator_stopped_is_not_started(dispatch, tmp_path):
    stored = [*running_events("v1", 7), ev.LeftAuto("v1", "left AUTO: mode 4", by_operator=True)]
    daemon = resumed_daemon(dispatch, tmp_path, stored)
    v = daemon.state.vehicles["v1"]
    assert v.operator_hold
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    feed(daemon.state, "v1", stopped(11), 0.0)
    feed(daemon.state, "v1", position(1_000), 0.0)  # its clock (no fix yet)
    feed(daemon.state, "v1", mission_current(11, 8, len(v.items) - 1, 2), 0.0)
    read_back(daemon, "v1", 11)
    assert v.phase is Phase.RUNNING and v.needs_restart
    assert not [c for c in commands_to(daemon, "v1", 11) if c[0] != mc.MAV_CMD_DO_SET_MODE]
    assert mc.MAV_CMD_COMPONENT_ARM_DISARM not in [c for c, _ in commands_to(daemon, "v1", 11)]


def test_a_vehicle_alive_by_its_token_but_never_heard_is_lost_after_the_alive_timeout(dispatch):
    """Its token is there, no frame of it is taken (signed with another key, say): it is
    lost once the alive timeout is over, saying why, and its work re-planned; it stood
    'alive' for ever, the run never ending."""
    daemon = daemon_for(dispatch)
    daemon.state.vehicles["v2"].phase = Phase.DONE
    v = daemon.state.vehicles["v1"]
    daemon._apply(ev.VehicleSeen("v1"), 0.0)  # the liveliness token
    v.frames_refused = 140
    daemon._tick(30.0)
    assert v.phase is Phase.ALIVE
    daemon._tick(61.0)
    assert v.phase is Phase.LOST and "140 frame(s) of it refused" in v.error


def test_a_left_out_tractor_back_with_no_work_left_is_parked(dispatch, caplog):
    """Its work went to the others; back, the re-plan asked for finds nothing left to give
    it: it is parked (HOLD, disarm), not left armed in HOLD in the field, and the re-plan's
    'no tasks' is no error."""
    from dispatcher.daemon.server import NoWorkLeft

    daemon = daemon_for(dispatch)
    daemon.config.replanner = lambda state, cancel: (_ for _ in ()).throw(NoWorkLeft("no tasks"))
    v, link = daemon.state.vehicles["v1"], daemon.links["v1"]
    v.retired, v.phase = True, Phase.ALIVE  # heard again after it was left out
    daemon._advance("v1", 1.0)
    assert daemon._replan_reason == "v1 back" and link.park is None
    daemon._replan_step(1.0)  # the re-plan runs (a thread) ...
    daemon._replan.join(5.0)
    with caplog.at_level("INFO"):
        daemon._replan_step(2.0)  # ... and gave nothing out
        daemon._advance("v1", 2.0)
    assert "nothing to give out (no tasks)" in caplog.text and "ERROR" not in caplog.text
    assert link.park is not None
    sent = [c for c, _ in commands_to(daemon, "v1", 11)]
    assert sent[-1] == mc.MAV_CMD_DO_SET_MODE  # HOLD first, then disarm on its answer


def test_after_a_restart_a_vehicle_lost_before_is_given_the_heartbeat_timeout(dispatch, tmp_path):
    """Lost when the dispatcher stopped (its re-plan under way, not kept): its work waited
    for the 60 s alive timeout after a restart while the others finished; now twice the
    heartbeat timeout, then it is lost again and its work re-planned."""
    stored = [*running_events("v1", 7), ev.VehicleLost("v1", "heartbeats stopped")]
    daemon = resumed_daemon(dispatch, tmp_path, stored)
    v = daemon.state.vehicles["v1"]
    assert v.phase is Phase.WAITING and v.lost_before_restart
    started = daemon._started
    daemon._tick(started + 9.0)
    assert v.phase is Phase.WAITING
    daemon._tick(started + 11.0)
    assert v.phase is Phase.LOST
    assert not daemon.state.vehicles["v2"].lost_before_restart


def test_a_left_out_vehicle_not_heard_after_a_restart_is_no_error(dispatch, tmp_path, caplog):
    daemon = resumed_daemon(dispatch, tmp_path, running_events("v1", 7))
    v = daemon.state.vehicles["v1"]
    v.retired = True  # left out of the plan by a re-plan before the restart
    daemon.config.replanner = lambda state, cancel: None
    with caplog.at_level("INFO"):
        daemon._tick(daemon._started + 61.0)
    assert v.phase is Phase.LOST and "v1: not heard since the restart" in caplog.text
    assert not [r for r in caplog.records if r.levelname == "ERROR" and "v1:" in r.message]
    # Its work is the others' already: a review's restarts each re-planned the farm for it.
    asked = daemon._replan_reason + daemon._replan_asked[0]
    assert "v2 lost" in asked and "v1" not in asked


def left_out_before_a_restart(dispatch, tmp_path):
    """A daemon restarted after a re-plan that left v1 (lost, still powered) out."""
    doc = dispatch.document
    rest = dataclasses.replace(doc, machines=doc.machines[1:]).with_id()
    stored = [
        *running_events("v1", 7),
        *running_events("v2", 3),
        ev.VehicleLost("v1", "heartbeats stopped"),
        ev.PlanReplaced(ev.FLEET, rest.plan_id, "v1 lost", rest.to_dict()),
    ]
    return resumed_daemon(dispatch, tmp_path, stored)


def test_a_left_out_tractor_heard_after_a_restart_is_held_and_asks_to_rejoin(dispatch, tmp_path):
    """A review: the restarted dispatcher asked it where it stood on a mission it no longer
    had (KeyError, exit 1, at every restart while the stalled tractor stayed powered)."""
    daemon = left_out_before_a_restart(dispatch, tmp_path)
    v, link = daemon.state.vehicles["v1"], daemon.links["v1"]
    assert v.retired and not v.resuming
    feed(daemon.state, "v1", heartbeat(11), 1.0)
    daemon._advance("v1", 1.0)
    assert v.phase is Phase.ALIVE, v.phase
    assert link.download is None and link.upload is None  # not read back nor sent a mission
    assert daemon._replan_reason == "v1 back" and link.rejoin_asked
    sent = [c for c, _ in commands_to(daemon, "v1", 11)]
    assert sent == [mc.MAV_CMD_DO_SET_MODE]  # HOLD


def test_a_tractor_left_out_by_a_re_plan_after_a_restart_is_held_when_heard_again(
    dispatch, tmp_path
):
    """An outside review: a restarted dispatcher re-planned without a tractor it had not
    heard yet ("never came alive"); heard then, it was asked where it stood on the mission
    the re-plan took away (KeyError, exit 1, the fleet held). It is held, and asks to rejoin,
    as any tractor left out."""
    from dispatcher.mission.job import DispatchJob

    daemon = resumed_daemon(
        dispatch, tmp_path, [*running_events("v1", 7), *running_events("v2", 3)]
    )
    daemon.publishers["plan"] = Pub()
    v, link = daemon.state.vehicles["v1"], daemon.links["v1"]
    assert v.resuming
    job = daemon.job
    rest = dataclasses.replace(job.document, machines=job.document.machines[1:], plan_id="")
    missions = {vid: m for vid, m in job.missions.items() if vid != "v1"}
    daemon._adopt(DispatchJob(rest.with_id(), missions, {}), "v1 lost (never came alive)", 1.0)
    assert v.retired and not v.resuming
    feed(daemon.state, "v1", heartbeat(11), 2.0)
    daemon._advance("v1", 2.0)  # (raised KeyError: 'v1')
    link = daemon.links["v1"]
    assert link.download is None and link.upload is None  # not read back nor sent a mission
    assert daemon._replan_reason == "v1 back" and link.rejoin_asked


def test_an_events_stored_copy_and_its_record_have_one_time(dispatch, tmp_path):
    """A resumed run's log copies the stored events; the review tells a copy from its
    original by the time (to SAME_EVENT_NS). A re-plan's event was stored 0.12 s before it
    was recorded (its 630 kB document written between), and the review told it twice."""
    import io

    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.store import Store
    from dispatcher.recording.mcap_file import EVENTS_TOPIC, Recorder, read_log
    from dispatcher.review.report import SAME_EVENT_NS

    store = Store.open(tmp_path, "tiny")
    job = dispatch.job()
    store.begin_run(job, "x")
    daemon = Dispatcher(DaemonConfig(job=job, store=store))
    buf = io.BytesIO()
    daemon.recorder = Recorder(buf, "tiny")
    daemon.recorder.start()
    daemon.store.append = lambda event, wall, append=store.append: (  # a slow write
        time.sleep(0.05),
        append(event, wall),
    )
    daemon._apply(ev.VehicleSeen("v1"), 0.0)
    store.commit()
    daemon.recorder.finish()
    (wall,) = [w for (w,) in store.rows("SELECT wall FROM events")]
    (record,) = read_log(io.BytesIO(buf.getvalue())).on(EVENTS_TOPIC)
    assert abs(record.log_time_ns - wall * 1e9) <= SAME_EVENT_NS


def test_a_position_still_queued_as_the_run_ends_is_recorded_as_a_fix_too(dispatch):
    """At the end the dispatcher records what is still queued, frames only: each tractor's
    last position, back in the garage, was on the MAVLink topic but not on its fix topic,
    and Foxglove's map ended without it (an outside review)."""
    import io

    from dispatcher.link import wire
    from dispatcher.recording.mcap_file import Recorder, read_log
    from dispatcher.recording.topics import location_topic

    daemon = daemon_for(dispatch)
    buf = io.BytesIO()
    daemon.recorder = Recorder(buf, "tiny")
    daemon.recorder.start()
    frame = mc.Codec(11, 1).encode(position(5_000, 440_003_000, 873_001_000))
    daemon._record_only(("frame", wire.vehicle_from("tiny", "v1"), frame, 1_000_000_000))
    daemon.recorder.finish()
    fixes = read_log(io.BytesIO(buf.getvalue())).on(location_topic("v1"))
    assert len(fixes) == 1


def test_progress_may_be_looked_at_more_often_than_the_status_is_published(dispatch):
    """The demo looks for its faults every 0.1 s; the status went out (and into the log, and
    to Foxglove) as often, ten times the documented once a second (an outside review)."""
    daemon = daemon_for(dispatch)
    calls = []
    daemon.config.on_progress = lambda state: calls.append(state)
    daemon.config.progress_period_s = 0.1
    published = []
    publish = daemon._publish_status
    daemon._publish_status = lambda now: (published.append(now), publish(now))
    for k in range(1, 61):  # 3 s in ticks of 0.05 s
        daemon._tick(daemon._started + k / 20 + 1e-6)
    assert len(published) == 3 and len(calls) >= 20


def test_set_off_is_the_first_move_taken_back_along_its_first_leg() -> None:
    # Standing (GPS noise under JITTER_M), then 10 m away at t = 20 s driving 2 m/s: it set
    # off 5 s before, at 15 s, not at the last fix standing (10 s) nor the first away.
    lat0, lon0 = 44.0, 87.0
    m_lat = 1.0 / 111_132.0  # about a metre of latitude
    so = SetOff(road_speed_ms=4.0)
    assert so.update(0.0, lat0, lon0, 0.0) is None
    assert so.update(10.0, lat0 + 0.2 * m_lat, lon0, 0.05) is None  # noise
    assert so.update(20.0, lat0 + 10.2 * m_lat, lon0, 2.0) == pytest.approx(15.0, abs=0.05)
    assert so.update(30.0, lat0, lon0, 0.0) == pytest.approx(15.0, abs=0.05)  # once for all
    # No speed reported: the road speed (10 m at 4 m/s); without one, the last fix standing.
    assert SetOff(4.0).update(1.0, lat0, lon0, None) is None
    road = SetOff(4.0)
    road.update(10.0, lat0, lon0, None)
    assert road.update(20.0, lat0 + 10 * m_lat, lon0, None) == pytest.approx(17.5, abs=0.05)
    bare = SetOff()
    bare.update(10.0, lat0, lon0, None)
    assert bare.update(20.0, lat0 + 10 * m_lat, lon0, None) == 10.0


def test_set_off_kept_live_from_the_positions_not_a_no_fix(dispatch) -> None:
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    feed(state, "v1", position(1_000), 1.0)  # 0, 0: no fix yet, not a place stood
    feed(state, "v1", position(2_000, 440_000_000, 870_000_000), 2.0)
    feed(state, "v1", position(3_000, 440_000_010, 870_000_000), 3.0)  # 0.1 m: noise
    assert v.set_off.at_s is None
    feed(state, "v1", position(9_000, 440_001_000, 870_000_000), 4.0)  # 11 m away
    # Standing still in the report (vx = vy = 0): the road speed takes it back.
    road_ms = v.set_off.road_speed_ms
    assert road_ms is not None and road_ms > 0
    assert v.set_off.at_s == pytest.approx(max(3.0, 9.0 - 11.1 / road_ms), abs=0.1)
    assert state.status_doc()["vehicles"]["v1"]["set_off_s"] == v.set_off.at_s


def test_a_mission_finishes_at_the_first_position_after_its_last_report(dispatch) -> None:
    """The last item reported at 100 s (its clock at the position before) and accepted once
    two more positions bore it out: it finished at the first of them, as review has it (the
    last of them made it 0.02-0.03 h late in the demo's summary)."""
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    last = len(v.items) - 1
    state.apply(ev.MissionStarted("v1", 1), 1.0)
    state.apply(ev.ItemReached("v1", last - 1, 90.0), 1.5)
    for t_ms in (100_000, 110_000, 170_000):
        feed(state, "v1", position(t_ms, 440_003_000, 872_995_000), 2.0)
    state.apply(ev.ItemReached("v1", last, 100.0), 2.1)
    assert v.phase is Phase.DONE and v.finished_s == 110.0
    # Accepted before any later position: the next one says when.
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    state.apply(ev.MissionStarted("v1", 1), 1.0)
    feed(state, "v1", position(100_000, 440_003_000, 872_995_000), 2.0)
    state.apply(ev.ItemReached("v1", last, 100.0), 2.1)
    assert v.finished_s == 100.0
    feed(state, "v1", position(104_000, 440_003_000, 872_995_000), 2.2)
    feed(state, "v1", position(108_000, 440_003_000, 872_995_000), 2.3)
    assert v.finished_s == 104.0


def test_set_off_not_guessed_by_a_dispatcher_resumed_mid_mission(dispatch) -> None:
    # Resumed (its events replayed) after the vehicle's first items: the first move heard
    # is not when it set off; the status says it does not know.
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    state.apply(ev.MissionStarted("v1", 1), 1.0)
    state.apply(ev.ItemReached("v1", 2, 50.0), 1.5)
    feed(state, "v1", position(100_000, 440_000_000, 870_000_000), 2.0)
    feed(state, "v1", position(110_000, 440_001_000, 870_000_000), 3.0)
    assert v.set_off.at_s is None
    assert state.status_doc()["vehicles"]["v1"]["set_off_s"] is None


def test_an_item_reached_heard_before_the_clock_after_a_restart_takes_the_clock_after(
    dispatch,
) -> None:
    """ArduPilot SITL (tests/test_sitl.py's killed dispatcher, 2026-11-29): the restarted
    dispatcher first heard an item reached, then the vehicle's clock; the item took 0 s
    (the clock not heard yet), so a field it finished would have. It takes the clock of
    the position that bears it out."""
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    for event in running_events("v1", 2):  # item 2 reached at 100 s, then a restart
        state.apply(event, 1.0)
    state.apply(ev.Resumed("v1"), 2.0)
    seq = next(s for s in range(3, len(v.items)) if v.items[s].is_nav)
    item = v.items[seq]
    reached = from_vehicle(mc.message("MISSION_ITEM_REACHED", seq=seq), 11)
    events = state.on_message("v1", reached, 3.0)
    events += state.on_message("v1", position(400_000, *_e7(item.lat, item.lon)), 3.1)
    (event,) = [e for e in events if isinstance(e, ev.ItemReached)]
    assert event.seq == seq and event.clock_s == 400.0


@pytest.mark.parametrize(
    "since",
    [
        [],
        # replayed, these set its progress to its clock, not heard in a replay (review)
        [ev.VehicleLost("v1", "no heartbeat"), ev.VehicleSeen("v1")],
        [ev.StartRequested("v1", 3), ev.MissionStarted("v1", 3)],
    ],
)
def test_a_vehicle_that_rebooted_before_a_restart_keeps_its_time_going_on(dispatch, since) -> None:
    """Its run clock was ahead of its own by the reboot (item 2 reached at 100 s of the
    run, 30 s after the autopilot booted again); the restarted dispatcher's new clock took
    the vehicle's own, and every time after the restart came out behind the stored ones."""
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    for event in running_events("v1", 2) + since:  # item 2 reached at 100 s, then a restart
        state.apply(event, 1.0)
    state.apply(ev.Resumed("v1"), 2.0)
    feed(state, "v1", position(30_000, 440_003_000, 872_995_000), 3.0)
    feed(state, "v1", position(31_000, 440_003_000, 872_995_000), 4.0)
    assert v.sim_time_s == 101.0
    # One that did not reboot: its own clock, as before.
    state = FleetState(dispatch.document)
    for event in running_events("v1", 2):
        state.apply(event, 1.0)
    state.apply(ev.Resumed("v1"), 2.0)
    feed(state, "v1", position(150_000, 440_003_000, 872_995_000), 3.0)
    assert state.vehicles["v1"].sim_time_s == 150.0


def _e7(lat: float, lon: float) -> tuple[int, int]:
    return round(lat * 1e7), round(lon * 1e7)


def test_every_key_of_the_status_document_is_documented(dispatch) -> None:
    """docs/link.md's tables of the status document name exactly its keys, at each level
    (a key added to ``status_doc`` and not to the page fails here)."""
    import re

    page = (Path(__file__).resolve().parents[2] / "docs" / "link.md").read_text()
    section = page[page.index("### The status document") :]
    tables = re.split(r"\n(?=Each (?:vehicle|field):)", section)
    documented = [
        {
            k
            for row in re.findall(r"^\| (`[^|]+`) \|", t, flags=re.M)
            for k in re.findall(r"`(\w+)`", row)
        }
        for t in tables
    ]
    doc = FleetState(dispatch.document).status_doc()
    vehicle = next(iter(doc["vehicles"].values())) | {"foreign_commands": 0}  # the server's
    field_doc = next(iter(doc["fields"].values()))
    assert documented == [set(doc), set(vehicle), set(field_doc)]


def test_a_lost_vehicle_left_out_stays_lost_through_a_restart(dispatch) -> None:
    """Lost, its work re-planned over the others, then the dispatcher restarted: it is
    still lost with its reason (shown "waiting", it had a field and hours of work it no
    longer has), and heard again it is alive as without the restart."""
    state = FleetState(dispatch.document)
    v = state.vehicles["v1"]
    state.apply(ev.VehicleSeen("v1"), 1.0)
    state.apply(ev.VehicleLost("v1", "liveliness token dropped"), 2.0)
    state.apply(ev.VehicleSeen("v2"), 2.5)  # the dispatcher's last event before it stopped
    v.retired = True  # what the re-plan does to a vehicle it leaves out
    state.apply(ev.Resumed("v1"), 1003.0)  # (on another clock: the daemon's, not the store's)
    state.apply(ev.Resumed("v2"), 1003.0)
    assert v.phase is Phase.LOST and "liveliness token dropped" in v.error
    assert state.status_doc()["vehicles"]["v1"]["phase"] == "lost"
    feed(state, "v1", position(5_000, 440_003_000, 872_995_000), 1005.0)
    assert v.phase is Phase.ALIVE and not v.error
    # Lost from 2 s to the last event at 2.5 s, and from the restart until heard again 2 s
    # later (the time lost before a restart was not counted).
    assert v.lost_s == 2.5
    # One in the plan, lost before the restart, is to be heard again: waiting.
    other = FleetState(dispatch.document)
    w = other.vehicles["v1"]
    other.apply(ev.VehicleSeen("v1"), 1.0)
    other.apply(ev.VehicleLost("v1", "liveliness token dropped"), 2.0)
    other.apply(ev.VehicleSeen("v2"), 3.0)
    other.apply(ev.Resumed("v2"), 1003.0)
    other.apply(ev.Resumed("v1"), 1003.0)
    assert w.phase is Phase.WAITING and not w.error and w.lost_before_restart
    assert w.lost_s == 1.0  # lost up to the dispatcher's last event


def foreign_daemon(dispatch, keys=None):
    """A daemon whose v1 drives its mission; ``keys``: each vehicle's signing key."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher

    daemon = Dispatcher(DaemonConfig(job=dispatch.job(), keys=keys))
    daemon.publishers = {vid: Pub() for vid in dispatch.missions}
    for event in running_events("v1", 3):
        daemon._apply(event, 0.0)
    return daemon


def stranger_upload(codec):
    """A foreign system's MISSION_COUNT for v1 (system 11)."""
    count = mc.message("MISSION_COUNT", target_system=11, target_component=1, count=2)
    return codec.encode(count)


def test_a_command_on_a_key_expression_with_wildcards_alarms_every_vehicle_it_reaches(dispatch):
    """A put on `…/vehicle/*/mavlink/to` (or `agrifleet/<farm>/**`) reaches every tractor's
    command key, and each took it; the dispatcher read `*` as a vehicle it does not know and
    dropped it without a word (an outside review: v1 driven 1.5 km away, no alarm)."""
    from dispatcher.link import wire

    daemon = foreign_daemon(dispatch)
    stranger = mc.Codec(77, 190)
    farm = daemon.farm
    for n, key in enumerate(
        [wire.vehicle_to(farm, "*"), f"{wire.PREFIX}/{farm}/**", "**/v2/mavlink/to"]
    ):
        daemon._handle(("command", key, stranger_upload(stranger), 0), 10.0 * n)
    alarmed = [vid for _, vid, _ in daemon.state.alarms]
    assert alarmed == ["v1", "v2", "v1", "v2", "v2"], daemon.state.alarms
    assert all(v.verify_mission for v in daemon.state.vehicles.values())
    assert daemon.foreign_frames == {"v1": 2, "v2": 3}
    daemon._handle(("command", f"{wire.PREFIX}/another-farm/**", b"x", 0), 40.0)
    assert len(daemon.state.alarms) == 5  # (another farm's keys: not ours to alarm)


@pytest.mark.parametrize("signed", [True, False], ids=["signed", "unsigned"])
def test_a_decoy_frame_does_not_let_the_upload_after_it_go_unchecked(dispatch, signed):
    """An alarm a second per vehicle: an unsigned decoy on v1's key silenced the upload
    signed with its leaked key 0.4 s later (no alarm; the read-back the decoy began found
    the mission intact before the upload came, and v1 drove the foreign mission: an outside
    review). A frame of another kind alarms, and one v1 may have taken while its mission
    is read back has it read back once more."""
    import secrets

    keys = {vid: secrets.token_bytes(32) for vid in dispatch.missions} if signed else None
    daemon = foreign_daemon(dispatch, keys)
    v, link = daemon.state.vehicles["v1"], daemon.links["v1"]
    decoy, leaked = mc.Codec(77, 190), mc.Codec(77, 190, key=keys["v1"] if keys else None)
    command = ("command", "agrifleet/tiny/vehicle/v1/mavlink/to")
    daemon._handle((*command, stranger_upload(decoy), 0), 1.0)
    daemon._advance("v1", 1.1)
    assert link.download is not None and v.verify_mission  # reading v1's mission back
    daemon._handle((*command, stranger_upload(leaked), 0), 1.4)
    texts = [text for _, _, text in daemon.state.alarms]
    assert len(texts) == (2 if signed else 1), texts
    assert not signed or "it has leaked" in texts[1]
    items = daemon.job.missions["v1"].to_mavlink(255)  # read back before the upload: intact
    count = mc.message("MISSION_COUNT", target_system=255, target_component=190, count=len(items))
    link.download.on_message(from_vehicle(count, 11), 1.5)
    for item in items:
        link.download.on_message(from_vehicle(item, 11), 1.5)
    daemon._advance("v1", 1.6)
    assert v.verify_mission, "the mission was taken as checked"
    daemon._advance("v1", 1.7)
    assert link.download is not None  # read back again
    asked = [m.get_type() for m in daemon.publishers["v1"].sent(11) if m is not None]
    assert asked.count("MISSION_REQUEST_LIST") == 2, asked


def test_a_vehicle_still_lost_has_its_loss_so_far_in_the_status(dispatch):
    """`lost_s` grew only when a vehicle came back: one stalled or killed for good showed
    0 in the live status and in the last one the review reads (an outside review: a
    tractor dead for the whole 108 s run, 0.0)."""
    state = FleetState(dispatch.document)
    state.apply(ev.VehicleSeen("v1"), 1.0)
    state.apply(ev.VehicleLost("v1", "liveliness token dropped"), 10.0)
    assert state.status_doc(25.0)["vehicles"]["v1"]["lost_s"] == 15.0
    state.apply(ev.VehicleSeen("v1"), 30.0)
    state.apply(ev.VehicleStalled("v1", 120.0), 40.0)
    assert state.status_doc(50.0)["vehicles"]["v1"]["lost_s"] == 30.0  # 20 s, then 10 s
    assert state.status_doc()["vehicles"]["v1"]["lost_s"] == 20.0  # (no clock: those ended)
