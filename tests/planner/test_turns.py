"""Turn paths between antiparallel swaths: radius, tangency, length, reach."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.errors import GeometryError
from planner.turns import (
    ARC_STEP_DEG,
    ARC_STEP_M,
    dubins_paths,
    plan_turn,
    turn_excursion_m,
    turn_kind,
    turn_length_m,
)

# A chord of one arc step over that step of arc (sinc): the shortest a sampled arc gets.
CHORD_RATIO = math.sin(math.radians(ARC_STEP_DEG) / 2) / (math.radians(ARC_STEP_DEG) / 2)


def circumradius(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """Radius of the circle through three points (inf when they are in line)."""
    ab, bc, ca = np.linalg.norm(b - a), np.linalg.norm(c - b), np.linalg.norm(a - c)
    cross = abs((b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0])
    return math.inf if cross < 1e-12 else ab * bc * ca / (2.0 * cross)


def full_path(end, heading, start, radius):
    """The swath's start, its end, the turn's points, the next swath's start and end."""
    turn = plan_turn(end, heading, start, radius)
    d = np.asarray(heading) / np.linalg.norm(heading)
    pts = [np.asarray(end) - 10 * d, np.asarray(end)]
    pts += [np.asarray(p) for p in turn.points]
    pts += [np.asarray(start), np.asarray(start) - 10 * d]
    return turn, pts


def test_u_turn_is_a_half_circle_when_the_spacing_is_twice_the_radius() -> None:
    turn = plan_turn((0.0, 0.0), (1.0, 0.0), (0.0, 10.0), 5.0)
    assert turn.kind == "u"
    assert turn.length_m == pytest.approx(5.0 * math.pi)
    assert turn.excursion_m == pytest.approx(5.0)
    pts = np.array(turn.points)
    assert np.allclose(np.hypot(pts[:, 0], pts[:, 1] - 5.0), 5.0)
    assert pts[:, 0].max() == pytest.approx(5.0)


def test_u_turn_with_a_straight_across_for_wide_spacing() -> None:
    turn = plan_turn((0.0, 0.0), (1.0, 0.0), (0.0, -30.0), 4.0)  # the next swath on the right
    assert turn.kind == "u"
    assert turn.length_m == pytest.approx(4.0 * math.pi + 22.0)
    pts = np.array(turn.points)
    assert pts[:, 1].min() >= -30.0 and pts[:, 1].max() <= 0.0
    assert pts[:, 0].max() == pytest.approx(4.0)


def test_bulb_turn_for_narrow_spacing() -> None:
    turn = plan_turn((0.0, 0.0), (1.0, 0.0), (0.0, 6.0), 6.0)
    assert turn.kind == "omega" == turn_kind(6.0, 6.0)
    reach = math.sqrt(144.0 - 81.0) + 6.0
    assert turn.excursion_m == pytest.approx(reach) == turn_excursion_m(6.0, 6.0)
    pts = np.array(turn.points)
    assert pts[:, 0].max() == pytest.approx(reach, abs=0.05)
    assert pts[:, 1].min() < 0.0  # the bulb swings out on the side away from the next swath
    polyline = np.vstack([[0.0, 0.0], pts, [0.0, 6.0]])
    chords = float(np.hypot(*np.diff(polyline, axis=0).T).sum())
    assert chords == pytest.approx(turn.length_m, rel=0.01)
    assert turn.length_m == pytest.approx(turn_length_m(6.0, 6.0))


def test_uneven_ends_drive_on_to_the_later_one() -> None:
    turn = plan_turn((0.0, 0.0), (1.0, 0.0), (7.0, 12.0), 5.0)
    pts = np.array(turn.points)
    assert tuple(pts[0]) == pytest.approx((7.0, 0.0))  # straight on first, level with the start
    assert turn.excursion_m == pytest.approx(5.0)
    assert pts[:, 0].max() == pytest.approx(12.0)
    turn = plan_turn((0.0, 0.0), (1.0, 0.0), (-7.0, 12.0), 5.0)
    pts = np.array(turn.points)
    assert tuple(pts[-1]) == pytest.approx((0.0, 12.0))  # then straight back along the next
    assert turn.length_m == pytest.approx(5.0 * math.pi + 2.0 + 7.0)


def test_turn_across_nothing_is_refused() -> None:
    with pytest.raises(GeometryError):
        plan_turn((0.0, 0.0), (1.0, 0.0), (5.0, 0.0), 5.0)
    with pytest.raises(GeometryError):
        plan_turn((0.0, 0.0), (1.0, 0.0), (0.0, 5.0), 0.0)


@settings(derandomize=True, max_examples=50, deadline=None)
@given(
    radius=st.floats(0.5, 15.0),
    spacing=st.floats(0.2, 40.0),
    offset=st.floats(-20.0, 20.0),
    angle=st.floats(0.0, 360.0),
    left=st.booleans(),
)
def test_every_turn_is_drivable(
    radius: float, spacing: float, offset: float, angle: float, left: bool
) -> None:
    """Points on arcs of the radius (or in line), heading continuous, arc steps bounded."""
    t = math.radians(angle)
    d = np.array([math.cos(t), math.sin(t)])
    n = np.array([-d[1], d[0]]) * (1 if left else -1)
    end = np.array([100.0, -50.0])
    start = end + offset * d + spacing * n
    turn, pts = full_path(tuple(end), tuple(d), tuple(start), radius)
    for a, b, c in zip(pts, pts[1:], pts[2:], strict=False):
        assert circumradius(a, b, c) >= radius * (1 - 1e-6)
    steps = [np.subtract(b, a) for a, b in zip(pts, pts[1:], strict=False)]
    headings = [math.atan2(s[1], s[0]) for s in steps if np.linalg.norm(s) > 1e-6]
    limit = math.radians(ARC_STEP_DEG) + 1e-6
    for h0, h1 in zip(headings, headings[1:], strict=False):
        turned = abs((h1 - h0 + math.pi) % (2 * math.pi) - math.pi)
        assert turned <= limit  # no kink: chords of one arc step at most
    arc_steps = [np.linalg.norm(s) for s in steps[2:-2]]
    assert max(arc_steps, default=0.0) <= max(ARC_STEP_M, abs(offset), spacing) + 1e-6
    polyline = np.vstack(pts[1:-1])
    chords = float(np.hypot(*np.diff(polyline, axis=0).T).sum())
    assert chords <= turn.length_m + 1e-6
    assert chords >= turn.length_m * CHORD_RATIO - 1e-6
    reach = max(0.0, offset) + turn.excursion_m
    assert float(np.max((polyline - end) @ d)) <= reach + 1e-6


@settings(derandomize=True, max_examples=50, deadline=None)
@given(
    radius=st.floats(1.0, 10.0),
    x=st.floats(-40.0, 40.0),
    y=st.floats(-40.0, 40.0),
    h0=st.floats(-math.pi, math.pi),
    h1=st.floats(-math.pi, math.pi),
)
def test_dubins_paths_join_the_poses_with_arcs_of_the_radius(radius, x, y, h0, h1) -> None:
    start, end = (5.0, -3.0), (5.0 + x, -3.0 + y)
    paths = dubins_paths(start, h0, end, h1, radius)
    assert paths and paths == sorted(paths, key=lambda p: p.length_m)
    assert paths[0].length_m >= math.dist(start, end) - 1e-9
    limit = math.radians(ARC_STEP_DEG) + 1e-6
    for path in paths[:3]:
        d0 = np.array([math.cos(h0), math.sin(h0)])
        d1 = np.array([math.cos(h1), math.sin(h1)])
        pts = [np.asarray(start) - d0, np.asarray(start)]
        pts += [np.asarray(p) for p in path.points]
        pts += [np.asarray(end), np.asarray(end) + d1]
        for a, b, c in zip(pts, pts[1:], pts[2:], strict=False):
            assert circumradius(a, b, c) >= radius * (1 - 1e-6)
        steps = [np.subtract(b, a) for a, b in zip(pts, pts[1:], strict=False)]
        headings = [math.atan2(s[1], s[0]) for s in steps if np.linalg.norm(s) > 1e-6]
        for g0, g1 in zip(headings, headings[1:], strict=False):
            assert abs((g1 - g0 + math.pi) % (2 * math.pi) - math.pi) <= limit
        chords = float(np.hypot(*np.diff(np.vstack(pts[1:-1]), axis=0).T).sum())
        assert path.length_m * CHORD_RATIO - 0.02 <= chords <= path.length_m + 1e-6


@pytest.mark.parametrize("spacing", [3.0, 6.9, 12.0, 20.0])
def test_dubins_agrees_with_the_turns_between_swaths(spacing: float) -> None:
    shortest = dubins_paths((0.0, 0.0), 0.0, (0.0, spacing), math.pi, 6.0)[0]
    assert shortest.length_m == pytest.approx(plan_turn((0, 0), (1, 0), (0, spacing), 6.0).length_m)
