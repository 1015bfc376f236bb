"""The rest of the day's work, planned again from what the fleet state knows.

:func:`replan` reads the dispatcher's :class:`~dispatcher.daemon.state.FleetState` (which
vehicles are still there, where each is and which item of its mission it drives to, which
fields are done, how far each field in progress is) against the plan being carried out, and
asks the planner (:func:`planner.replan.replan_farm`) for the rest: fields not started and
the remaining segments of fields in progress, over the vehicles still alive, each from where
it is. It returns the next :class:`~dispatcher.mission.plan.DispatchPlan`, missions and
plan document included.

A driving vehicle keeps its old mission for a while: up to the first item, from the one it
drives to, where a route may end (a segment's end or start, a road point, the garage) and
that it reaches no sooner than ``lead_s`` wall seconds from now at its pace (its clock's
speedup times the planned item times): a re-plan, upload and read-back fit in that, so the
vehicle does not go past the point where its new route begins. One that holds a window of
a longer mission (dispatcher/mission/window.py) keeps at least the whole window: its new
route begins after it, and nothing is uploaded to it before its next top-up. Its position is taken
there, the time to get there is its ready time, and the segments it works on the way count
as done. A vehicle gone (lost, failed) is not in the new plan; the segment it was on is not
done (its rest is worked again by whoever takes the field).
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from typing import TypeVar

from dispatcher.config.errors import DispatcherError
from dispatcher.config.scenario import Scenario
from dispatcher.daemon.server import NoWorkLeft
from dispatcher.daemon.state import GONE, FleetState, Phase, VehicleState
from dispatcher.link.mission_item import MissionItem
from dispatcher.mission.build import (
    IMPLEMENT_RAISED,
    Mission,
    Role,
    Trace,
    implement_down_after,
)
from dispatcher.mission.document import PlanDocument, PlannedItem
from dispatcher.mission.job import DispatchJob
from dispatcher.mission.plan import DispatchPlan, dispatch_plan
from dispatcher.mission.window import ROUTE_ENDS
from planner.errors import NothingLeftError
from planner.farm import Farm
from planner.field_plan import Visit, cover_farm
from planner.replan import FieldProgress, MachineState, replan_farm, visit_segments
from planner.solve import AnyOf, stop_after

ON_SEGMENT = "swath_end"
"""Driving to a segment's end (implement down) is being on that segment."""

LEAD_S = 4.0
"""Wall seconds from the fleet state a re-plan reads to the new missions on board, besides
the solver's time: a driving vehicle keeps at least this much of its old mission (module
doc)."""

REPLAN_SOLVER_S = 0.5
"""Wall seconds the solver has in a re-plan. It starts from the plan being carried out (the
lost vehicles' tasks put where they cost least, planner.solve), so it needs far less than
a first plan: on the 30-tractor, 200-field re-plan bench, 0.1 s found the makespan that
1-2 s found, 0.25-0.5 s the road length within 1 % (benchmarks/RESULTS.md)."""

FIRST_REPLAN_S = 2.5
"""What a re-plan is taken to take until one has been timed (the first re-plan of a run):
coverage of the rest, transit from where the vehicles are, the solver, the missions."""


_Seq = TypeVar("_Seq", MissionItem, PlannedItem)


class ReplanError(DispatcherError):
    """Nothing to re-plan with: no vehicle left, or no work left."""


class ReplanCancelled(ReplanError):
    """The re-plan was given up before its end (another vehicle lost meanwhile)."""


def replan(
    scenario: Scenario,
    current: DispatchPlan | None,
    state: FleetState,
    stop: AnyOf | None = None,
    gone: Collection[str] = (),
    lead_s: float = LEAD_S,
    base: Mapping[str, Visit] | None = None,
    cancel: threading.Event | None = None,
    finish_within_h: float = 0.0,
) -> DispatchPlan:
    """The next plan: the remaining work over the vehicles still alive (module doc).
    ``finish_within_h`` > 0: what is left of the run's deadline (:func:`deadline_left_h`),
    in hours from now, which the rest is planned within if it can be, the road distance
    deciding there; 0: as early as it can.
    ``gone`` adds vehicles to leave out whatever their phase; ``lead_s`` as in the module
    doc (:func:`handover` must be given the same); ``base`` (:func:`base_visits`): each
    field's visit in the layout whose segments ``PlannedItem.segment`` numbers (default:
    ``current``'s visits, right for the first re-plan). Without ``current`` (a run resumed
    after a restart, whose planner's view is not kept) there is no warm start, and
    ``base`` is needed. When ``cancel`` is set (it should stop ``stop`` too),
    :class:`ReplanCancelled` is raised before the missions are built."""
    farm = scenario.farm
    visits = {v.field.id: v for m in current.plan.machines for v in m.visits} if current else {}
    alive = [v for v in state.vehicles.values() if v.phase not in GONE and v.id not in set(gone)]
    if not alive:
        raise ReplanError("no vehicle left to take the remaining work")
    machines = {veh.id: veh.machine for veh in scenario.vehicles}
    states: list[MachineState] = []
    upto: dict[str, int] = {}  # vehicle -> the last item of its old mission it drives
    for v in alive:
        cut = _cut(v, lead_s)
        upto[v.id] = cut if cut is not None else v.reached
        position, ready_h = _where(v, farm, machines[v.id].work_speed_kmh, cut)
        work_h, turns = _kept_work(v, cut)
        states.append(
            MachineState(
                machines[v.id],
                position,
                ready_h,
                ready_work_h=min(work_h, ready_h),
                ready_turns=turns,
            )
        )
    done = [f.id for f in state.fields.values() if f.status == "done"]
    # Segments (numbered as in each field's first layout) that alive vehicles work before
    # their new routes begin; with those worked already, the rest of each field is known.
    claimed: dict[str, set[int]] = {}
    cut_in: dict[str, str] = {}  # field -> the alive vehicle whose new route begins in it
    for v in alive:
        for item in v.items[v.reached + 1 : upto[v.id] + 1]:
            if item.role == ON_SEGMENT and item.field_id and item.segment is not None:
                claimed.setdefault(item.field_id, set()).add(item.segment)
        if upto[v.id] > v.reached and v.items[upto[v.id]].field_id is not None:
            cut_in[str(v.items[upto[v.id]].field_id)] = v.id
    in_progress = []
    for f in state.fields.values():
        first = (base or visits).get(f.id)
        if f.status == "done" or first is None:
            continue
        taken = set(f.passes) | claimed.get(f.id, set())
        if not taken:
            continue  # not started: planned whole
        total = len(visit_segments(first))
        left = tuple(k for k in range(total) if k not in taken)
        worker = cut_in.get(f.id)
        in_progress.append(
            FieldProgress(
                first,
                worker or f.vehicle,
                # Kept with the vehicle whose route begins in it; otherwise the rest may go
                # to whoever is best placed.
                split_ok=worker is None,
                left=left,
            )
        )
    solver = scenario.solver
    try:
        plan = replan_farm(
            farm,
            states,
            done=done,
            in_progress=in_progress,
            objective=current.plan.objective if current else scenario.solver.objective,
            algorithm=solver.algorithm,
            stop=stop,
            seed=solver.seed,
            previous=current.plan if current else None,
            makespan_slack=solver.makespan_slack,
            finish_within_h=finish_within_h,
        )
    except NothingLeftError as exc:
        raise NoWorkLeft(str(exc)) from exc
    if cancel is not None and cancel.is_set():
        raise ReplanCancelled("given up")
    kept = {m.machine.id for m in plan.machines}
    vehicles = tuple(veh for veh in scenario.vehicles if veh.id in kept)
    return dispatch_plan(dataclasses.replace(scenario, vehicles=vehicles), plan)


def _where(
    v: VehicleState, farm: Farm, work_speed_kmh: float, cut: int | None
) -> tuple[tuple[float, float], float]:
    """Where a vehicle starts its new route (local metres) and when (hours from now): at
    item ``cut`` of its old mission when it drives on to there, else where it is. Rebooted
    and not yet placed again (``v.where`` None), where it was heard last: a tractor whose
    autopilot restarts stands where it stood (a simulator starts again in its garage; its
    route then begins with a longer drive than planned, and the daemon waits for its fix
    before it starts it)."""
    lat = v.lat if v.lat is not None else v.items[0].lat
    lon = v.lon if v.lon is not None else v.items[0].lon
    x0, y0 = (float(c) for c in farm.frame.to_local(lon, lat))
    if cut is None:
        return (x0, y0), 0.0
    heading = _heading(v)
    # The first item from there with a position: a speed change or an implement command has
    # none (0, 0), which is no place on the farm (its local coordinates can be infinite).
    towards = next((k for k in range(heading, cut + 1) if v.items[k].x or v.items[k].y), cut)
    end = v.items[cut]
    hx, hy = (float(c) for c in farm.frame.to_local(v.items[towards].lon, v.items[towards].lat))
    x, y = (float(c) for c in farm.frame.to_local(end.lon, end.lat))
    seconds = math.hypot(hx - x0, hy - y0) / (work_speed_kmh / 3.6)
    if v.planned_s and len(v.planned_s) == len(v.items):
        seconds += max(v.planned_s[cut] - v.planned_s[heading], 0.0)
    elif cut != heading:
        seconds += math.hypot(x - hx, y - hy) / (work_speed_kmh / 3.6)
    return (x, y), seconds / 3600.0


def _kept_work(v: VehicleState, cut: int | None) -> tuple[float, int]:
    """Of the part of its old mission a vehicle drives on before its new route (to item
    ``cut``): the planned hours on a segment (the legs that end at one's end) and the turns
    (the implement raised between two swaths), from its items' planned times (none known:
    0 and the turns)."""
    if cut is None:
        return 0.0, 0
    kept = range(_heading(v), cut + 1)
    turns = sum(1 for k in kept if v.items[k].role == "implement_raise")
    if not v.planned_s or len(v.planned_s) != len(v.items):
        return 0.0, turns
    work_s = sum(
        max(v.planned_s[k] - v.planned_s[k - 1], 0.0)
        for k in kept
        if k > 0 and v.items[k].role == ON_SEGMENT
    )
    return work_s / 3600.0, turns


def _heading(v: VehicleState) -> int:
    """The item the vehicle drives to now."""
    return min(max(v.reached + 1, v.current, 1), len(v.items) - 1)


def visit_of(plan: DispatchPlan, field_id: str) -> Visit:
    """The visit of ``field_id`` in ``plan`` (KeyError when none)."""
    for m in plan.plan.machines:
        for v in m.visits:
            if v.field.id == field_id:
                return v
    raise KeyError(field_id)


def handover(
    current: DispatchJob, state: FleetState, nxt: DispatchPlan, lead_s: float = LEAD_S
) -> DispatchJob:
    """The job that takes the fleet from ``current`` to the next plan without stopping it.

    A vehicle driving its mission keeps what it has done and what it is doing: its new
    mission is its old one up to where its new route begins (module doc), then the
    implement raised (when it is down there), then its new route (without the new
    mission's home item). Uploaded while it drives, the items it is on are the same, so it
    carries on; once past them it drives the new route. When its new route works the same
    segments of the same fields in the same order as the rest of its old mission, it keeps
    its old mission as it is (nothing to upload). A vehicle not driving (in the garage,
    done, not started) gets the new mission whole. The plan document says the same (items,
    roles, fields), with a new plan id."""
    machines = []
    missions: dict[str, Mission] = {}
    new_doc = nxt.document
    still_to_do = {fid for m in new_doc.machines for fid in m.fields}
    for planned in new_doc.machines:
        v = state.vehicles[planned.id]
        new_mission = nxt.missions[planned.id]
        cut = _cut(v, lead_s) if planned.id in current.missions else None
        if (
            cut is None
            and v.phase is Phase.DONE
            and not planned.fields
            and planned.id in current.missions
        ):
            # Finished, parked, and nothing more for it: its mission stays (a "route" from
            # the garage to the garage, uploaded and started, completed at once: no report
            # of it active, no progress, and it was taken for stalled; 20 %-loss soak).
            machines.append(dataclasses.replace(planned, items=v.items, fields=_fields(v.items)))
            missions[planned.id] = current.missions[planned.id]
            continue
        if cut is None:
            machines.append(planned)
            missions[planned.id] = new_mission
            continue
        old = current.missions[planned.id]
        if _work(v.items[cut + 1 :]) == _work(planned.items[1:]):
            machines.append(dataclasses.replace(planned, items=v.items, fields=_fields(v.items)))
            missions[planned.id] = old
            continue
        items = list(old.items[: cut + 1])
        traces = list(old.traces[: cut + 1])
        items_doc = list(v.items[: cut + 1])
        if implement_down_after(old.traces[: cut + 1]):  # the implement up before going on
            raise_at = next(
                k for k in range(cut + 1, len(old.items)) if old.traces[k].role in IMPLEMENT_RAISED
            )
            raise_item = v.items[raise_at]
            # The field's last work when no route goes back to it: it is done there.
            role: Role = (
                "implement_up" if raise_item.field_id not in still_to_do else "implement_raise"
            )
            items.append(old.items[raise_at])
            traces.append(Trace(raise_item.field_id, raise_item.swath_index, role))
            items_doc.append(dataclasses.replace(raise_item, role=role))
        for item, trace, planned_item in zip(
            new_mission.items[1:], new_mission.traces[1:], planned.items[1:], strict=True
        ):
            items.append(item)
            traces.append(trace)
            items_doc.append(planned_item)
        items = _numbered(items)
        items_doc = _numbered(items_doc)
        missions[planned.id] = Mission(planned.id, tuple(items), tuple(traces))
        done_here = [f for f in v.fields_done if f not in planned.fields]
        machines.append(
            dataclasses.replace(
                planned, items=tuple(items_doc), fields=tuple(done_here) + planned.fields
            )
        )
    document = dataclasses.replace(new_doc, machines=tuple(machines), plan_id="")  # new id
    return DispatchJob(document, missions, dict(nxt.job().geojson))


def _numbered(items: Sequence[_Seq]) -> list[_Seq]:
    """``items`` with ``seq`` their index (the kept part has it already: only the new
    route's items are copied, a few hundred where a whole day's mission has thousands)."""
    return [it if it.seq == k else dataclasses.replace(it, seq=k) for k, it in enumerate(items)]


def _cut(v: VehicleState, lead_s: float) -> int | None:
    """Where a driving vehicle's old mission ends in its new one (module doc): the first
    item from the one it drives to where a route may end and that it reaches no sooner than
    ``lead_s`` wall seconds from now; the mission's last item when none is that far. None:
    it is not driving a mission (it gets the new one whole)."""
    if v.phase is not Phase.RUNNING or v.reached == 0 or v.retired:
        return None
    heading = _heading(v)
    # A window of a longer mission on board is driven whole (mission/window.py): the new
    # route begins after it, and what the vehicle holds is not uploaded again.
    first = max(heading, v.held - 1) if v.held < len(v.items) else heading
    planned = v.planned_s if len(v.planned_s) == len(v.items) else None
    ahead = lead_s * v.clock.rate  # in the vehicle's seconds
    for k in range(first, len(v.items)):
        if v.items[k].role not in ROUTE_ENDS:
            continue
        if planned is None or planned[k] - planned[v.reached] >= ahead:
            return k
    return len(v.items) - 1


def _work(items: Sequence[PlannedItem]) -> list[tuple[str | None, int | None]]:
    """The segments these items work, in order, as (field, segment)."""
    return [(item.field_id, item.segment) for item in items if item.role == ON_SEGMENT]


def _fields(items: Sequence[PlannedItem]) -> tuple[str, ...]:
    """The fields these items work, in order."""
    return tuple(dict.fromkeys(str(i.field_id) for i in items if i.role == ON_SEGMENT))


def replanner_for(
    scenario: Scenario,
    dispatch: DispatchPlan,
    seconds: float = REPLAN_SOLVER_S,
    *,
    started: float,
) -> Callable[[FleetState, threading.Event], DispatchJob]:
    """What the daemon calls to plan the rest of the work (``DaemonConfig.replanner``):
    each call plans from the state it is given against the plan carried out so far, and
    returns the job to carry on with, or raises :class:`ReplanCancelled` soon after its
    second argument is set (nothing of it kept); the solver stops after ``seconds``, and driving
    vehicles keep a lead of their old missions: ``LEAD_S``, plus ``seconds`` or twice what
    the last re-plan took when that is more (a big farm on a busy gateway), plus one and a
    half times what getting missions on board took last (``FleetState.upload_s``).
    ``started``: when the run began (:func:`time.time`, as its store keeps it), from which
    the scenario's ``[solver] finish_within_h`` counts (:func:`run_hours`)."""
    base = {v.field.id: v for m in dispatch.plan.machines for v in m.visits}
    return _replanner(scenario, dispatch, dispatch.job(), base, seconds, started)


def replanner_resumed(
    scenario: Scenario,
    job: DispatchJob,
    started: float,
    documents: Sequence[PlanDocument],
    seconds: float = REPLAN_SOLVER_S,
) -> Callable[[FleetState, threading.Event], DispatchJob]:
    """:func:`replanner_for` of a run resumed from the store: ``job`` as stored (the last
    plan's document, the missions as last uploaded), ``started`` when the run began and
    ``documents`` its plans' documents in order (as stored: the first, then each re-plan's).
    The layouts the fields' segments are numbered in are laid out again from them
    (:func:`base_visits`; coverage is deterministic, each visit's corner is recorded), at
    the first re-plan: from the first plan alone, a field a re-plan had laid out anew for a
    machine of another width was counted in the wrong layout (a review: the rest of a field
    dropped, another worked twice)."""
    return _replanner(scenario, None, job, None, seconds, started, tuple(documents))


def run_hours(state: FleetState, started: float, now: float) -> float:
    """Hours of the run from ``started`` to ``now`` (wall, :func:`time.time`) on the
    vehicles' clocks: the wall time times the fastest measured speedup of a vehicle's clock
    (:attr:`~dispatcher.daemon.state.RunClock.rate`; 1 for real vehicles, and until one is
    measured)."""
    rates = [v.clock.rate for v in state.vehicles.values() if v.clock.rate_known]
    return max(now - started, 0.0) * max(rates, default=1.0) / 3600.0


def deadline_left_h(finish_within_h: float, elapsed_h: float) -> float:
    """What is left, in hours from now, of a deadline ``finish_within_h`` hours after the
    run began, ``elapsed_h`` into it; 0 (none) when there is no deadline or it has passed:
    the rest is then finished as early as it can be."""
    left = finish_within_h - elapsed_h
    return left if finish_within_h > 0.0 and left > 0.0 else 0.0


def base_visits(scenario: Scenario, *documents: PlanDocument) -> dict[str, Visit]:
    """Each field's visit in the layout its segments are numbered in, from a run's plan
    ``documents`` in order (its first plan, then its re-plans): the first plan's, or that of
    the last re-plan that laid the field out whole again (not the rest of it: ``rest``), as
    the re-planner keeps them while it runs (:func:`_replanner`)."""
    machines = {veh.id: veh.machine for veh in scenario.vehicles}
    used = {m.id for doc in documents for m in doc.machines if m.id in machines}
    coverage = cover_farm(scenario.farm, [machines[vid] for vid in sorted(used)])
    out = {}
    for k, document in enumerate(documents):
        for m in document.machines:
            for pv in m.visits:
                if k == 0 or not pv.rest:
                    field = scenario.farm.field(pv.field)
                    out[pv.field] = Visit(field, coverage[(m.id, pv.field)], pv.corner)
    return out


def _replanner(
    scenario: Scenario,
    dispatch: DispatchPlan | None,
    job: DispatchJob,
    base: dict[str, Visit] | None,
    seconds: float,
    started: float,
    documents: tuple[PlanDocument, ...] = (),
) -> Callable[[FleetState, threading.Event], DispatchJob]:
    current = dispatch
    took_s = (
        FIRST_REPLAN_S  # how long the last re-plan took (wall); the next lead allows twice that
    )

    def plan_rest(state: FleetState, cancel: threading.Event) -> DispatchJob:
        nonlocal current, job, base, took_s
        began = time.monotonic()
        if base is None:
            base = base_visits(scenario, *(documents or (job.document,)))
        lead_s = max(seconds, 2.0 * took_s) + 1.5 * state.upload_s + LEAD_S
        stop = stop_after(scenario.solver.generations, seconds, flag=cancel)
        left_h = deadline_left_h(
            scenario.solver.finish_within_h, run_hours(state, started, time.time())
        )
        nxt = replan(
            scenario, current, state, stop=stop, lead_s=lead_s, base=base, cancel=cancel,
            finish_within_h=left_h,
        )  # fmt: skip
        for m in nxt.plan.machines:  # a field planned whole again is numbered anew
            base.update({v.field.id: v for v in m.visits if not v.original_segments})
        job = handover(job, state, nxt, lead_s)
        current = nxt
        took_s = time.monotonic() - began
        return job

    return plan_rest
