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
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from planner.errors import GeometryError

XY = tuple[float, float]
FloatArray = NDArray[np.float64]

ARC_STEP_DEG = 15.0  # largest angle between consecutive points on an arc
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
    # points at the ends themselves, or within a centimetre of them (a straight on of a few
    # millimetres to a level end), are left out: a mission would merge them anyway
    apart = (np.hypot(*(world - e).T) > MIN_GAP_M) & (np.hypot(*(world - e - gap).T) > MIN_GAP_M)
    inner = world[apart]
    return Turn(
        kind=turn_kind(s, r),
        points=tuple((float(x), float(y)) for x, y in inner),
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
