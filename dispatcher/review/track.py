"""How well a vehicle drove its mission: cross-track error on the swaths, time with the
implement down outside the field, and turns driven without a loop.

Measured from the log alone (the positions a vehicle reported and the items it reached),
so it works for the simulator and for a real autopilot alike:

* **implement down**: from the moment the navigation item before an item that lowers the
  implement (``implement_down``, ``implement_lower``) was reached (ArduPilot runs DO items
  as it leaves the waypoint before them; reached again when the vehicle was sent back to
  it, then: the report's ``_item_times``) until the one before the next item that raises
  it (``implement_raise``, ``implement_up``) was reached;
* **cross-track error**: for every position while the implement is down, its distance to
  the planned working line of that stretch (the waypoints between the two items);
  median and 95th percentile, over every working line and over the straight swaths alone
  (the stretches that are one line: every swath when turns are planned), headland rings
  with their rounded corners left out of the latter;
* **outside the field**: the time between successive positions, implement down, at
  least one of which lies outside the field's polygon by more than
  ``OUTSIDE_TOLERANCE_M`` (goal: 0);
* **loops**: a turn (implement up between two working stretches of one field) whose driven
  heading changes by more than the planned turn path's change plus ``LOOP_EXTRA_DEG``;
  a tractor that overshoots and circles back to catch a waypoint does that.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from dispatcher.mission.build import IMPLEMENT_LOWERED, IMPLEMENT_RAISED
from dispatcher.mission.document import PlannedItem
from planner.geo import LocalFrame

LOOP_EXTRA_DEG: Final = 180.0
"""A turn whose driven heading change exceeds the planned one by more than this looped."""
OUTSIDE_TOLERANCE_M: Final = 0.1
"""A position counts as outside its field only when farther than this beyond the border
(a swath end on the border reads a few centimetres out after projection and rounding)."""
MIN_STEP_M: Final = 0.5
"""Positions closer than this to the previous one give no heading (GPS jitter)."""


@dataclass(frozen=True)
class TrackQuality:
    """How the driven track matched the mission's working lines and turns."""

    samples: int  # positions with the implement down
    cross_track_median_m: float | None  # on every working line (swaths and headland)
    cross_track_p95_m: float | None
    cross_track_max_m: float | None
    swath_samples: int  # of them, on straight swaths worked one at a time
    swath_median_m: float | None  # cross-track error on those swaths alone
    swath_p95_m: float | None
    outside_down_s: float  # implement down outside the field, vehicle seconds
    turns: int  # turns between working stretches that were driven
    loops: int  # of them, how many were driven with a loop


def track_quality(
    items: Sequence[PlannedItem],
    times: Mapping[int, float],
    track: Sequence[tuple[float, float, float]],
    fields: Mapping[str, Sequence[Sequence[Sequence[float]]]],
    up_spans: Sequence[tuple[float, float]] = (),
) -> TrackQuality | None:
    """Measure one vehicle's track (``(clock s, lat, lon)`` in time order) against its
    mission ``items``, given when each item was done (``times``, the vehicle's clock) and
    the fields' rings (each field's outline, then its holes: lists of ``(lon, lat)``);
    a hole (a pond) counts as outside. ``up_spans``: times the implement was up within a
    working stretch (driven back to where a line starts after a reboot, the dispatcher's
    start raising it). None when nothing was driven."""
    if len(track) < 2 or not items:
        return None
    frame = LocalFrame.around(float(track[0][2]), float(track[0][1]))
    t = np.array([p[0] for p in track], dtype=np.float64)
    x, y = frame.to_local(
        np.array([p[2] for p in track], dtype=np.float64),
        np.array([p[1] for p in track], dtype=np.float64),
    )
    points = shapely.points(x, y)

    def local(item: PlannedItem) -> tuple[float, float]:
        lx, ly = frame.to_local(float(item.lon), float(item.lat))
        return float(lx), float(ly)

    outlines: dict[str, Polygon] = {}
    for fid, rings in fields.items():
        try:
            local_rings = []
            for ring in rings:
                xs, ys = frame.to_local(
                    np.array([float(p[0]) for p in ring]), np.array([float(p[1]) for p in ring])
                )
                local_rings.append(np.column_stack([xs, ys]))
            polygon = Polygon(local_rings[0], local_rings[1:])
            outlines[fid] = polygon.buffer(OUTSIDE_TOLERANCE_M)
        except (TypeError, ValueError, IndexError):
            continue

    errors: list[np.ndarray] = []
    swath_errors: list[np.ndarray] = []
    outside_s = 0.0
    samples = 0
    turns = loops = 0
    previous_stretch_end: tuple[int, float] | None = None  # (seq, time) of the last up
    last_heard = max(times, default=-1)
    for down_seq, up_seq in _stretches(items):
        if down_seq not in times:
            previous_stretch_end = None
            continue
        if up_seq in times:
            t0, t1 = times[down_seq], times[up_seq]
            line_points = [local(items[s]) for s in _nav_between(items, down_seq, up_seq)]
        elif last_heard > up_seq:  # its end not heard, what came after was: not measured
            previous_stretch_end = None
            continue
        else:
            # Begun, never ended: the vehicle failed (or the log ended) while working it.
            # Measured up to its track's end against the line up to the waypoint it drove
            # to (it was left out: the stretch a tractor failed on went unchecked, the
            # whole field with turns not planned; an outside review).
            last = max((s for s in times if down_seq < s < up_seq), default=down_seq)
            towards = next((s for s in range(last + 1, up_seq) if items[s].is_nav), up_seq)
            t0, t1 = times[down_seq], float(t[-1])
            line_points = [local(items[s]) for s in _nav_between(items, down_seq, towards + 1)]
        field_id = items[down_seq].field_id
        if previous_stretch_end is not None and items[previous_stretch_end[0]].field_id == field_id:
            turns += 1
            if _looped(items, previous_stretch_end, (down_seq, t0), t, x, y, local):
                loops += 1
        previous_stretch_end = (up_seq, t1)
        inside = (t > t0) & (t < t1)
        for a, b in up_spans:
            inside &= ~((t >= a) & (t <= b))
        if not np.any(inside) or len(line_points) < 1:
            continue
        line = LineString(line_points) if len(line_points) > 1 else shapely.points(line_points[0])
        error = np.asarray(shapely.distance(line, points[inside]), dtype=np.float64)
        errors.append(error)
        if len(line_points) == 2:  # one straight swath, implement raised at both ends
            swath_errors.append(error)
        samples += int(inside.sum())
        outline = outlines.get(field_id or "")
        if outline is not None:
            out = ~np.asarray(shapely.covers(outline, points), dtype=bool)
            idx = np.flatnonzero(inside)
            for k in idx:
                if k + 1 >= len(t):
                    continue
                # Up from a reboot on (up_spans): the leg into it is not down outside, the
                # vehicle back in the garage after the reboot (counted up to the reboot only
                # when it was outside already).
                up_from = min((a for a, _ in up_spans if t[k] < a <= t[k + 1]), default=None)
                if up_from is not None:
                    if out[k]:
                        outside_s += float(min(up_from, t1) - t[k])
                elif out[k] or out[k + 1]:
                    outside_s += float(min(t[k + 1], t1) - t[k])
    every = np.concatenate(errors) if errors else np.zeros(0)
    swaths = np.concatenate(swath_errors) if swath_errors else np.zeros(0)
    return TrackQuality(
        samples=samples,
        cross_track_median_m=float(np.median(every)) if len(every) else None,
        cross_track_p95_m=float(np.percentile(every, 95)) if len(every) else None,
        cross_track_max_m=float(every.max()) if len(every) else None,
        swath_samples=len(swaths),
        swath_median_m=float(np.median(swaths)) if len(swaths) else None,
        swath_p95_m=float(np.percentile(swaths, 95)) if len(swaths) else None,
        outside_down_s=outside_s,
        turns=turns,
        loops=loops,
    )


def _stretches(items: Sequence[PlannedItem]) -> list[tuple[int, int]]:
    """(seq lowering the implement, seq raising it next) for every working stretch: a
    whole field when turns are not planned, else one swath or headland run each."""
    out = []
    down: int | None = None
    for item in items:
        if item.role in IMPLEMENT_LOWERED:
            down = item.seq
        elif item.role in IMPLEMENT_RAISED and down is not None:
            out.append((down, item.seq))
            down = None
    return out


def _nav_before(items: Sequence[PlannedItem], seq: int) -> int:
    """The navigation item before ``seq`` (0, home, when there is none)."""
    return next((s for s in range(seq - 1, -1, -1) if items[s].is_nav), 0)


def _nav_between(items: Sequence[PlannedItem], down_seq: int, up_seq: int) -> list[int]:
    """The working line: the navigation item before ``down_seq`` and those up to
    ``up_seq``."""
    seqs = [_nav_before(items, down_seq)]
    seqs += [s for s in range(down_seq + 1, up_seq) if items[s].is_nav]
    return seqs


def _heading_change(xs: np.ndarray, ys: np.ndarray) -> float:
    """Sum of absolute heading changes (degrees) along a polyline, steps under
    MIN_STEP_M skipped."""
    keep_x, keep_y = [float(xs[0])], [float(ys[0])]
    for px, py in zip(xs[1:].tolist(), ys[1:].tolist(), strict=True):
        if math.hypot(px - keep_x[-1], py - keep_y[-1]) >= MIN_STEP_M:
            keep_x.append(px)
            keep_y.append(py)
    if len(keep_x) < 3:
        return 0.0
    headings = np.arctan2(np.diff(keep_y), np.diff(keep_x))
    turn = np.diff(headings)
    turn = (turn + math.pi) % (2 * math.pi) - math.pi
    return float(np.degrees(np.abs(turn).sum()))


def _looped(
    items: Sequence[PlannedItem],
    after: tuple[int, float],
    before: tuple[int, float],
    t: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    local: Callable[[PlannedItem], tuple[float, float]],
) -> bool:
    """Whether the turn from the stretch ending at ``after`` to the one starting at
    ``before`` was driven with a loop."""
    (up_seq, t_up), (down_seq, t_down) = after, before
    if t_down <= t_up:
        return False
    window = (t >= t_up) & (t <= t_down)
    if window.sum() < 3:
        return False
    first = _nav_before(items, up_seq)
    last = _nav_before(items, down_seq)
    planned = [local(items[s]) for s in range(first, last + 1) if items[s].is_nav]
    if len(planned) >= 3:
        px = np.array([p[0] for p in planned])
        py = np.array([p[1] for p in planned])
        planned_change = _heading_change(px, py)
    else:
        planned_change = 180.0
    return _heading_change(x[window], y[window]) > planned_change + LOOP_EXTRA_DEG
