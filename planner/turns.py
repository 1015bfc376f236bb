"""Drivable turns from the end of one swath to the start of the next, driven the other way.

A machine that cannot turn tighter than ``radius`` (forward only) turns between two
antiparallel swaths ``spacing`` apart (across) with the shortest forward path of Dubins'
family that fits the case:

* ``spacing >= 2 * radius``: a **U-turn**, quarter arc, straight across, quarter arc
  (a half circle when ``spacing == 2 * radius``);
* ``spacing < 2 * radius``: a **bulb (omega) turn**, three arcs of ``radius``: away from
  the next swath, around, and back onto it. Its bulb reaches past the swath ends and to both
  sides of the two swaths.

When the two swath ends are not level (a slanted border), the machine first drives straight
on to the later one, so the arcs start and end level with each other and the swaths are
worked to their ends.

Paths are polylines: points on the arcs every ``ARC_STEP_DEG`` degrees and at most
``ARC_STEP_M`` metres apart, so that ArduPilot Rover (``WP_RADIUS`` 1-2 m, L1/S-curve
navigation) drives them as a smooth curve. Every three consecutive points lie on an arc of
``radius`` (chords of it) or on straight lines, and the heading is continuous: the path
leaves the first swath and joins the second tangentially.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from planner.errors import GeometryError

XY = tuple[float, float]
FloatArray = NDArray[np.float64]

ARC_STEP_DEG = 30.0  # largest angle between consecutive points on an arc (below)
ARC_STEP_M = 2.0  # largest arc length between consecutive points on an arc
MIN_GAP_M = 0.01  # turn points closer than this to the swath end or start are left out
_EPS_M = 1e-9

TurnKind = Literal["u", "omega"]


@dataclass(frozen=True)
class Turn:
    """A planned turn: its points strictly between the swath end and the next swath start."""

    kind: TurnKind
    points: tuple[XY, ...]
    length_m: float  # exact length of the arcs and straights, end to start
    excursion_m: float  # how far the path reaches past the later of the two swath ends


def turn_kind(spacing_m: float, radius_m: float) -> TurnKind:
    """``"u"`` when a U-turn of ``radius_m`` fits between swaths ``spacing_m`` apart."""
    return "u" if spacing_m >= 2.0 * radius_m - _EPS_M else "omega"


def turn_excursion_m(spacing_m: float, radius_m: float) -> float:
    """How far past the swath ends a turn between swaths ``spacing_m`` apart reaches.

    ``radius`` for a U-turn; for a bulb turn the bulb's centre lies ``h`` past the ends,
    ``h = sqrt((2r)^2 - (s/2 + r)^2)``, and its far side ``h + r``. Decreases with the
    spacing.
    """
    r, s = float(radius_m), float(spacing_m)
    if turn_kind(s, r) == "u":
        return r
    return _omega_reach(s, r) + r


def turn_length_m(spacing_m: float, radius_m: float) -> float:
    """Length of a turn between level swath ends ``spacing_m`` apart."""
    r, s = float(radius_m), float(spacing_m)
    if turn_kind(s, r) == "u":
        return math.pi * r + (s - 2.0 * r)
    h = _omega_reach(s, r)
    alpha = math.atan2(h, s / 2.0 + r)  # angle turned away from the next swath
    return r * (2.0 * alpha + (math.pi + 2.0 * alpha))


def plan_turn(end: XY, heading: XY, start: XY, radius_m: float) -> Turn:
    """The turn from ``end`` (driving along ``heading``) to ``start`` (driving against it).

    ``start`` must lie to one side of the line through ``end`` along ``heading``, at least
    a millimetre across.
    """
    r = float(radius_m)
    if not (math.isfinite(r) and r > 0.0):
        raise GeometryError(f"turn radius must be a positive number of metres, got {radius_m!r}")
    d = np.asarray(heading, dtype=np.float64)
    d = d / math.hypot(d[0], d[1])
    e = np.asarray(end, dtype=np.float64)
    gap = np.asarray(start, dtype=np.float64) - e
    left = np.array([-d[1], d[0]])
    across = float(gap @ left)
    if abs(across) < 1e-3:
        raise GeometryError("a turn needs the next swath beside the last one, not in line")
    side = left if across > 0 else -left  # towards the next swath
    a, s = float(gap @ d), abs(across)
    x0 = max(0.0, a)  # drive on to the later of the two ends first
    pieces: list[FloatArray] = [np.array([[0.0, 0.0], [x0, 0.0]])]
    if turn_kind(s, r) == "u":
        pieces.append(_arc((x0, r), r, -math.pi / 2, 0.0))
        pieces.append(_arc((x0, s - r), r, 0.0, math.pi / 2))
        length = math.pi * r + (s - 2.0 * r)
        reach = r
    else:
        h = _omega_reach(s, r)
        c1, c2, c3 = (x0, -r), (x0 + h, s / 2.0), (x0, s + r)
        t12 = math.atan2(c2[1] - c1[1], c2[0] - c1[0])
        t21 = math.atan2(c1[1] - c2[1], c1[0] - c2[0])
        t23 = math.atan2(c3[1] - c2[1], c3[0] - c2[0])
        t32 = math.atan2(c2[1] - c3[1], c2[0] - c3[0])
        pieces.append(_arc(c1, r, math.pi / 2, t12))  # away from the next swath (clockwise)
        pieces.append(_arc(c2, r, t21, t21 + (t23 - t21) % (2 * math.pi)))  # around the bulb
        pieces.append(_arc(c3, r, t32, -math.pi / 2))  # back onto the next swath (clockwise)
        alpha = math.pi / 2 - t12
        length = r * (2.0 * alpha + (math.pi + 2.0 * alpha))
        reach = h + r
    pieces.append(np.array([[x0, s], [a, s]]))
    local = np.vstack(pieces)
    keep = np.r_[True, np.hypot(*np.diff(local, axis=0).T) > 1e-6]
    local = local[keep]
    world = e + local[:, :1] * d + local[:, 1:] * side
    return Turn(
        kind=turn_kind(s, r),
        points=_between(world, e, e + gap),
        length_m=float(length + x0 + (x0 - a)),
        excursion_m=float(reach),
    )


def _omega_reach(s: float, r: float) -> float:
    """How far past the ends the centre of a bulb turn's middle arc lies."""
    return math.sqrt(max(4.0 * r * r - (s / 2.0 + r) ** 2, 0.0))


def _arc(centre: XY, r: float, theta_from: float, theta_to: float) -> FloatArray:
    """Points on an arc from angle ``theta_from`` to ``theta_to`` (either way), both ends
    included, at most ``ARC_STEP_DEG`` and ``ARC_STEP_M`` apart."""
    sweep = theta_to - theta_from
    step = min(math.radians(ARC_STEP_DEG), ARC_STEP_M / r)
    n = max(1, math.ceil(abs(sweep) / step - 1e-9))
    theta = theta_from + sweep * np.arange(n + 1) / n
    return np.column_stack([centre[0] + r * np.cos(theta), centre[1] + r * np.sin(theta)])


# ----------------------------------------------------------------------------- Dubins paths


@dataclass(frozen=True)
class _Arc:
    centre: tuple[float, float]
    turn: int  # +1 left (counter-clockwise), -1 right
    heading: float  # heading where the arc starts
    sweep: float  # radians turned, >= 0


@dataclass(frozen=True)
class _Line:
    start: tuple[float, float]
    end: tuple[float, float]


@dataclass(frozen=True)
class DubinsPath:
    """One of Dubins' shortest-path words between two poses: its name, length and points."""

    word: str  # "LSL", "RSR", "LSR", "RSL", "LRL" or "RLR"
    length_m: float
    start: XY
    end: XY
    radius_m: float
    pieces: tuple[_Arc | _Line, ...] = field(repr=False, compare=False)

    @cached_property
    def points(self) -> tuple[XY, ...]:
        """The path's points strictly between the two poses (sampled when first asked)."""
        return _sample(
            list(self.pieces), np.asarray(self.start), np.asarray(self.end), self.radius_m
        )


def dubins_paths(
    start: XY, start_heading: float, end: XY, end_heading: float, radius_m: float
) -> list[DubinsPath]:
    """Every feasible Dubins word from ``start`` (heading in radians) to ``end``, shortest
    first: two arcs of ``radius_m`` joined by a straight (CSC) or by a third arc (CCC).
    The first is the shortest forward path with curvature at most ``1 / radius_m``
    (Dubins 1957). Points as for :func:`plan_turn`."""
    r = float(radius_m)
    if not (math.isfinite(r) and r > 0.0):
        raise GeometryError(f"turn radius must be a positive number of metres, got {radius_m!r}")
    p0 = (float(start[0]), float(start[1]))
    p1 = (float(end[0]), float(end[1]))
    out: list[DubinsPath] = []
    for word in ("LSL", "RSR", "LSR", "RSL", "LRL", "RLR"):
        for pieces in _word(word, p0, start_heading, p1, end_heading, r):
            length = sum(
                r * piece.sweep if isinstance(piece, _Arc) else math.dist(piece.start, piece.end)
                for piece in pieces
            )
            out.append(DubinsPath(word, float(length), start, end, r, tuple(pieces)))
    out.sort(key=lambda path: path.length_m)
    return out


def _centre(p: XY, heading: float, turn: int, r: float) -> XY:
    return (p[0] - turn * r * math.sin(heading), p[1] + turn * r * math.cos(heading))


def _on_circle(c: XY, heading: float, turn: int, r: float) -> XY:
    """The point of the circle around ``c`` where a machine turning ``turn`` heads so."""
    return (c[0] + turn * r * math.sin(heading), c[1] - turn * r * math.cos(heading))


def _sweep(turn: int, heading_from: float, heading_to: float) -> float:
    sweep = (turn * (heading_to - heading_from)) % (2.0 * math.pi)
    return 0.0 if sweep > 2.0 * math.pi - 1e-9 else sweep


def _word(word: str, p0: XY, h0: float, p1: XY, h1: float, r: float) -> list[list[_Arc | _Line]]:
    """The pieces of ``word`` between the two poses (none when it does not exist; two
    variants for CCC words). Plain floats: called some 10^5 times when a farm is covered."""
    t0 = 1 if word[0] == "L" else -1
    t1 = 1 if word[2] == "L" else -1
    c0, c1 = _centre(p0, h0, t0, r), _centre(p1, h1, t1, r)
    vx, vy = c1[0] - c0[0], c1[1] - c0[1]
    dist = math.hypot(vx, vy)
    if word[1] == "S":
        if t0 == t1:
            psi = h0 if dist < 1e-12 else math.atan2(vy, vx)  # one circle: one arc
        else:
            if dist < 2.0 * r:
                return []
            psi = math.atan2(vy, vx) + t0 * math.asin(min(1.0, 2.0 * r / dist))
        a, b = _on_circle(c0, psi, t0, r), _on_circle(c1, psi, t1, r)
        return [
            [
                _Arc(c0, t0, h0, _sweep(t0, h0, psi)),
                _Line(a, b),
                _Arc(c1, t1, psi, _sweep(t1, psi, h1)),
            ]
        ]
    if dist > 4.0 * r or dist < 1e-12:
        return []
    half = math.sqrt(max(4.0 * r * r - dist * dist / 4.0, 0.0))
    ax, ay = -vy / dist, vx / dist
    variants: list[list[_Arc | _Line]] = []
    for sign in (1.0, -1.0):
        cm = ((c0[0] + c1[0]) / 2.0 + sign * half * ax, (c0[1] + c1[1]) / 2.0 + sign * half * ay)
        ta = ((c0[0] + cm[0]) / 2.0, (c0[1] + cm[1]) / 2.0)
        tb = ((cm[0] + c1[0]) / 2.0, (cm[1] + c1[1]) / 2.0)
        ha = math.atan2(ta[1] - c0[1], ta[0] - c0[0]) + t0 * math.pi / 2
        hb = math.atan2(tb[1] - c1[1], tb[0] - c1[0]) + t1 * math.pi / 2
        variants.append(
            [
                _Arc(c0, t0, h0, _sweep(t0, h0, ha)),
                _Arc(cm, -t0, ha, _sweep(-t0, ha, hb)),
                _Arc(c1, t1, hb, _sweep(t1, hb, h1)),
            ]
        )
    return variants


def _sample(pieces: list[_Arc | _Line], p0: FloatArray, p1: FloatArray, r: float) -> tuple[XY, ...]:
    points: list[FloatArray] = [p0[None, :]]
    step = min(math.radians(ARC_STEP_DEG), ARC_STEP_M / r)
    for piece in pieces:
        if isinstance(piece, _Line):
            points.append(np.array([piece.start, piece.end]))
            continue
        n = max(1, math.ceil(piece.sweep / step - 1e-9))
        start = piece.heading - piece.turn * math.pi / 2  # position angle on the circle
        theta = start + piece.turn * piece.sweep * np.arange(n + 1) / n
        c = piece.centre
        points.append(np.column_stack([c[0] + r * np.cos(theta), c[1] + r * np.sin(theta)]))
    every = np.vstack(points)
    every = every[np.r_[True, np.hypot(*np.diff(every, axis=0).T) > 1e-6]]
    return _between(every, p0, p1)


def _between(points: FloatArray, p0: FloatArray, p1: FloatArray) -> tuple[XY, ...]:
    """``points`` without the leading ones within ``MIN_GAP_M`` of ``p0`` and the trailing
    ones within it of ``p1`` (the poses themselves, and a few millimetres of straight or
    arc next to them, which a mission would merge anyway)."""
    first, last = 0, len(points)
    while first < last and math.dist(points[first], p0) <= MIN_GAP_M:
        first += 1
    while last > first and math.dist(points[last - 1], p1) <= MIN_GAP_M:
        last -= 1
    return tuple((float(x), float(y)) for x, y in points[first:last])
