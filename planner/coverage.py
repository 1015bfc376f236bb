"""Boustrophedon coverage of one field for one working width (our stand-in for Fields2Cover).

:func:`cover_field` takes a shapely polygon in local metres (see :mod:`planner.geo`; holes and
non-convex outlines allowed) and returns a :class:`FieldCoverage`: parallel swaths one
working width apart, grouped into cells that are each driven back and forth, optional
headland rings around the border, and the driving order from each of four start corners.

Outline (details in ``docs/coverage.md``):

* headland: ``headland_passes`` rings at ``(k + 1/2)`` working widths inside the border;
  the swaths are laid out on the field shrunk by ``headland_passes`` working widths and
  run on to the innermost ring's centre line. The rings are driven *after* the swaths,
  innermost first, so the machine turns on unworked ground and leaves on the border.
* swath direction: given, or searched like Fields2Cover's brute force with its "NSwath"
  objective: every 1° and every long edge direction; fewest swaths wins, ties go to the
  least uncovered area, then the shortest total swath length, then the smallest angle.
* cells: a boustrophedon decomposition along the sweep, so a sweep line meets a cell in
  one segment. Each cell has its own swaths: the first half a width inside its lower
  border, the last half a width inside its upper border, the others spread evenly between
  them: adjacent swaths are at most a width and at least half a width apart
  (``MIN_SPACING_FRACTION``), so the overlap is shared out instead of left as a sliver.
* turns: every move from one swath to the next counts as one turn, ``len(swaths) - 1``;
  ``cell_transitions`` of them are moves to another cell, whose in-field driving is
  reported by :meth:`FieldCoverage.transit_inside_m`.
* planned turns (``turn_radius_m > 0``): moves between swaths of a cell become U-turns or
  bulb turns of that radius (:mod:`planner.turns`), in a headland as wide as they need when
  ``headland_passes`` is ``None``; a cell is driven skipping a row when that turns less;
  moves to another cell and onto the headland rings follow Dubins paths inside the field;
  the rings' convex corners are rounded to the radius.
"""

from __future__ import annotations

import heapq
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from numbers import Real
from typing import TypeVar

import numpy as np
import shapely
import shapely.errors
from numpy.typing import NDArray
from shapely.geometry import LineString, MultiPolygon, Point, Polygon
from shapely.geometry.polygon import orient
from shapely.validation import explain_validity

from planner.errors import NO_DEADLINE, Deadline, GeometryError, TimeLimitError
from planner.turns import (
    ARC_STEP_DEG,
    ARC_STEP_M,
    MIN_GAP_M,
    DubinsPath,
    dubins_paths,
    plan_turn,
    turn_excursion_m,
)

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
XY = tuple[float, float]
_T = TypeVar("_T")

ANGLE_STEP_DEG = 1.0  # grid of the angle search, plus every long edge direction exactly
EXACT_CANDIDATES = 32  # angles with the lowest estimated counts, decomposed exactly
COVERAGE_CANDIDATES = 12  # angles tied on the fewest swaths, compared by covered area
MIN_CELL_FRACTION = 0.1  # cells thinner than this many working widths are dropped
MIN_SWATH_M = 1e-3  # shorter sweep segments are not swaths
# A field the short side of whose minimum rotated rectangle is a working width across may
# still be nowhere that wide (an L of thin arms, a thin rim about a hole): one where no
# circle this many working widths across fits is refused too. A convex field a width
# across always has room for one 2/3 of a width across (a triangle's inradius is at least
# a third of its least width), so this refuses no convex field the rectangle lets through.
MIN_INSIDE_FRACTION = 0.6
# A field far from convex (its area under this share of its convex hull's: an L, a U, a rim
# about a hole) must have room somewhere for a circle a whole working width across: its
# arms narrower than the implement were worked crosswise, every turn a hop (an L of 5 m
# arms given to a 6 m machine while a 3 m one stood idle: review of 2026-11-27).
CONVEX_SOLIDITY = 0.9
# A field of which more than this share is swept by no swath and no headland ring is named
# in a warning with that area (an acute corner: 19 % of a 10-degree triangle, 400 m long, at
# 6.9 m; the demo farm's fields leave 0.3-1.1 %, slanted swath ends).
UNWORKED_WARN_SHARE = 0.05
# ... or one piece of it, half a width across or more, of more than this many squares of a
# width (800 m2 between a pond 20 m from the border and the border, 0.6 % of the field, went
# unsaid: review of 2026-11-27).
UNWORKED_BLOCK_WIDTHS = 4.0
# A headland ring's points closer than this to the point before are dropped: the offset of
# a jittery outline (GPS noise) leaves edges of a fraction of a millimetre, which a mission
# in lat/lon cannot tell from a point (1e-7 degrees, ~1 cm: two points 2.5 cm apart stay
# more than the mission builder's 1 cm apart when rounded to it).
MIN_RING_EDGE_M = 0.025
# A headland ring's centre line keeps within this of the outline's offset, in metres and at
# most a twentieth of the working width (the overlap or gap it may leave beside the next
# pass): a boundary driven with a GNSS receiver (a point every 0.6 m, 0.3 m of drift) made
# rings of 2 500 points a 1.4 km lap, 250 at 0.2 m. Simplified before the corners are
# rounded to the turning radius (:func:`_rounded`), so the arcs keep their points.
RING_SIMPLIFY_M = 0.2
# Adjacent swaths of a cell are at least this many working widths apart (and at most one);
# a cell that would need them closer gets one swath less (see swath_counts).
MIN_SPACING_FRACTION = 0.5
_SNAP_M = 1e-3  # vertices closer than this across the sweep share one level
SIMPLIFY_FRACTION = 0.25  # default outline simplification for the layout, in working widths
_EPS_M = 1e-6
_GRID_M = 1e-4  # precision grid of the overlays that score angles
_EDGE_CANDIDATES = 90  # longest edges whose directions join the angle search
MAX_SWATHS = 10_000
"""The most working widths a field may be across (at its narrowest, or across the swath
direction it gives): a field wider is refused at once (:class:`GeometryError` naming it,
its width across and the swath count), before any work. Far beyond any real field (3 km
across at the narrowest implement a scenario accepts, 0.5 m, is 6,000 swaths), and about
what one MAVLink mission can drive: at least four items a swath (its two ends, implement
down and up), turn points besides, in at most 65,535 items."""
_SCORE_CHUNK = 2048  # swaths scored per shapely call in the angle search (deadline checks)
_GRAPH_CHUNK = 100_000  # node pairs per visibility call of the in-field graph

# headland rings by pass, swath region, area the swath ends reach, angle, cells, frame origin
_Layout = tuple[
    list[list[FloatArray]], MultiPolygon, MultiPolygon | None, float, list["_Cell"], FloatArray
]

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
    cells: tuple[Polygon, ...]  # cell outlines (of the simplified outline), by Swath.cell
    turns: int  # len(swaths) - 1: every move to the next swath, cell changes included
    cell_transitions: int  # how many of the turns move to another cell
    swath_length_m: float
    headland_length_m: float
    area_m2: float
    paths: tuple[tuple[Swath, ...], ...] = field(repr=False)
    headland_paths: tuple[tuple[tuple[XY, ...], ...], ...] = field(repr=False)
    transits_m: tuple[float, ...] = field(repr=False)
    # Per corner, per move from swath k to k + 1: the corners of the in-field path when the
    # straight line between them would leave the field (around a notch or a hole).
    links: tuple[tuple[tuple[XY, ...], ...], ...] = field(repr=False, default=())
    # Per corner, per move from swath k to k + 1: the drivable turn path (points between the
    # end of swath k and the start of swath k + 1, both excluded), empty for a hop.
    turn_paths: tuple[tuple[tuple[XY, ...], ...], ...] = field(repr=False, default=())
    # Per corner, per headland ring: the drivable path (points strictly between) from where
    # the machine was (the last swath's end, or the previous ring's end) to the ring's start;
    # empty when there is none (a hop).
    headland_moves: tuple[tuple[tuple[XY, ...], ...], ...] = field(repr=False, default=())
    # Per corner, per headland ring: when the move onto it is no planned path (a hop, or no
    # turns planned), the corners of the in-field path onto its start where the straight
    # line would leave the field (around a hole between two rings); else empty.
    headland_links: tuple[tuple[tuple[XY, ...], ...], ...] = field(repr=False, default=())
    turn_radius_m: float = 0.0
    headland_passes: int = 0  # as laid out (given, or as many as the turns need)
    # The field's area neither a swath nor a headland ring sweeps (:func:`_unworked_m2`).
    unworked_m2: float = 0.0
    # What the farmer should hear of this coverage (corners left unworked, turns driven as
    # hops, fewer headland passes than the turns need), for :func:`cover_field`'s caller to
    # say once it knows the coverage is used: a fleet's other widths are covered too.
    notes: tuple[str, ...] = field(repr=False, default=())

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

    def link(self, corner: int) -> tuple[tuple[XY, ...], ...]:
        """For each move from swath k to k + 1 from ``corner``, the points the machine
        drives through to stay inside the field (usually none)."""
        return self.links[_check_corner(corner)] if self.links else ()

    def turn(self, corner: int) -> tuple[tuple[XY, ...], ...]:
        """For each move from swath k to k + 1 from ``corner``, the turn path's points
        (empty when turns are not planned: the machine hops from one swath to the next)."""
        return self.turn_paths[_check_corner(corner)] if self.turn_paths else ()

    def headland_move(self, corner: int) -> tuple[tuple[XY, ...], ...]:
        """For each headland ring of :meth:`headland_path`, the points of the drivable path
        onto it (empty: a hop, or turns are not planned)."""
        return self.headland_moves[_check_corner(corner)] if self.headland_moves else ()

    def headland_link(self, corner: int) -> tuple[tuple[XY, ...], ...]:
        """For each headland ring of :meth:`headland_path`, the points that keep a move onto
        it that is no planned path inside the field (usually none)."""
        return self.headland_links[_check_corner(corner)] if self.headland_links else ()

    def turn_length_m(self, corner: int) -> float:
        """Metres driven in the planned turns between swaths from ``corner``, moves to
        another cell included when they are planned (0 without planned turns: the paper's
        t_T per turn applies then)."""
        total = 0.0
        for before, after, via in zip(
            self.path(corner)[:-1], self.path(corner)[1:], self.turn(corner), strict=False
        ):
            if via:
                total += LineString([before.end, *via, after.start]).length
        return total

    def transit_inside_m(self, corner: int) -> float:
        """Metres driven inside the field between work from ``corner``, U-turns excluded.

        Sum of the shortest in-field paths from each cell's last swath to the next cell's
        first swath (unless the move is a planned turn, counted in :meth:`turn_length_m`),
        from the last swath to the first headland ring and between rings (the planned
        paths onto the rings when there are).
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
    headland_passes: int | None = None,
    simplify_m: float | None = None,
    turn_radius_m: float = 0.0,
    deadline: Deadline = NO_DEADLINE,
    quiet: bool = False,
) -> FieldCoverage:
    """Plan boustrophedon coverage of ``polygon`` (local metres) for one working width.

    ``angle_deg`` fixes the swath direction (degrees counter-clockwise from +x, taken
    modulo 180); ``None`` searches the direction with the fewest swaths.
    ``headland_passes`` rings are laid around the border (and around holes); ``None``
    lays as many as turns of ``turn_radius_m`` need (none when it is 0).
    ``turn_radius_m`` > 0 plans the turns between swaths of a cell as drivable paths
    (:attr:`FieldCoverage.turn_paths`); 0 leaves them hops between swath ends.
    ``simplify_m`` (default a quarter of the working width) smooths a non-convex outline
    before the cells are laid out, so that GPS noise does not split the field into many
    cells; swath ends are always put on the real outline.
    Raises :class:`GeometryError` naming ``field_id`` when the field cannot be covered,
    at once when it is more than :data:`MAX_SWATHS` working widths across; with a
    ``deadline``, :class:`~planner.errors.TimeLimitError` naming it once that has passed
    (looked at in every loop of the angle search, the layout and the turn planning).
    What the farmer should hear of it (:attr:`FieldCoverage.notes`) is logged as warnings,
    unless ``quiet``: then the caller says it, for the coverages it uses.
    """
    notes: list[str] = []
    radius = _checked_radius(turn_radius_m, field_id)
    field_poly = _checked_field(
        polygon,
        working_width_m,
        0 if headland_passes is None else headland_passes,
        angle_deg,
        simplify_m,
        field_id,
    )
    w = float(working_width_m)
    across = _swaths_across(field_poly, w, angle_deg, field_id)
    clock = _Clock(deadline, field_id, w, across)
    if headland_passes is None:  # as many as the turns need (none for hops)
        passes = headland_passes_for_turns(w, radius, w)
        rings_by_pass, region, lane, angle, cells, ref = _layout_fitting_turns(
            field_poly, w, passes, radius, angle_deg, simplify_m, field_id, clock, notes
        )
        passes = len(rings_by_pass)  # as laid out: fewer where the field has no room
    else:
        passes = headland_passes
        rings_by_pass, region, lane, angle, cells, ref = _layout(
            field_poly, w, passes, angle_deg, simplify_m, field_id, radius, clock
        )
        needed = headland_passes_for_turns(w, radius, _closest_swaths_m(cells, w))
        if passes < needed:
            notes.append(
                f"field {field_id!r}: headland_passes = {passes} is less than turns of radius "
                f"{radius:g} m need ({needed}): the machine's {w:g} m implement may reach up "
                f"to {w / 2:g} m past the border in a turn (give the field {needed} passes, "
                "or leave headland_passes out to have as many as the turns need)"
            )

    skips = [_skips_rows(cell, radius, clock) for cell in cells]
    clock.check("ordering the swaths")
    paths = tuple(_drive(cells, corner, angle, ref, skips) for corner in range(4))
    distance = _InFieldDistance(field_poly, clock)
    headland_paths: list[tuple[tuple[XY, ...], ...]] = []
    transits: list[float] = []
    links: list[tuple[tuple[XY, ...], ...]] = []
    turn_paths: list[tuple[tuple[XY, ...], ...]] = []
    fits = _TurnsInside(field_poly, radius, clock)
    headland_moves: list[tuple[tuple[XY, ...], ...]] = []
    headland_links: list[tuple[tuple[XY, ...], ...]] = []
    for corner_path in paths:
        routes = tuple(
            # Any move whose straight line would leave the field: cell changes, and
            # the odd long jump within a cell of a notched outline.
            distance.route(before.end, after.start)[1]
            for before, after in zip(corner_path[:-1], corner_path[1:], strict=True)
        )
        turns: tuple[tuple[XY, ...], ...] = ()
        moves: tuple[tuple[XY, ...], ...] = ()
        if radius > 0.0:
            turns = fits.turns(corner_path, routes)
            routes = tuple(() if turn else route for turn, route in zip(turns, routes, strict=True))
            last = corner_path[-1]
            rings, moves = fits.enter_rings(rings_by_pass, last.end, _heading(last))
        else:
            rings = _order_rings(rings_by_pass, corner_path[-1].end)
        links.append(routes)
        turn_paths.append(turns)
        headland_paths.append(rings)
        headland_moves.append(moves)
        headland_links.append(_ring_links(corner_path[-1].end, rings, moves, distance))
        transits.append(_transit_m(corner_path, rings, distance, turns, moves))
        clock.check("planning the moves between swaths")
    if fits.hops:
        notes.append(
            f"field {field_id!r}: {fits.hops} of {fits.planned + fits.hops} moves between "
            "swaths and onto the headland (all start corners) have no drivable path of "
            f"radius {radius:g} m inside the field; driven as hops (give the field more "
            "headland passes)"
        )

    cell_polys = tuple(_to_polygon(cell.outline, angle, ref) for cell in cells)
    n_swaths = len(paths[0])
    clock.check("measuring the land left unworked")
    unworked, block = _unworked_m2(field_poly, paths[0], headland_paths[0], w)
    if unworked > UNWORKED_WARN_SHARE * field_poly.area:
        notes.append(
            f"field {field_id!r}: {unworked:.0f} m2 ({100.0 * unworked / field_poly.area:.1f} %) "
            f"left unworked at a working width of {w:g} m: corners narrower than the swaths "
            "and the headland reach (give the field a work angle or more headland passes, "
            "or work those corners by hand)"
        )
    elif block > UNWORKED_BLOCK_WIDTHS * w * w:
        notes.append(
            f"field {field_id!r}: {block:.0f} m2 in one piece left unworked at a working width "
            f"of {w:g} m ({100.0 * unworked / field_poly.area:.1f} % of the field in all): "
            "the headland found no room there (a hole near the border, a narrow arm); work "
            "it by hand, or give the field another work angle"
        )
    if not quiet:
        for note in notes:
            logger.warning("%s", note)
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
        links=tuple(links),
        turn_paths=tuple(turn_paths) if radius > 0.0 else (),
        headland_moves=tuple(headland_moves) if radius > 0.0 else (),
        headland_links=tuple(headland_links),
        turn_radius_m=radius,
        headland_passes=passes,
        unworked_m2=unworked,
        notes=tuple(notes),
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


def headland_passes_for_turns(w: float, radius_m: float, spacing_m: float) -> int:
    """Headland passes that leave room for turns of ``radius_m`` between swaths
    ``spacing_m`` apart: 0 for hops (radius 0).

    With planned turns the swaths end on the headland's inner edge, ``p w`` from the
    border; the turn reaches ``e`` past the swath end (:func:`planner.turns.turn_excursion_m`)
    and the machine needs half a working width beside that, so ``e + w/2 <= p w``:
    ``p = ceil(e / w + 1/2)``.
    """
    if radius_m <= 0.0:
        return 0
    reach = turn_excursion_m(spacing_m, radius_m)
    return max(1, math.ceil(reach / w + 0.5 - 1e-9))


def _layout(
    field_poly: Polygon,
    w: float,
    passes: int,
    angle_deg: float | None,
    simplify_m: float | None,
    field_id: str,
    radius: float = 0.0,
    clock: _Clock | None = None,
) -> _Layout:
    """Headland rings, swath region, the area swath ends reach, swath angle, cells and the
    reference point of the swath frame."""
    clock = clock or _Clock(NO_DEADLINE, field_id, w, 0)
    rings_by_pass, region, lane = _headland_and_region(
        field_poly, w, passes, field_id, radius, clock
    )
    ref = np.array(region.centroid.coords[0])  # work near the origin for precision
    tolerance = SIMPLIFY_FRACTION * w if simplify_m is None else float(simplify_m)
    outline = _simplified(region, tolerance)
    edges = _edges(outline, ref)
    if angle_deg is None:
        angle, cells = _search_angle(outline, ref, edges, w, field_id, clock)
    else:
        angle = _normalise_angle(angle_deg)
        cells = _sweep(edges, angle, field_id).cells(w)
    clock.check("laying out the swaths")
    if cells:
        cells = _clip_lines(cells, _edges(region if lane is None else lane, ref), angle)
    if not cells:
        raise GeometryError(
            f"field {field_id!r}: no swath of working width {w:g} m fits in the field"
        )
    return rings_by_pass, region, lane, angle, cells, ref


def _unworked_m2(
    field_poly: Polygon,
    swaths: tuple[Swath, ...],
    rings: tuple[tuple[XY, ...], ...],
    w: float,
) -> tuple[float, float]:
    """The area of ``field_poly`` that no swath and no headland ring sweeps, each a strip
    ``w`` wide about its centre line: the slanted ends of swaths, and the corners too
    narrow for either (the apex of an acute corner, beyond the innermost ring); and the
    largest piece of it half a width across or more (a block the headland gave up on
    beside a hole near the border, the middle of a narrow arm), 0 when there is none."""
    strips = [LineString([s.start, s.end]).buffer(w / 2, cap_style="flat") for s in swaths]
    strips += [LineString(ring).buffer(w / 2, cap_style="flat") for ring in rings]
    if not strips:
        return float(field_poly.area), float(field_poly.area)
    with np.errstate(invalid="ignore"):
        left = field_poly.difference(shapely.union_all(strips))
        solid = left.buffer(-w / 4, join_style="mitre").buffer(w / 4, join_style="mitre")
    block = max((float(p.area) for p in _polygons(solid)), default=0.0)
    return float(left.area), block


def _layout_fitting_turns(
    field_poly: Polygon,
    w: float,
    passes: int,
    radius: float,
    angle_deg: float | None,
    simplify_m: float | None,
    field_id: str,
    clock: _Clock | None,
    notes: list[str],
) -> _Layout:
    """:func:`_layout` with as many headland passes as the turns need (each pass given up
    for want of room said in ``notes``).

    Sized first for swaths a full width apart, then again for the closest pair the layout
    gives (evenly spread swaths may be closer, down to half a width, and a bulb turn
    reaches further the closer they are). A field too small for that many passes gets as
    many as leave room for swaths; turns that then do not fit are driven as hops.
    """
    most = math.inf  # passes the field has room for, once some did not fit
    wanted = None  # the most passes tried that did not fit: said once, with what did
    while True:
        try:
            layout = _layout(field_poly, w, passes, angle_deg, simplify_m, field_id, radius, clock)
        except TimeLimitError:
            raise
        except GeometryError:
            if passes == 0:
                raise
            wanted = max(wanted or 0, passes)
            most = passes = passes - 1
            continue
        needed = min(headland_passes_for_turns(w, radius, _closest_swaths_m(layout[4], w)), most)
        if needed <= passes:
            if wanted is not None:
                notes.append(
                    f"field {field_id!r}: no room for {wanted} headland passes for turns of "
                    f"radius {radius:g} m; laid out with {passes}"
                )
            return layout
        passes = int(needed)


def _closest_swaths_m(cells: Sequence[_Cell], w: float) -> float:
    """The least distance between two neighbouring swaths of a cell (``w`` when no cell
    has two)."""
    gaps = [float(np.diff(c.lines[:, 0]).min()) for c in cells if len(c.lines) > 1]
    return min(gaps, default=w)


def _checked_radius(turn_radius_m: float, field_id: str) -> float:
    if (
        isinstance(turn_radius_m, bool)
        or not isinstance(turn_radius_m, Real)
        or not (math.isfinite(turn_radius_m) and turn_radius_m >= 0.0)
    ):
        raise GeometryError(
            f"field {field_id!r}: turn radius must be a number of metres >= 0,"
            f" got {turn_radius_m!r}"
        )
    return float(turn_radius_m)


# ----------------------------------------------------------------------------- checks


class _Clock:
    """One field's coverage against a :class:`~planner.errors.Deadline`: :meth:`check`
    raises :class:`~planner.errors.TimeLimitError` naming the field, its working width,
    its swaths across and what was being done once the deadline has passed."""

    __slots__ = ("_at", "across", "deadline", "field_id", "w")

    def __init__(self, deadline: Deadline, field_id: str, w: float, across: int) -> None:
        self.deadline, self.field_id, self.w, self.across = deadline, field_id, w, across
        self._at = deadline.at

    def check(self, doing: str) -> None:
        if self._at < math.inf and time.monotonic() >= self._at:
            self.deadline.check(
                f"field {self.field_id!r}: coverage at a working width of {self.w:g} m"
                f" ({self.across:,} swaths across)",
                doing,
            )

    def checked(self, value: _T, doing: str = "searching the swath angle") -> _T:
        """``value``, after :meth:`check` (for comprehensions)."""
        self.check(doing)
        return value


def _swaths_across(polygon: Polygon, w: float, angle_deg: float | None, field_id: str) -> int:
    """Working widths across the field, ``ceil(width / w)``: across the swath direction
    when it is given, else at the field's narrowest (the least any direction can take).
    More than :data:`MAX_SWATHS` raises :class:`GeometryError` at once."""
    hull = np.asarray(orient(polygon.convex_hull, sign=1.0).exterior.coords)[:-1]
    if angle_deg is None:
        across, how = _min_width_m(hull.tolist()), "across at its narrowest"
    else:
        t = math.radians(_normalise_angle(angle_deg))
        v = -hull[:, 0] * math.sin(t) + hull[:, 1] * math.cos(t)
        across, how = float(v.max() - v.min()), f"across its swath direction ({angle_deg:g} deg)"
    swaths = max(1, math.ceil(across / w - 1e-9))
    if swaths > MAX_SWATHS:
        raise GeometryError(
            f"field {field_id!r}: it is {across:,.1f} m {how}, {swaths:,} swaths at a working"
            f" width of {w:g} m; coverage is planned for at most {MAX_SWATHS:,}"
            " swaths across a field (planner.coverage.MAX_SWATHS): use a wider implement,"
            " or split the field"
        )
    return swaths


def _min_width_m(hull: list[list[float]]) -> float:
    """The least width of a convex polygon (vertices counter-clockwise, not closed) over
    every direction: rotating calipers, the least over its edges of the farthest vertex
    from the edge's line."""
    n = len(hull)
    if n < 3:
        return 0.0
    best = math.inf
    j = 1
    for i in range(n):
        (ax, ay), (bx, by) = hull[i], hull[(i + 1) % n]
        ex, ey = bx - ax, by - ay
        length = math.hypot(ex, ey)
        if length == 0.0:
            continue

        def height(k: int, ax: float = ax, ay: float = ay, ex: float = ex, ey: float = ey) -> float:
            return ex * (hull[k][1] - ay) - ey * (hull[k][0] - ax)

        while height((j + 1) % n) > height(j):
            j = (j + 1) % n
        best = min(best, height(j) / length)
    return best


def _check_corner(corner: int) -> int:
    if corner not in (0, 1, 2, 3) or isinstance(corner, bool):
        raise ValueError(f"corner must be 0, 1, 2 or 3, got {corner!r}")
    return int(corner)


def _checked_field(
    polygon: Polygon,
    working_width_m: float,
    headland_passes: int,
    angle_deg: float | None,
    simplify_m: float | None,
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
    if angle_deg is not None and not (isinstance(angle_deg, Real) and math.isfinite(angle_deg)):
        raise GeometryError(f"{where}: swath angle must be a finite number, got {angle_deg!r}")
    if simplify_m is not None and not (
        isinstance(simplify_m, Real) and math.isfinite(simplify_m) and simplify_m >= 0.0
    ):
        raise GeometryError(f"{where}: simplify_m must be a number >= 0, got {simplify_m!r}")
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
    widest = _widest_inside_m(polygon)
    convex = polygon.area >= CONVEX_SOLIDITY * polygon.convex_hull.area
    fraction = MIN_INSIDE_FRACTION if convex else 1.0
    if widest + 2.0 * _INSCRIBED_TOLERANCE_M < fraction * working_width_m:
        share = "a" if fraction == 1.0 else f"{fraction:g} of the"
        raise GeometryError(
            f"{where}: the field is nowhere {share} working width"
            f" {working_width_m:g} m wide (the widest circle inside it, holes and bends"
            f" counted, is {widest:.2f} m across)"
        )
    return orient(polygon, sign=1.0)


def _narrowest_m(polygon: Polygon) -> float:
    """Short side of the minimum rotated rectangle."""
    with np.errstate(divide="ignore", invalid="ignore"):  # GEOS on near-collinear outlines
        rect = shapely.minimum_rotated_rectangle(polygon)
    if not isinstance(rect, Polygon):  # a degenerate (line or point) outline
        return 0.0
    c = np.asarray(rect.exterior.coords)
    sides = np.hypot(*(c[1:3] - c[0:2]).T)
    return float(sides.min())


_INSCRIBED_TOLERANCE_M = 0.01


def _widest_inside_m(polygon: Polygon) -> float:
    """The diameter of the largest circle inside ``polygon`` (outside its holes), to within
    :data:`_INSCRIBED_TOLERANCE_M` below."""
    with np.errstate(divide="ignore", invalid="ignore"):  # GEOS on near-collinear outlines
        radius = shapely.maximum_inscribed_circle(polygon, tolerance=_INSCRIBED_TOLERANCE_M)
    return 2.0 * float(radius.length)


def _normalise_angle(angle_deg: float) -> float:
    angle = float(angle_deg) % 180.0
    return 0.0 if angle >= 180.0 - 1e-9 else angle + 0.0  # + 0.0 turns -0.0 into 0.0


# ----------------------------------------------------------------------------- headland


def _simplified(region: MultiPolygon, tolerance: float) -> MultiPolygon:
    """``region`` without the wiggles under ``tolerance`` that would each start a new cell.

    A convex region has no such wiggles and is kept as it is.
    """
    if tolerance <= 0.0 or _is_convex(region):
        return region
    simple = shapely.simplify(region, tolerance, preserve_topology=True)
    parts = [orient(p, sign=1.0) for p in _polygons(simple) if p.is_valid and p.area > 0.0]
    return MultiPolygon(parts) if parts else region


def _is_convex(region: MultiPolygon) -> bool:
    return len(region.geoms) == 1 and region.area >= region.convex_hull.area * (1 - 1e-9)


def _polygons(geom: shapely.Geometry) -> list[Polygon]:
    if isinstance(geom, Polygon):
        return [] if geom.is_empty else [geom]
    if isinstance(geom, MultiPolygon):
        return [p for p in geom.geoms if not p.is_empty]
    return [g for g in getattr(geom, "geoms", ()) if isinstance(g, Polygon) and not g.is_empty]


def _headland_and_region(
    field_poly: Polygon,
    w: float,
    passes: int,
    field_id: str,
    radius: float = 0.0,
    clock: _Clock | None = None,
) -> tuple[list[list[FloatArray]], MultiPolygon, MultiPolygon | None]:
    """Headland ring centre lines per pass (outer first), the region left for swaths and the
    area inside the innermost ring's centre line (``None`` without headland).

    With a turning radius the rings' convex corners are rounded to it (:func:`_rounded`)."""
    min_area = 0.01 * w * w
    if passes == 0:
        return [], MultiPolygon([field_poly]), None
    inner = field_poly.buffer(-passes * w, join_style="round")
    parts = [orient(p, sign=1.0) for p in _polygons(inner) if p.area >= min_area]
    if not parts:
        raise GeometryError(
            f"field {field_id!r}: {passes} headland passes of {w:g} m consume the whole field"
        )
    rings_by_pass: list[list[FloatArray]] = []
    for k in range(passes):
        if clock is not None:
            clock.check("laying out the headland")
        offset = field_poly.buffer(-(k + 0.5) * w, join_style="round")
        offset = _rounded(_simplified_ring(offset, min(RING_SIMPLIFY_M, w / 20.0)), radius)
        rings: list[FloatArray] = []
        for part in (orient(p, sign=1.0) for p in _polygons(offset)):
            rings.append(_without_short_edges(np.asarray(part.exterior.coords), MIN_RING_EDGE_M))
            rings.extend(
                _without_short_edges(np.asarray(hole.coords), MIN_RING_EDGE_M)
                for hole in part.interiors
            )
        rings_by_pass.append(rings)
    if clock is not None:
        clock.check("laying out the headland")
    if radius > 0.0:
        # Planned turns: swaths end on the headland's inner edge and the machine turns on
        # the headland, which is worked last (as Fields2Cover's mainland and headland).
        return rings_by_pass, MultiPolygon(parts), MultiPolygon(parts)
    # Hops: swaths run on to the innermost ring's centre line: the swath region grown by
    # half a width is inside that ring, and does not pass through necks the region lacks
    reach = MultiPolygon(parts).buffer(w / 2)
    return rings_by_pass, MultiPolygon(parts), MultiPolygon(_polygons(reach))


def _simplified_ring(offset: shapely.Geometry, tolerance: float) -> shapely.Geometry:
    """``offset`` within ``tolerance`` of itself with fewer corners (Douglas-Peucker), kept
    as it is should that change its parts or holes."""
    simple = shapely.simplify(offset, tolerance, preserve_topology=True)
    before, after = _polygons(offset), _polygons(simple)
    if len(after) != len(before) or sum(len(p.interiors) for p in after) != sum(
        len(p.interiors) for p in before
    ):
        return offset
    return simple


def _rounded(offset: shapely.Geometry, radius: float) -> shapely.Geometry:
    """``offset`` with its convex corners rounded to ``radius`` (a morphological opening:
    shrink by the radius, grow back with round joins), arc points as in
    :mod:`planner.turns`. Kept as it is when there is no radius or when the opening would
    drop a part (a neck narrower than two radii). Concave corners (around holes, at an
    inner corner of the outline) stay sharp."""
    if radius <= 0.0 or offset.is_empty:
        return offset
    segments = max(
        math.ceil(90.0 / ARC_STEP_DEG - 1e-9), math.ceil(math.pi / 2 * radius / ARC_STEP_M)
    )
    opened = offset.buffer(-radius, join_style="mitre").buffer(
        radius, join_style="round", quad_segs=segments
    )
    if len(_polygons(opened)) != len(_polygons(offset)) or opened.area < 0.5 * offset.area:
        return offset
    return opened


def _without_short_edges(ring: FloatArray, min_m: float) -> FloatArray:
    """A closed ring without the points within ``min_m`` of the point kept before them
    (its first point stays, and so it stays closed)."""
    if len(ring) < 4:
        return ring
    kept = [0]
    for k in range(1, len(ring) - 1):
        if math.dist(ring[k], ring[kept[-1]]) > min_m:
            kept.append(k)
    while len(kept) > 1 and math.dist(ring[kept[-1]], ring[-1]) <= min_m:
        kept.pop()
    kept.append(len(ring) - 1)
    return ring[kept] if len(kept) >= 4 else ring


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
    """The closed ``ring`` rotated to start and end at its point nearest ``point``; at a
    corner instead, where that point is within :data:`MIN_RING_EDGE_M` of one (cut there, an
    edge of 0.1 mm was left, a swath of no length the mission refused: the whole plan of a
    field with three ponds failed; an outside review)."""
    line = LineString(ring)
    along = line.project(Point(point))
    nearest = np.asarray(line.interpolate(along).coords[0])
    seg = np.hypot(*np.diff(ring, axis=0).T)
    i = int(np.clip(np.searchsorted(np.cumsum(seg), along, side="left"), 0, len(seg) - 1))
    for corner in (ring[i], ring[i + 1]):
        if math.dist(nearest, corner) < MIN_RING_EDGE_M:
            nearest = corner
    out = np.vstack([nearest, ring[i + 1 :], ring[1 : i + 1]])
    out = out[np.r_[True, np.hypot(*np.diff(out, axis=0).T) > _EPS_M]]
    if math.dist(out[-1], out[0]) <= _EPS_M:
        out = out[:-1]
    return np.vstack([out, out[:1]])


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
    region: MultiPolygon,
    ref: FloatArray,
    edges: _Edges,
    w: float,
    field_id: str,
    clock: _Clock | None = None,
) -> tuple[float, list[_Cell]]:
    """Swath direction with the fewest swaths, then the least uncovered area, then the
    shortest total swath length, then the smallest angle; and its cells.

    Every grid angle and long-edge direction is first counted with sweep lines shared by the
    whole region (exact for a convex region); for other regions the lowest estimates are
    decomposed exactly. Angles tied on the fewest swaths are compared by covered area.
    """
    clock = clock or _Clock(NO_DEADLINE, field_id, w, 0)
    length = np.hypot(edges.bx - edges.ax, edges.by - edges.ay)
    longest = np.argsort(-length, kind="stable")[:_EDGE_CANDIDATES]
    longest = longest[length[longest] >= min(w, float(length.max()))]
    edge_angles = np.degrees(
        np.arctan2(edges.by[longest] - edges.ay[longest], edges.bx[longest] - edges.ax[longest])
    )
    candidates = np.concatenate([np.arange(0.0, 180.0, ANGLE_STEP_DEG), edge_angles % 180.0])
    candidates[candidates >= 180.0 - 1e-9] = 0.0
    candidates = np.unique(np.round(candidates, 9))

    if _is_convex(region):
        estimate = _estimate_swaths(edges, candidates, w, clock)
        pool = np.lexsort((candidates, estimate))
        pool = pool[estimate[pool] == estimate[pool[0]]][:COVERAGE_CANDIDATES]
    else:  # rank on a lightly simplified outline, then decompose the best exactly
        coarse = shapely.simplify(region, 0.05 * w, preserve_topology=True)
        coarse_polys = [orient(p, sign=1.0) for p in _polygons(coarse)]
        coarse_edges = _edges(MultiPolygon(coarse_polys), ref) if coarse_polys else edges
        estimate = _estimate_swaths(coarse_edges, candidates, w, clock)
        pool = np.lexsort((candidates, estimate))[:EXACT_CANDIDATES]
        exact = np.array(
            [
                clock.checked(_sweep(edges, float(candidates[i]), field_id).count(w), "angles")
                for i in pool
            ]
        )
        fewest = exact[exact > 0].min() if np.any(exact > 0) else 0
        pool = pool[exact == fewest][:COVERAGE_CANDIDATES]

    finalists = [
        (float(candidates[i]), clock.checked(_sweep(edges, float(candidates[i]), field_id)))
        for i in pool
    ]
    if len(finalists) == 1:
        return finalists[0][0], finalists[0][1].cells(w)
    scored = []
    for angle, sweep in finalists:
        cells = sweep.cells(w)
        scored.append((_score(cells, w, float(region.area), clock), angle, cells))
    (_, _, _), angle, cells = min(scored, key=lambda item: (*item[0], item[1]))
    return angle, cells


def _score(
    cells: list[_Cell], w: float, area: float, clock: _Clock | None = None
) -> tuple[float, float, float]:
    """(swath count, uncovered area, total swath length) of ``cells``, rounded for ties.

    Each strip is clipped to its own cell (cells tile the region), less the overlap of each
    strip with its neighbour below in the cell (evenly spread swaths overlap a little).
    An overlay GEOS cannot compute scores the angle as covering nothing, and one with no
    swaths (a region too narrow at that angle) loses to any with some.
    """
    if not any(len(c.lines) for c in cells):
        return (math.inf, round(area, 2), 0.0)
    lines = np.vstack([c.lines for c in cells])
    total = round(float((lines[:, 2] - lines[:, 1]).sum()), 3)
    sizes = np.array([len(c.lines) for c in cells])
    outlines = np.repeat(np.array([Polygon(c.outline) for c in cells], dtype=object), sizes)
    not_first = np.ones(len(lines), dtype=bool)
    not_first[np.cumsum(sizes) - sizes] = False
    last = np.flatnonzero(not_first)  # every swath with its neighbour below in the cell
    before = last - 1
    overlaps = shapely.box(
        np.maximum(lines[last, 1], lines[before, 1]),
        lines[last, 0] - w / 2,
        np.minimum(lines[last, 2], lines[before, 2]),
        lines[before, 0] + w / 2,
    )
    real = (
        np.minimum(lines[last, 2], lines[before, 2]) > np.maximum(lines[last, 1], lines[before, 1])
    ) & (lines[before, 0] + w / 2 > lines[last, 0] - w / 2)
    strips = shapely.box(lines[:, 1], lines[:, 0] - w / 2, lines[:, 2], lines[:, 0] + w / 2)
    clock = clock or _Clock(NO_DEADLINE, "", w, 0)
    try:  # fixed precision: strip borders can coincide with cell borders to 1e-15
        covered = 0.0
        for k in range(0, len(strips), _SCORE_CHUNK):  # one chunk for a field of ≤ 2048 swaths
            part = slice(k, k + _SCORE_CHUNK)
            overlay = shapely.intersection(strips[part], outlines[part], grid_size=_GRID_M)
            covered += shapely.area(overlay).sum()
            clock.check("comparing swath angles")
        pairs, pair_outlines = overlaps[real], outlines[last][real]
        for k in range(0, max(len(pairs), 1), _SCORE_CHUNK):
            part = slice(k, k + _SCORE_CHUNK)
            doubled = shapely.intersection(pairs[part], pair_outlines[part], grid_size=_GRID_M)
            covered -= shapely.area(doubled).sum()
            clock.check("comparing swath angles")
    except shapely.errors.GEOSException as error:
        logger.debug("cannot score a swath angle: %s", error)
        covered = 0.0
    return (float(len(lines)), round(area - float(covered), 2), total)


def _estimate_swaths(
    edges: _Edges, angles_deg: FloatArray, w: float, clock: _Clock | None = None
) -> NDArray[np.int64]:
    """Sweep-line segment count for every angle, with sweep lines shared by the whole region.

    Lines are spread as in a cell (:func:`swath_offsets`) between the lowest and the
    highest vertex. A line meets an edge when it lies in the edge's
    half-open ``[low, high)`` span; each inside segment has two such crossings.
    """
    theta = np.radians(angles_deg)[:, None]
    c, s = np.cos(theta), np.sin(theta)
    va = -edges.ax * s + edges.ay * c
    vb = -edges.bx * s + edges.by * c
    lo = np.minimum(va.min(axis=1), vb.min(axis=1))
    hi = np.maximum(va.max(axis=1), vb.max(axis=1))
    n_lines = swath_counts(hi - lo, w)
    k = np.arange(int(n_lines.max()))[None, :]
    lines = lo[:, None] + swath_offsets((hi - lo)[:, None], n_lines[:, None], k, w)
    lines = np.where(k < n_lines[:, None], lines, np.nan)

    counts = np.zeros(len(angles_deg), dtype=np.int64)
    chunk = max(1, int(2_000_000 // max(1, va.shape[1] * lines.shape[1])))
    for start in range(0, len(angles_deg), chunk):
        sl = slice(start, start + chunk)
        y = lines[sl][:, None, :]  # (angles, 1, lines) against (angles, edges, 1)
        a, b = va[sl][:, :, None], vb[sl][:, :, None]
        cross = ((a <= y) & (y < b)) | ((b <= y) & (y < a))
        counts[sl] = cross.sum(axis=(1, 2)) // 2
        if clock is not None:
            clock.check("searching the swath angle")
    return counts


# ----------------------------------------------------------------------------- swath layout


def swath_counts(height: FloatArray, w: float) -> NDArray[np.int64]:
    """Swaths across cells ``height`` high: ``ceil(height / w)``, at least one, and one
    (centred) when two would be closer than ``MIN_SPACING_FRACTION * w``.

    With ``n = ceil(height / w) >= 3`` the even spacing ``(height - w) / (n - 1)`` is always
    above ``w / 2``; only two swaths in a cell under 1.5 widths high could be closer, and
    such a cell gets one swath in its middle instead, leaving a strip of at most
    ``w / 4`` unworked along each side.
    """
    height = np.asarray(height, dtype=np.float64)
    n = np.maximum(np.ceil(height / w - 1e-9), 1).astype(np.int64)
    too_close = (n == 2) & (height - w < MIN_SPACING_FRACTION * w - 1e-9)
    return np.where(too_close, 1, n)


def swath_offsets(
    height: FloatArray, n: NDArray[np.int64], k: NDArray[np.int64], w: float
) -> FloatArray:
    """Offset of swath ``k`` of ``n`` above the bottom of a cell ``height`` high.

    The first and last swaths lie half a width inside the cell's borders and the others
    are spread evenly between them, ``(height - w) / (n - 1)`` apart: never more than a
    width (no gap) and, with :func:`swath_counts`, never less than
    ``MIN_SPACING_FRACTION * w`` (no sliver). A single swath lies in the middle.
    """
    height = np.asarray(height, dtype=np.float64)
    spacing = (height - w) / np.maximum(n - 1, 1)
    return np.where(n > 1, w / 2 + k * spacing, height / 2)


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


@dataclass(frozen=True)
class _Sweep:
    """Boustrophedon decomposition of the swath region at one angle, in the swath frame.

    The region is cut at every vertex level into trapezoids bounded by two edges. A
    trapezoid continues its cell into the band above when it touches exactly one trapezoid
    there, that one touches only it, and their widths match at the shared level: a step
    parallel to the swaths starts a new cell with its own swath offsets.
    """

    levels: FloatArray  # sweep levels (v), increasing
    ua: FloatArray  # edge ends in the swath frame, v snapped to the levels
    va: FloatArray
    ub: FloatArray
    vb: FloatArray
    band: NDArray[np.int64]  # per trapezoid, sorted by band then u
    left: NDArray[np.int64]  # left and right edge of each trapezoid
    right: NDArray[np.int64]
    chain: NDArray[np.int64]  # trapezoids ordered by cell, bottom to top
    cell_start: NDArray[np.int64]  # offsets of each cell in ``chain`` (plus the end)

    def u_at(self, edge: NDArray[np.int64], v: FloatArray) -> FloatArray:
        """Abscissa of ``edge`` at level ``v`` (exact at its ends)."""
        va, vb, ua, ub = self.va[edge], self.vb[edge], self.ua[edge], self.ub[edge]
        dv = np.where(vb != va, vb - va, 1.0)
        u = ua + (v - va) * (ub - ua) / dv
        return np.where(v == va, ua, np.where(v == vb, ub, u))

    def _extent(self) -> tuple[FloatArray, FloatArray]:
        first = self.chain[self.cell_start[:-1]]
        last = self.chain[self.cell_start[1:] - 1]
        return self.levels[self.band[first]], self.levels[self.band[last] + 1]

    def count(self, w: float) -> int:
        """Number of swaths :meth:`cells` lays out (before dropping degenerate ones)."""
        bottom, top = self._extent()
        height = top - bottom
        n = swath_counts(height, w)
        return int(n[height >= MIN_CELL_FRACTION * w].sum())

    def cells(self, w: float) -> list[_Cell]:
        """Each cell's swath lines, spread evenly (:func:`swath_offsets`)."""
        bottom, top = self._extent()
        height = top - bottom
        n = swath_counts(height, w)
        n[height < MIN_CELL_FRACTION * w] = 0
        cell_of = np.repeat(np.arange(len(n)), n)
        k = np.arange(len(cell_of)) - np.repeat(np.cumsum(n) - n, n)
        ys = bottom[cell_of] + swath_offsets(height[cell_of], n[cell_of], k, w)
        first_band = self.band[self.chain[self.cell_start[:-1]]]
        last_band = self.band[self.chain[self.cell_start[1:] - 1]]
        band = np.clip(
            np.searchsorted(self.levels, ys, side="right") - 1,
            first_band[cell_of],
            last_band[cell_of],
        )
        trap = self.chain[self.cell_start[cell_of] + band - first_band[cell_of]]
        u_left, u_right = self.u_at(self.left[trap], ys), self.u_at(self.right[trap], ys)
        keep = u_right - u_left > MIN_SWATH_M

        cells: list[_Cell] = []
        for c in np.unique(cell_of[keep]):
            mine = keep & (cell_of == c)
            traps = self.chain[self.cell_start[c] : self.cell_start[c + 1]]
            v_levels = np.append(self.levels[self.band[traps]], top[c])
            lefts = np.append(self.left[traps], self.left[traps[-1]])
            rights = np.append(self.right[traps], self.right[traps[-1]])
            outline = np.vstack(
                [
                    np.column_stack([self.u_at(lefts, v_levels), v_levels]),
                    np.column_stack([self.u_at(rights, v_levels), v_levels])[::-1],
                ]
            )
            cells.append(_Cell(np.column_stack([ys, u_left, u_right])[mine], outline))
        return cells


def _sweep(edges: _Edges, angle_deg: float, field_id: str) -> _Sweep:
    """Decompose the region bounded by ``edges`` for swaths along ``angle_deg``."""
    ua, va = _rotate(edges.ax, edges.ay, angle_deg)
    ub, vb = _rotate(edges.bx, edges.by, angle_deg)
    levels, snapped = _snap_levels(np.concatenate([va, vb]))
    va, vb = snapped[: len(va)], snapped[len(va) :]
    lo = np.searchsorted(levels, np.minimum(va, vb))
    hi = np.searchsorted(levels, np.maximum(va, vb))
    span = hi - lo
    edge_of = np.repeat(np.arange(len(ua)), span)
    band_of = lo[edge_of] + np.arange(len(edge_of)) - np.repeat(np.cumsum(span) - span, span)
    partial = _Sweep(levels, ua, va, ub, vb, *(np.empty(0, np.int64),) * 5)
    mid = (levels[band_of] + levels[band_of + 1]) / 2
    order = np.lexsort((partial.u_at(edge_of, mid), band_of))
    left, right = order[0::2], order[1::2]
    if len(left) != len(right) or np.any(band_of[left] != band_of[right]):
        raise GeometryError(
            f"field {field_id!r}: the outline has features under {_SNAP_M * 1000:g} mm"
            " that cannot be decomposed; simplify it"
        )
    band, tl, tr = band_of[left], edge_of[left], edge_of[right]
    top = levels[band + 1]
    bot_l, bot_r = partial.u_at(tl, levels[band]), partial.u_at(tr, levels[band])
    top_l, top_r = partial.u_at(tl, top), partial.u_at(tr, top)

    # link each trapezoid to those of the band below whose intervals overlap its own; per
    # band the intervals are disjoint and sorted, so the overlapping ones are contiguous
    span_u = float(max(np.abs(ua).max(), np.abs(ub).max())) * 2 + 1.0
    key_l = band * span_u * 2 + top_l
    key_r = band * span_u * 2 + top_r
    below = (band - 1) * span_u * 2
    first = np.searchsorted(key_r, below + bot_l + _EPS_M, side="right")
    last = np.searchsorted(key_l, below + bot_r - _EPS_M, side="left") - 1
    has_below = band > 0
    first = np.where(has_below, np.maximum(first, np.searchsorted(band, band - 1)), 0)
    last = np.where(has_below, np.minimum(last, np.searchsorted(band, band) - 1), -1)
    n_links = np.maximum(last - first + 1, 0)
    upper = np.repeat(np.arange(len(band)), n_links)
    lower = (
        np.repeat(first, n_links)
        + np.arange(len(upper))
        - np.repeat(np.cumsum(n_links) - n_links, n_links)
    )
    real = (top_r[lower] - top_l[lower] > _EPS_M) & (bot_r[upper] - bot_l[upper] > _EPS_M)
    upper, lower = upper[real], lower[real]
    n_up = np.bincount(lower, minlength=len(band))
    n_down = np.bincount(upper, minlength=len(band))
    same_width = (np.abs(top_l[lower] - bot_l[upper]) <= 10 * _EPS_M) & (
        np.abs(top_r[lower] - bot_r[upper]) <= 10 * _EPS_M
    )
    merge = (n_up[lower] == 1) & (n_down[upper] == 1) & same_width
    below_of = np.full(len(band), -1)
    below_of[upper[merge]] = lower[merge]

    cell_of = np.empty(len(band), dtype=np.int64)
    n_cells = 0
    for t, b in enumerate(below_of.tolist()):  # sorted by band: the one below comes first
        if b < 0:
            cell_of[t] = n_cells
            n_cells += 1
        else:
            cell_of[t] = cell_of[b]
    chain = np.lexsort((band, cell_of))
    cell_start = np.searchsorted(cell_of[chain], np.arange(n_cells + 1))
    return _Sweep(levels, ua, va, ub, vb, band, tl, tr, chain, cell_start)


def _clip_lines(cells: list[_Cell], clip: _Edges, angle_deg: float) -> list[_Cell]:
    """Cells whose swath lines end where the line leaves ``clip`` around its middle.

    Lines are laid out on the simplified outline; this puts their ends on the real one (or,
    with headland, on the innermost ring's centre line). Lines whose middle falls outside
    ``clip`` are dropped, and so are cells left without lines.
    """
    ua, va = _rotate(clip.ax, clip.ay, angle_deg)
    ub, vb = _rotate(clip.bx, clip.by, angle_deg)
    slope = np.divide(ub - ua, vb - va, out=np.zeros_like(ua), where=vb != va)
    lines = np.vstack([c.lines for c in cells])
    v, mid = lines[:, 0], lines[:, 1:].mean(axis=1)
    a, b = va[:, None], vb[:, None]
    cross = ((a <= v) & (v < b)) | ((b <= v) & (v < a))  # (edges, lines), half-open spans
    u = ua[:, None] + (v - a) * slope[:, None]
    before = cross & (u <= mid)
    left = np.where(before, u, -np.inf).max(axis=0)
    right = np.where(cross & ~before, u, np.inf).min(axis=0)
    keep = (before.sum(axis=0) % 2 == 1) & (right - left > MIN_SWATH_M)
    clipped = np.column_stack([v, left, right])
    out: list[_Cell] = []
    for cell, rows, kept in zip(
        cells,
        np.split(clipped, np.cumsum([len(c.lines) for c in cells])[:-1]),
        np.split(keep, np.cumsum([len(c.lines) for c in cells])[:-1]),
        strict=True,
    ):
        if np.any(kept):
            out.append(_Cell(rows[kept], cell.outline))
    return out


def _to_polygon(outline: FloatArray, angle: float, ref: FloatArray) -> Polygon:
    x, y = _unrotate(outline[:, 0], outline[:, 1], angle)
    return Polygon(np.column_stack([x + ref[0], y + ref[1]]))


# ----------------------------------------------------------------------------- driving order


def _cell_order(n: int, from_top: bool, skip: bool) -> NDArray[np.int64]:
    """Indices of a cell's ``n`` lines in driving order: neighbour after neighbour, or
    skipping a row (every other line out, the ones between on the way back)."""
    if skip and n >= 3:
        idx = np.concatenate([np.arange(0, n, 2), np.arange(1, n, 2)[::-1]])
    else:
        idx = np.arange(n)
    return (n - 1 - idx) if from_top else idx


def _cell_swaths(cell: _Cell, from_top: bool, reverse_first: bool, skip: bool) -> FloatArray:
    """Rows ``u_start, u_end, v, index`` of one cell driven back and forth."""
    n = len(cell.lines)
    idx = _cell_order(n, from_top, skip)
    forward = (np.arange(n) % 2 == 0) != reverse_first
    v, ul, ur = cell.lines[idx, 0], cell.lines[idx, 1], cell.lines[idx, 2]
    return np.column_stack([np.where(forward, ul, ur), np.where(forward, ur, ul), v, idx])


def _skips_rows(cell: _Cell, radius: float, clock: _Clock | None = None) -> bool:
    """Whether driving every other line out and the others back turns less than going
    from neighbour to neighbour, for a machine that turns on ``radius`` (never for hops).

    Neighbours closer than two radii need bulb turns; lines two apart are twice as far
    apart and may allow U-turns, at the price of one bulb turn where the order comes back.
    """
    if radius <= 0.0 or len(cell.lines) < 3:
        return False

    def turning_m(rows: FloatArray) -> float:
        total = 0.0
        for a, b in zip(rows[:-1], rows[1:], strict=True):
            if clock is not None:
                clock.check("choosing the swath order for the turns")
            heading = (1.0 if a[1] > a[0] else -1.0, 0.0)
            try:
                total += plan_turn((a[1], a[2]), heading, (b[0], b[2]), radius).length_m
            except GeometryError:
                return math.inf
        return total

    neighbours = turning_m(_cell_swaths(cell, False, False, False))
    return turning_m(_cell_swaths(cell, False, False, True)) < neighbours - 1e-6


def _drive(
    cells: Sequence[_Cell],
    corner: int,
    angle: float,
    ref: FloatArray,
    skips: Sequence[bool] = (),
) -> tuple[Swath, ...]:
    """Swaths from ``corner``: the cell whose entry is nearest that corner of the swaths'
    bounding box first, entered as the corner says; then, greedily, the cell and entry
    nearest to where the previous cell was left. ``skips`` says which cells are driven
    skipping a row (:func:`_skips_rows`)."""
    skip = list(skips) or [False] * len(cells)
    every = np.vstack([c.lines for c in cells])
    u_min, u_max = float(every[:, 1].min()), float(every[:, 2].max())
    v_min, v_max = float(every[:, 0].min()), float(every[:, 0].max())
    target = np.array([[u_min, v_min], [u_max, v_min], [u_max, v_max], [u_min, v_max]][corner])
    orientations = [_CORNER_ORIENTATION[corner]] + [
        o for o in _CORNER_ORIENTATION if o != _CORNER_ORIENTATION[corner]
    ]
    # entry and exit point of every cell in every orientation: (cells, 4, 2)
    entries = np.empty((len(cells), 4, 2))
    exits = np.empty((len(cells), 4, 2))
    for ci, cell in enumerate(cells):
        n = len(cell.lines)
        odd = n % 2 == 1
        for oi, (from_top, reverse_first) in enumerate(orientations):
            order = _cell_order(n, from_top, skip[ci])
            first, last = cell.lines[order[0]], cell.lines[order[-1]]
            entries[ci, oi] = (first[2] if reverse_first else first[1], first[0])
            ends_forward = reverse_first != odd  # the last swath drives +u
            exits[ci, oi] = (last[2] if ends_forward else last[1], last[0])

    gaps = np.hypot(*(entries[:, 0] - target).T)
    current = int(np.argmin(gaps))  # ties: the lowest cell index
    sequence = [(current, 0)]
    done = np.zeros(len(cells), dtype=bool)
    done[current] = True
    for _ in range(len(cells) - 1):
        position = exits[current, sequence[-1][1]]
        gaps = np.hypot(entries[..., 0] - position[0], entries[..., 1] - position[1])
        gaps[done] = np.inf
        current, oi = divmod(int(np.argmin(gaps)), 4)
        sequence.append((current, oi))
        done[current] = True

    rows = np.vstack([_cell_swaths(cells[ci], *orientations[oi], skip[ci]) for ci, oi in sequence])
    cell_ids = np.concatenate([np.full(len(cells[ci].lines), ci) for ci, _ in sequence])
    x0, y0 = _unrotate(rows[:, 0], rows[:, 2], angle)
    x1, y1 = _unrotate(rows[:, 1], rows[:, 2], angle)
    rx, ry = float(ref[0]), float(ref[1])
    return tuple(
        Swath((xa + rx, ya + ry), (xb + rx, yb + ry), c, i)
        for xa, ya, xb, yb, c, i in zip(
            x0.tolist(),
            y0.tolist(),
            x1.tolist(),
            y1.tolist(),
            cell_ids.tolist(),
            rows[:, 3].astype(np.int64).tolist(),
            strict=True,
        )
    )


def _transit_m(
    path: tuple[Swath, ...],
    rings: tuple[tuple[XY, ...], ...],
    distance: _InFieldDistance,
    turns: tuple[tuple[XY, ...], ...] = (),
    moves: tuple[tuple[XY, ...], ...] = (),
) -> float:
    total = 0.0
    for k, (before, after) in enumerate(zip(path[:-1], path[1:], strict=True)):
        if before.cell != after.cell and not (k < len(turns) and turns[k]):
            total += distance(before.end, after.start)
    position = path[-1].end
    for i, ring in enumerate(rings):
        via = moves[i] if i < len(moves) else ()
        if via:
            total += LineString([position, *via, ring[0]]).length
        else:
            total += distance(position, ring[0])
        position = ring[-1]
    return total


def _ring_links(
    position: XY,
    rings: tuple[tuple[XY, ...], ...],
    moves: tuple[tuple[XY, ...], ...],
    distance: _InFieldDistance,
) -> tuple[tuple[XY, ...], ...]:
    """For each ring, the in-field path's corners from where the machine was onto its
    start when no planned path leads there (:attr:`FieldCoverage.headland_links`)."""
    links: list[tuple[XY, ...]] = []
    for i, ring in enumerate(rings):
        planned = i < len(moves) and bool(moves[i])
        links.append(() if planned else distance.route(position, ring[0])[1])
        position = ring[-1]
    return tuple(links)


def _heading(swath: Swath) -> float:
    return math.atan2(swath.end[1] - swath.start[1], swath.end[0] - swath.start[0])


class _TurnsInside:
    """Drivable paths of radius ``radius`` for the moves between swaths and onto the
    headland rings, kept only when they stay inside the field (else the move is a hop,
    counted in ``hops``).

    A move between neighbouring swaths of a cell (or two rows apart) is a U-turn or a bulb
    turn (:func:`planner.turns.plan_turn`); any other move (another cell, around a notch)
    and a turn that does not fit try Dubins' paths from the swath's end to the next start,
    shortest first.
    """

    def __init__(self, field_poly: Polygon, radius: float, clock: _Clock | None = None) -> None:
        self._inside = field_poly.buffer(1e-3, join_style="mitre")
        shapely.prepare(self._inside)
        self.radius = radius
        self.planned = 0
        self.hops = 0
        self._clock = clock or _Clock(NO_DEADLINE, "", 1.0, 0)

    def _fits(self, a: XY, via: tuple[XY, ...], b: XY) -> bool:
        return bool(self._inside.covers(LineString([a, *via, b])))

    def turns(
        self, path: tuple[Swath, ...], links: tuple[tuple[XY, ...], ...]
    ) -> tuple[tuple[XY, ...], ...]:
        return tuple(
            self._turn(before, after, link)
            for before, after, link in zip(path[:-1], path[1:], links, strict=True)
        )

    def _turn(self, before: Swath, after: Swath, link: tuple[XY, ...]) -> tuple[XY, ...]:
        self._clock.check("planning the turns")
        heading = np.subtract(before.end, before.start)
        if (
            before.cell == after.cell
            and abs(before.index - after.index) <= 2
            and not link
            and float(np.dot(heading, np.subtract(after.end, after.start))) < 0.0
        ):
            try:
                turn = plan_turn(
                    before.end, (float(heading[0]), float(heading[1])), after.start, self.radius
                )
            except GeometryError:
                pass
            else:
                if self._fits(before.end, turn.points, after.start):
                    self.planned += 1
                    return turn.points
        for path in dubins_paths(
            before.end, _heading(before), after.start, _heading(after), self.radius
        ):
            if self._fits(before.end, path.points, after.start):
                self.planned += 1
                return path.points
        self.hops += 1
        return ()

    def enter_rings(
        self, rings_by_pass: list[list[FloatArray]], position: XY, heading: float
    ) -> tuple[tuple[tuple[XY, ...], ...], tuple[tuple[XY, ...], ...]]:
        """The rings innermost pass first, each started (and driven in the direction) where
        the shortest drivable path from the machine's pose joins it, and those paths.

        Candidate joins are points every half radius along the ring, within a few radii of
        the machine, in either direction; a ring no path reaches is started at its point
        nearest the machine, as without a radius."""
        ordered: list[tuple[XY, ...]] = []
        moves: list[tuple[XY, ...]] = []
        pos, head = np.asarray(position, dtype=np.float64), heading
        for rings in reversed(rings_by_pass):
            left = list(range(len(rings)))
            while left:
                gaps = shapely.distance(Point(pos), [LineString(rings[i]) for i in left])
                ring = rings[left.pop(int(np.argmin(gaps)))]
                joined = self._join(ring, pos, head)
                if joined is None:
                    self.hops += 1
                    ring = _start_ring_near(ring, pos)
                    via: tuple[XY, ...] = ()
                else:
                    ring, via = joined
                    self.planned += 1
                ordered.append(tuple((float(x), float(y)) for x, y in ring))
                moves.append(via)
                pos = ring[-1]
                head = math.atan2(ring[-1][1] - ring[-2][1], ring[-1][0] - ring[-2][0])
        return tuple(ordered), tuple(moves)

    def _join(
        self, ring: FloatArray, pos: FloatArray, head: float
    ) -> tuple[FloatArray, tuple[XY, ...]] | None:
        r = self.radius
        edges = np.diff(ring, axis=0)
        lengths = np.hypot(*edges.T)
        ends = np.cumsum(lengths)
        along = np.arange(0.0, float(ends[-1]), max(0.5, r / 2))
        edge = np.clip(np.searchsorted(ends, along, side="right"), 0, len(edges) - 1)
        into = along - (ends[edge] - lengths[edge])
        # no start within a centimetre of a vertex: it would leave a sliver of an edge
        at_end = lengths[edge] - into < MIN_GAP_M
        edge = np.where(at_end, (edge + 1) % len(edges), edge)
        into = np.where(at_end | (into < MIN_GAP_M), 0.0, into)
        points = ring[edge] + (into / np.maximum(lengths[edge], 1e-12))[:, None] * edges[edge]
        gaps = np.hypot(*(points - pos).T)
        near = gaps <= 6.0 * r + 10.0
        start = (float(pos[0]), float(pos[1]))
        # Shortest drivable path first. A path is never shorter than the straight line to
        # its end, so candidates are taken nearest first and a path found is tried as soon
        # as no candidate left can beat it: the same choice as sorting every path, with far
        # fewer paths computed.
        found: list[tuple[float, int, DubinsPath, bool, FloatArray]] = []
        for k in np.flatnonzero(near)[np.argsort(gaps[near], kind="stable")]:
            self._clock.check("planning the way onto the headland")
            while found and found[0][0] < gaps[k]:
                fitting = self._first_fitting(found, start, ring)
                if fitting is not None:
                    return fitting
            point, tangent = points[k], edges[edge[k]]
            forward = math.atan2(tangent[1], tangent[0])
            # Driven reversed from a vertex, the ring goes on along the edge before it
            # (a headland ring's sharp corner: the way in joined it at the wrong angle).
            back = edges[edge[k] - 1] if into[k] == 0.0 else tangent
            backward = math.atan2(-back[1], -back[0])
            target = (float(point[0]), float(point[1]))
            paths = [
                (reverse, path)
                for reverse, h in ((False, forward), (True, backward))
                for path in dubins_paths(start, head, target, h, r)[:2]
            ]
            for n, (reverse, path) in enumerate(paths):
                # ties go to the candidate earlier along the ring, as a stable sort would
                heapq.heappush(found, (path.length_m, 4 * int(k) + n, path, reverse, point))
        while found:
            self._clock.check("planning the way onto the headland")
            fitting = self._first_fitting(found, start, ring)
            if fitting is not None:
                return fitting
        return None

    def _first_fitting(
        self,
        found: list[tuple[float, int, DubinsPath, bool, FloatArray]],
        start: XY,
        ring: FloatArray,
    ) -> tuple[FloatArray, tuple[XY, ...]] | None:
        """Pop the shortest path found; the ring started there and the path when it fits."""
        _, _, path, reverse, point = heapq.heappop(found)
        if self._fits(start, path.points, path.end):
            return _start_ring_near(ring[::-1] if reverse else ring, point), path.points
        return None


class _InFieldDistance:
    """Shortest driving distance between two points without leaving the field.

    Straight when the segment stays inside; otherwise Dijkstra over the field's visibility
    graph, whose nodes are the vertices where the free space is reflex (exterior vertices
    turning right, hole vertices turning right in the holes' clockwise order).
    """

    def __init__(self, field_poly: Polygon, clock: _Clock | None = None) -> None:
        self._clock = clock or _Clock(NO_DEADLINE, "", 1.0, 0)
        self._inside = field_poly.buffer(1e-3, join_style="mitre")
        shapely.prepare(self._inside)
        corners: list[FloatArray] = []
        for ring in (field_poly.exterior, *field_poly.interiors):  # exterior CCW, holes CW
            c = np.asarray(ring.coords)[:-1]
            into, out = c - np.roll(c, 1, axis=0), np.roll(c, -1, axis=0) - c
            turn = into[:, 0] * out[:, 1] - into[:, 1] * out[:, 0]
            corners.append(c[turn < 0.0])
        self._nodes = np.vstack(corners)
        self._graph: FloatArray | None = None
        self._known: dict[tuple[XY, XY], tuple[float, tuple[XY, ...]]] = {}

    def _visible(self, a: FloatArray, b: FloatArray) -> NDArray[np.bool_]:
        a, b = np.broadcast_arrays(a, b)
        lines = shapely.linestrings(np.stack([a, b], axis=-2))
        return np.asarray(shapely.covers(self._inside, lines), dtype=bool)

    def _node_graph(self) -> FloatArray:
        if self._graph is None:
            n = len(self._nodes)
            graph = np.full((n, n), np.inf)
            i_all, j_all = np.triu_indices(n, k=1)
            for k in range(0, len(i_all), _GRAPH_CHUNK):
                self._clock.check("finding the ways around holes and notches")
                i, j = i_all[k : k + _GRAPH_CHUNK], j_all[k : k + _GRAPH_CHUNK]
                ok = self._visible(self._nodes[i], self._nodes[j])
                d = np.hypot(*(self._nodes[i] - self._nodes[j]).T)
                graph[i[ok], j[ok]] = d[ok]
                graph[j[ok], i[ok]] = d[ok]
            self._graph = graph
        return self._graph

    def __call__(self, a: XY, b: XY) -> float:
        return self.route(a, b)[0]

    def route(self, a: XY, b: XY) -> tuple[float, tuple[XY, ...]]:
        """Length of the shortest in-field path from ``a`` to ``b`` and the corners it
        turns at (empty when the straight line stays inside)."""
        if (a, b) not in self._known:
            self._clock.check("finding the ways between swaths")
            self._known[a, b] = self._shortest(np.asarray(a), np.asarray(b))
        return self._known[a, b]

    def _shortest(self, a: FloatArray, b: FloatArray) -> tuple[float, tuple[XY, ...]]:
        straight = float(np.hypot(*(b - a)))
        if straight < _EPS_M or self._visible(a, b):
            return straight, ()
        nodes = self._nodes
        if len(nodes) == 0:
            logger.warning("no in-field path from %s to %s; counting the straight line", a, b)
            return straight, ()
        graph = self._node_graph()
        to_b = np.where(self._visible(nodes, b), np.hypot(*(nodes - b).T), np.inf)
        dist = np.where(self._visible(a, nodes), np.hypot(*(nodes - a).T), np.inf)
        previous = np.full(len(nodes), -1, dtype=np.int64)  # -1: reached straight from a
        settled = np.zeros(len(nodes), dtype=bool)
        best, last = math.inf, -1
        while True:  # dense Dijkstra, stopped once no unsettled node can improve on best
            self._clock.check("finding the ways between swaths")
            tentative = np.where(settled, np.inf, dist)
            i = int(np.argmin(tentative))
            if tentative[i] >= best:
                break
            settled[i] = True
            if dist[i] + to_b[i] < best:
                best, last = float(dist[i] + to_b[i]), i
            through = dist[i] + graph[i]
            better = through < dist
            previous[better] = i
            dist = np.where(better, through, dist)
        if not math.isfinite(best):
            logger.warning("no in-field path from %s to %s; counting the straight line", a, b)
            return straight, ()
        via: list[XY] = []
        while last >= 0:
            via.append((float(nodes[last][0]), float(nodes[last][1])))
            last = int(previous[last])
        return best, tuple(reversed(via))
