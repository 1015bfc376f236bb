"""The rest of the day's work, planned again from what the fleet state knows.

:func:`replan` reads the dispatcher's :class:`~dispatcher.daemon.state.FleetState` (which
vehicles are still there, where each is and which item of its mission it drives to, which
fields are done, how far each field in progress is) against the plan being carried out, and
asks the planner (:func:`planner.replan.replan_farm`) for the rest: fields not started and
the remaining segments of fields in progress, over the vehicles still alive, each from where
it is. It returns the next :class:`~dispatcher.mission.plan.DispatchPlan`, missions and
plan document included.

A vehicle on a segment of a field (a swath or a headland edge, implement down) finishes it
first: its position is taken at the segment's end and the time left to get there is its
ready time; the segment counts as done. A vehicle gone (lost, failed) is not in the new
plan; the segment it was on is not done (its rest is worked again by whoever takes the
field).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection

from dispatcher.config.errors import DispatcherError
from dispatcher.config.scenario import Scenario
from dispatcher.daemon.state import FleetState, Phase, VehicleState
from dispatcher.mission.build import Mission, Trace
from dispatcher.mission.document import PlannedItem
from dispatcher.mission.job import DispatchJob
from dispatcher.mission.plan import DispatchPlan, dispatch_plan
from planner.farm import Farm
from planner.field_plan import Visit
from planner.replan import FieldProgress, MachineState, replan_farm, visit_segments
from planner.solve import AnyOf, stop_after

GONE = (Phase.LOST, Phase.FAILED, Phase.WAITING)
"""Phases of a vehicle that gets no work in a re-plan."""

ON_SEGMENT = "swath_end"
"""Driving to a segment's end (implement down) is being on that segment."""


class ReplanError(DispatcherError):
    """Nothing to re-plan with: no vehicle left, or no work left."""


def replan(
    scenario: Scenario,
    current: DispatchPlan,
    state: FleetState,
    stop: AnyOf | None = None,
    gone: Collection[str] = (),
) -> DispatchPlan:
    """The next plan: the remaining work over the vehicles still alive (module doc).
    ``gone`` adds vehicles to leave out whatever their phase."""
    farm = scenario.farm
    visits = {v.field.id: v for m in current.plan.machines for v in m.visits}
    alive = [v for v in state.vehicles.values() if v.phase not in GONE and v.id not in set(gone)]
    if not alive:
        raise ReplanError("no vehicle left to take the remaining work")
    machines = {veh.id: veh.machine for veh in scenario.vehicles}
    states: list[MachineState] = []
    finishing: dict[str, int] = {}  # field -> segments done once its vehicle ends the one it is on
    for v in alive:
        position, ready_h, on = _where(v, farm, machines[v.id].work_speed_kmh)
        if on is not None:
            finishing[on[0]] = on[1] + 1
        states.append(MachineState(machines[v.id], position, ready_h))
    done = [f.id for f in state.fields.values() if f.status == "done"]
    in_progress = []
    for f in state.fields.values():
        if f.status != "working" or f.id not in visits:
            continue
        owner = state.vehicles[f.vehicle]
        segments = finishing.get(f.id, _segments_done(owner, f.id))
        # Kept with its vehicle only while that vehicle is in it; a field that vehicle was
        # given but has not reached yet may go to whoever is best placed.
        free = owner.current_field != f.id or owner.phase in GONE or owner.retired
        in_progress.append(
            FieldProgress(
                visits[f.id],
                f.vehicle,
                min(segments, len(visit_segments(visits[f.id]))),
                split_ok=free,
            )
        )
    solver = scenario.solver
    plan = replan_farm(
        farm,
        states,
        done=done,
        in_progress=in_progress,
        objective=current.plan.objective,
        algorithm=solver.algorithm,
        stop=stop,
        seed=solver.seed,
        previous=current.plan,
    )
    kept = {m.machine.id for m in plan.machines}
    vehicles = tuple(veh for veh in scenario.vehicles if veh.id in kept)
    return dispatch_plan(dataclasses.replace(scenario, vehicles=vehicles), plan)


def _segments_done(v: VehicleState, field_id: str) -> int:
    """Segments of ``field_id`` (as its current route's visit counts them) the vehicle
    finished: its last swath end reached on that route, plus one."""
    ends = [
        item.swath_index
        for item in v.items[v.route_from : v.reached + 1]
        if item.field_id == field_id and item.role == "swath_end" and item.swath_index is not None
    ]
    return max(ends) + 1 if ends else 0


def _where(
    v: VehicleState, farm: Farm, work_speed_kmh: float
) -> tuple[tuple[float, float], float, tuple[str, int] | None]:
    """Where a vehicle starts its new route (local metres), when (hours from now), and the
    (field, segment) it finishes first when it is on one."""
    lat = v.lat if v.lat is not None else v.items[0].lat
    lon = v.lon if v.lon is not None else v.items[0].lon
    here = farm.frame.to_local(lon, lat)
    heading = _heading_to(v)
    if heading is None or v.phase is Phase.DONE or v.retired:
        return (float(here[0]), float(here[1])), 0.0, None
    end = heading
    if end.field_id is None or end.swath_index is None:
        return (float(here[0]), float(here[1])), 0.0, None
    x, y = farm.frame.to_local(end.lon, end.lat)
    metres = math.hypot(float(x) - float(here[0]), float(y) - float(here[1]))
    # A segment of the route before the last re-plan was counted done by it already.
    on = (end.field_id, end.swath_index) if end.seq >= v.route_from else None
    return (float(x), float(y)), metres / (1000.0 * work_speed_kmh), on


def _heading_to(v: VehicleState) -> PlannedItem | None:
    """The segment item the vehicle drives to now, if it is on a segment."""
    seq = min(max(v.reached + 1, v.current, 1), len(v.items) - 1)
    item = v.items[seq]
    if item.role == ON_SEGMENT and item.field_id is not None and v.phase is Phase.RUNNING:
        return item
    return None


def visit_of(plan: DispatchPlan, field_id: str) -> Visit:
    """The visit of ``field_id`` in ``plan`` (KeyError when none)."""
    for m in plan.plan.machines:
        for v in m.visits:
            if v.field.id == field_id:
                return v
    raise KeyError(field_id)


def handover(current: DispatchJob, state: FleetState, nxt: DispatchPlan) -> DispatchJob:
    """The job that takes the fleet from ``current`` to the next plan without stopping it.

    A vehicle driving its mission keeps what it has done and what it is doing: its new
    mission is its old one up to the item it drives to (the end of the segment it is on, or
    the next item of its transit), then the implement raised (when it was on a segment),
    then its new route (without the new mission's home item). Uploaded while it drives, the
    items it is on are the same, so it carries on; once past them it drives the new route.
    A vehicle not driving (in the garage, done, not started) gets the new mission whole.
    The plan document says the same (items, roles, fields), with a new plan id."""
    machines = []
    missions: dict[str, Mission] = {}
    new_doc = nxt.document
    for planned in new_doc.machines:
        v = state.vehicles[planned.id]
        new_mission = nxt.missions[planned.id]
        cut = _cut(v) if planned.id in current.missions else None
        if cut is None:
            machines.append(planned)
            missions[planned.id] = new_mission
            continue
        old = current.missions[planned.id]
        items = list(old.items[: cut + 1])
        traces = list(old.traces[: cut + 1])
        items_doc = list(v.items[: cut + 1])
        if v.items[cut].role == ON_SEGMENT:  # the implement up before going on
            raise_at = next(
                k
                for k in range(cut + 1, len(old.items))
                if old.traces[k].role in ("implement_raise", "implement_up")
            )
            raise_item = v.items[raise_at]
            items.append(old.items[raise_at])
            traces.append(Trace(raise_item.field_id, raise_item.swath_index, "implement_raise"))
            items_doc.append(dataclasses.replace(raise_item, role="implement_raise"))
        for item, trace, planned_item in zip(
            new_mission.items[1:], new_mission.traces[1:], planned.items[1:], strict=True
        ):
            items.append(item)
            traces.append(trace)
            items_doc.append(planned_item)
        items = [dataclasses.replace(it, seq=k) for k, it in enumerate(items)]
        items_doc = [dataclasses.replace(it, seq=k) for k, it in enumerate(items_doc)]
        missions[planned.id] = Mission(planned.id, tuple(items), tuple(traces))
        done_here = [f for f in v.fields_done if f not in planned.fields]
        machines.append(
            dataclasses.replace(
                planned, items=tuple(items_doc), fields=tuple(done_here) + planned.fields
            )
        )
    document = dataclasses.replace(new_doc, machines=tuple(machines), plan_id="").with_id()
    return DispatchJob(document, missions, dict(nxt.job().geojson))


def _cut(v: VehicleState) -> int | None:
    """Where a driving vehicle's old mission ends in its new one: the item it drives to
    when that ends the segment it is on, else the last item it reached. None: it is not
    driving a mission (it gets the new one whole)."""
    if v.phase is not Phase.RUNNING or v.reached == 0 or v.retired:
        return None
    heading = _heading_to(v)
    return heading.seq if heading is not None else v.reached


def replanner_for(
    scenario: Scenario, dispatch: DispatchPlan, seconds: float = 1.5
) -> Callable[[FleetState], DispatchJob]:
    """What the daemon calls to plan the rest of the work (``DaemonConfig.replanner``):
    each call plans from the state it is given against the plan carried out so far, and
    returns the job to carry on with; the solver stops after ``seconds``."""
    current, job = dispatch, dispatch.job()

    def plan_rest(state: FleetState) -> DispatchJob:
        nonlocal current, job
        nxt = replan(
            scenario, current, state, stop=stop_after(scenario.solver.generations, seconds)
        )
        job = handover(job, state, nxt)
        current = nxt
        return job

    return plan_rest
