"""Boustrophedon coverage of one field for one working width (our stand-in for Fields2Cover).

:func:`cover_field` takes a shapely polygon in local metres (see :mod:`planner.geo`; holes and
non-convex outlines allowed) and returns a :class:`FieldCoverage`: parallel swaths one
working width apart, grouped into cells that are each driven back and forth, optional
headland rings around the border, and the driving order from each of four start corners.

Outline (details in ``docs/coverage.md``):

* headlands: ``headland_passes`` rings at ``(k + 1/2)`` working widths inside the border;
  the swaths cover the field shrunk by ``headland_passes`` working widths. The rings are
  driven *after* the swaths, innermost first, so the machine turns on unworked ground and
  leaves the field on its border.
* swath direction: given, or searched like Fields2Cover's brute force with the "NSwath"
  objective (fewest swaths, then shortest total length, then smallest angle).
* cells: a boustrophedon decomposition along the sweep; every sweep line meets a cell in
  one segment. Each cell has its own swaths: the first half a width inside its lower
  border, then one every working width; the last one is pulled back to lie half a width
  inside the upper border (so it may overlap its neighbour, never the outside).
* turns: every move from one swath to the next counts as one turn, ``len(swaths) - 1``;
  ``cell_transitions`` of them are moves to another cell, whose in-field driving is
  reported by :meth:`FieldCoverage.transit_inside_m`.
"""

from __future__ import annotations

import heapq
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from numbers import Real

import numpy as np
import shapely
import shapely.affinity
from numpy.typing import NDArray
from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.geometry.polygon import orient
from shapely.validation import explain_validity

from planner.errors import GeometryError

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
XY = tuple[float, float]

ANGLE_STEP_DEG = 1.0  # grid of the angle search, plus every long edge direction exactly
EXACT_CANDIDATES = 32  # angles with the lowest estimated counts, decomposed exactly
COVERAGE_CANDIDATES = 12  # angles tied on the fewest swaths, compared by covered area
MIN_CELL_FRACTION = 0.1  # cells thinner than this many working widths are dropped
MIN_SWATH_M = 1e-3  # shorter sweep segments are not swaths
_SNAP_M = 1e-3  # vertices closer than this across the sweep share one level
_EPS_M = 1e-6
_GRID_M = 1e-4  # precision grid of the overlays that score angles
_EDGE_CANDIDATES = 90  # longest edges whose directions join the angle search

# corner -> (start on the high-v side, first swath drives towards -u); CCW from (min u, min v)
_CORNER_ORIENTATION: tuple[tuple[bool, bool], ...] = (
    (False, False),
    (False, True),
    (True, True),
    (True, False),
)


@dataclass(frozen=True)
class Swath:
    """One straight working pass, oriented in its driving direction.

    ``cell`` is the cell it belongs to; ``index`` its position across the sweep inside that
    cell (0 on the cell's side facing corners 0 and 1), so ``(cell, index)`` names the same
    strip of ground in every driving order.
    """

    start: XY
    end: XY
    cell: int
    index: int

    @property
    def length_m(self) -> float:
        """Working length of the pass in metres."""
        return math.dist(self.start, self.end)

    def reversed(self) -> Swath:
        """The same pass driven the other way."""
        return Swath(self.end, self.start, self.cell, self.index)


@dataclass(frozen=True)
class FieldCoverage:
    """Coverage of one field: swaths, headland rings and driving orders for four corners.

    ``swaths`` and ``headland`` are the driving order from corner 0; :meth:`path`,
    :meth:`headland_path`, :meth:`entry`, :meth:`exit` and :meth:`transit_inside_m` give it
    for any corner. Corners are numbered counter-clockwise in the swath frame (``u`` along
    ``angle_deg``, ``v`` 90° to its left): 0 = (min u, min v), 1 = (max u, min v),
    2 = (max u, max v), 3 = (min u, max v); at angle 0 that is SW, SE, NE, NW.
    """

    field_id: str
    working_width_m: float
    angle_deg: float  # swath direction, degrees counter-clockwise from +x, in [0, 180)
    swaths: tuple[Swath, ...]
    headland: tuple[tuple[XY, ...], ...]  # closed rings, in driving order
    cells: tuple[Polygon, ...]  # cell outlines in local metres, indexed by Swath.cell
    turns: int  # len(swaths) - 1: every move to the next swath, cell changes included
    cell_transitions: int  # how many of the turns move to another cell
    swath_length_m: float
    headland_length_m: float
    area_m2: float
    paths: tuple[tuple[Swath, ...], ...] = field(repr=False)
    headland_paths: tuple[tuple[tuple[XY, ...], ...], ...] = field(repr=False)
    transits_m: tuple[float, ...] = field(repr=False)

    def path(self, corner: int) -> tuple[Swath, ...]:
        """Swaths in driving order, each oriented as driven, when starting at ``corner``."""
        return self.paths[_check_corner(corner)]

    def headland_path(self, corner: int) -> tuple[tuple[XY, ...], ...]:
        """Headland rings in driving order after the swaths started at ``corner``.

        Innermost ring first; each closed ring starts and ends at its point nearest to where
        the machine was before.
        """
        return self.headland_paths[_check_corner(corner)]

    def entry(self, corner: int) -> XY:
        """Where work starts: the start of the first swath from ``corner``."""
        return self.path(corner)[0].start

    def exit(self, corner: int) -> XY:
        """Where work ends: the end of the outer headland ring, else of the last swath.

        Without headland, starting at corner 0 of a single-cell field ends next to corner 3
        after an even number of swaths and next to corner 2 after an odd number.
        """
        rings = self.headland_path(corner)
        if rings:
            return rings[-1][-1]
        return self.path(corner)[-1].end

    def transit_inside_m(self, corner: int) -> float:
        """Metres driven inside the field between work from ``corner``, U-turns excluded.

        Sum of the shortest in-field paths from each cell's last swath to the next cell's
        first swath, from the last swath to the first headland ring and between rings.
        """
        return self.transits_m[_check_corner(corner)]


def rectangle_field(
    width_m: float, length_m: float, angle_deg: float = 0.0, origin: XY = (0.0, 0.0)
) -> Polygon:
    """A ``length_m`` by ``width_m`` rectangle: length along ``angle_deg``, width to its left.

    ``origin`` is the corner the length starts from; at angle 0 the rectangle spans
    ``[0, length_m] x [0, width_m]`` from the origin.
    """
    for name, value in (("width_m", width_m), ("length_m", length_m)):
        if not (math.isfinite(value) and value > 0.0):
            raise GeometryError(f"rectangle: {name} must be a positive number, got {value!r}")
    theta = math.radians(angle_deg)
    along = np.array([math.cos(theta), math.sin(theta)])
    left = np.array([-math.sin(theta), math.cos(theta)])
    o = np.asarray(origin, dtype=np.float64)
    corners = [o, o + length_m * along, o + length_m * along + width_m * left, o + width_m * left]
    return Polygon([tuple(map(float, c)) for c in corners])


def cover_field(
    polygon: Polygon,
    working_width_m: float,
    *,
    field_id: str,
    angle_deg: float | None = None,
    headland_passes: int = 0,
) -> FieldCoverage:
    """Plan boustrophedon coverage of ``polygon`` (local metres) for one working width.

    ``angle_deg`` fixes the swath direction (degrees counter-clockwise from +x, taken
    modulo 180); ``None`` searches the direction with the fewest swaths.
    Raises :class:`GeometryError` naming ``field_id`` when the field cannot be covered.
    """
    field_poly = _checked_field(polygon, working_width_m, headland_passes, angle_deg, field_id)
    w = float(working_width_m)
    rings_by_pass, region, lane = _headland_and_region(field_poly, w, headland_passes, field_id)
    ref = np.array(region.centroid.coords[0])  # work near the origin for precision
    edges = _edges(region, ref)

    if angle_deg is None:
        angle, cells = _search_angle(region, ref, edges, w, field_id)
    else:
        angle = _normalise_angle(angle_deg)
        cells = _decompose(edges, angle, w, field_id)
    if not cells:
        raise GeometryError(
            f"field {field_id!r}: no swath of working width {w:g} m fits in the field"
        )
    if lane is not None:
        cells = _extend_to_lane(cells, _edges(lane, ref), angle)

    paths = tuple(_drive(cells, corner, angle, ref) for corner in range(4))
    distance = _InFieldDistance(field_poly)
    headland_paths: list[tuple[tuple[XY, ...], ...]] = []
    transits: list[float] = []
    for corner_path in paths:
        rings = _order_rings(rings_by_pass, corner_path[-1].end)
        headland_paths.append(rings)
        transits.append(_transit_m(corner_path, rings, distance))

    cell_polys = tuple(_to_polygon(cell.outline, angle, ref) for cell in cells)
    n_swaths = len(paths[0])
    coverage = FieldCoverage(
        field_id=field_id,
        working_width_m=w,
        angle_deg=angle,
        swaths=paths[0],
        headland=headland_paths[0],
        cells=cell_polys,
        turns=max(n_swaths - 1, 0),
        cell_transitions=len(cells) - 1,
        swath_length_m=float(sum(s.length_m for s in paths[0])),
        headland_length_m=float(sum(LineString(r).length for r in headland_paths[0])),
        area_m2=float(field_poly.area),
        paths=paths,
        headland_paths=tuple(headland_paths),
        transits_m=tuple(transits),
    )
    logger.debug(
        "field %r: %d swaths in %d cells at %.3f deg, %d headland rings",
        field_id,
        n_swaths,
        len(cells),
        angle,
        len(coverage.headland),
    )
    return coverage


# ----------------------------------------------------------------------------- checks


def _check_corner(corner: int) -> int:
    if corner not in (0, 1, 2, 3) or isinstance(corner, bool):
        raise ValueError(f"corner must be 0, 1, 2 or 3, got {corner!r}")
    return int(corner)


def _checked_field(
    polygon: Polygon,
    working_width_m: float,
    headland_passes: int,
    angle_deg: float | None,
    field_id: str,
) -> Polygon:
    """The polygon, oriented (exterior CCW, holes CW), after every input check."""
    where = f"field {field_id!r}"
    if (
        isinstance(working_width_m, bool)
        or not isinstance(working_width_m, Real)
        or not (math.isfinite(working_width_m) and working_width_m > 0.0)
    ):
        raise GeometryError(f"{where}: working width must be positive, got {working_width_m!r}")
    if isinstance(headland_passes, bool) or not isinstance(headland_passes, int | np.integer):
        raise GeometryError(f"{where}: headland passes must be an integer, got {headland_passes!r}")
    if headland_passes < 0:
        raise GeometryError(f"{where}: headland passes must be >= 0, got {headland_passes}")
    if angle_deg is not None and not math.isfinite(angle_deg):
        raise GeometryError(f"{where}: swath angle must be finite, got {angle_deg!r}")
    if not isinstance(polygon, Polygon):
        raise GeometryError(f"{where}: expected one shapely Polygon, got {type(polygon).__name__}")
    if polygon.is_empty:
        raise GeometryError(f"{where}: the polygon is empty")
    if not np.all(np.isfinite(shapely.get_coordinates(polygon))):
        raise GeometryError(f"{where}: the polygon has non-finite coordinates")
    if not polygon.is_valid:
        raise GeometryError(f"{where}: invalid polygon: {explain_validity(polygon)}")
    if polygon.area <= 0.0:
        raise GeometryError(f"{where}: the polygon has no area")
    short_side = _narrowest_m(polygon)
    if short_side < working_width_m:
        raise GeometryError(
            f"{where}: the field is {short_side:.2f} m across at its narrowest,"
            f" less than the working width {working_width_m:g} m"
        )
    return orient(polygon, sign=1.0)


def _narrowest_m(polygon: Polygon) -> float:
    """Short side of the minimum rotated rectangle."""
    rect = shapely.minimum_rotated_rectangle(polygon)
    if not isinstance(rect, Polygon):  # a degenerate (line or point) outline
        return 0.0
    c = np.asarray(rect.exterior.coords)
    sides = np.hypot(*(c[1:3] - c[0:2]).T)
    return float(sides.min())


def _normalise_angle(angle_deg: float) -> float:
    angle = float(angle_deg) % 180.0
    return 0.0 if angle >= 180.0 - 1e-9 else angle + 0.0  # + 0.0 turns -0.0 into 0.0


# ----------------------------------------------------------------------------- headland


def _polygons(geom: shapely.Geometry) -> list[Polygon]:
    if isinstance(geom, Polygon):
        return [] if geom.is_empty else [geom]
    if isinstance(geom, MultiPolygon):
        return [p for p in geom.geoms if not p.is_empty]
    return [g for g in getattr(geom, "geoms", ()) if isinstance(g, Polygon) and not g.is_empty]


def _headland_and_region(
    field_poly: Polygon, w: float, passes: int, field_id: str
) -> tuple[list[list[FloatArray]], MultiPolygon, MultiPolygon | None]:
    """Headland ring centre lines per pass (outer first), the region left for swaths and the
    area inside the innermost ring's centre line (``None`` without headland)."""
    min_area = 0.01 * w * w
    if passes == 0:
        return [], MultiPolygon([field_poly]), None
    inner = field_poly.buffer(-passes * w, join_style="mitre")
    parts = [orient(p, sign=1.0) for p in _polygons(inner) if p.area >= min_area]
    if not parts:
        raise GeometryError(
            f"field {field_id!r}: {passes} headland passes of {w:g} m consume the whole field"
        )
    rings_by_pass: list[list[FloatArray]] = []
    for k in range(passes):
        offset = field_poly.buffer(-(k + 0.5) * w, join_style="mitre")
        rings: list[FloatArray] = []
        for part in (orient(p, sign=1.0) for p in _polygons(offset)):
            rings.append(np.asarray(part.exterior.coords))
            rings.extend(np.asarray(hole.coords) for hole in part.interiors)
        rings_by_pass.append(rings)
    # swaths run on to the innermost ring's centre line: the swath region grown by half a
    # width is inside that ring, and does not pass through necks the swath region lacks
    reach = MultiPolygon(parts).buffer(w / 2, join_style="mitre")
    return rings_by_pass, MultiPolygon(parts), MultiPolygon(_polygons(reach))


def _order_rings(rings_by_pass: list[list[FloatArray]], after: XY) -> tuple[tuple[XY, ...], ...]:
    """Rings innermost pass first, each started at its point nearest the previous position."""
    ordered: list[tuple[XY, ...]] = []
    position = np.asarray(after, dtype=np.float64)
    for rings in reversed(rings_by_pass):
        left = list(range(len(rings)))
        while left:
            lines = [LineString(rings[i]) for i in left]
            gaps = shapely.distance(Point(position), lines)
            pick = left.pop(int(np.argmin(gaps)))
            ring = _start_ring_near(rings[pick], position)
            ordered.append(tuple((float(x), float(y)) for x, y in ring))
            position = ring[-1]
    return tuple(ordered)


def _start_ring_near(ring: FloatArray, point: FloatArray) -> FloatArray:
    """The closed ``ring`` rotated to start and end at its point nearest ``point``."""
    line = LineString(ring)
    along = line.project(Point(point))
    nearest = np.asarray(line.interpolate(along).coords[0])
    seg = np.hypot(*np.diff(ring, axis=0).T)
    i = int(np.clip(np.searchsorted(np.cumsum(seg), along, side="left"), 0, len(seg) - 1))
    body = np.vstack([ring[i + 1 :], ring[1 : i + 1]])
    out = np.vstack([nearest, body, nearest])
    keep = np.ones(len(out), dtype=bool)
    keep[1:] = np.hypot(*np.diff(out, axis=0).T) > _EPS_M
    keep[-1] = True
    return out[keep]


# ----------------------------------------------------------------------------- angle search


@dataclass(frozen=True)
class _Edges:
    """Boundary edges of the swath region, oriented (exterior CCW), relative to a reference."""

    ax: FloatArray
    ay: FloatArray
    bx: FloatArray
    by: FloatArray


def _edges(region: MultiPolygon, ref: FloatArray) -> _Edges:
    starts: list[FloatArray] = []
    ends: list[FloatArray] = []
    for part in region.geoms:
        for ring in (part.exterior, *part.interiors):
            c = np.asarray(ring.coords) - ref
            starts.append(c[:-1])
            ends.append(c[1:])
    a = np.vstack(starts)
    b = np.vstack(ends)
    keep = np.hypot(*(b - a).T) > 0.0
    a, b = a[keep], b[keep]
    return _Edges(a[:, 0].copy(), a[:, 1].copy(), b[:, 0].copy(), b[:, 1].copy())


def _search_angle(
    region: MultiPolygon, ref: FloatArray, edges: _Edges, w: float, field_id: str
) -> tuple[float, list[_Cell]]:
    """Swath direction with the fewest swaths, then the least uncovered area, then the
    shortest total swath length, then the smallest angle; and its cells.

    Every grid angle and long-edge direction is first counted quickly with sweep lines over
    the whole region (exact for convex fields); the lowest counts are then decomposed
    exactly, and the angles tied on the fewest swaths are compared by covered area.
    """
    length = np.hypot(edges.bx - edges.ax, edges.by - edges.ay)
    longest = np.argsort(-length, kind="stable")[:_EDGE_CANDIDATES]
    longest = longest[length[longest] >= min(w, float(length.max()))]
    edge_angles = np.degrees(
        np.arctan2(edges.by[longest] - edges.ay[longest], edges.bx[longest] - edges.ax[longest])
    )
    candidates = np.concatenate([np.arange(0.0, 180.0, ANGLE_STEP_DEG), edge_angles % 180.0])
    candidates[candidates >= 180.0 - 1e-9] = 0.0
    candidates = np.unique(np.round(candidates, 9))

    # the estimate runs on a lightly simplified outline: it only ranks angles
    coarse = shapely.simplify(region, 0.05 * w, preserve_topology=True)
    coarse_polys = [orient(p, sign=1.0) for p in _polygons(coarse)]
    coarse_edges = _edges(MultiPolygon(coarse_polys), ref) if coarse_polys else edges
    estimate = _estimate_swaths(coarse_edges, candidates, w)
    pool = np.lexsort((candidates, estimate))[:EXACT_CANDIDATES]

    decomposed = [
        (float(candidates[i]), _decompose(edges, float(candidates[i]), w, field_id)) for i in pool
    ]
    counts = [sum(len(c.lines) for c in cells) for _, cells in decomposed]
    fewest = min((n for n in counts if n > 0), default=0)
    if fewest == 0:
        return decomposed[0]
    finalists = [d for d, n in zip(decomposed, counts, strict=True) if n == fewest]
    region_uv = shapely.affinity.translate(region, -ref[0], -ref[1])

    def score(angle: float, cells: list[_Cell]) -> tuple[float, float, float]:
        lines = np.vstack([c.lines for c in cells])
        strips = shapely.box(lines[:, 1], lines[:, 0] - w / 2, lines[:, 2], lines[:, 0] + w / 2)
        rotated = shapely.affinity.rotate(region_uv, -angle, origin=(0.0, 0.0))
        # fixed-precision overlay: strip borders can coincide with the outline to 1e-15
        covered = shapely.intersection(
            shapely.union_all(strips, grid_size=_GRID_M), rotated, grid_size=_GRID_M
        ).area
        total = float((lines[:, 2] - lines[:, 1]).sum())
        return round(rotated.area - covered, 2), round(total, 3), angle

    return min(finalists[:COVERAGE_CANDIDATES], key=lambda d: score(*d))


def _estimate_swaths(edges: _Edges, angles_deg: FloatArray, w: float) -> NDArray[np.int64]:
    """Sweep-line segment count for every angle, with sweep lines shared by the whole region.

    Lines start half a width above the lowest vertex, one every width, the last one pulled
    back half a width below the highest. A line meets an edge when it lies in the edge's
    half-open ``[low, high)`` span; each inside segment has two such crossings.
    """
    theta = np.radians(angles_deg)[:, None]
    c, s = np.cos(theta), np.sin(theta)
    va = -edges.ax * s + edges.ay * c
    vb = -edges.bx * s + edges.by * c
    lo = np.minimum(va.min(axis=1), vb.min(axis=1))
    hi = np.maximum(va.max(axis=1), vb.max(axis=1))
    n_lines = np.maximum(np.ceil((hi - lo) / w - 1e-9), 1).astype(np.int64)
    k = np.arange(int(n_lines.max()))[None, :]
    lines = lo[:, None] + w / 2 + k * w
    pulled_back = np.maximum(np.minimum(lines, hi[:, None] - w / 2), lo[:, None] + w / 2)
    lines = np.where(k == n_lines[:, None] - 1, pulled_back, lines)
    thin = (hi - lo) < w
    lines[thin, 0] = (lo[thin] + hi[thin]) / 2
    lines = np.where(k < n_lines[:, None], lines, np.nan)

    counts = np.zeros(len(angles_deg), dtype=np.int64)
    chunk = max(1, int(2_000_000 // max(1, va.shape[1] * lines.shape[1])))
    for start in range(0, len(angles_deg), chunk):
        sl = slice(start, start + chunk)
        y = lines[sl][:, None, :]  # (angles, 1, lines) against (angles, edges, 1)
        a, b = va[sl][:, :, None], vb[sl][:, :, None]
        cross = ((a <= y) & (y < b)) | ((b <= y) & (y < a))
        counts[sl] = cross.sum(axis=(1, 2)) // 2
    return counts


# ----------------------------------------------------------------------------- decomposition


@dataclass(frozen=True)
class _Cell:
    """One monotone cell in the swath frame: its swath lines and outline."""

    lines: FloatArray  # (n, 3): v, u_left, u_right; v increasing
    outline: FloatArray  # (m, 2) polygon in (u, v)


def _rotate(x: FloatArray, y: FloatArray, angle_deg: float) -> tuple[FloatArray, FloatArray]:
    """Local (x, y) -> swath frame (u along the swaths, v to their left)."""
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    return x * c + y * s, -x * s + y * c


def _unrotate(u: FloatArray, v: FloatArray, angle_deg: float) -> tuple[FloatArray, FloatArray]:
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    return u * c - v * s, u * s + v * c


def _snap_levels(values: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Distinct sweep levels and ``values`` snapped to them (no value moves more than 1 mm)."""
    uniq = np.unique(values)
    rep = np.empty_like(uniq)
    current = uniq[0]
    for i, value in enumerate(uniq):
        if value - current > _SNAP_M:
            current = value
        rep[i] = current
    return np.unique(rep), rep[np.searchsorted(uniq, values)]


def _decompose(edges: _Edges, angle_deg: float, w: float, field_id: str) -> list[_Cell]:
    """Boustrophedon cells of the region at ``angle_deg`` and their swath lines.

    The region is cut at every vertex level into trapezoids (two boundary edges each).
    A trapezoid continues its cell into the band above when it touches exactly one
    trapezoid there, that one touches only it, and their widths match at the shared level
    (so a step parallel to the swaths starts a new cell with its own swath offsets).
    """
    ua, va = _rotate(edges.ax, edges.ay, angle_deg)
    ub, vb = _rotate(edges.bx, edges.by, angle_deg)
    levels, snapped = _snap_levels(np.concatenate([va, vb]))
    va, vb = snapped[: len(va)], snapped[len(va) :]
    lo = np.searchsorted(levels, np.minimum(va, vb))
    hi = np.searchsorted(levels, np.maximum(va, vb))
    slope = np.divide(ub - ua, vb - va, out=np.zeros_like(ua), where=vb != va)

    def u_at(edge: NDArray[np.int64], v: FloatArray) -> FloatArray:
        u = ua[edge] + (v - va[edge]) * slope[edge]
        return np.where(v == va[edge], ua[edge], np.where(v == vb[edge], ub[edge], u))

    span = hi - lo
    edge_of = np.repeat(np.arange(len(ua)), span)
    first = np.cumsum(span) - span
    band_of = lo[edge_of] + (np.arange(len(edge_of)) - first[edge_of])
    mid = (levels[band_of] + levels[band_of + 1]) / 2
    order = np.lexsort((u_at(edge_of, mid), band_of))
    left, right = order[0::2], order[1::2]
    if len(left) != len(right) or np.any(band_of[left] != band_of[right]):
        raise GeometryError(
            f"field {field_id!r}: the outline has features under {_SNAP_M * 1000:g} mm"
            " that cannot be decomposed; simplify it"
        )
    band = band_of[left]
    tl, tr = edge_of[left], edge_of[right]
    bottom, top = levels[band], levels[band + 1]
    bot_l, bot_r = u_at(tl, bottom), u_at(tr, bottom)
    top_l, top_r = u_at(tl, top), u_at(tr, top)

    # link trapezoids across each level where their intervals overlap
    n_traps = len(band)
    up: list[list[int]] = [[] for _ in range(n_traps)]
    down: list[list[int]] = [[] for _ in range(n_traps)]
    band_start = np.searchsorted(band, np.arange(len(levels)))
    for j in range(len(levels) - 2):
        below = range(band_start[j], band_start[j + 1])
        above = range(band_start[j + 1], band_start[j + 2])
        i = k = 0
        while i < len(below) and k < len(above):
            a, b = below[i], above[k]
            if min(top_r[a], bot_r[b]) - max(top_l[a], bot_l[b]) > _EPS_M:
                up[a].append(b)
                down[b].append(a)
            if top_r[a] < bot_r[b]:
                i += 1
            else:
                k += 1

    cell_of = np.full(n_traps, -1)
    chains: list[list[int]] = []
    for t in range(n_traps):  # trapezoids come sorted by band, so predecessors come first
        if cell_of[t] < 0:
            cell_of[t] = len(chains)
            chains.append([t])
        if len(up[t]) == 1:
            nxt = up[t][0]
            same_width = (
                abs(top_l[t] - bot_l[nxt]) <= _EPS_M * 10
                and abs(top_r[t] - bot_r[nxt]) <= _EPS_M * 10
            )
            if len(down[nxt]) == 1 and same_width:
                cell_of[nxt] = cell_of[t]
                chains[cell_of[t]].append(nxt)

    cells: list[_Cell] = []
    for chain in chains:
        trap = np.asarray(chain)
        v_lo, v_hi = float(bottom[trap[0]]), float(top[trap[-1]])
        height = v_hi - v_lo
        if height < MIN_CELL_FRACTION * w:
            continue
        n = max(math.ceil(height / w - 1e-9), 1)
        ys: FloatArray = v_lo + w / 2 + np.arange(n, dtype=np.float64) * w
        ys[-1] = min(ys[-1], v_hi - w / 2)
        if height < w:
            ys[:] = (v_lo + v_hi) / 2
        which = np.clip(
            np.searchsorted(levels, ys, side="right") - 1 - band[trap[0]], 0, len(trap) - 1
        )
        t = trap[which]
        u_left, u_right = u_at(tl[t], ys), u_at(tr[t], ys)
        keep = u_right - u_left > MIN_SWATH_M
        if not np.any(keep):
            continue
        lines = np.column_stack([ys, u_left, u_right])[keep]
        left_chain = np.column_stack(
            [np.append(bot_l[trap], top_l[trap[-1]]), np.append(bottom[trap], v_hi)]
        )
        right_chain = np.column_stack(
            [np.append(bot_r[trap], top_r[trap[-1]]), np.append(bottom[trap], v_hi)]
        )[::-1]
        cells.append(_Cell(lines, np.vstack([left_chain, right_chain])))
    return cells


def _extend_to_lane(cells: list[_Cell], lane: _Edges, angle_deg: float) -> list[_Cell]:
    """Cells whose swaths run on, both ways, to the innermost headland ring's centre line.

    The machine works into the headland by half a width, so the wedges a slanted border
    leaves beside each swath end are covered by the headland pass.
    """
    ua, va = _rotate(lane.ax, lane.ay, angle_deg)
    ub, vb = _rotate(lane.bx, lane.by, angle_deg)
    slope = np.divide(ub - ua, vb - va, out=np.zeros_like(ua), where=vb != va)
    extended: list[_Cell] = []
    for cell in cells:
        v, mid = cell.lines[:, 0], cell.lines[:, 1:].mean(axis=1)
        a, b = va[:, None], vb[:, None]
        cross = ((a <= v) & (v < b)) | ((b <= v) & (v < a))  # (edges, lines)
        u = ua[:, None] + (v - a) * slope[:, None]
        left = np.where(cross & (u <= mid), u, -np.inf).max(axis=0)
        right = np.where(cross & (u >= mid), u, np.inf).min(axis=0)
        lines = cell.lines.copy()
        lines[:, 1] = np.where(np.isfinite(left), np.minimum(left, lines[:, 1]), lines[:, 1])
        lines[:, 2] = np.where(np.isfinite(right), np.maximum(right, lines[:, 2]), lines[:, 2])
        extended.append(_Cell(lines, cell.outline))
    return extended


def _to_polygon(outline: FloatArray, angle: float, ref: FloatArray) -> Polygon:
    x, y = _unrotate(outline[:, 0], outline[:, 1], angle)
    return Polygon(np.column_stack([x + ref[0], y + ref[1]]))


# ----------------------------------------------------------------------------- driving order


def _cell_swaths(cell: _Cell, from_top: bool, reverse_first: bool) -> FloatArray:
    """(n, 5) rows u_start, u_end, v, index, 0 for one cell driven back and forth."""
    n = len(cell.lines)
    idx = np.arange(n)[::-1] if from_top else np.arange(n)
    forward = (np.arange(n) % 2 == 0) != reverse_first
    v, ul, ur = cell.lines[idx, 0], cell.lines[idx, 1], cell.lines[idx, 2]
    return np.column_stack([np.where(forward, ul, ur), np.where(forward, ur, ul), v, idx])


def _drive(cells: Sequence[_Cell], corner: int, angle: float, ref: FloatArray) -> tuple[Swath, ...]:
    """Swaths from ``corner``: start cell nearest that corner, then nearest next cell entry."""
    every = np.vstack([c.lines for c in cells])
    u_min, u_max = float(every[:, 1].min()), float(every[:, 2].max())
    v_min, v_max = float(every[:, 0].min()), float(every[:, 0].max())
    target = np.array([[u_min, v_min], [u_max, v_min], [u_max, v_max], [u_min, v_max]][corner])
    orientations = [_CORNER_ORIENTATION[corner]] + [
        o for o in _CORNER_ORIENTATION if o != _CORNER_ORIENTATION[corner]
    ]

    plans = {(ci, o): _cell_swaths(cell, *o) for ci, cell in enumerate(cells) for o in orientations}

    def entry(ci: int, o: tuple[bool, bool]) -> FloatArray:
        row = plans[ci, o][0]
        return np.array([row[0], row[2]])

    def exit_(ci: int, o: tuple[bool, bool]) -> FloatArray:
        row = plans[ci, o][-1]
        return np.array([row[1], row[2]])

    first_o = orientations[0]
    first = min(
        range(len(cells)), key=lambda ci: (float(np.hypot(*(entry(ci, first_o) - target))), ci)
    )
    sequence = [(first, first_o)]
    left = [ci for ci in range(len(cells)) if ci != first]
    position = exit_(first, first_o)
    while left:
        best = min(
            (
                (float(np.hypot(*(entry(ci, o) - position))), ci, oi)
                for ci in left
                for oi, o in enumerate(orientations)
            ),
        )
        _, ci, oi = best
        sequence.append((ci, orientations[oi]))
        left.remove(ci)
        position = exit_(ci, orientations[oi])

    swaths: list[Swath] = []
    for ci, o in sequence:
        rows = plans[ci, o]
        x0, y0 = _unrotate(rows[:, 0], rows[:, 2], angle)
        x1, y1 = _unrotate(rows[:, 1], rows[:, 2], angle)
        for k in range(len(rows)):
            swaths.append(
                Swath(
                    (float(x0[k] + ref[0]), float(y0[k] + ref[1])),
                    (float(x1[k] + ref[0]), float(y1[k] + ref[1])),
                    ci,
                    int(rows[k, 3]),
                )
            )
    return tuple(swaths)


def _transit_m(
    path: tuple[Swath, ...], rings: tuple[tuple[XY, ...], ...], distance: _InFieldDistance
) -> float:
    total = 0.0
    for before, after in zip(path[:-1], path[1:], strict=True):
        if before.cell != after.cell:
            total += distance(before.end, after.start)
    position = path[-1].end
    for ring in rings:
        total += distance(position, ring[0])
        position = ring[-1]
    return total


class _InFieldDistance:
    """Shortest driving distance between two points without leaving the field.

    Straight when the segment stays inside; otherwise Dijkstra over the field's
    visibility graph (paths bend only at vertices where the free space is reflex).
    """

    def __init__(self, field_poly: Polygon) -> None:
        self._inside = field_poly.buffer(1e-3, join_style="mitre")
        shapely.prepare(self._inside)
        corners: list[FloatArray] = []
        for ring in (field_poly.exterior, *field_poly.interiors):  # exterior CCW, holes CW
            c = np.asarray(ring.coords)[:-1]
            into, out = c - np.roll(c, 1, axis=0), np.roll(c, -1, axis=0) - c
            turn = into[:, 0] * out[:, 1] - into[:, 1] * out[:, 0]
            corners.append(c[turn < 0.0])
        self._nodes = np.vstack(corners) if corners else np.empty((0, 2))
        self._graph: FloatArray | None = None

    def _visible(self, a: FloatArray, b: FloatArray) -> NDArray[np.bool_]:
        lines = shapely.linestrings(np.stack([a, b], axis=1))
        return np.asarray(shapely.covers(self._inside, lines), dtype=bool)

    def _node_graph(self) -> FloatArray:
        if self._graph is None:
            n = len(self._nodes)
            graph = np.full((n, n), np.inf)
            i, j = np.triu_indices(n, k=1)
            if len(i):
                ok = self._visible(self._nodes[i], self._nodes[j])
                d = np.hypot(*(self._nodes[i] - self._nodes[j]).T)
                graph[i[ok], j[ok]] = d[ok]
                graph[j[ok], i[ok]] = d[ok]
            self._graph = graph
        return self._graph

    def __call__(self, a: XY, b: XY) -> float:
        pa, pb = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        straight = float(np.hypot(*(pb - pa)))
        if straight < _EPS_M or self._visible(pa[None], pb[None])[0]:
            return straight
        nodes = self._nodes
        n = len(nodes)
        if n == 0:
            logger.warning("no in-field path between %s and %s; using the straight line", a, b)
            return straight
        graph = self._node_graph()
        dist_a = np.where(
            self._visible(np.repeat(pa[None], n, 0), nodes), np.hypot(*(nodes - pa).T), np.inf
        )
        dist_b = np.where(
            self._visible(np.repeat(pb[None], n, 0), nodes), np.hypot(*(nodes - pb).T), np.inf
        )
        best: dict[int, float] = {}
        heap = [(float(d), i) for i, d in enumerate(dist_a) if math.isfinite(d)]
        heapq.heapify(heap)
        result = math.inf
        while heap:
            d, i = heapq.heappop(heap)
            if i in best or d >= result:
                continue
            best[i] = d
            result = min(result, d + float(dist_b[i]))
            row = graph[i]
            for j in np.flatnonzero(np.isfinite(row)):
                if int(j) not in best:
                    heapq.heappush(heap, (d + float(row[j]), int(j)))
        if not math.isfinite(result):
            logger.warning("no in-field path between %s and %s; using the straight line", a, b)
            return straight
        return result
