"""Transit between fields: roads and gates in the farm file, road routes, free-space routes."""

import copy
import itertools
import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import pytest
import shapely
import shapely.affinity
from shapely.geometry import LineString, Polygon, box

from planner.coverage import cover_field
from planner.errors import GeometryError
from planner.farm import Farm, Field, Gate, Road, farm_from_geojson, load_farm
from planner.field_plan import best_corners, plan_farm
from planner.geo import LocalFrame
from planner.problem import Machine
from planner.roads import MANY_CORNERS, TransitNetwork
from planner.solve import stop_after

ROOT = Path(__file__).resolve().parents[2]
FRAME = LocalFrame.around(87.3, 44.0)
FLEET = [
    Machine("t1", 6.9, 9400.0, 12.0, 0.0035, 6.0, 12.0, work_speed_kmh=6.0),
    Machine("t2", 5.5, 7000.0, 10.0, 0.0030, 5.0, 10.0, work_speed_kmh=6.0),
    Machine("t3", 3.7, 5000.0, 10.0, 0.0025, 4.0, 8.0, work_speed_kmh=6.0),
]


def farm_of(
    polygons: dict[str, Polygon],
    garage: tuple[float, float],
    roads: list[list[tuple[float, float]]] = (),  # type: ignore[assignment]
    gates: list[tuple[str, tuple[float, float]]] = (),  # type: ignore[assignment]
) -> Farm:
    return Farm(
        fields=tuple(Field(k, k, p, p) for k, p in polygons.items()),
        garage=garage,
        garage_lonlat=(87.3, 44.0),
        frame=FRAME,
        roads=tuple(Road(f"r{k}", LineString(r), LineString(r)) for k, r in enumerate(roads)),
        gates=tuple(Gate(f, xy, xy) for f, xy in gates),
    )


def crosses(path: list[tuple[float, float]], polygon: Polygon, margin: float = 0.5) -> bool:
    """Whether the polyline enters the polygon's interior shrunk by ``margin``."""
    return not LineString(path).intersection(polygon.buffer(-margin)).is_empty


# --- the farm file ---------------------------------------------------------------------


def tiny_doc() -> dict:
    return json.loads((ROOT / "tests/data/tiny-farm.geojson").read_text())


def feature(kind: str, geometry: dict, **props: object) -> dict:
    return {"type": "Feature", "properties": {"kind": kind, **props}, "geometry": geometry}


def test_tiny_farm_has_its_road_and_gates():
    farm = load_farm(ROOT / "tests/data/tiny-farm.geojson")
    assert len(farm.roads) == 2
    assert [g.field_id for g in farm.gates] == ["A", "A", "B"]
    assert farm.gates_of("C") == ()
    # The gates lie on their fields' boundaries (to the centimetre of the file's degrees).
    for g in farm.gates:
        assert farm.field(g.field_id).boundary.boundary.distance(shapely.Point(g.xy)) < 0.05


def test_multilinestring_roads_give_one_road_per_part():
    doc = tiny_doc()
    line = [[87.2995, 44.00045], [87.302, 44.00045]]
    doc["features"].append(
        feature("road", {"type": "MultiLineString", "coordinates": [line, line[::-1]]}, id="m")
    )
    farm = farm_from_geojson(doc, "x.geojson")
    assert [r.id for r in farm.roads][-2:] == ["m.0", "m.1"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            feature("gate", {"type": "Point", "coordinates": [87.3, 44.0]}, field="Z"),
            "x.geojson: feature #4 (gate of 'Z'): no field 'Z'",
        ),
        (
            feature("gate", {"type": "Point", "coordinates": [87.3, 44.0]}),
            "x.geojson: feature #4 (gate): a gate needs properties.field",
        ),
        (
            feature("gate", {"type": "LineString", "coordinates": []}, field="A"),
            "(gate of 'A'): a gate must be a Point",
        ),
        (
            feature("gate", {"type": "Point", "coordinates": [87.2980, 44.0]}, field="A"),
            "(gate of 'A'): the gate is 160 m from the boundary of field 'A' (limit 50 m)",
        ),
        (
            feature("road", {"type": "LineString", "coordinates": [[87.3, 44.0]]}, id="lane"),
            "x.geojson: feature #4 (road 'lane'): a road needs at least 2 points",
        ),
        (
            feature("road", {"type": "LineString", "coordinates": [[87.3, 44.0], [87.3, 44.0]]}),
            "(road 'road#4'): a road needs at least 2 distinct points",
        ),
        (
            feature("road", {"type": "Point", "coordinates": [87.3, 44.0]}, id="p"),
            "(road 'p'): a road must be a LineString or MultiLineString, not Point",
        ),
        (
            feature("road", {"type": "LineString", "coordinates": [[87.3, 44.0], [500, 1]]}),
            "(road 'road#4'): longitude 500.0 is not a finite WGS84 value",
        ),
    ],
)
def test_bad_roads_and_gates_are_named(extra, message):
    doc = tiny_doc()
    doc["features"] = [f for f in doc["features"] if f["properties"]["kind"] in ("field", "garage")]
    doc["features"].append(extra)
    with pytest.raises(GeometryError) as err:
        farm_from_geojson(copy.deepcopy(doc), "x.geojson")
    assert message in str(err.value)


# --- routes on roads -------------------------------------------------------------------

# Two 100 m squares side by side 200 m apart; a road along their north side at y = 120
# and a spur down to y = 0 at x = 150, between them.
SQUARES = {"A": box(0, 0, 100, 100), "B": box(300, 0, 400, 100)}
ROAD = [(-50, 120), (450, 120)]
SPUR = [(150, 120), (150, 0)]


def test_route_along_a_road_is_the_hand_computed_length():
    farm = farm_of(SQUARES, (-50, 120), [ROAD, SPUR], [("A", (50, 100)), ("B", (350, 100))])
    net = TransitNetwork(farm)
    length, via = net.route((50, 50), (350, 50), "A", "B")
    # 50 up to the gate, 20 to the road, 300 along it, 20 down to B's gate, 50 to b.
    assert length == pytest.approx(50 + 20 + 300 + 20 + 50)
    assert via == ((50, 100), (50, 120), (150, 120), (350, 120), (350, 100))
    # From the garage (on the road's west end) and back: symmetric.
    there = net.route((-50, 120), (350, 50), None, "B")
    back = net.route((350, 50), (-50, 120), "B", None)
    assert there[0] == pytest.approx(400 + 20 + 50) == pytest.approx(back[0])
    assert back[1] == tuple(reversed(there[1]))


def test_the_best_gate_is_taken_and_a_field_without_gate_is_entered_nearest_the_road():
    farm = farm_of(
        SQUARES, (-50, 120), [ROAD, SPUR], [("A", (50, 100)), ("A", (100, 50))]
    )  # B has no gate: entered where it is nearest to the roads (its north side, 20 m off)
    net = TransitNetwork(farm)
    assert len(net.gates["B"]) == 1
    gx, gy = net.gates["B"][0]
    assert gy == pytest.approx(100) and 300 <= gx <= 400
    # From near A's east side: out of its east gate, 50 m to the spur, up the spur and along
    # the road, down to B's gate and across B: shorter than leaving by the north gate.
    length, via = net.route((100, 10), (300, 10), "A", "B")
    tail = (gx - 150) + 20 + math.dist((gx, gy), (300, 10))
    assert length == pytest.approx(40 + 50 + 70 + tail)
    assert length < math.dist((100, 10), (50, 100)) + 20 + 100 + tail
    assert (100, 50) in via


def test_a_field_without_gate_is_entered_from_the_roads_the_garage_reaches(caplog):
    """A piece of road drawn along A's east fence, joined to nothing, took A's gate (0 m
    from it): "the roads do not connect field 'A' to the garage", its transit around the
    fields, the garage's road 20 m north of A (an outside review). A is entered from the
    roads the garage's road joins."""
    stray = [(100, 0), (100, 60), (180, 60)]  # on A's fence, then off to nowhere
    farm = farm_of(SQUARES, (-50, 120), [ROAD, stray], [("B", (350, 100))])
    with caplog.at_level("WARNING", logger="planner.roads"):
        net = TransitNetwork(farm)
    assert "do not connect" not in caplog.text, caplog.text
    ((gx, gy),) = net.gates["A"]
    assert gy == pytest.approx(100) and 0 <= gx <= 100  # its north fence, under the road
    length, _ = net.route((-50, 120), (50, 50), None, "A")
    assert length == pytest.approx(
        math.dist((-50, 120), (gx, 120)) + 20 + math.dist((gx, gy), (50, 50))
    )


def test_roads_drawn_with_a_small_gap_at_a_junction_connect():
    # The spur stops 1 cm short of the road (rounded coordinates): still one network.
    gap_spur = [(150, 119.99), (150, 0)]
    corner = [(450.004, 120.003), (450, 0)]  # an L corner at the road's east end, 5 mm off
    farm = farm_of(SQUARES, (150, 0), [ROAD, gap_spur, corner], [("B", (350, 100))])
    net = TransitNetwork(farm)
    length, via = net.route((150, 0), (350, 50), None, "B")
    assert length == pytest.approx(120 + 200 + 20 + 50, abs=0.02)
    assert via[0] == pytest.approx((150, 120), abs=0.02)
    length, _ = net.route((450, 0), (350, 50), None, "B")
    assert length == pytest.approx(120 + 100 + 20 + 50, abs=0.02)


def test_a_field_the_roads_do_not_reach_is_reached_around_the_fields(caplog):
    # The garage's road and B's road do not meet: a warning, then free-space transit.
    farm = farm_of(
        SQUARES,
        (-50, 120),
        [[(-50, 120), (200, 120)], [(250, -20), (450, -20)]],
        [("A", (50, 100)), ("B", (350, 0))],
    )
    with caplog.at_level("WARNING", logger="planner.roads"):
        net = TransitNetwork(farm)
    assert "do not connect field 'B' to the garage" in caplog.text
    length, via = net.route((-50, 120), (350, 50), None, "B")
    assert via[0] == (101.0, 101.0)  # around A's corner, grown by 1 m
    # ... and round B to its gate on the south side, not across B's fence.
    assert via[-1] == (350.0, 0.0)
    path = [(-50, 120), *via, (350, 50)]
    assert not crosses(path[:-1], SQUARES["B"])
    assert length == pytest.approx(LineString(path).length)
    # A is still reached along its road.
    assert net.route((-50, 120), (50, 50), None, "A")[0] == pytest.approx(100 + 20 + 50)


def test_a_road_far_from_the_fields_is_not_driven_to_and_is_said_so(caplog):
    # Two fields 50 m apart, the garage beside them, one road 1 km away (a stray piece of a
    # GIS layer): every leg went out to it and back, 12 times the road km.
    fields = {"A": box(0, 0, 100, 100), "B": box(150, 0, 250, 100)}
    stray = [[(1000, 1000), (1200, 1000)]]
    with caplog.at_level("WARNING", logger="planner.roads"):
        net = TransitNetwork(farm_of(fields, (125, -30), stray))
    plain = TransitNetwork(farm_of(fields, (125, -30)))
    for what in ("the garage is", "field 'A' is", "field 'B' is"):
        assert f"{what} " in caplog.text
        assert "m of driving off the roads from the nearest road" in caplog.text
    for a, b, f, g in [((125, -30), (50, 50), None, "A"), ((50, 50), (200, 50), "A", "B")]:
        assert net.route(a, b, f, g) == plain.route(a, b, f, g)
    # A road beside the fields is still driven, though going straight would be shorter.
    near = TransitNetwork(farm_of(fields, (125, -30), [[(-20, 120), (270, 120)]]))
    length, via = near.route((50, 50), (200, 50), "A", "B")
    assert length > plain.length((50, 50), (200, 50), "A", "B")
    assert all(y >= 100 for _, y in via)


def test_fields_of_many_corners_are_gone_around_with_few():
    # Centre pivots drawn as GIS circles, 360 corners each: every convex corner was a node
    # of the visibility graph (12 such took 100 s and 1.4 GB before a plan could start).
    angles = np.linspace(0.0, 2.0 * np.pi, 360, endpoint=False)
    circles = {
        f"P{k}": Polygon(
            np.column_stack([820.0 * k + 400.0 * np.cos(angles), 400.0 * np.sin(angles)])
        )
        for k in range(3)
    }
    net = TransitNetwork(farm_of(circles, (-500.0, 0.0)))
    length, via = net.route((-500.0, 0.0), (2140.0, 0.0), None, None)
    path = [(-500.0, 0.0), *via, (2140.0, 0.0)]
    assert len(net._free.nodes) <= 3 * MANY_CORNERS  # not 3 x 360
    assert not any(crosses(path, c, margin=-0.99) for c in circles.values())  # 1 m clear
    # A taut string over the three, 1 m clear: a tangent from each end (500 m from the
    # centre), an arc down to it from the top of each end circle, 820 m between the tops.
    r = 401.0
    tangent = math.sqrt(500.0**2 - r**2)
    arc = r * (math.pi / 2 - math.acos(r / 500.0))
    assert 2 * (tangent + arc + 820.0) <= length < 1.005 * 2 * (tangent + arc + 820.0)


def test_a_point_off_the_roads_joins_the_nearest_road_point():
    farm = farm_of(SQUARES, (-50, 120), [ROAD], [("B", (350, 100))])
    net = TransitNetwork(farm)
    length, via = net.route((200, 140), (350, 50), None, "B")
    assert length == pytest.approx(20 + 150 + 20 + 50)
    assert via[0] == (200, 120)


def grid_farm(rows, cols, garage, with_roads):
    """Fields of 80 m in a grid 100 m apart, with 20 m roads between them and one gate
    each (or no roads)."""
    polys = {
        f"f{r}_{c}": box(100 * c, 100 * r, 100 * c + 80, 100 * r + 80)
        for r in range(rows)
        for c in range(cols)
    }
    if not with_roads:
        return polys, farm_of(polys, garage)
    roads = [[(-10, 100 * r - 10), (100 * cols - 10, 100 * r - 10)] for r in range(rows + 1)]
    roads += [[(100 * c - 10, -10), (100 * c - 10, 100 * rows - 10)] for c in range(cols + 1)]
    gates = [(k, (p.bounds[0] + 40, p.bounds[1])) for k, p in polys.items()]
    return polys, farm_of(polys, garage, roads, gates)


@pytest.mark.parametrize("with_roads", [True, False])
def test_the_solver_matrix_stays_fast_for_200_fields(with_roads):
    # 10 x 20 fields of 80 m, 20 m roads between them, one gate each (or nothing).
    polys, farm = grid_farm(10, 20, (-30, 480), with_roads)
    start = time.perf_counter()
    net = TransitNetwork(farm)
    points = [farm.garage] + [(p.centroid.x, p.centroid.y) for p in polys.values()]
    matrix = net.length_matrix(points, [None, *polys])
    assert time.perf_counter() - start < 10.0
    assert matrix.shape == (201, 201)
    if with_roads:  # neighbours in a row: 40 down to the gate, 10 to the road, 100 along, up
        assert matrix[1, 2] == pytest.approx(40 + 10 + 100 + 10 + 40)
    else:  # straight through the road gap between them
        assert matrix[1, 2] == pytest.approx(100)
    # From f0_0 to f2_0 (two rows up, same column): around f1_0 without roads.
    assert matrix[1, 41] > 200 + (0 if with_roads else 1)
    assert matrix[1, 41] == pytest.approx(net.length(points[1], points[41], "f0_0", "f2_0"))


# --- without roads: around the fields ------------------------------------------------


def test_without_roads_the_transit_goes_around_a_field_in_between():
    fields = {"A": box(0, 0, 100, 100), "M": box(150, -50, 250, 150), "B": box(300, 0, 400, 100)}
    net = TransitNetwork(farm_of(fields, (-50, 50)))
    a, b = (90.0, 50.0), (310.0, 50.0)
    length, via = net.route(a, b, "A", "B")
    path = [a, *via, b]
    assert not crosses(path, fields["M"])
    # Around M's grown corners (1 m clearance): a -> (149, -51) -> (251, -51) -> b.
    expected = math.dist(a, (149, -51)) + 102 + math.dist((251, -51), b)
    assert length == pytest.approx(expected)
    assert length == pytest.approx(LineString(path).length)
    # The start and end fields are no obstacles for their own leg; with nothing between,
    # the route is straight.
    assert net.route((10, 10), (90, 90), "A", "A") == (
        pytest.approx(math.dist((10, 10), (90, 90))),
        (),
    )
    assert net.route((-50, 50), (10, 50), None, "A") == (pytest.approx(60.0), ())


def test_without_roads_the_garage_leg_goes_around_fields():
    fields = {"A": box(0, 0, 100, 100), "B": box(200, 0, 300, 100)}
    net = TransitNetwork(farm_of(fields, (-50, 50)))
    length, via = net.route((-50, 50), (250, 50), None, "B")
    assert not crosses([(-50, 50), *via, (250, 50)], fields["A"])
    assert length > 300


def test_without_a_gate_a_field_is_left_and_entered_around_its_own_holes():
    """A field with no gate is left (and entered) straight across itself; where that line
    would cross one of its holes (a pond, a barn) it goes around inside the field instead
    (it drove 200 m across a pond: review of 2026-11-27)."""
    pond = box(60, 60, 240, 240)
    holed = Polygon(box(0, 0, 300, 300).exterior, [pond.exterior.coords[::-1]])
    fields = {"P": holed, "B": box(400, 0, 500, 300)}
    net = TransitNetwork(farm_of(fields, (650, 150)))
    for a, b, f_from, f_to in [
        ((10.0, 150.0), (410.0, 150.0), "P", "B"),  # out of P, across the pond's line
        ((410.0, 150.0), (10.0, 150.0), "B", "P"),  # into P from the far side
        ((650.0, 150.0), (10.0, 150.0), None, "P"),  # from the garage
    ]:
        length, via = net.route(a, b, f_from, f_to)
        path = [a, *via, b]
        assert not crosses(path, pond), (f_from, f_to, path)
        assert length == pytest.approx(LineString(path).length)
        assert length > math.dist(a, b)
        # The solver's matrix says the same.
        assert net.lengths([a], [f_from], [b], [f_to])[0, 0] == pytest.approx(length)
    # A way that misses the hole is left straight.
    assert net.route((10.0, 20.0), (410.0, 20.0), "P", "B") == (pytest.approx(400.0), ())


def test_a_field_on_anothers_fence_reaches_the_road_around_it(caplog):
    """Field N on S's north fence, the road south of S: N's gate was put on the fence they
    share (nearest the road), a hair inside S once projected, and its way to the road went
    straight through S for 99 m (review of 2026-11-27). So was a field's gate at a corner
    two fields share, and a road ending inside a field drew its neighbours' gates across it
    to its end."""
    S, N = box(0, 0, 300, 100), box(0, 100.002, 100, 200)
    net = TransitNetwork(farm_of({"S": S, "N": N}, (-50, -15), roads=[[(-50, -15), (350, -15)]]))
    inside = (50.0, 150.0)
    for a, b, f, g in [(inside, (-50.0, -15.0), "N", None), ((-50.0, -15.0), inside, None, "N")]:
        length, via = net.route(a, b, f, g)
        assert not crosses([a, *via, b], S) and length == pytest.approx(
            LineString([a, *via, b]).length
        )
    # A road that ends 50 m inside F3: F4 beyond it is not reached across F3.
    fields = {k: box(200 * i, 0, 200 * i + 150, 100) for i, k in enumerate(["F1", "F2", "F3"])}
    spur = [[(-50, -15), (380, -15)], [(380, -15), (460, 50)]]
    fields["F4"] = box(600, 0, 750, 100)
    net = TransitNetwork(farm_of(fields, (-50, -15), roads=spur))
    a, b = (675.0, 50.0), (-50.0, -15.0)
    length, via = net.route(a, b, "F4", None)
    assert not crosses([a, *via, b], fields["F3"])
    # A machine stopped beside a field, the road beyond that field: around it to the road.
    p = (275.0, 115.0)
    length, via = net.route(p, (75.0, 50.0), None, "F1")
    assert not crosses([p, *via, (75.0, 50.0)], fields["F2"])


def test_a_gate_drawn_inside_its_field_is_on_its_fence():
    """With roads, a gate drawn 40 m inside its field was driven to as drawn: from the
    fence into the crop and back out (review)."""
    field = box(0, 0, 150, 100)
    farm = farm_of(
        {"F": field}, (-50, -15), roads=[[(-50, -15), (300, -15)]], gates=[("F", (75, 40))]
    )
    net = TransitNetwork(farm)
    assert net.gates["F"] == ((75.0, 0.0),)
    length, via = net.route((140.0, 90.0), (-50.0, -15.0), "F", None)
    assert (75.0, 40.0) not in via and (75.0, 0.0) in via


def test_a_field_in_anothers_hole_is_said_to_be_reached_across_it(caplog):
    """A field in a hole of another was reached across it without a word (review)."""
    outer = Polygon(box(0, 0, 300, 300).exterior, [box(100, 100, 200, 200).exterior.coords[::-1]])
    fields = {"O": outer, "I": box(120, 120, 180, 180)}
    with caplog.at_level(logging.WARNING):
        TransitNetwork(farm_of(fields, (-50, 150)))
    assert "field 'I' lies in a hole of field 'O': its transit crosses 'O'" in caplog.text


def test_a_stray_road_by_the_garage_is_named_not_every_field(caplog):
    """A driveway by the garage that joins no other road took the garage: every field was
    "not connected to the garage", the road at fault unnamed (review)."""
    fields = {"A": box(0, 0, 100, 100), "B": box(200, 0, 300, 100)}
    roads = [[(-20, -15), (320, -15)], [(-60, -40), (-60, 10)]]  # the main road; the stray
    with caplog.at_level(logging.WARNING):
        TransitNetwork(farm_of(fields, (-57, -20), roads=roads))
    assert "the road the garage joins (at lon" in caplog.text
    assert "leads to no field while the fields' roads join each other" in caplog.text
    assert "do not connect field" not in caplog.text


def test_roads_all_shorter_than_the_join_are_no_roads(caplog):
    """Every road shorter than ROAD_JOIN_M (a stub drawn by a slip of the mouse): joined
    into a point, no network left, and a traceback (exit 1). Now: said, and no roads."""
    fields = {"A": box(0, 0, 100, 100)}
    with caplog.at_level(logging.WARNING):
        net = TransitNetwork(farm_of(fields, (-50, 50), roads=[[(-20, 0), (-20, 0.3)]]))
    assert not net.has_roads
    assert "each shorter than 0.5 m once their ends are joined" in caplog.text
    assert net.route((-50, 50), (50, 50), None, "A")[0] == pytest.approx(100.0)


def test_corner_dp_with_transit_is_the_best_of_all_combinations():
    fields = {"A": box(0, 0, 100, 60), "M": box(150, -80, 250, 140), "B": box(300, 0, 360, 90)}
    farm = farm_of(fields, (-60, 30))
    net = TransitNetwork(farm)
    covs = [cover_field(fields[k], 6.0, field_id=k) for k in ("A", "B")]
    corners, road = best_corners(farm.garage, covs, net)

    def length(choice):
        total, where, inside = 0.0, farm.garage, None
        for cov, c in zip(covs, choice, strict=True):
            total += net.length(where, cov.entry(c), inside, cov.field_id)
            total += cov.transit_inside_m(c)
            where, inside = cov.exit(c), cov.field_id
        return total + net.length(where, farm.garage, inside, None)

    brute = min(itertools.product(range(4), repeat=len(covs)), key=length)
    assert road == pytest.approx(length(brute))
    assert road == pytest.approx(length(corners))


# --- the demo farm -------------------------------------------------------------------


@pytest.fixture(scope="module")
def demo_plan():
    farm = load_farm(ROOT / "config/changji.geojson")
    return plan_farm(farm, FLEET, "makespan", "ighoa", stop_after(60), seed=1)


def test_demo_roads_cross_no_field():
    farm = load_farm(ROOT / "config/changji.geojson")
    assert len(farm.roads) >= 10
    assert sorted(g.field_id for g in farm.gates) == sorted(f.id for f in farm.fields)
    for road in farm.roads:
        for f in farm.fields:
            assert not road.line.intersects(f.boundary), (road.id, f.id)


def test_demo_transit_crosses_no_other_field(demo_plan):
    farm = demo_plan.farm
    legs = 0
    for route in demo_plan.machines:
        where, inside = farm.garage, None
        for visit in route.visits:
            path = [where, *visit.approach, visit.entry]
            others = [f for f in farm.fields if f.id not in (inside, visit.field.id)]
            for f in others:
                assert not crosses(path, f.boundary), (
                    route.machine.id,
                    inside,
                    visit.field.id,
                    f.id,
                )
            where, inside = visit.exit, visit.field.id
            legs += 1
        if route.visits:
            path = [where, *route.return_path, farm.garage]
            for f in farm.fields:
                if f.id != inside:
                    assert not crosses(path, f.boundary), (route.machine.id, inside, f.id)
            legs += 1
    assert legs == len(farm.fields) + 3


def test_demo_road_metres_are_the_transit_lengths(demo_plan):
    farm = demo_plan.farm
    for route in demo_plan.machines:
        driven = 0.0
        where = farm.garage
        for visit in route.visits:
            driven += LineString([where, *visit.approach, visit.entry]).length
            driven += visit.coverage.transit_inside_m(visit.corner)
            where = visit.exit
        driven += LineString([where, *route.return_path, farm.garage]).length
        assert route.road_m == pytest.approx(driven, rel=1e-9)


@pytest.mark.parametrize("with_roads", [True, False])
def test_lengths_from_many_points_equal_the_routes_one_by_one(with_roads):
    # 4 x 4 fields of 80 m; sources in fields, on the roads and at the garage.
    polys, farm = grid_farm(4, 4, (-30, 180), with_roads)
    net = TransitNetwork(farm)
    sources = [farm.garage, (10.0, 10.0), (250.0, 190.0), (390.0, 5.0), (-30.0, 180.0)]
    source_fields = [None, "f0_0", None, None, None]
    targets = [(p.centroid.x, p.centroid.y) for p in polys.values()]
    got = net.lengths(sources, source_fields, targets, list(polys))
    want = [
        [net.length(a, b, f, g) for b, g in zip(targets, polys, strict=True)]
        for a, f in zip(sources, source_fields, strict=True)
    ]
    assert got == pytest.approx(np.array(want))
    assert got[0, 15] > math.dist(sources[0], targets[15])  # around fields in the way


def test_a_road_logged_every_two_metres_is_driven_as_a_few_points():
    """A 2 km track logged by GPS every 2 m, wobbling 0.2 m: simplified to within
    ROAD_SIMPLIFY_M, its route has a handful of points, not a thousand mission items."""
    track = [(x, 120.0 + 0.2 * math.sin(x)) for x in np.arange(-50.0, 2000.0, 2.0)]
    fields = {"A": box(0, 0, 100, 100), "B": box(1800, 0, 1900, 100)}
    farm = farm_of(fields, (-50, 120), [track], [("A", (50, 100)), ("B", (1850, 100))])
    length, via = TransitNetwork(farm).route((50, 50), (1850, 50), "A", "B")
    assert len(via) < 10
    assert length == pytest.approx(50 + 20 + 1800 + 20 + 50, abs=2.0)


def test_a_phone_logged_road_of_metre_noise_is_driven_as_the_road():
    """A track logged every metre, wandering ±0.8 m (a phone's GPS): at ROAD_SIMPLIFY_M
    alone its route kept a waypoint a metre and three times the road's length (review);
    each stretch between junctions is smoothed to ROAD_SMOOTH_M."""
    rng = np.random.default_rng(1)
    xs = np.arange(-50.0, 2000.0, 1.0)
    track = list(zip(xs, 120.0 + rng.uniform(-0.8, 0.8, len(xs)), strict=True))
    fields = {"A": box(0, 0, 100, 100), "B": box(1800, 0, 1900, 100)}
    farm = farm_of(fields, (-50, 120), [track], [("A", (50, 100)), ("B", (1850, 100))])
    length, via = TransitNetwork(farm).route((50, 50), (1850, 50), "A", "B")
    assert len(via) < 20
    assert length == pytest.approx(50 + 20 + 1800 + 20 + 50, rel=0.01)


def test_no_way_around_is_said_with_the_fields_it_is_between(caplog):
    """A yard closed all round by four fields, the garage in it: from a field outside
    there is no way around; the warning names the farm and the places, not local metres."""
    fields = {
        "S": box(-100, -100, 200, 0),
        "N": box(-100, 100, 200, 200),
        "W": box(-100, 0, 0, 100),
        "E": box(100, 0, 200, 100),
        "C": box(300, 0, 360, 60),
    }
    net = TransitNetwork(farm_of(fields, (50, 50)))
    with caplog.at_level(logging.WARNING, logger="planner.roads"):
        net.route((330.0, 30.0), (50.0, 50.0), "C", None)
    assert (
        "<memory>: no way around the other fields from field 'C' to the garage (or a point "
        "off the fields)"
    ) in caplog.text


def test_a_garage_by_a_fence_goes_around_that_field_too():
    """Half a metre from a field's fence (within its clearance, outside the field) the
    garage went straight across that field: it was no obstacle for the garage's legs."""
    fields = {"A": box(0, 0, 100, 100), "B": box(200, 0, 300, 100)}
    garage, north = (50.0, -0.5), (50.0, 150.0)
    net = TransitNetwork(farm_of(fields, garage))
    length, via = net.route(garage, north, None, None)
    assert not crosses([garage, *via, north], fields["A"])
    assert via == ((101.0, -1.0), (101.0, 101.0))  # round A's grown corners
    assert length == pytest.approx(LineString([garage, *via, north]).length)
    matrix = net.length_matrix([garage, (250.0, 50.0), north], [None, "B", None])
    assert matrix[0, 2] == pytest.approx(length)
    assert matrix[0, 1] == pytest.approx(net.length(garage, (250.0, 50.0), None, "B"))


def test_the_way_from_a_gate_onto_the_road_goes_around_a_field_in_between():
    """A's gate faces B, and the road runs beyond B: the way from the gate onto the road
    went straight through B; it goes around it, and so does the garage's."""
    fields = {"A": box(0, 0, 100, 100), "B": box(0, 150, 100, 250), "C": box(300, 150, 400, 250)}
    road = [(-100.0, 300.0), (500.0, 300.0)]
    farm = farm_of(fields, (50, -60), [road], [("A", (50, 100)), ("C", (350, 250))])
    net = TransitNetwork(farm)
    length, via = net.route((50, 50), (350, 200), "A", "C")
    assert not crosses([(50, 50), *via, (350, 200)], fields["B"])
    assert length == pytest.approx(LineString([(50, 50), *via, (350, 200)]).length)
    back = net.route((50, 200), (50, -60), "B", None)  # the garage, behind A from the road
    assert not crosses([(50, 200), *back[1], (50, -60)], fields["A"])


def test_without_roads_a_gated_field_is_left_and_entered_through_its_gate():
    """A fenced field with its gate on the far side from the garage: the transit goes
    round to the gate (it went straight through the fence), and from one gated field to
    the next through both gates; every way agrees with the matrix the solver gets."""
    fields = {"A": box(0, 0, 100, 100), "B": box(200, 0, 300, 100)}
    gates = [("A", (50.0, 100.0)), ("B", (300.0, 50.0))]
    net = TransitNetwork(farm_of(fields, (50, -50), gates=gates))
    garage, a, b = (50.0, -50.0), (50.0, 50.0), (250.0, 50.0)
    length, via = net.route(garage, a, None, "A")
    path = [garage, *via, a]
    assert (50.0, 100.0) in via
    assert not crosses(path[: path.index((50.0, 100.0)) + 1], fields["A"])  # round A, not across
    assert length == pytest.approx(LineString(path).length)
    assert length > 150 + 100  # round a corner to the north side, then in to the middle
    length, via = net.route(a, b, "A", "B")
    path = [a, *via, b]
    assert (50.0, 100.0) in via and (300.0, 50.0) in via
    assert via.index((50.0, 100.0)) < via.index((300.0, 50.0))
    between = path[path.index((50.0, 100.0)) : path.index((300.0, 50.0)) + 1]
    assert not crosses(between, fields["A"]) and not crosses(between, fields["B"])
    assert length == pytest.approx(LineString(path).length)
    points, owners = [garage, a, b], [None, "A", "B"]
    matrix = net.length_matrix(points, owners)
    for i, j in itertools.permutations(range(3), 2):
        assert matrix[i, j] == pytest.approx(net.length(points[i], points[j], owners[i], owners[j]))
    assert net.lengths(points, owners, points[1:], owners[1:]) == pytest.approx(matrix[:, 1:])
    # A field without a gate is still entered straight from wherever is nearest.
    open_field = TransitNetwork(farm_of(fields, (50, -50), gates=[("B", (300.0, 50.0))]))
    assert open_field.route(garage, a, None, "A") == (pytest.approx(100.0), ())


@pytest.mark.parametrize("angle", [0.0, 45.0])
def test_fields_two_metres_apart_do_not_hang_the_router(angle):
    """Grown by 1 m each, fields 2 m apart have corners that coincide: the walk along the
    shortest paths went from one to the other for ever (a plan hung past its time limit),
    then, turned 45 degrees, round a long way that the length did not count."""
    polys = {
        f"f{r}_{c}": shapely.affinity.rotate(
            box(82.0 * c, 82.0 * r, 82.0 * c + 80, 82.0 * r + 80), angle, origin=(0, 0)
        )
        for r in range(3)
        for c in range(4)
    }
    net = TransitNetwork(farm_of(polys, (-20.0, -20.0)))
    points = [(-20.0, -20.0)] + [(p.centroid.x, p.centroid.y) for p in polys.values()]
    ids = [None, *polys]
    for i, j in itertools.permutations(range(len(points)), 2):
        length, via = net.route(points[i], points[j], ids[i], ids[j])
        path = [points[i], *via, points[j]]
        assert length == pytest.approx(LineString(path).length)
        assert not any(crosses(path, p) for f, p in polys.items() if f not in (ids[i], ids[j]))


def test_a_gate_drawn_inside_its_field_is_used_where_the_fence_is():
    """A gate digitised 3 m inside the field: its way out was inside the field too, and the
    transit went straight across the field again."""
    fields = {"A": box(0, 0, 100, 100)}
    net = TransitNetwork(farm_of(fields, (50, -50), gates=[("A", (50.0, 97.0))]))
    length, via = net.route((50.0, -50.0), (50.0, 50.0), None, "A")
    assert (50.0, 100.0) in via  # on the fence
    path = [(50.0, -50.0), *via]
    assert not crosses(path[: path.index((50.0, 100.0)) + 1], fields["A"])
    assert length > 250


def test_a_gate_into_a_neighbouring_field_is_no_way_out():
    """A's only gate is in the fence it shares with B: leaving by it is driving into B, so A
    is left and entered as a field without a gate, and B is not crossed."""
    fields = {"A": box(0, 0, 100, 100), "B": box(100, 0, 200, 100), "C": box(300, 0, 400, 100)}
    gates = [("A", (100.0, 50.0)), ("B", (150.0, 0.0))]
    net = TransitNetwork(farm_of(fields, (-50, 50), gates=gates))
    assert net.route((-50.0, 50.0), (50.0, 50.0), None, "A") == (pytest.approx(100.0), ())
    length, via = net.route((50.0, 50.0), (350.0, 50.0), "A", "C")
    assert not crosses([(50.0, 50.0), *via, (350.0, 50.0)], fields["B"])


def test_a_gate_on_the_side_away_from_the_road_is_reached_around_its_field():
    """The road runs north of the field, its gate is in the south fence: the way from the
    road to the gate went straight across the field."""
    fields = {"A": box(0, 0, 100, 100)}
    road = [(-60.0, 120.0), (160.0, 120.0)]
    net = TransitNetwork(farm_of(fields, (-60, 120), [road], [("A", (50.0, 0.0))]))
    length, via = net.route((-60.0, 120.0), (50.0, 50.0), None, "A")
    path = [(-60.0, 120.0), *via]
    assert (50.0, 0.0) in via
    assert not crosses(path[: path.index((50.0, 0.0)) + 1], fields["A"])
    assert length == pytest.approx(LineString([*path, (50.0, 50.0)]).length)


def test_a_gate_on_a_pond_in_the_field_is_no_way_out_and_is_said_so(caplog):
    field = box(0, 0, 100, 100).difference(box(30, 30, 60, 60))
    net = TransitNetwork(farm_of({"A": field}, (50, 150), gates=[("A", (45.0, 30.0))]))
    with caplog.at_level(logging.WARNING, logger="planner.roads"):
        length, via = net.route((50.0, 150.0), (20.0, 20.0), None, "A")
    assert "the gate of field 'A'" in caplog.text and "opens onto a hole" in caplog.text
    assert length == pytest.approx(math.dist((50.0, 150.0), (20.0, 20.0)))  # as if none


def test_a_gate_at_the_tip_of_a_narrow_inlet_is_used():
    """An inlet of 50 degrees into the field from the north, its gate at the tip: the way
    out lies in the inlet, close to both fences; it was taken for no way out."""
    inlet = Polygon([(40, 100), (50, 80), (60, 100)]).buffer(0)
    field = box(0, 0, 100, 100).difference(inlet)
    net = TransitNetwork(farm_of({"A": field}, (50, -50), gates=[("A", (50.0, 80.0))]))
    length, via = net.route((50.0, -50.0), (20.0, 20.0), None, "A")
    assert (50.0, 80.0) in via and length > 250  # round to the north, in at the tip
