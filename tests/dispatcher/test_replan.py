"""Planning the rest of the day from the fleet state: a vehicle lost in the middle of a
field, the others taking over from where they are (dispatcher/tools/replan.py)."""

import dataclasses
import math
import threading
import time
from pathlib import Path

import pytest

from dispatcher.config.scenario import load_scenario
from dispatcher.daemon import events as ev
from dispatcher.daemon.state import FleetState, Phase
from dispatcher.mission.plan import DispatchPlan, dispatch_plan
from dispatcher.tools.replan import ReplanError, base_visits, replan, visit_of
from planner.field_plan import plan_farm
from planner.replan import visit_segments
from planner.solve import solve, stop_after

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="module")
def current() -> DispatchPlan:
    scenario = load_scenario(DATA / "restart.toml")  # two machines of the same width
    machines = [v.machine for v in scenario.vehicles]
    plan = plan_farm(scenario.farm, machines, "makespan", "ighoa", stop_after(20), seed=1)
    return dispatch_plan(scenario, plan)


def swath_end(current: DispatchPlan, vid: str, field: str, index: int) -> int:
    items = current.document.machine(vid).items
    return next(
        i.seq
        for i in items
        if i.field_id == field and i.role == "swath_end" and i.swath_index == index
    )


def started(state: FleetState, vid: str) -> None:
    for event in (
        ev.VehicleSeen(vid),
        ev.UploadStarted(vid, 1),
        ev.UploadAcked(vid),
        ev.StartRequested(vid, 1),
        ev.MissionStarted(vid, 1),
    ):
        state.apply(event, 0.0)


def test_the_rest_of_a_lost_vehicles_field_goes_to_the_other_from_where_it_stopped(current):
    scenario = current.scenario
    state = FleetState(current.document)
    lost, other = ("v2", "v1")
    lost_field = current.document.machine(lost).fields[0]
    other_field = current.document.machine(other).fields[0]
    for vid in (lost, other):
        started(state, vid)
    state.apply(ev.ItemReached(lost, swath_end(current, lost, lost_field, 2), 100.0), 1.0)
    state.apply(ev.VehicleLost(lost, "heartbeats stopped"), 2.0)
    # The other one is driving its second swath of its first field.
    reached = swath_end(current, other, other_field, 0)
    state.apply(ev.ItemReached(other, reached, 100.0), 1.0)
    v = state.vehicles[other]
    v.current = swath_end(current, other, other_field, 1)
    v.lat, v.lon = v.items[reached].lat, v.items[reached].lon
    assert state.fields[lost_field].status == "working" and state.vehicles[lost].phase is Phase.LOST

    nxt = replan(scenario, current, state, stop=stop_after(30))
    assert [m.id for m in nxt.document.machines] == [other]
    assert nxt.plan_id != current.plan_id
    new_fields = nxt.document.machine(other).fields
    assert sorted(new_fields) == sorted(current.document.fields)  # nothing was done yet
    # The lost vehicle's field: exactly its segments not done (three were), each once.
    lost_visit = visit_of(nxt, lost_field)
    total = len(visit_segments(visit_of(current, lost_field)))
    assert sorted(lost_visit.original_segments) == list(range(3, total))
    # The other's own field: on from the swath it drives (it finishes it first).
    own_visit = visit_of(nxt, other_field)
    assert own_visit.original_segments[0] == 2
    assert sorted(own_visit.original_segments) == list(
        range(2, len(visit_segments(visit_of(current, other_field))))
    )
    assert nxt.plan.machines[0].ready_h > 0.0


def test_the_part_a_vehicle_drives_on_counts_in_its_plans_work_and_fuel(current):
    """Re-planned in the middle of a field, a vehicle works on to the end of its window
    first: those hours were in its plan's time alone (a review: its planned fuel 26-33 %
    short of what it burned)."""
    from dispatcher.tools.replan import _kept_work

    state = FleetState(current.document)
    started(state, "v1")
    v = state.vehicles["v1"]
    ends = [k for k, i in enumerate(v.items) if i.role == "swath_end"]
    state.apply(ev.ItemReached("v1", ends[1], 100.0), 1.0)
    work_h, _ = _kept_work(v, ends[4])
    legs = [v.planned_s[k] - v.planned_s[k - 1] for k in ends[2:5]]
    assert work_h == pytest.approx(sum(legs) / 3600.0) and work_h > 0.0
    assert _kept_work(v, None) == (0.0, 0)


def test_a_replan_with_no_vehicle_left_says_so(current):
    state = FleetState(current.document)
    for vid in state.vehicles:
        state.apply(ev.VehicleLost(vid, "gone"), 0.0)
    with pytest.raises(ReplanError, match="no vehicle left"):
        replan(current.scenario, current, state, stop=stop_after(5))


def test_a_resumed_run_lays_out_each_fields_first_visit_again_from_the_document(current):
    """The planner's view of a run is not stored; the fields' first layouts, which number
    the segments, come back exactly from the plan document."""
    again = base_visits(current.scenario, current.document)
    for m in current.plan.machines:
        for visit in m.visits:
            assert visit_segments(again[visit.field.id]) == visit_segments(visit)


def test_a_resumed_run_numbers_a_field_a_replan_laid_out_anew_in_that_layout(dispatch):
    """A review: after a restart, a field a re-plan had given whole to a machine of another
    width was counted in its first layout (109 segments instead of 159: the rest of it
    dropped as done; another field worked twice). The re-plans' documents say which."""
    from dispatcher.mission.document import PlanDocument

    scenario, first = dispatch.scenario, dispatch.document
    a, b = first.machines[0], first.machines[1]
    assert a.working_width_m != b.working_width_m
    moved = b.visits[0]

    def replanned(rest: bool) -> PlanDocument:
        """``b``'s first field given to ``a`` by a re-plan: laid out anew, or its rest."""
        visit = dataclasses.replace(moved, rest=rest)
        machine = dataclasses.replace(a, visits=(*a.visits, visit))
        doc = dataclasses.replace(first, machines=(machine,)).with_id()
        return PlanDocument.from_json(doc.to_json())  # as the store reads it back

    layouts = base_visits(scenario, first)
    anew = base_visits(scenario, first, replanned(rest=False))
    kept = base_visits(scenario, first, replanned(rest=True))
    theirs = base_visits(
        scenario, dataclasses.replace(first, machines=(replanned(False).machines[0],))
    )
    field = moved.field
    assert len(visit_segments(anew[field])) == len(visit_segments(theirs[field]))
    assert len(visit_segments(anew[field])) != len(visit_segments(layouts[field]))
    assert visit_segments(kept[field]) == visit_segments(layouts[field])


def test_a_replan_without_the_planners_view_plans_the_rest_from_the_first_layouts(current):
    scenario = current.scenario
    state = FleetState(current.document)
    lost, other = ("v2", "v1")
    lost_field = current.document.machine(lost).fields[0]
    for vid in (lost, other):
        started(state, vid)
    state.apply(ev.ItemReached(lost, swath_end(current, lost, lost_field, 2), 100.0), 1.0)
    state.apply(ev.VehicleLost(lost, "heartbeats stopped"), 2.0)
    base = base_visits(scenario, current.document)
    nxt = replan(scenario, None, state, stop=stop_after(30), base=base)
    total = len(visit_segments(visit_of(current, lost_field)))
    assert sorted(visit_of(nxt, lost_field).original_segments) == list(range(3, total))
    visits = {v.field: v for m in nxt.document.machines for v in m.visits}
    assert visits[lost_field].rest  # numbered in its first layout (base_visits)
    assert not any(v.rest for f, v in visits.items() if f != lost_field)


def test_a_vehicle_heading_for_an_item_without_a_position_starts_its_route_somewhere(current):
    """A speed change or an implement command has no position (0, 0): where a driving
    vehicle starts its new route is counted from the next item that has one (before, the
    re-plan failed with "ready_h must be a finite number, not inf": found by the soak)."""
    from dispatcher.tools.replan import _where

    state = FleetState(current.document)
    started(state, "v1")
    v = state.vehicles["v1"]
    blind = next(k for k, i in enumerate(v.items) if k > 1 and not (i.x or i.y))
    v.reached = blind - 1  # heading for an item without a position
    cut = next(k for k in range(blind, len(v.items)) if v.items[k].role == "swath_end")
    farm = current.scenario.farm
    (x, y), ready_h = _where(v, farm, 5.0, cut)
    assert all(math.isfinite(c) for c in (x, y, ready_h)) and ready_h > 0.0


def test_a_loss_during_a_re_plan_gives_it_up_and_the_next_one_answers_both():
    """A vehicle lost while a re-plan runs: that re-plan (whose copy of the state still
    counts on the vehicle) is told to stop and its result is not used; the next one starts
    at once, from a state with both losses, and is timed from the first."""
    from helpers.daemon import Pub

    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.daemon.state import GONE

    scenario = load_scenario(DATA / "restart3.toml")
    machines = [v.machine for v in scenario.vehicles]
    plan = plan_farm(scenario.farm, machines, "makespan", "ighoa", stop_after(5), seed=1)
    dispatch = dispatch_plan(scenario, plan)
    calls: list[tuple[list[str], threading.Event]] = []

    def replanner(state: FleetState, cancel: threading.Event):
        calls.append((sorted(v.id for v in state.vehicles.values() if v.phase in GONE), cancel))
        if len(calls) == 1:
            assert cancel.wait(10.0)  # runs until it is given up
        return daemon.job

    daemon = Dispatcher(DaemonConfig(job=dispatch.job(), replanner=replanner))
    daemon.publishers = {key: Pub() for key in [*dispatch.missions, "plan"]}
    for vid in dispatch.missions:
        started(daemon.state, vid)
        daemon.state.vehicles[vid].clock.update(0.0, 0.0)
        daemon.state.vehicles[vid].clock.update(2.0, 2.0)  # its clock's rate is known
    first = time.monotonic() - 5.0  # v1 was lost 5 s ago
    daemon._apply(ev.VehicleLost("v1", "liveliness token dropped"), first)
    daemon._replan_step(first + 0.1)
    assert len(calls) == 1 and calls[0][0] == ["v1"]
    daemon._apply(ev.VehicleLost("v2", "liveliness token dropped"), time.monotonic())
    assert calls[0][1].is_set()
    daemon._replan.join(10.0)
    daemon._replan_step(time.monotonic())  # the first one's result is dropped; the next starts
    assert daemon.replans == [] and len(calls) == 2 and calls[1][0] == ["v1", "v2"]
    daemon._replan.join(10.0)
    daemon._replan_step(time.monotonic())
    assert len(daemon.replans) == 1
    reason, to_plan, _ = daemon.replans[0]
    assert "v1 lost" in reason and "v2 lost" in reason
    assert 5.0 <= to_plan < 15.0  # from the first loss


def test_a_finished_vehicle_given_no_more_work_keeps_its_mission(current):
    # Garage to garage, uploaded and started, it completed at once, never said its mission
    # was active, made no progress and was taken for stalled (20 %-loss soak).
    import dataclasses

    from dispatcher.tools.replan import handover

    state = FleetState(current.document)
    v1 = state.vehicles["v1"]
    started(state, "v1")
    state.apply(ev.ItemReached("v1", len(v1.items) - 1, 100.0), 1.0)
    assert v1.phase is Phase.DONE
    idle = dataclasses.replace(current.document.machine("v1"), fields=())
    machines = tuple(idle if m.id == "v1" else m for m in current.document.machines)
    short = dataclasses.replace(
        current.missions["v1"],
        items=current.missions["v1"].items[:3],
        traces=current.missions["v1"].traces[:3],
    )
    nxt = dataclasses.replace(
        current,
        document=dataclasses.replace(current.document, machines=machines),
        missions={**current.missions, "v1": short},
    )
    job = handover(current.job(), state, nxt)
    assert job.missions["v1"] is current.missions["v1"]  # nothing to upload
    assert job.document.machine("v1").items == v1.items
    assert job.missions["v2"] is nxt.missions["v2"]  # not started: the new one, whole


def test_the_scenarios_makespan_slack_reaches_the_solver_of_the_plan_and_the_re_plan(
    current, monkeypatch
):
    """``[solver] makespan_slack`` is passed to the solver by the first plan
    (:func:`agrifleet.api.dispatch_for`) and by every re-plan."""
    import planner.field_plan
    import planner.replan
    from agrifleet.api import dispatch_for

    solver = dataclasses.replace(
        current.scenario.solver, algorithm="hybrid", generations=5, makespan_slack=0.02
    )
    scenario = dataclasses.replace(current.scenario, solver=solver)
    slacks = []

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        slacks.append(kwargs["makespan_slack"])
        return solve(*args, **kwargs)

    monkeypatch.setattr(planner.field_plan, "solve", spy)
    monkeypatch.setattr(planner.replan, "solve", spy)
    first = dispatch_for(scenario, "makespan", 30.0)
    state = FleetState(first.document)
    for vid in state.vehicles:
        started(state, vid)
    state.apply(ev.VehicleLost("v2", "heartbeats stopped"), 1.0)
    replan(scenario, first, state, stop=stop_after(5))
    assert slacks == [0.02, 0.02]


def _lost_one(scenario):  # type: ignore[no-untyped-def]
    """The scenario's first plan (hybrid, a few generations), its vehicles driving, v1 lost."""
    from agrifleet.api import dispatch_for

    solver = dataclasses.replace(scenario.solver, algorithm="hybrid", generations=30)
    scenario = dataclasses.replace(scenario, solver=solver)
    first = dispatch_for(scenario, "makespan", 30.0)
    state = FleetState(first.document)
    for vid in state.vehicles:
        started(state, vid)
    state.apply(ev.VehicleLost("v1", "heartbeats stopped"), 1.0)
    return scenario, first, state


def test_a_re_plan_within_what_is_left_of_the_deadline_drives_less_road():
    """With room under the deadline the rest is planned for the road distance: on the
    three-tractor farm with one lost, as early as it can the two left share the two fields;
    within 1.5 times that, one tractor does both and the fleet drives less."""
    scenario, first, state = _lost_one(load_scenario(DATA / "restart3.toml"))
    early = replan(scenario, first, state, stop=stop_after(30))
    deadline = 1.5 * early.plan.makespan_h
    within = replan(scenario, first, state, stop=stop_after(30), finish_within_h=deadline)
    assert within.plan.makespan_h <= deadline
    assert within.plan.distance_m < early.plan.distance_m - 100.0


def test_the_replanner_gives_the_re_plan_what_is_left_of_the_runs_deadline(monkeypatch):
    """``[solver] finish_within_h`` counts from the run's start: a re-plan two hours in is
    given eight hours of a ten-hour deadline, and none once it has passed (the rest then
    finishes as early as it can)."""
    import planner.replan
    from dispatcher.tools.replan import replanner_for

    scenario, first, state = _lost_one(load_scenario(DATA / "restart3.toml"))
    solver = dataclasses.replace(scenario.solver, finish_within_h=10.0)
    scenario = dataclasses.replace(scenario, solver=solver)
    given = []

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        given.append(kwargs["finish_within_h"])
        return solve(*args, **kwargs)

    monkeypatch.setattr(planner.replan, "solve", spy)
    for hours_ago in (2.0, 11.0):
        replanner = replanner_for(scenario, first, 0.2, started=time.time() - 3600.0 * hours_ago)
        replanner(state, threading.Event())
    assert given[0] == pytest.approx(8.0, abs=0.01) and given[1] == 0.0


def test_the_runs_hours_are_counted_on_the_vehicles_clocks(current):
    from dispatcher.tools.replan import deadline_left_h, run_hours

    state = FleetState(current.document)
    assert run_hours(state, 100.0, 100.0 + 1800.0) == pytest.approx(0.5)  # no rate known: 1
    clock = state.vehicles["v2"].clock
    clock.update(0.0, 0.0)
    clock.update(40.0, 2.0)  # a simulated tractor at 20 x
    assert run_hours(state, 100.0, 100.0 + 1800.0) == pytest.approx(10.0)
    assert run_hours(state, 100.0, 50.0) == 0.0
    assert deadline_left_h(12.0, 10.0) == pytest.approx(2.0)
    assert deadline_left_h(12.0, 12.5) == 0.0  # passed: none
    assert deadline_left_h(0.0, 1.0) == 0.0  # no deadline


def test_a_run_re_planned_before_a_restart_resumes_with_the_last_plan(current, tmp_path):
    """The store keeps the first plan's document and the last plan's missions: read back,
    the job is the last plan's (its document from the plan_replaced event), and the events
    replay from the first plan through the re-plan (it failed to read back before)."""
    from dispatcher.daemon.store import Store
    from dispatcher.tools.replan import handover

    scenario = current.scenario
    first = current.job()
    store = Store.open(tmp_path, scenario.farm_id)
    store.begin_run(first, "inputs")
    state = FleetState(current.document)
    events = []
    for vid in ("v1", "v2"):
        events += [
            ev.VehicleSeen(vid),
            ev.UploadStarted(vid, 1),
            ev.UploadAcked(vid),
            ev.StartRequested(vid, 1),
            ev.MissionStarted(vid, 1),
        ]
    events += [ev.ItemReached("v1", 3, 30.0), ev.VehicleLost("v2", "heartbeats stopped")]
    for event in events:
        state.apply(event, 1.0)
        store.append(event, 1.0)
    nxt = replan(scenario, current, state, stop=stop_after(5))
    job = handover(first, state, nxt)
    store.append(ev.PlanReplaced(ev.FLEET, job.plan_id, "v2 lost", job.document.to_dict()), 2.0)
    store.replace_missions(job)
    store.commit()
    store.close()

    store = Store.open(tmp_path, scenario.farm_id)
    run = store.unfinished_run()
    store.close()
    assert run is not None and run.first_document == first.document
    assert run.job.document == job.document and run.job.geojson == job.geojson
    assert {vid: m.items for vid, m in run.job.missions.items()} == {
        vid: m.items for vid, m in job.missions.items()
    }
    replayed = run.replay()
    assert replayed.plan_id == job.plan_id and replayed.vehicles["v2"].retired
    assert replayed.vehicles["v1"].items == job.document.machine("v1").items


def test_a_field_a_re_plan_lays_out_anew_counts_the_new_layouts_segments(dispatch):
    """A field half worked by a tractor lost, whose rest no other can drive (another
    working width), is planned whole again with its segments numbered anew: the status
    counts the new layout's segments, and once they are worked none is 'never worked' or
    'worked twice' (the old layout's passes were mixed in: 'segment 6 of 7 never worked')."""
    from dispatcher.tools.replan import handover

    state = FleetState(dispatch.document)
    lost, other = (m.id for m in dispatch.document.machines)
    widths = {m.id: m.working_width_m for m in dispatch.document.machines}
    assert widths[lost] != widths[other]
    fid = dispatch.document.machine(lost).fields[0]
    for vid in (lost, other):
        started(state, vid)
    state.apply(ev.ItemReached(lost, swath_end(dispatch, lost, fid, 1), 100.0), 1.0)
    state.apply(ev.VehicleLost(lost, "heartbeats stopped"), 2.0)
    worked = len(state.fields[fid].passes)
    assert worked
    nxt = replan(dispatch.scenario, dispatch, state, stop=stop_after(5))
    job = handover(dispatch.job(), state, nxt)
    state.apply(ev.PlanReplaced(ev.FLEET, job.plan_id, "lost", job.document.to_dict()), 3.0)
    items = job.document.machine(other).items
    new = {i.segment for i in items if i.field_id == fid and i.role == "swath_end"}
    f = state.fields[fid]
    assert f.segments == max(new) + 1 and not f.passes
    # What was worked of it is said (to be worked again: the status and the review lost it,
    # and the start went to the second tractor: an outside review)
    assert f.relaid == [(lost, worked)] and f.started_by == lost
    assert state.status_doc()["fields"][fid]["relaid"] == [[lost, worked]]
    for event in (ev.SwitchUploaded(other), ev.UploadAcked(other)):  # its new mission on board
        state.apply(event, 4.0)
    state.apply(ev.ItemReached(other, len(items) - 1, 900.0), 5.0)
    assert f.status == "done" and not f.never_worked and not f.worked_twice
    assert f.started_by == lost  # the first start is kept
