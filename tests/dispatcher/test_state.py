"""The dispatcher's state through losses of link: vehicles resume where they were."""

from pathlib import Path

import pytest

from dispatcher import mavlink_codec as mc
from dispatcher.errors import ConfigError
from dispatcher.plan_output import dispatch_plan, write_plan_files
from dispatcher.scenario import load_scenario
from dispatcher.state import FleetState, Phase
from planner.field_plan import plan_farm
from planner.solve import stop_after

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="module")
def dispatch():
    scenario = load_scenario(DATA / "tiny.toml")
    plan = plan_farm(
        scenario.farm,
        [v.machine for v in scenario.vehicles],
        "makespan",
        "ighoa",
        stop_after(20),
        seed=1,
    )
    return dispatch_plan(scenario, plan)


def heartbeat(sysid):
    msg = mc.message(
        "HEARTBEAT",
        type=mc.MAV_TYPE_GROUND_ROVER,
        autopilot=mc.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode=0,
        custom_mode=10,
        system_status=4,
        mavlink_version=3,
    )
    return mc.Codec(255, 190).decode_one(mc.Codec(sysid, 1).encode(msg))


@pytest.mark.parametrize("phase", [Phase.UPLOADING, Phase.STARTING, Phase.RUNNING])
def test_a_vehicle_lost_for_a_moment_resumes_its_phase(dispatch, phase):
    state = FleetState(dispatch)
    v = state.vehicles["v1"]
    v.phase = phase
    state.on_gone("v1", 10.0, "liveliness token dropped")
    assert v.phase is Phase.LOST
    assert not state.finished(12.0, lost_grace_s=30.0)  # not given up yet
    state.on_alive("v1", 14.0)
    assert v.phase is phase and v.lost_s == pytest.approx(4.0) and v.error == ""
    state.on_gone("v1", 20.0, "heartbeats stopped")
    state.on_message("v1", heartbeat(11), 21.0)  # frames again: the link is back
    assert v.phase is phase and v.lost_s == pytest.approx(5.0)


def test_a_vehicle_lost_for_good_ends_the_run_after_the_grace(dispatch):
    state = FleetState(dispatch)
    state.vehicles["v2"].phase = Phase.DONE
    state.vehicles["v1"].phase = Phase.RUNNING
    state.on_gone("v1", 100.0, "heartbeats stopped")
    assert not state.finished(120.0, lost_grace_s=30.0)
    assert state.finished(131.0, lost_grace_s=30.0)


def test_replanning_into_the_same_folder_leaves_no_stale_mission(dispatch, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old-tractor.waypoints").write_text("QGC WPL 110\n")
    (out / "old-tractor.plan").write_text("{}")
    write_plan_files(dispatch, out)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["map.png", "plan.json", "v1.plan", "v1.waypoints", "v2.plan", "v2.waypoints"]


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


def test_a_failed_upload_is_tried_again_from_the_count(dispatch):
    from dispatcher.daemon import DaemonConfig, Dispatcher
    from dispatcher.mission_client import Outcome

    class Pub:
        def __init__(self):
            self.frames = []

        def put(self, frame):
            self.frames.append(frame)

    daemon = Dispatcher(DaemonConfig(dispatch=dispatch))
    daemon.publishers = {vid: Pub() for vid in dispatch.missions}
    for vid in dispatch.missions:
        daemon.state.on_alive(vid, 0.0)
    daemon._advance("v1", 0.0)
    first = daemon.links["v1"].upload
    assert daemon.state.vehicles["v1"].phase is Phase.UPLOADING and first is not None
    for attempt in (2, 3):
        daemon.links["v1"].upload._fail("no answer")
        daemon._advance("v1", 1.0)
        assert daemon.state.vehicles["v1"].upload_attempts == attempt
        assert daemon.links["v1"].upload.outcome is Outcome.RUNNING
    daemon.links["v1"].upload._fail("no answer")
    daemon._advance("v1", 2.0)
    v1 = daemon.state.vehicles["v1"]
    assert v1.phase is Phase.FAILED and "after 3 attempts" in v1.error
    counts = [mc.Codec(11, 1).decode_one(f) for f in daemon.publishers["v1"].frames]
    assert [m.get_type() for m in counts].count("MISSION_COUNT") == 3


def test_a_running_vehicle_out_of_auto_is_flagged_and_given_up_after_the_grace(dispatch):
    state = FleetState(dispatch)
    state.vehicles["v2"].phase = Phase.DONE
    v = state.vehicles["v1"]
    v.phase = Phase.RUNNING
    hold = heartbeat(11)
    hold.custom_mode = 4  # HOLD: a failsafe or the operator stopped it
    state.on_message("v1", hold, 10.0)
    assert v.off_auto_since == 10.0 and not state.finished(20.0, lost_grace_s=30.0)
    assert state.status_doc()["vehicles"]["v1"]["stopped_outside_auto"] is True
    assert state.finished(41.0, lost_grace_s=30.0)
    auto = heartbeat(11)
    auto.base_mode = mc.MAV_MODE_FLAG_SAFETY_ARMED
    state.on_message("v1", auto, 42.0)  # back in AUTO and armed
    assert v.off_auto_since is None and not state.finished(43.0, lost_grace_s=30.0)


def test_a_field_starts_at_its_entry_when_the_implement_item_is_not_reported(dispatch):
    state = FleetState(dispatch)
    v = state.vehicles["v1"]
    v.phase = Phase.RUNNING
    mission = v.mission
    entry = next(s for s, t in enumerate(mission.traces) if t.role == "transit" and t.field_id)
    first_end = next(s for s, t in enumerate(mission.traces) if t.role == "swath_end")
    fid = mission.traces[entry].field_id
    v.sim_time_s = 100.0
    state.on_item_reached("v1", entry)
    assert state.fields[fid].status == "working" and state.fields[fid].started_s == 100.0
    v.sim_time_s = 300.0
    state.on_item_reached("v1", first_end)  # real ArduPilot skips the DO items' reports
    assert state.fields[fid].started_s == 100.0  # not moved to the end of the first swath
