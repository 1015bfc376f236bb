"""Re-planning the rest of a day: machines where they are, fields done and half done."""

import itertools
import logging
import math

import pytest
from shapely.geometry import Polygon

from planner.coverage import rectangle_field
from planner.errors import ProblemError
from planner.farm import Farm, Field
from planner.field_plan import Visit, cover_farm, plan_farm
from planner.geo import LocalFrame
from planner.problem import Machine
from planner.replan import (
    FieldProgress,
    MachineState,
    remaining_coverage,
    replan_farm,
    visit_segments,
)
from planner.solve import stop_after

WIDE = Machine("a", 6.0, 5000.0, 10.0, 0.003, 2.5, 5.0, work_speed_kmh=8.0, min_turn_radius_m=4.5)
WIDE2 = Machine("b", 6.0, 4500.0, 10.0, 0.003, 2.5, 5.0, work_speed_kmh=8.0, min_turn_radius_m=4.5)
NARROW = Machine("c", 3.7, 4000.0, 10.0, 0.002, 2.0, 4.0)


def row_farm(k: int = 5) -> Farm:
    frame = LocalFrame.around(87.3, 44.0)
    fields = tuple(
        Field(
            f"f{i}",
            f"f{i}",
            rectangle_field(60.0, 90.0, 0.0, (130.0 * i, 0.0)),
            rectangle_field(60.0, 90.0, 0.0, (130.0 * i, 0.0)),
        )
        for i in range(k)
    )
    return Farm(fields=fields, garage=(-60.0, 20.0), garage_lonlat=(87.3, 44.0), frame=frame)


def undirected(segment):
    a, b = segment
    return (tuple(round(c, 6) for c in a), tuple(round(c, 6) for c in b))


def same_segment(new, old):
    return undirected(new) in (undirected(old), undirected(old[::-1]))


@pytest.mark.parametrize("machine", [WIDE, NARROW])
def test_the_rest_of_a_visit_is_exactly_the_segments_not_done(machine):
    farm = row_farm(1)
    cov = cover_farm(farm, [machine])[(machine.id, "f0")]
    for corner in range(4):
        visit = Visit(farm.fields[0], cov, corner)
        old = visit_segments(visit)
        for done in range(len(old)):
            rest, share, orders = remaining_coverage(visit, done)
            assert 0.0 < share <= 1.0
            for c in range(4):
                new = visit_segments(Visit(farm.fields[0], rest, c))
                assert sorted(orders[c]) == list(range(done, len(old)))  # none twice, none skipped
                assert all(same_segment(s, old[k]) for s, k in zip(new, orders[c], strict=True))
                # Consecutive segments and the moves between them as a mission lays them out.
                assert len(rest.link(c)) == len(new) - 1
                if machine.min_turn_radius_m > 0:
                    assert len(rest.turn(c)) == len(new) - 1
                else:
                    assert rest.turn(c) == ()
            forward = visit_segments(Visit(farm.fields[0], rest, 0))
            assert forward == old[done:]
        with pytest.raises(ProblemError, match="segments done"):
            remaining_coverage(visit, len(old))


def previous_plan():
    farm = row_farm()
    plan = plan_farm(farm, [WIDE, WIDE2, NARROW], "makespan", "ighoa", stop_after(40), seed=2)
    return farm, plan


def half_done(plan, machine_id):
    route = next(m for m in plan.machines if m.machine.id == machine_id)
    visit = route.visits[0]
    segments = visit_segments(visit)
    done = len(segments) // 2
    return visit, done, segments[done - 1][1]  # the machine stands where it stopped


@pytest.mark.parametrize("objective", ["makespan", "distance", "time", "fuel"])
def test_replan_with_a_machine_gone_and_a_field_half_done(objective):
    farm, plan = previous_plan()
    visit, done, where = half_done(plan, "a")
    gone = next(m for m in plan.machines if m.machine.id == "b")
    finished = [gone.visits[0].field.id] if gone.visits else []
    states = [MachineState(WIDE, where, ready_h=0.1), MachineState(NARROW, (-60.0, 20.0))]
    progress = [FieldProgress(visit, "a", done, split_ok=False)]
    new = replan_farm(
        farm, states, finished, progress, objective, "ighoa", stop_after(30), 3, previous=plan
    )
    ids = sorted(fid for m in new.machines for fid in m.field_ids)
    assert ids == sorted(f.id for f in farm.fields if f.id not in finished)
    a = new.machines[0]
    assert a.machine.id == "a" and a.field_ids[0] == visit.field.id  # pinned, first
    rest = a.visits[0]
    old = visit_segments(visit)
    new_segments = visit_segments(rest)
    assert sorted(rest.original_segments) == list(range(done, len(old)))
    assert all(
        same_segment(s, old[k]) for s, k in zip(new_segments, rest.original_segments, strict=True)
    )
    assert rest.original_segments[0] == done and rest.entry == old[done][0]  # goes on
    assert 0.0 < rest.work_share < 1.0
    assert a.ready_h == 0.1 and a.time_h > a.work_h + 0.1
    assert a.work_h == pytest.approx(
        sum(v.field.area_m2 * v.work_share for v in a.visits) / WIDE.capacity_m2h
    )
    assert new.solver.problem.ready_h.tolist() == [0.1, 0.0]
    if new.objective.name == "MAKESPAN":
        assert new.makespan_h == max(m.time_h for m in new.machines)


def test_a_field_that_may_be_split_goes_to_a_machine_that_can_drive_its_swaths():
    farm, plan = previous_plan()
    visit, done, where = half_done(plan, "a")
    # a broke down in the field; b (same width and radius) is near; c is narrower.
    states = [MachineState(WIDE2, where), MachineState(NARROW, (-60.0, 20.0))]
    progress = [FieldProgress(visit, "a", done, split_ok=True)]
    new = replan_farm(farm, states, (), progress, "distance", "ga", stop_after(30), 1)
    holder = next(m for m in new.machines if visit.field.id in m.field_ids)
    rest = next(v for v in holder.visits if v.field.id == visit.field.id)
    if holder.machine.id == "b":
        assert sorted(rest.original_segments) == list(range(done, len(visit_segments(visit))))
    else:  # the narrow machine works the field whole with its own swaths
        assert rest.original_segments == () and rest.work_share == 1.0


def test_a_field_no_alive_machine_can_finish_is_planned_whole(caplog):
    farm, plan = previous_plan()
    visit, done, _ = half_done(plan, "a")
    progress = [FieldProgress(visit, "a", done)]
    with caplog.at_level(logging.WARNING, logger="planner.replan"):
        new = replan_farm(
            farm, [MachineState(NARROW, (0.0, 0.0))], (), progress, stop=stop_after(5)
        )
    assert "planned whole again" in caplog.text
    assert len(new.machines[0].visits) == 5
    assert all(v.work_share == 1.0 for v in new.machines[0].visits)


def test_bad_progress_is_named():
    farm, plan = previous_plan()
    visit, done, where = half_done(plan, "a")
    states = [MachineState(WIDE, where)]
    with pytest.raises(ProblemError, match="given as done or in progress twice"):
        replan_farm(farm, states, [visit.field.id], [FieldProgress(visit, "a", done)])
    with pytest.raises(ProblemError, match="every field is done"):
        replan_farm(farm, states, [f.id for f in farm.fields])


@pytest.mark.parametrize("corner", range(4))
def test_the_rest_may_be_any_segments_left_with_moves_across_the_gaps(corner: int) -> None:
    """Segments left out of the visit's order (a vehicle died before the part a re-plan
    counted on it): exactly those, each once, and no planned turn across a gap."""
    machine = WIDE
    farm = row_farm(1)
    cov = cover_farm(farm, [machine])[(machine.id, "f0")]
    visit = Visit(farm.fields[0], cov, corner)
    old = visit_segments(visit)
    left = [1, 2, 3, 7, 8, len(old) - 1]
    rest, share, orders = remaining_coverage(visit, left)
    work = [math.dist(a, b) for a, b in old]
    assert share == pytest.approx(sum(work[k] for k in left) / sum(work))
    for c in range(4):
        new = visit_segments(Visit(farm.fields[0], rest, c))
        assert sorted(orders[c]) == left
        assert all(same_segment(s, old[k]) for s, k in zip(new, orders[c], strict=True))
        gaps = [k for k, (a, b) in enumerate(itertools.pairwise(orders[c])) if abs(a - b) != 1]
        assert gaps and all(rest.turn(c)[k] == () for k in gaps)
    with pytest.raises(ProblemError, match="segments left"):
        remaining_coverage(visit, [])


def test_a_field_only_a_machine_gone_could_work_stays_undone_and_the_rest_is_planned(caplog):
    """A mixed fleet: the narrow machine, the only one that fits the strip, broke down;
    the strip stays undone (a warning says why) and the rest goes to the others, where the
    re-plan failed whole."""
    farm = row_farm(3)
    strip = rectangle_field(5.0, 200.0, 0.0, (0.0, 150.0))
    farm = Farm(
        fields=(*farm.fields, Field("strip", "strip", strip, strip)),
        garage=farm.garage,
        garage_lonlat=farm.garage_lonlat,
        frame=farm.frame,
    )
    plan = plan_farm(farm, [WIDE, NARROW], "makespan", "ighoa", stop_after(20), seed=1)
    assert "strip" in next(m for m in plan.machines if m.machine.id == "c").field_ids
    with caplog.at_level(logging.WARNING, logger="planner.replan"):
        new = replan_farm(
            farm, [MachineState(WIDE, (0.0, 0.0))], (), (), stop=stop_after(5), previous=plan
        )
    assert "field strip: no machine left can work it" in caplog.text
    assert "stays undone" in caplog.text
    assert new.machines[0].field_ids and "strip" not in new.machines[0].field_ids
    assert sorted(new.machines[0].field_ids) == ["f0", "f1", "f2"]


def test_what_a_coverage_leaves_unworked_is_said_when_a_replan_hands_it_over(caplog):
    """The wedge's apex, which the narrow machine works, is left unworked by the wide one:
    said when the re-plan gives the wedge to the wide machine, not again for a machine
    that keeps its field."""
    frame = LocalFrame.around(87.3, 44.0)
    apex = Polygon([(0, 0), (400, 0), (400, 400 * math.tan(math.radians(10.0)))])
    square = rectangle_field(60.0, 90.0, 0.0, (0.0, 150.0))
    farm = Farm(
        fields=(Field("wedge", "wedge", apex, Polygon()), Field("sq", "sq", square, square)),
        garage=(-60.0, 20.0),
        garage_lonlat=(87.3, 44.0),
        frame=frame,
    )
    wide = Machine("wide", 6.9, 400.0, 5.0, 0.002, 1.0, 2.0, min_turn_radius_m=6.0)
    narrow = Machine("narrow", 1.5, 9000.0, 10.0, 0.002, 1.0, 2.0, work_speed_kmh=8.0)
    with caplog.at_level(logging.WARNING):
        plan = plan_farm(farm, [narrow, wide], "makespan", "hybrid", stop_after(10), seed=1)
    assert "wedge" in plan.machines[0].field_ids and "unworked" not in caplog.text
    with caplog.at_level(logging.WARNING):
        replan_farm(
            farm,
            [MachineState(narrow, (0.0, 0.0)), MachineState(wide, (0.0, 0.0))],
            stop=stop_after(10),
            previous=plan,
        )
    assert "unworked" not in caplog.text  # the same machine keeps it
    with caplog.at_level(logging.WARNING):
        replan_farm(farm, [MachineState(wide, (0.0, 0.0))], stop=stop_after(10), previous=plan)
    assert "field 'wedge': " in caplog.text and "(machine 'wide')" in caplog.text
    assert "left unworked at a working width of 6.9 m" in caplog.text


def test_a_machine_given_nothing_new_still_counts_its_hours_and_its_drive_home():
    """A machine busy for hours with what it is doing (the rest of its old mission up to
    where its new route would begin) and given no field by the re-plan still finishes
    then, after its drive home: its figures and the plan's makespan say so (they said 0 h)."""
    farm, plan = previous_plan()
    busy = MachineState(WIDE, (130.0 * 4, 150.0), ready_h=50.0)  # far beyond the rest's hours
    new = replan_farm(
        farm,
        [busy, MachineState(NARROW, farm.garage)],
        [],
        [],
        "makespan",
        "hybrid",
        stop_after(20),
        3,
        previous=plan,
    )
    a = new.machines[0]
    assert a.machine.id == "a" and a.visits == ()
    home_h = math.hypot(130.0 * 4 - farm.garage[0], 150.0 - farm.garage[1]) / (
        1000.0 * WIDE.road_speed_kmh
    )
    assert a.time_h >= 50.0 + home_h - 1e-9 and a.road_m > 0.0
    assert new.makespan_h == a.time_h
    # Home around the fields, not across them (its mission, when it gets this one, drives it).
    assert new.network is not None and a.return_path
