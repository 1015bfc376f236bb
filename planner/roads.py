"""Transit between fields: along the farm's roads, or around the other fields.

:class:`TransitNetwork` answers ``route(a, b, from_field, to_field) -> (length_m, via)``:
the shortest drive from ``a`` (a point of field ``from_field``, or off the fields when
``None``, e.g. the garage) to ``b``, in the farm's local metric frame. ``via`` holds the
points strictly between ``a`` and ``b``.

With roads (:attr:`planner.farm.Farm.roads`) the road polylines are noded where they cross
and where the garage, the gates and the fields without a gate hang on them, giving a graph
whose edges weigh their length. A route is then

    a -> (inside from_field) -> gate -> access -> roads -> access -> gate -> (inside) -> b,

taking the pair of gates that gives the shortest total. A field without a gate is entered at
the point of its boundary nearest the roads, the garage and the gates reach the nearest road
point by a straight access segment. Where those access segments, driven off the roads, are
longer than the whole way around the fields (a road far from both ends), the route goes
around the fields instead; a garage or field more than :data:`FAR_FROM_ROADS_M` from the
roads is warned of. The legs inside a field are straight when that stays
inside, else go around notches and holes (:class:`FieldInterior`). One Dijkstra per gate and
the garage is run once, up front; the routes themselves are cached.

Without roads (or when the roads do not connect two fields) a route goes around the other
fields: the shortest path in the plane with every field, grown by :data:`CLEARANCE_M`, as an
obstacle, except ``from_field`` for the leg that leaves it and ``to_field`` for the leg that
enters it (a visibility graph over the obstacles' convex corners, all pairs precomputed).
A field with declared gates is left and entered through one of them there too, whichever
gives the shortest route: inside the field to the gate, straight out to a point
:data:`DOOR_M` beyond the clearance, and around every field from there, its own included
(a fenced field is not crossed to reach the far side of it).
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
from collections.abc import Callable, Sequence
from collections.abc import Set as AbstractSet
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely
from numpy.typing import NDArray
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import shortest_path
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient
from shapely.ops import nearest_points, substring

from planner.coverage import _InFieldDistance
from planner.farm import CROSSING_M, Farm

log = logging.getLogger(__name__)

XY = tuple[float, float]
FloatArray = NDArray[np.float64]
Route = tuple[float, tuple[XY, ...]]  # length in metres, points strictly between the ends

CLEARANCE_M = 1.0  # fields grow by this much as obstacles to free-space transit
ROAD_JOIN_M = 0.5  # a road ending this close to another road (or its end) joins it
ROAD_SIMPLIFY_M = 0.5  # roads are simplified to within this (Douglas-Peucker) before use
# ... and each stretch between junctions to within this once they are joined (its ends,
# the junctions, kept): a GPS-logged track wanders a metre either way (at 0.5 m a 740 m
# track of ±0.8 m noise kept 1 441 waypoints a leg and drove 8.6 km for 2.6: review).
ROAD_SMOOTH_M = 2.0
DOOR_M = 0.5  # off the roads, a gated field is left this far beyond CLEARANCE_M of its gate
MANY_CORNERS = 64  # a field outline of more corners is simplified as an obstacle (_grown)
FAR_FROM_ROADS_M = 100.0  # a garage or field farther than this from the roads is said so
_SAME_M = 1e-6  # points closer than this are one
_TOUCH_M = 1e-3  # obstacles shrink by this much so that running along their edge is allowed


class FieldInterior:
    """Shortest paths without leaving one field (the coverage's visibility-graph router)."""

    def __init__(self, polygon: Polygon) -> None:
        self.polygon = polygon
        self._router = _InFieldDistance(polygon)
        self._inside = polygon.buffer(_TOUCH_M, join_style="mitre")
        shapely.prepare(self._inside)

    def route(self, a: XY, b: XY) -> Route:
        """Length and corners of the shortest in-field path from ``a`` to ``b``; a point
        outside the field is joined straight from the field's boundary point nearest it."""
        a_in, b_in = self._snap(a), self._snap(b)
        length, via = self._router.route(a_in, b_in)
        points = [a_in, *via, b_in]
        total = length + math.dist(a, a_in) + math.dist(b_in, b)
        return total, _strictly_between(a, points, b)

    def _snap(self, p: XY) -> XY:
        if self._inside.covers(Point(p)):
            return p
        q = nearest_points(self.polygon.boundary, Point(p))[0]
        return (float(q.x), float(q.y))


@dataclass(frozen=True)
class _Exit:
    """One way from a point of a route's end into free space or from there to it: the
    point in free space (``at``), the obstacle it may cross (``own``: its field, or none
    once out through a gate), the length up to it and the points strictly between."""

    at: XY
    own: int | None
    length_m: float
    via: tuple[XY, ...]


@dataclass(frozen=True)
class _Option:
    """One way onto the road graph from an end of a route: which node, how far, through what
    (the points strictly after the route's start up to the node, or from the node up to
    strictly before its end)."""

    node: int
    length_m: float
    via: tuple[XY, ...]
    off_road_m: float  # of length_m, what is driven off the roads (the access leg)


class _RoadGraph:
    """The roads as a weighted graph, noded at crossings and where ``anchors`` hang on."""

    def __init__(
        self,
        roads: Sequence[LineString],
        anchors: Sequence[XY],
        access: Callable[[int, XY, XY], tuple[XY, ...]] | None = None,
        fields: BaseGeometry | None = None,
    ) -> None:
        """``roads`` with their ends joined (:func:`joined`); ``access(k, p, q)``: the points
        strictly between anchor ``k`` at ``p`` and the road point ``q`` it hangs on (default:
        none, a straight segment). An anchor hangs on the nearest road point outside
        ``fields`` when there is one (a road ending inside a field drew the gates of the
        fields beside it across that field to its end)."""
        merged = shapely.unary_union(roads)
        segments = [
            g.simplify(ROAD_SMOOTH_M) for g in shapely.get_parts(merged) if g.length > _SAME_M
        ]
        pieces, piece_of = _outside(segments, fields)
        self.graph: nx.Graph = nx.Graph()
        self.xy: list[XY] = []
        self._ids: dict[tuple[float, float, int | None], int] = {}
        self._dijkstra: dict[int, tuple[dict[int, list[int]], dict[int, float]]] = {}
        tree = shapely.STRtree(pieces)
        cuts: dict[int, list[tuple[float, int]]] = {k: [] for k in range(len(segments))}
        self.anchor_nodes: list[int] = []
        self.access_m: dict[int, float] = {}  # per anchor node, its way onto the roads
        for n, p in enumerate(anchors):
            nearest = int(tree.query_nearest(Point(p))[0])
            k = piece_of[nearest]
            seg = segments[k]
            along = float(seg.project(nearest_points(pieces[nearest], Point(p))[0]))
            q = seg.interpolate(along)
            on_road = self._node((float(q.x), float(q.y)))
            cuts[k].append((along, on_road))
            # A node of its own: gates of two fields at one point (a corner they share)
            # have each their own way onto the road (one's, around a field in the way,
            # gave way to the other's straight one, shorter, across it).
            here = self._node(p, anchor=n)
            if here != on_road:
                via = () if access is None else access(n, p, self.xy[on_road])
                self._edge(here, on_road, (p, *via, self.xy[on_road]))
            self.access_m[here] = (
                float(self.graph.edges[here, on_road]["weight"]) if here != on_road else 0.0
            )
            self.anchor_nodes.append(here)
        for k, seg in enumerate(segments):
            coords = list(seg.coords)
            stops = sorted(
                [(0.0, self._node(coords[0])), (seg.length, self._node(coords[-1]))] + cuts[k]
            )
            for (d0, u), (d1, v) in zip(stops[:-1], stops[1:], strict=True):
                if u != v and d1 - d0 > _SAME_M:
                    piece = coords if (d0, d1) == (0.0, seg.length) else substring(seg, d0, d1)
                    pts = piece if isinstance(piece, list) else list(piece.coords)
                    self._edge(u, v, tuple((float(x), float(y)) for x, y in pts))
        self._edges = [(u, v) for u, v in self.graph.edges]
        self._edge_tree = shapely.STRtree(
            [LineString(self.graph.edges[u, v]["coords"]) for u, v in self._edges]
        )

    def _node(self, p: XY, anchor: int | None = None) -> int:
        key = (round(p[0] / _SAME_M) * _SAME_M, round(p[1] / _SAME_M) * _SAME_M, anchor)
        if key not in self._ids:
            self._ids[key] = len(self.xy)
            self.xy.append((float(p[0]), float(p[1])))
            self.graph.add_node(self._ids[key])
        return self._ids[key]

    def _edge(self, u: int, v: int, coords: tuple[XY, ...]) -> None:
        length = float(LineString(coords).length)
        if self.graph.has_edge(u, v) and self.graph.edges[u, v]["weight"] <= length:
            return
        self.graph.add_edge(u, v, weight=length, coords=coords, start=u)

    def edge_points(self, u: int, v: int) -> tuple[XY, ...]:
        """The points of edge ``u``-``v`` driven from ``u`` to ``v``."""
        data = self.graph.edges[u, v]
        coords: tuple[XY, ...] = data["coords"]
        return coords if data["start"] == u else coords[::-1]

    def shortest_from(self, source: int) -> tuple[dict[int, list[int]], dict[int, float]]:
        """Dijkstra from ``source``: predecessors and distances of every reachable node
        (computed once per source)."""
        if source not in self._dijkstra:
            self._dijkstra[source] = nx.dijkstra_predecessor_and_distance(
                self.graph, source, weight="weight"
            )
        return self._dijkstra[source]

    def distance(self, u: int, v: int) -> float:
        return self.shortest_from(u)[1].get(v, math.inf)

    def path(self, u: int, v: int) -> tuple[XY, ...]:
        """The points of the shortest path from node ``u`` to node ``v``, both included."""
        pred, _ = self.shortest_from(u)
        nodes = [v]
        while nodes[-1] != u:
            nodes.append(pred[nodes[-1]][0])
        nodes.reverse()
        points: list[XY] = [self.xy[u]]
        for a, b in zip(nodes[:-1], nodes[1:], strict=True):
            points += self.edge_points(a, b)[1:]
        return tuple(points)

    def nearest_edge(self, p: XY) -> tuple[int, int, float, XY]:
        """The edge nearest ``p``: its nodes, how far along from ``u`` and the foot point."""
        k = int(self._edge_tree.query_nearest(Point(p))[0])
        u, v = self._edges[k]
        line = LineString(self.edge_points(u, v))
        along = float(line.project(Point(p)))
        q = line.interpolate(along)
        return u, v, along, (float(q.x), float(q.y))


def _joined_to(network: BaseGeometry, point: XY) -> BaseGeometry:
    """The part of ``network`` (lines) that hangs together (touching, crossing, through
    others) with its line nearest ``point``."""
    parts = shapely.get_parts(network)
    if len(parts) <= 1:
        return network
    tree = shapely.STRtree(parts)
    touching = nx.Graph()
    touching.add_nodes_from(range(len(parts)))
    left, right = tree.query(parts, predicate="intersects")
    touching.add_edges_from(zip(left.tolist(), right.tolist(), strict=True))
    home = nx.node_connected_component(touching, int(tree.query_nearest(Point(point))[0]))
    return shapely.union_all(parts[sorted(home)])


def _outside(
    segments: Sequence[LineString], fields: BaseGeometry | None
) -> tuple[list[BaseGeometry], list[int]]:
    """The parts of ``segments`` outside ``fields``, each with the segment it is of; the
    segments whole when none is (every road inside a field)."""
    if fields is None or fields.is_empty:
        return list(segments), list(range(len(segments)))
    pieces: list[BaseGeometry] = []
    piece_of: list[int] = []
    for k, seg in enumerate(segments):
        for part in shapely.get_parts(seg.difference(fields)):
            if part.length > _SAME_M:
                pieces.append(part)
                piece_of.append(k)
    if not pieces:
        return list(segments), list(range(len(segments)))
    return pieces, piece_of


_UNIONS_KEPT = 16
"""Unions of the obstacles but a few (:meth:`_FreeSpace._blocks_but`) kept for reuse."""

_MANY_LINES = 32
"""Segments tested at once from which one union of the obstacles, prepared, is cheaper than
testing each against the obstacles its bounding box meets (:meth:`_FreeSpace._visible`)."""


class _FreeSpace:
    """Shortest paths in the plane around grown field outlines (a visibility graph)."""

    def __init__(
        self,
        outlines: Sequence[Polygon],
        clearance_m: float,
        names: Sequence[str] = (),
        source: str = "<memory>",
    ) -> None:
        self._names = list(names) or [f"#{k}" for k in range(len(outlines))]  # for messages
        self._source = source
        grown = [orient(_grown(p, clearance_m), 1.0) for p in outlines]
        self._blocks = [g.buffer(-_TOUCH_M, join_style="mitre") for g in grown]
        # The fields less CROSSING_M: what a point within the clearance of a field, but not
        # that deep in it (a garage beside a fence, a gate on a fence two fields share),
        # must still go around; a point deeper in stands in the field and may cross it.
        self._fields = np.array(
            [Polygon(p.exterior).buffer(-CROSSING_M, join_style="mitre") for p in outlines],
            dtype=object,
        )
        shapely.prepare(self._fields)
        self._tree = shapely.STRtree(self._blocks)
        # The last UNIONS_KEPT unions, by the obstacles left out (one a field: 400 fields
        # kept 400 unions of 399 obstacles, 1.7 GB; the matrix asks field by field).
        self._unions: collections.OrderedDict[frozenset[int], BaseGeometry] = (
            collections.OrderedDict()
        )
        self._prepared = np.array(self._blocks, dtype=object)  # each tested against many lines
        shapely.prepare(self._prepared)
        nodes, prev, succ = [], [], []
        for g in grown:
            c = np.asarray(g.exterior.coords)[:-1]
            before, after = np.roll(c, 1, axis=0), np.roll(c, -1, axis=0)
            into, out = c - before, after - c
            convex = into[:, 0] * out[:, 1] - into[:, 1] * out[:, 0] > 0.0
            nodes.append(c[convex])
            prev.append(before[convex])
            succ.append(after[convex])
        self.nodes = np.vstack(nodes) if nodes else np.zeros((0, 2))
        self._prev = np.vstack(prev) if prev else np.zeros((0, 2))
        self._next = np.vstack(succ) if succ else np.zeros((0, 2))
        n = len(self.nodes)
        weights = np.full((n, n), np.inf)
        np.fill_diagonal(weights, 0.0)
        i, j = np.triu_indices(n, k=1)
        # A shortest path only bends at a corner it hugs: both neighbours of the corner on
        # one side of the path. Pairs failing that at either end are never needed.
        keep = self._tangent(i, self.nodes[j]) & self._tangent(j, self.nodes[i])
        i, j = i[keep], j[keep]
        if len(i):
            lines = shapely.linestrings(np.stack([self.nodes[i], self.nodes[j]], axis=-2))
            ok = ~shapely.intersects(self._blocks_but(frozenset()), lines)
            d = np.hypot(*(self.nodes[i] - self.nodes[j]).T)
            weights[i[ok], j[ok]] = d[ok]
            weights[j[ok], i[ok]] = d[ok]
        self._weights = weights
        # All pairs by Dijkstra from every corner on the (sparse: tangent pairs only)
        # visibility graph; Floyd-Warshall in numpy took 20 s and 1.7 GB for 400 fields'
        # 1 600 corners (review). Edges of no length (corners that coincide once grown)
        # kept as a hair, as a sparse matrix drops zeros.
        edges = np.isfinite(weights)
        np.fill_diagonal(edges, False)
        rows, cols = np.nonzero(edges)
        graph = csr_matrix((np.maximum(weights[rows, cols], 1e-9), (rows, cols)), shape=(n, n))
        self._dist = shortest_path(graph, method="D", directed=False) if n else weights.copy()
        self._reach: dict[tuple[XY, int | None], tuple[FloatArray, FloatArray]] = {}

    def _visible(
        self, a: FloatArray, b: FloatArray, ignore: set[int], near: AbstractSet[int] = frozenset()
    ) -> NDArray[np.bool_]:
        """For each segment a[k]-b[k], whether it stays off every obstacle not in
        ``ignore``, and off the field itself of those in ``near`` (an end lies within
        their clearance)."""
        a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
        lines = shapely.linestrings(np.stack([a, b], axis=-2).reshape(-1, 2, 2))
        near = set(near) - set(ignore)
        if len(lines) >= _MANY_LINES:  # from one point to the corners: one union, prepared
            union = self._blocks_but(frozenset(ignore | near))
            blocked = np.asarray(shapely.intersects(union, lines))
            for k in near:
                blocked |= np.asarray(shapely.intersects(self._fields[k], lines))
            return ~blocked
        hit_line, hit_block = self._tree.query(lines)  # bounding boxes that meet
        keep = np.array([int(k) not in ignore for k in hit_block], dtype=bool)
        hit_line, hit_block = hit_line[keep], hit_block[keep]
        shapes = np.where(
            np.isin(hit_block, list(near)), self._fields[hit_block], self._prepared[hit_block]
        )
        blocked = np.zeros(len(lines), dtype=bool)
        blocked[hit_line[shapely.intersects(shapes, lines[hit_line])]] = True
        return ~blocked

    def _blocks_but(self, ignore: frozenset[int]) -> BaseGeometry:
        """The obstacles but those in ``ignore``, as one prepared geometry (cached): a long
        segment's bounding box meets many obstacles, and testing it against each in turn
        (an STRtree query) costs ten times more than one prepared union."""
        if ignore not in self._unions:
            union = shapely.union_all([g for k, g in enumerate(self._blocks) if k not in ignore])
            shapely.prepare(union)
            self._unions[ignore] = union
            if len(self._unions) > _UNIONS_KEPT:
                self._unions.popitem(last=False)
        self._unions.move_to_end(ignore)
        return self._unions[ignore]

    def _tangent(self, k: NDArray[np.int64], other: FloatArray) -> NDArray[np.bool_]:
        """Whether the lines from nodes ``k`` to ``other`` leave both neighbours of the node
        on one side (or on the line)."""
        d = other - self.nodes[k]
        p, q = self._prev[k] - self.nodes[k], self._next[k] - self.nodes[k]
        side_p = d[:, 0] * p[:, 1] - d[:, 1] * p[:, 0]
        side_q = d[:, 0] * q[:, 1] - d[:, 1] * q[:, 0]
        return np.asarray(side_p * side_q >= -1e-9, dtype=bool)

    def _ignored(self, p: XY, own: int | None) -> set[int]:
        """The obstacles ``p`` may cross: its own, and any field it stands in (more than
        CROSSING_M from its edge: a gate on a shared fence, a hair inside the neighbour
        once projected, crossed the neighbour straight to the road)."""
        inside = {int(k) for k in self._tree.query(Point(p), predicate="intersects")}
        return {k for k in inside if self._fields[k].intersects(Point(p))} | (
            {own} if own is not None else set()
        )

    def _near(self, p: XY, own: int | None) -> set[int]:
        """The obstacles whose clearance ``p`` lies in, outside the field (a garage by a
        fence): their fields are still in the way, their clearance not."""
        inside = {int(k) for k in self._tree.query(Point(p), predicate="intersects")}
        return inside - self._ignored(p, own)

    def reach(self, p: XY, own: int | None) -> tuple[FloatArray, FloatArray]:
        """From ``p`` (in obstacle ``own``, which it may cross): the straight distance to
        every node it sees (inf if hidden) and the shortest distance to every node."""
        key = (p, own)
        if key not in self._reach:
            n = len(self.nodes)
            seen = np.full(n, np.inf)
            if n:
                here = np.asarray(p, dtype=float)
                near = self._near(p, own)
                # Only corners the way hugs (see __init__); from within a clearance, the
                # corners of that clearance are reached from inside it: any corner.
                k = (
                    np.arange(n)
                    if near
                    else np.flatnonzero(self._tangent(np.arange(n), np.broadcast_to(here, (n, 2))))
                )
                ok = self._visible(here[None, :], self.nodes[k], self._ignored(p, own), near)
                seen[k[ok]] = np.hypot(*(self.nodes[k[ok]] - here).T)
                best = (seen[:, None] + self._dist).min(axis=0)
            else:
                best = seen
            self._reach[key] = (seen, best)
        return self._reach[key]

    def route(
        self,
        a: XY,
        b: XY,
        own_a: int | None,
        own_b: int | None,
        ends: tuple[int | None, int | None] | None = None,
    ) -> Route:
        """The shortest way from ``a`` (in obstacle ``own_a``, which it may cross) to ``b``;
        ``ends``: the fields to name in a warning (default: the owners)."""
        ignore = self._ignored(a, own_a) | self._ignored(b, own_b)
        near = self._near(a, own_a) | self._near(b, own_b)
        straight = math.dist(a, b)
        if straight < _SAME_M or self._visible(np.asarray(a), np.asarray(b), ignore, near)[0]:
            return straight, ()
        seen_a, reach_a = self.reach(a, own_a)
        seen_b, _ = self.reach(b, own_b)
        total = reach_a + seen_b
        j = int(np.argmin(total)) if len(total) else -1
        if j < 0 or not math.isfinite(total[j]):
            crossed = [
                self._names[int(k)]
                for k in self._tree.query(LineString([a, b]), predicate="intersects")
                if int(k) not in ignore and self._fields[int(k)].intersects(LineString([a, b]))
            ]
            log.warning(
                "%s: no way around the other fields from %s to %s (enclosed by fields); "
                "driven straight across %s",
                self._source,
                self._where(own_a if ends is None else ends[0]),
                self._where(own_b if ends is None else ends[1]),
                ", ".join(f"field {name!r}" for name in sorted(crossed)) or "them",
            )
            return straight, ()
        i = int(np.argmin(seen_a + self._dist[:, j]))
        nodes = [i]
        visited = np.zeros(len(self.nodes), dtype=bool)
        while nodes[-1] != j:  # walk the all-pairs table: the next hop on a shortest path
            k = nodes[-1]
            visited[k] = True
            step = self._weights[k] + self._dist[:, j]
            # Fields 2 m apart have corners that coincide once grown, joined at no length:
            # never back (the walk went from one to the other for ever), and of the hops on
            # a shortest path one that gets nearer first (the other corner of the pair may
            # lead only back, and then round the long way).
            step[visited] = np.inf
            best = float(step.min())
            if not math.isfinite(best):
                break  # cannot happen on a shortest-path table; never loop
            ties = np.flatnonzero(step <= best + 1e-9)
            nearer = ties[self._dist[ties, j] < self._dist[k, j] - 1e-9]
            nodes.append(int(nearer[0] if len(nearer) else ties[0]))
        via = tuple((float(self.nodes[k][0]), float(self.nodes[k][1])) for k in nodes)
        return float(total[j]), via

    def _where(self, own: int | None) -> str:
        return (
            "the garage (or a point off the fields)"
            if own is None
            else (f"field {self._names[own]!r}")
        )

    def length_matrix(self, points: Sequence[XY], owners: Sequence[int | None]) -> FloatArray:
        """Route lengths between all pairs of ``points`` (point k lies in obstacle
        ``owners[k]``), vectorised for the solver's matrix."""
        m = len(points)
        out = np.zeros((m, m))
        i, j = np.triu_indices(m, k=1)
        d = self._pair_lengths(points, owners, points, owners, i, j)
        out[i, j] = out[j, i] = d
        return out

    def lengths(
        self,
        sources: Sequence[XY],
        source_owners: Sequence[int | None],
        targets: Sequence[XY],
        target_owners: Sequence[int | None],
    ) -> FloatArray:
        """Route lengths from each source to each target (rows: sources), vectorised."""
        i, j = np.indices((len(sources), len(targets))).reshape(2, -1)
        d = self._pair_lengths(sources, source_owners, targets, target_owners, i, j)
        return d.reshape(len(sources), len(targets))

    def _table(self, sets: Sequence[AbstractSet[int]]) -> NDArray[np.bool_]:
        """``sets`` of obstacles as rows of a table [row, obstacle]."""
        table = np.zeros((len(sets), len(self._blocks)), dtype=bool)
        for row, members in enumerate(sets):
            table[row, list(members)] = True
        return table

    def _pair_lengths(
        self,
        a: Sequence[XY],
        own_a: Sequence[int | None],
        b: Sequence[XY],
        own_b: Sequence[int | None],
        i: NDArray[np.int64],
        j: NDArray[np.int64],
    ) -> FloatArray:
        """The route length from ``a[i[k]]`` to ``b[j[k]]`` for each k, as :meth:`route`
        finds it: straight when no obstacle but their own is in the way, else around the
        obstacles' corners."""
        out = np.zeros(len(i))
        if not len(i):
            return out
        pa, pb = (
            np.asarray(a, dtype=float).reshape(-1, 2),
            np.asarray(b, dtype=float).reshape(-1, 2),
        )
        out[:] = np.hypot(*(pa[i] - pb[j]).T)
        lines = shapely.linestrings(np.stack([pa[i], pb[j]], axis=-2))
        hit_line, hit_block = self._tree.query(lines)  # bounding boxes that meet
        inside_a = [self._ignored(p, o) for p, o in zip(a, own_a, strict=True)]
        inside_b = [self._ignored(p, o) for p, o in zip(b, own_b, strict=True)]
        near_a = [self._near(p, o) for p, o in zip(a, own_a, strict=True)]
        near_b = [self._near(p, o) for p, o in zip(b, own_b, strict=True)]
        # As tables [point, obstacle], looked up for every (line, obstacle) pair at once: a
        # Python tuple a pair took 1.7 GB and most of 20 s for 400 fields (review).
        in_a, in_b, by_a, by_b = (
            self._table(sets) for sets in (inside_a, inside_b, near_a, near_b)
        )
        line_a, line_b = i[hit_line], j[hit_line]
        keep = ~in_a[line_a, hit_block] & ~in_b[line_b, hit_block]
        by_field = by_a[line_a, hit_block] | by_b[line_b, hit_block]
        hit_line, hit_block, by_field = hit_line[keep], hit_block[keep], by_field[keep]
        shapes = np.where(by_field, self._fields[hit_block], self._prepared[hit_block])
        blocked = np.zeros(len(i), dtype=bool)
        blocked[hit_line[shapely.intersects(shapes, lines[hit_line])]] = True
        blocked &= out >= _SAME_M
        k = np.flatnonzero(blocked)
        if len(self.nodes) and len(k):
            rows, row_of = np.unique(i[k], return_inverse=True)
            cols, col_of = np.unique(j[k], return_inverse=True)
            reach_a = np.stack([self.reach(a[r], own_a[r])[1] for r in rows.tolist()])
            seen_b = np.stack([self.reach(b[c], own_b[c])[0] for c in cols.tolist()])
            around = np.empty(len(k))
            step = max(1, 2**22 // len(self.nodes))  # pairs at once: 32 MB of sums
            for lo in range(0, len(k), step):
                hi = lo + step
                around[lo:hi] = (reach_a[row_of[lo:hi]] + seen_b[col_of[lo:hi]]).min(axis=1)
            found = np.isfinite(around)
            out[k[found]] = around[found]
        return out


class TransitNetwork:
    """Where a machine drives between fields and the garage (see the module doc)."""

    def __init__(self, farm: Farm, clearance_m: float = CLEARANCE_M) -> None:
        self.farm = farm
        self._index = {f.id: k for k, f in enumerate(farm.fields)}
        self._interiors: dict[str, FieldInterior] = {}
        self._clearance_m = clearance_m
        self._free_space: _FreeSpace | None = None  # built on first use
        self._known: dict[tuple[XY, XY, str | None, str | None], Route] = {}
        self._doors: dict[tuple[str, XY], tuple[XY, XY | None]] = {}
        self._outlines: shapely.STRtree | None = None  # the fields, holes filled
        self._roads: _RoadGraph | None = None
        # Per field, its gates as (gate point, road-graph node); the garage's node.
        self.gates: dict[str, tuple[XY, ...]] = {}
        self._gate_nodes: dict[str, tuple[int, ...]] = {}
        self._garage_node = -1
        # The fields shrunk by CROSSING_M (what a way onto the roads must not cross), indexed
        # on first use.
        self._fields_tree: shapely.STRtree | None = None
        # The fields with holes and no gate: left and entered around their holes.
        self._holed = frozenset(
            f.id for f in farm.fields if f.boundary.interiors and not farm.gates_of(f.id)
        )
        self._say_nested()
        if farm.roads:
            self._build_roads()

    def _say_nested(self) -> None:
        """A field in a hole of another (an island in a pond, a plot in a yard) is reached
        across that field, which no way around avoids: said once, naming both (it was
        driven across silently: review)."""
        holes = [(f.id, Polygon(ring)) for f in self.farm.fields for ring in f.boundary.interiors]
        if not holes:
            return
        for f in self.farm.fields:
            inside = f.boundary.representative_point()
            for outer, hole in holes:
                if outer != f.id and hole.contains(inside):
                    log.warning(
                        "%s: field %r lies in a hole of field %r: its transit crosses %r",
                        self.farm.source,
                        f.id,
                        outer,
                        outer,
                    )

    @property
    def _free(self) -> _FreeSpace:
        if self._free_space is None:
            outlines = [f.boundary for f in self.farm.fields]
            self._free_space = _FreeSpace(
                outlines,
                self._clearance_m,
                [f.id for f in self.farm.fields],
                self.farm.source,
            )
        return self._free_space

    @property
    def has_roads(self) -> bool:
        return self._roads is not None

    def _build_roads(self) -> None:
        farm = self.farm
        # Simplified first: a track logged by GPS every metre or two would make every
        # vertex a mission item (25 000 for 30 km), for nothing a tractor can follow.
        lines = joined([r.line.simplify(ROAD_SIMPLIFY_M) for r in farm.roads])
        network = shapely.unary_union([line for line in lines if line.length > _SAME_M])
        if network.is_empty:
            log.warning(
                "%s: the roads (%s) are each shorter than %g m once their ends are joined: "
                "no roads to drive; transit goes around the fields",
                farm.source,
                ", ".join(repr(r.id) for r in farm.roads),
                ROAD_JOIN_M,
            )
            return
        # Inside the fields by more than half CROSSING_M (a road drawn along a fence a little
        # inside it still counts as outside; a road point on the line stands not in the field).
        cores = shapely.union_all([f.boundary.buffer(-CROSSING_M / 2) for f in farm.fields])
        # A field without a gate is entered where it is nearest a road outside the fields,
        # from a part of its fence it shares with no other field (else across that field).
        outside = network.difference(cores)
        outside = network if outside.is_empty else outside
        # On the roads the garage's road joins (a piece of road drawn on a field's fence,
        # joined to nothing, took that field's gate: "the roads do not connect field 'A'",
        # with the garage's road 11 m away; an outside review).
        reached = outside.intersection(_joined_to(network, farm.garage))
        outside = outside if reached.is_empty else reached
        outlines = shapely.STRtree([Polygon(f.boundary.exterior) for f in farm.fields])
        for k, f in enumerate(farm.fields):
            # A gate drawn inside the field is on its fence: the tractor drove from the fence
            # to the point as drawn, into the crop, and back (review).
            declared = tuple(_on_fence(f.boundary, g.xy) for g in farm.gates_of(f.id))
            if not declared:
                fence = f.boundary.exterior
                others = [
                    int(j)
                    for j in outlines.query(fence, predicate="dwithin", distance=self._clearance_m)
                    if int(j) != k
                ]
                if others:
                    shared = shapely.union_all(
                        [outlines.geometries[j].buffer(self._clearance_m) for j in others]
                    )
                    free = fence.difference(shared)
                    fence = free if not free.is_empty else fence
                p = nearest_points(fence, outside)[0]
                declared = ((float(p.x), float(p.y)),)
            self.gates[f.id] = declared
        anchors = [farm.garage] + [g for f in farm.fields for g in self.gates[f.id]]
        owners: list[int | None] = [None] + [
            k for k, f in enumerate(farm.fields) for _ in self.gates[f.id]
        ]
        roads = _RoadGraph(
            lines, anchors, lambda n, p, q: self._access(p, q, owners[n]), fields=cores
        )
        self._garage_node = roads.anchor_nodes[0]
        k = 1
        for f in farm.fields:
            count = len(self.gates[f.id])
            self._gate_nodes[f.id] = tuple(roads.anchor_nodes[k : k + count])
            k += count
        for node in set(roads.anchor_nodes):  # one Dijkstra per gate and the garage
            roads.shortest_from(node)
        far = [
            (f"field {f.id!r}", min(roads.access_m[n] for n in self._gate_nodes[f.id]))
            for f in farm.fields
        ]
        for what, metres in [("the garage", roads.access_m[self._garage_node]), *far]:
            if metres > FAR_FROM_ROADS_M:
                log.warning(
                    "%s: %s is %.0f m of driving off the roads from the nearest road (around "
                    "the fields in the way); where getting onto the roads "
                    "drives more off them than the way around the fields, its transit "
                    "goes around the fields",
                    farm.source,
                    what,
                    metres,
                )
        reached = roads.shortest_from(self._garage_node)[1]
        apart = [f.id for f in farm.fields if not any(n in reached for n in self._gate_nodes[f.id])]
        joined_gates = {n for f in farm.fields for n in self._gate_nodes[f.id]}
        if apart and len(apart) == len(farm.fields) and len(farm.fields) > 1:
            # None reached: the garage hangs on a stretch of road the others do not join (a
            # stray piece, a junction drawn with a gap), not every field on a road apart.
            on_road = next(iter(roads.graph.neighbors(self._garage_node)), self._garage_node)
            lon, lat = farm.frame.to_lonlat(*roads.xy[on_road])
            component = nx.node_connected_component(roads.graph, next(iter(joined_gates)))
            linked = len(joined_gates & component) > 1
            log.warning(
                "%s: the road the garage joins (at lon %.7f, lat %.7f) leads to no field%s; "
                "transit goes around the fields instead. Join it to the others (a gap of more "
                "than %g m at a junction is no junction) or remove the stray piece",
                farm.source,
                lon,
                lat,
                " while the fields' roads join each other" if linked else "",
                ROAD_JOIN_M,
            )
        else:
            for fid in apart:
                log.warning(
                    "%s: the roads do not connect field %r to the garage; its transit goes "
                    "around the fields instead",
                    farm.source,
                    fid,
                )
        self._roads = roads

    def _access(self, p: XY, q: XY, own: int | None) -> tuple[XY, ...]:
        """The way from the garage or a gate of field ``own`` at ``p`` to the road point
        ``q``: straight, unless that crosses another field (a gate behind a neighbour, a
        garage beside a field away from the road) or its own (a gate on the side away from
        the road): then around the fields, out of a gate straight away from its field."""
        if self._fields_tree is None:
            inner = [f.boundary.buffer(-CROSSING_M) for f in self.farm.fields]
            self._fields_tree = shapely.STRtree(inner)
        crossed = {
            int(k) for k in self._fields_tree.query(LineString([p, q]), predicate="intersects")
        }
        if not crossed:
            return ()
        if own is not None and own in crossed:
            at, door = self._door(self.farm.fields[own].id, p)
            if door is not None:
                return _strictly_between(
                    p, [at, door, *self._free.route(door, q, None, None)[1]], q
                )
        return self._free.route(p, q, own, None)[1]

    def interior(self, field_id: str) -> FieldInterior:
        """The in-field router of one field (built on first use)."""
        if field_id not in self._interiors:
            self._interiors[field_id] = FieldInterior(self.farm.field(field_id).boundary)
        return self._interiors[field_id]

    def route(self, a: XY, b: XY, from_field: str | None, to_field: str | None) -> Route:
        """The shortest transit from ``a`` in ``from_field`` (``None``: off the fields, e.g.
        the garage) to ``b`` in ``to_field``: its length in metres and the points strictly
        between ``a`` and ``b``. Cached."""
        a, b = (float(a[0]), float(a[1])), (float(b[0]), float(b[1]))
        key = (a, b, from_field, to_field)
        if key not in self._known:
            self._known[key] = self._route(a, b, from_field, to_field)
        return self._known[key]

    def length(self, a: XY, b: XY, from_field: str | None, to_field: str | None) -> float:
        return self.route(a, b, from_field, to_field)[0]

    def _route(self, a: XY, b: XY, from_field: str | None, to_field: str | None) -> Route:
        if from_field is not None and from_field == to_field:
            return self.interior(from_field).route(a, b)
        if self._roads is not None:
            found = self._road_route(a, b, from_field, to_field)
            if found is not None:
                road, off_road = found
                # The roads are driven, unless getting onto and off them drives more off
                # the roads than the whole way around the fields (a road far from both
                # ends: 12 times the road km, silently). No way around is shorter than
                # the straight line: then it need not be looked for.
                if off_road <= math.dist(a, b):
                    return road
                free = self._free_route(a, b, from_field, to_field)
                return free if free[0] < off_road else road
        return self._free_route(a, b, from_field, to_field)

    def _free_route(self, a: XY, b: XY, from_field: str | None, to_field: str | None) -> Route:
        best: tuple[float, list[XY]] | None = None
        named = (  # for a warning: the fields, also where the ways start outside them
            None if from_field is None else self._index[from_field],
            None if to_field is None else self._index[to_field],
        )
        for out in self._exits(a, from_field, leaving=True):
            for into in self._exits(b, to_field, leaving=False):
                length, via = self._free.route(out.at, into.at, out.own, into.own, named)
                total = out.length_m + length + into.length_m
                if best is None or total < best[0]:
                    points = [a, *out.via, out.at, *via, into.at, *into.via, b]
                    kept = points
                    if out.own is not None and from_field is not None:
                        points = self._off_holes(points, from_field, leaving=True)
                    if into.own is not None and to_field is not None:
                        points = self._off_holes(points, to_field, leaving=False)
                    if points is not kept:
                        total = float(LineString(points).length)
                    best = (total, points)
        assert best is not None
        return best[0], _strictly_between(a, best[1], b)

    def _off_holes(self, points: list[XY], field_id: str, leaving: bool) -> list[XY]:
        """A way out of (``leaving``) or into a field with no gate crosses the field itself
        in a straight line; where that part would cross one of the field's holes (a pond,
        a building), it is driven inside the field around them instead: from the start to
        where the way last leaves the field's outline, or from where it first meets it to
        the end."""
        field = self.farm.field(field_id).boundary
        if not field.interiors or len(points) < 2:
            return points
        line = LineString(points)
        ring = field.exterior
        crossings = [
            line.project(Point(c))
            for g in shapely.get_parts(line.intersection(ring))
            for c in g.coords
        ]
        if not crossings:
            return points
        t = max(crossings) if leaving else min(crossings)
        part = substring(line, 0.0, t) if leaving else substring(line, t, line.length)
        holes = shapely.union_all([Polygon(r).buffer(-_TOUCH_M) for r in field.interiors])
        if not part.intersects(holes):
            return points
        x = line.interpolate(t)
        edge: XY = (float(x.x), float(x.y))
        if leaving:
            via = self.interior(field_id).route(points[0], edge)[1]
            rest = list(substring(line, t, line.length).coords)[1:]
            return [points[0], *via, edge, *((float(p[0]), float(p[1])) for p in rest)]
        via = self.interior(field_id).route(edge, points[-1])[1]
        before = list(substring(line, 0.0, t).coords)[:-1]
        return [*((float(p[0]), float(p[1])) for p in before), edge, *via, points[-1]]

    def _exits(self, p: XY, field_id: str | None, leaving: bool) -> list[_Exit]:
        """The ways from ``p`` in ``field_id`` out into free space (``leaving``) or from
        there to it: through each of the field's declared gates that opens onto free space,
        or (none, or off the fields) from ``p`` itself across its own field."""
        if field_id is None or not self.farm.gates_of(field_id):
            own = None if field_id is None else self._index[field_id]
            return [_Exit(p, own, 0.0, ())]
        out = []
        own = self._index[field_id]
        for gate in self.farm.gates_of(field_id):
            at, door = self._door(field_id, gate.xy)
            if leaving:
                length, via = self.interior(field_id).route(p, at)
                points: tuple[XY, ...] = (*via, at)
            else:
                length, via = self.interior(field_id).route(at, p)
                points = (at, *via)
            if door is not None:  # else it leads into another field, or a hole: not out
                out.append(_Exit(door, None, length + math.dist(at, door), points))
        return out or [_Exit(p, own, 0.0, ())]  # no way out through a gate: as if none

    def _door(self, field_id: str, gate: XY) -> tuple[XY, XY | None]:
        """Where the gate is on the field's outline (a gate drawn a little inside is moved
        out to it), and a point :data:`DOOR_M` beyond the clearance out of the field there:
        of 32 around it, the farthest from the field, holes filled, that lies in no other
        field; None where there is none (a gate on the ring of a hole, or in a fence shared
        with another field), with a warning: off the roads it is no way out."""
        key = (field_id, gate)
        if key not in self._doors:
            field = self.farm.field(field_id).boundary
            outline = Polygon(field.exterior)
            at, in_hole = _on_fence(field, gate), _in_hole(field, gate)
            r = self._clearance_m + DOOR_M
            t = np.linspace(0.0, 2.0 * math.pi, 32, endpoint=False)
            around = np.column_stack([at[0] + r * np.cos(t), at[1] + r * np.sin(t)])
            points = shapely.points(around)
            away = shapely.distance(outline, points)
            if self._outlines is None:
                self._outlines = shapely.STRtree(
                    [Polygon(f.boundary.exterior) for f in self.farm.fields]
                )
            hit_point, hit_field = self._outlines.query(points, predicate="intersects")
            away[hit_point[hit_field != self._index[field_id]]] = -1.0
            k = int(np.argmax(away))
            # Out of the field, however little (the tip of a narrow inlet), and in no other.
            door = (float(around[k, 0]), float(around[k, 1])) if away[k] > _SAME_M else None
            if in_hole or door is None:
                door = None
                lon, lat = next(
                    (g.lonlat for g in self.farm.gates_of(field_id) if g.xy == gate),
                    (math.nan,) * 2,
                )
                log.warning(
                    "%s: the gate of field %r at lon %.7f, lat %.7f opens %s; off the roads "
                    "the field is left and entered as if it had no gate there",
                    self.farm.source,
                    field_id,
                    lon,
                    lat,
                    "onto a hole in the field" if in_hole else "into another field",
                )
            self._doors[key] = (at, door)
        return self._doors[key]

    def _free_lengths(
        self,
        sources: Sequence[XY],
        source_fields: Sequence[str | None],
        targets: Sequence[XY],
        target_fields: Sequence[str | None],
    ) -> FloatArray:
        """:meth:`_free_route`'s lengths from each source to each target, vectorised: the
        free-space lengths between all their ways out and in, the shortest per pair."""
        if not len(sources) or not len(targets):
            return np.zeros((len(sources), len(targets)))
        outs = [self._exits(p, f, True) for p, f in zip(sources, source_fields, strict=True)]
        ins = [self._exits(p, f, False) for p, f in zip(targets, target_fields, strict=True)]
        flat_out = [e for ways in outs for e in ways]
        flat_in = [e for ways in ins for e in ways]
        free = self._free.lengths(
            [e.at for e in flat_out],
            [e.own for e in flat_out],
            [e.at for e in flat_in],
            [e.own for e in flat_in],
        )
        total = (
            np.array([e.length_m for e in flat_out])[:, None]
            + free
            + np.array([e.length_m for e in flat_in])[None, :]
        )
        rows = np.cumsum([0, *(len(w) for w in outs[:-1])])
        cols = np.cumsum([0, *(len(w) for w in ins[:-1])])
        return np.minimum.reduceat(np.minimum.reduceat(total, rows, axis=0), cols, axis=1)

    def _road_route(
        self, a: XY, b: XY, from_field: str | None, to_field: str | None
    ) -> tuple[Route, float] | None:
        """The shortest route along the roads, and how much of it is off them (the ways
        onto and off the roads), or None if the roads do not connect the two."""
        assert self._roads is not None
        best: tuple[float, _Option, _Option] | None = None
        starts = self._options(a, from_field, leaving=True)
        ends = self._options(b, to_field, leaving=False)
        for s in starts:
            for e in ends:
                total = s.length_m + self._roads.distance(s.node, e.node) + e.length_m
                if math.isfinite(total) and (best is None or total < best[0]):
                    best = (total, s, e)
        if best is None:
            return None
        total, s, e = best
        points = [a, *s.via, *self._roads.path(s.node, e.node), *e.via, b]
        return (total, _strictly_between(a, points, b)), s.off_road_m + e.off_road_m

    def _options(self, p: XY, field_id: str | None, leaving: bool) -> list[_Option]:
        """The ways from ``p`` onto the road graph (``leaving``) or from it to ``p``."""
        assert self._roads is not None
        roads = self._roads
        if field_id is not None:
            out = []
            for gate, node in zip(self.gates[field_id], self._gate_nodes[field_id], strict=True):
                off = roads.access_m[node]
                if leaving:
                    length, via = self.interior(field_id).route(p, gate)
                    out.append(_Option(node, length, (*via, gate), off))
                else:
                    length, via = self.interior(field_id).route(gate, p)
                    out.append(_Option(node, length, (gate, *via), off))
            return out
        if math.dist(p, self.farm.garage) < _SAME_M:
            return [_Option(self._garage_node, 0.0, (), roads.access_m[self._garage_node])]
        # Onto the road around any field in the way (a machine stopped beside a field, the
        # road beyond it, drove across it to the road after a re-plan): at the road point
        # nearest it, and at the one nearest where that way comes out (not back along the
        # road to the foot behind the field); the caller takes the shortest.
        feet = [roads.nearest_edge(p)]
        ways = [self._access(p, feet[0][3], None)]
        if ways[0]:
            feet.append(roads.nearest_edge(ways[0][-1]))
            ways.append(self._access(p, feet[1][3], None))
        out = []
        for (u, v, along, foot), way in zip(feet, ways, strict=True):
            line = LineString(roads.edge_points(u, v))
            access = float(LineString([p, *way, foot]).length)
            for node, part in (
                (u, substring(line, along, 0.0)),
                (v, substring(line, along, line.length)),
            ):
                coords = getattr(part, "coords", [foot])
                pts = way + tuple((float(x), float(y)) for x, y in coords)
                if not leaving:
                    pts = pts[::-1]
                out.append(_Option(node, access + float(part.length), pts, access))
        return out

    def lengths(
        self,
        sources: Sequence[XY],
        source_fields: Sequence[str | None],
        targets: Sequence[XY],
        target_fields: Sequence[str | None],
    ) -> FloatArray:
        """Transit lengths from each source (in ``source_fields[k]``) to each target, rows
        the sources; vectorised when there are no roads."""
        if self._roads is not None:
            return np.array(
                [
                    [self.length(a, b, f, g) for b, g in zip(targets, target_fields, strict=True)]
                    for a, f in zip(sources, source_fields, strict=True)
                ]
            ).reshape(len(sources), len(targets))
        out = self._free_lengths(sources, source_fields, targets, target_fields)
        # Within one field its own router; out of or into a field with holes and no gate,
        # the route that goes around them (:meth:`_off_holes`), one by one.
        holed = self._holed
        for r, (a, f) in enumerate(zip(sources, source_fields, strict=True)):
            for c, (b, g) in enumerate(zip(targets, target_fields, strict=True)):
                if (f is not None and f == g) or f in holed or g in holed:
                    out[r, c] = self.length(a, b, f, g)
        return out

    def length_matrix(self, points: Sequence[XY], field_ids: Sequence[str | None]) -> FloatArray:
        """Route lengths between all pairs of ``points`` (point k in ``field_ids[k]``),
        symmetric; what the solver gets as its distance matrix."""
        m = len(points)
        if self._roads is None and not self.farm.gates:
            owners = [None if f is None else self._index[f] for f in field_ids]
            return self._free.length_matrix(points, owners)
        if self._roads is None and m:
            # A way out and the way back in through the same gate are as long (the field's
            # router is symmetric), so the free lengths between the gates are needed one
            # way only: half the pairs of _free_lengths.
            exits = [self._exits(p, f, True) for p, f in zip(points, field_ids, strict=True)]
            flat = [e for ways in exits for e in ways]
            free = self._free.length_matrix([e.at for e in flat], [e.own for e in flat])
            inner = np.array([e.length_m for e in flat])
            total = inner[:, None] + free + inner[None, :]
            starts = np.cumsum([0, *(len(ways) for ways in exits[:-1])])
            out = np.minimum.reduceat(np.minimum.reduceat(total, starts, axis=0), starts, axis=1)
            np.fill_diagonal(out, 0.0)
            for i, j in itertools.combinations(range(m), 2):
                if field_ids[i] is not None and field_ids[i] == field_ids[j]:
                    out[i, j] = out[j, i] = self.length(points[i], points[j], field_ids[i], None)
            return out
        out = np.zeros((m, m))
        for i in range(m):
            for j in range(i + 1, m):
                d = self.length(points[i], points[j], field_ids[i], field_ids[j])
                out[i, j] = out[j, i] = d
        return out


def _grown(outline: Polygon, clearance_m: float) -> Polygon:
    """A field's outline grown by ``clearance_m``, as an obstacle to transit. One of more
    than :data:`MANY_CORNERS` corners (a pivot's circle of 360, a boundary logged by GPS)
    is grown by twice that and simplified to within it (Douglas-Peucker), so that it stays
    at least ``clearance_m`` off the field with a few dozen corners: every convex corner is
    a node of the visibility graph, whose all-pairs table is n x n (12 circles of 360
    corners took 100 s and 1.4 GB)."""
    shell = Polygon(outline.exterior)
    grown = shell.buffer(clearance_m, join_style="mitre")
    if len(grown.exterior.coords) - 1 <= MANY_CORNERS:
        return grown
    wider = shell.buffer(2.0 * clearance_m, join_style="mitre")
    simple = wider.simplify(clearance_m, preserve_topology=True)
    return simple if isinstance(simple, Polygon) and not simple.is_empty else grown


def joined(roads: Sequence[LineString], tolerance_m: float = ROAD_JOIN_M) -> list[LineString]:
    """The roads with ends closer than ``tolerance_m`` merged into one point and every road
    passing that close to an end given a vertex there, so that T and L junctions drawn with a
    small gap (rounded coordinates) connect."""
    ends: list[XY] = []
    size = max(tolerance_m, 1e-6)
    cells: dict[tuple[int, int], list[XY]] = {}  # the ends by square of side ``size``

    def end(p: XY) -> XY:
        cx, cy = math.floor(p[0] / size), math.floor(p[1] / size)
        for dx, dy in itertools.product((-1, 0, 1), repeat=2):
            for q in cells.get((cx + dx, cy + dy), ()):
                if math.dist(p, q) <= tolerance_m:
                    return q
        ends.append((float(p[0]), float(p[1])))
        cells.setdefault((cx, cy), []).append(ends[-1])
        return ends[-1]

    lines = []
    for road in roads:
        coords = [(float(x), float(y)) for x, y in road.coords]
        coords[0], coords[-1] = end(coords[0]), end(coords[-1])
        lines.append(LineString(coords))
    points = shapely.points(ends)
    near = shapely.STRtree(points).query(lines, predicate="dwithin", distance=tolerance_m)
    targets: list[list[int]] = [[] for _ in lines]
    for k, e in zip(*near, strict=True):
        targets[int(k)].append(int(e))
    return [
        shapely.snap(line, shapely.multipoints(points[sorted(t)]), tolerance_m) if t else line
        for line, t in zip(lines, targets, strict=True)
    ]


def _in_hole(field: Polygon, gate: XY) -> bool:
    """Whether the gate is nearer one of the field's holes than its outline (it opens onto
    the hole)."""
    to_hole = min((ring.distance(Point(gate)) for ring in field.interiors), default=math.inf)
    return bool(to_hole < field.exterior.distance(Point(gate)))


def _on_fence(field: Polygon, gate: XY) -> XY:
    """Where a gate drawn inside its field (not in a hole) is on its outline: the nearest
    point of the outline; a gate drawn on or outside it, where it is."""
    if Polygon(field.exterior).contains(Point(gate)) and not _in_hole(field, gate):
        q = nearest_points(field.exterior, Point(gate))[0]
        return (float(q.x), float(q.y))
    return gate


def _strictly_between(a: XY, points: Sequence[XY], b: XY) -> tuple[XY, ...]:
    """``points`` (which may start with ``a`` and end with ``b``) without repeats and
    without ``a`` and ``b`` themselves."""
    out: list[XY] = []
    for p in points:
        q = (float(p[0]), float(p[1]))
        if out and math.dist(out[-1], q) < _SAME_M:
            continue
        out.append(q)
    while out and math.dist(out[0], a) < _SAME_M:
        out.pop(0)
    while out and math.dist(out[-1], b) < _SAME_M:
        out.pop()
    return tuple(out)
