"""The plan for other tools (dispatcher/mission/export.py): plan.geojson and plan.kml read
back with pyogrio carry every field and every machine's route within 1 cm, and field ids
as they are whatever their characters; the .plan files' fence holds every waypoint, loads
by QGroundControl's rules and is simple as written; nothing is written when a writer fails.
And `agrifleet plan` plans the tiny farm the same from every format."""

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pyogrio
import pytest
import shapely
from helpers.farm_formats import convert
from shapely.geometry import Point, Polygon
from shapely.validation import explain_validity

from agrifleet.api import dispatch_for
from dispatcher.cli.main import main
from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import load_scenario
from dispatcher.mission import export
from dispatcher.mission.files import QGC_FENCE_POLYGON_VERSION, QGC_GEOFENCE_VERSION
from dispatcher.mission.plan import plan_geojson, write_plan_files
from planner.geo import LocalFrame

DATA = Path(__file__).resolve().parents[1] / "data"
CM_DEG = 1e-7  # about 1 cm


@pytest.fixture(scope="module")
def written(dispatch, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("plan")
    write_plan_files(dispatch, out)
    return out


def read_layer(path: Path, layer: str | None = None) -> list[tuple[object, dict]]:
    meta, _, geometry, values = pyogrio.raw.read(path, layer=layer)
    names = list(meta["fields"])
    geoms = shapely.force_2d(shapely.from_wkb(geometry))  # KML has altitudes
    return [(g, {n: values[i][k] for i, n in enumerate(names)}) for k, g in enumerate(geoms)]


def waypoints(mission) -> list[tuple[float, float]]:
    return [(it.lon, it.lat) for it in mission.items if it.is_waypoint]


def check_routes(features, dispatch, id_key: str = "id") -> None:
    routes = {p["machine"]: g for g, p in features if p["kind"] == "route"}
    assert set(routes) == set(dispatch.missions)
    for machine, mission in dispatch.missions.items():
        assert np.allclose(np.asarray(routes[machine].coords), waypoints(mission), atol=CM_DEG)
    fields = {p[id_key]: g for g, p in features if p["kind"] == "field"}
    for f in dispatch.scenario.farm.fields:
        assert fields[f.id].hausdorff_distance(f.boundary_lonlat) < CM_DEG


def route_fields(value: object) -> list[str]:
    """A route's ``fields``: an array in GeoJSON, the same array as JSON text in KML (ids
    may hold spaces: a space-separated list could not be split back)."""
    return json.loads(value) if isinstance(value, str) else [str(v) for v in value]  # type: ignore[attr-defined]


def test_plan_geojson_carries_fields_routes_and_timed_swaths(written, dispatch):
    features = read_layer(written / "plan.geojson")
    check_routes(features, dispatch)
    doc = dispatch.document
    for machine in doc.machines:
        route = next(p for _, p in features if p["kind"] == "route" and p["machine"] == machine.id)
        assert route_fields(route["fields"]) == list(machine.fields)
        assert route["time_h"] == pytest.approx(machine.time_h)
        swaths = [p for _, p in features if p["kind"] == "swath" and p["machine"] == machine.id]
        assert [s["order"] for s in swaths] == list(range(1, len(swaths) + 1))
        starts = [s["start_s"] for s in swaths]
        assert starts == sorted(starts) and all(s["end_s"] > s["start_s"] for s in swaths)
        assert {s["field"] for s in swaths} == set(machine.fields)
    worked = {p["id"]: p for _, p in features if p["kind"] == "field"}
    for machine in doc.machines:
        assert [worked[f]["order"] for f in machine.fields] == list(
            range(1, len(machine.fields) + 1)
        )


def test_plan_kml_has_a_folder_per_machine(written, dispatch):
    layers = [str(name) for name, _ in pyogrio.list_layers(written / "plan.kml")]
    assert layers == [export.FARM_LAYER, *dispatch.missions]
    features = [f for layer in layers for f in read_layer(written / "plan.kml", layer)]
    check_routes(features, dispatch, id_key=export.KML_ID_PROPERTY)
    assert "<Folder" in (written / "plan.kml").read_text()


def test_plan_kml_and_geojson_keep_field_ids_xml_cannot_hold_as_an_attribute(tmp_path):
    # GDAL's KML writer put a column "id" unescaped into <Placemark id="...">: a Google
    # Earth placemark named "Schlag 3 & 4" (its field id) made plan.kml unreadable, and
    # `agrifleet plan` failed on reopening it for the machines' folders.
    ids = {"A": "Schlag 3 & 4", "B": '<B> "Süd"', "C": "3 'C' > 2"}
    roads = {"lane": "lane & <yard>", "yard": 'yard "1"'}
    doc = json.loads((DATA / "tiny-farm.geojson").read_text())
    for f in doc["features"]:
        props = f["properties"]
        if props["kind"] == "field":
            props["id"] = ids[props["id"]]
        elif props["kind"] == "road":
            props["id"] = roads[props["id"]]
        elif props["kind"] == "gate":
            props["field"] = ids[props["field"]]
    (tmp_path / "farm.geojson").write_text(json.dumps(doc))
    out = tmp_path / "out"
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(tmp_path / "farm.geojson")]
    assert main([*args, "--out", str(out), "--time-limit", "60", "--seed", "3"]) == 0
    plan = json.loads((out / "plan.json").read_text())
    ET.parse(out / "plan.kml")  # well-formed XML
    layers = [str(name) for name, _ in pyogrio.list_layers(out / "plan.kml")]
    assert layers == [export.FARM_LAYER, *(m["id"] for m in plan["machines"])]
    kml = [p for layer in layers for _, p in read_layer(out / "plan.kml", layer)]
    geojson = [p for _, p in read_layer(out / "plan.geojson")]
    for features, id_key in ((kml, export.KML_ID_PROPERTY), (geojson, "id")):
        assert sorted(p[id_key] for p in features if p["kind"] == "field") == sorted(ids.values())
        assert sorted(p[id_key] for p in features if p["kind"] == "road") == sorted(roads.values())
        for m in plan["machines"]:
            route = next(p for p in features if p["kind"] == "route" and p["machine"] == m["id"])
            assert route_fields(route["fields"]) == m["fields"]
            swaths = {
                p["field"] for p in features if p["kind"] == "swath" and p["machine"] == m["id"]
            }
            assert swaths == set(m["fields"])
    assert {f for m in plan["machines"] for f in m["fields"]} == set(ids.values())


def test_the_plan_files_fence_the_farm_and_rally_at_the_garage(written, dispatch):
    glon, glat = dispatch.scenario.farm.garage_lonlat
    for machine, mission in dispatch.missions.items():
        doc = json.loads((written / f"{machine}.plan").read_text())
        fence = doc["geoFence"]
        assert fence["version"] == QGC_GEOFENCE_VERSION and fence["circles"] == []
        inclusion = [p for p in fence["polygons"] if p["inclusion"] is True]
        assert len(inclusion) == 1  # ArduPilot keeps a vehicle inside every one at once
        for p in fence["polygons"]:
            assert p["version"] == QGC_FENCE_POLYGON_VERSION and len(p["polygon"]) >= 3
            assert p["polygon"][0] != p["polygon"][-1]  # QGroundControl's are not closed
        areas = [Polygon([(lon, lat) for lat, lon in p["polygon"]]) for p in inclusion]
        for lon, lat in waypoints(mission):
            assert any(a.contains(Point(lon, lat)) for a in areas)
        for f in dispatch.scenario.farm.fields:
            assert any(a.contains(f.boundary_lonlat) for a in areas)
        assert doc["rallyPoints"]["version"] == 2
        assert doc["rallyPoints"]["points"] == [[glat, glon, 0.0]]


def road_at_the_margins_farm(origin: tuple[float, float], gap_m: float) -> dict:
    """A field with a road along its north side ``gap_m`` away (their fence margins touch
    at 2 x FENCE_MARGIN_M) that turns south 25.5 m west of it, to the garage."""
    frame = LocalFrame.around(*origin)

    def lonlat(points):
        return [[float(v) for v in frame.to_lonlat(x, y)] for x, y in points]

    w, h = 123.4, 77.7
    road = [(-25.5, -30.0), (-25.5, h + gap_m), (w + 50.0, h + gap_m)]
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"id": "A"},
                "geometry": {
                    "type": "Polygon",
                    "coordinates": [lonlat([(0, 0), (w, 0), (w, h), (0, h), (0, 0)])],
                },
            },
            {
                "type": "Feature",
                "properties": {"kind": "road", "id": "r"},
                "geometry": {"type": "LineString", "coordinates": lonlat(road)},
            },
            {
                "type": "Feature",
                "properties": {"kind": "garage"},
                "geometry": {"type": "Point", "coordinates": lonlat(road[:1])[0]},
            },
        ],
    }


@pytest.mark.parametrize("gap_m", [2 * export.FENCE_MARGIN_M, 2 * export.FENCE_MARGIN_M + 0.001])
@pytest.mark.parametrize("origin", [(151.0, -33.9), (87.3, 44.0)])
def test_a_road_at_twice_the_margin_from_a_field_leaves_every_fence_simple(tmp_path, origin, gap_m):
    # Where the margins touch, the fence's outline passed twice within a millimetre of one
    # point: rounded to 7 decimals, it crossed itself there (QGroundControl and the
    # autopilot take such a polygon's inside wrongly).
    farm = road_at_the_margins_farm(origin, gap_m)
    (tmp_path / "farm.geojson").write_text(json.dumps(farm))
    out = tmp_path / "out"
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(tmp_path / "farm.geojson")]
    args += ["--machines", "1", "--out", str(out)]
    assert main([*args, "--time-limit", "60", "--seed", "3"]) == 0
    field = Polygon(farm["features"][0]["geometry"]["coordinates"][0])
    garage = Point(farm["features"][2]["geometry"]["coordinates"])
    doc = json.loads((out / "v1.plan").read_text())
    fence = doc["geoFence"]["polygons"]
    polygons = [Polygon([(lon, lat) for lat, lon in p["polygon"]]) for p in fence]
    for k, polygon in enumerate(polygons):
        assert polygon.is_valid, f"v1.plan: fence polygon #{k}: {explain_validity(polygon)}"
    inclusion = [a for p, a in zip(fence, polygons, strict=True) if p["inclusion"]]
    exclusion = [a for p, a in zip(fence, polygons, strict=True) if not p["inclusion"]]
    items = [i for i in doc["mission"]["items"] if i["command"] == 16]
    home = doc["mission"]["plannedHomePosition"]
    points = [Point(i["params"][5], i["params"][4]) for i in items] + [Point(home[1], home[0])]
    points += [Point(lon, lat) for lat, lon, _ in doc["rallyPoints"]["points"]]
    for point in points:
        assert any(a.contains(point) for a in inclusion), point
        assert not any(a.contains(point) for a in exclusion), point
    assert any(a.contains(field) for a in inclusion)
    assert any(a.contains(garage) for a in inclusion)


def test_a_road_apart_from_the_rest_makes_no_second_inclusion_polygon(tmp_path):
    # ArduPilot is in breach outside any of its inclusion polygons: a stray road 1 km off
    # (in no path) made a second one, and the rover was in breach everywhere.
    farm = road_at_the_margins_farm((87.3, 44.0), 10.0)
    frame = LocalFrame.around(87.3, 44.0)
    stray = [[float(v) for v in frame.to_lonlat(x, 1000.0)] for x in (0.0, 200.0)]
    farm["features"].append(
        {
            "type": "Feature",
            "properties": {"kind": "road", "id": "stray"},
            "geometry": {"type": "LineString", "coordinates": stray},
        }
    )
    (tmp_path / "farm.geojson").write_text(json.dumps(farm))
    out = tmp_path / "out"
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(tmp_path / "farm.geojson")]
    assert main([*args, "--machines", "1", "--out", str(out), "--time-limit", "5"]) == 0
    doc = json.loads((out / "v1.plan").read_text())
    (inclusion,) = [p for p in doc["geoFence"]["polygons"] if p["inclusion"]]
    area = Polygon([(lon, lat) for lat, lon in inclusion["polygon"]])
    items = [i for i in doc["mission"]["items"] if i["command"] == 16]
    assert all(area.contains(Point(i["params"][5], i["params"][4])) for i in items)
    assert not area.intersects(Point(stray[0]))


def test_a_farm_across_the_antimeridian_gets_no_fence(tmp_path, caplog):
    # A fence ring across longitude 180 jumped from 179.99 to -179.99: ArduPilot, testing
    # raw longitudes, took its inside as the rest of the world.
    farm = road_at_the_margins_farm((179.9993, -17.0), 10.0)
    for feature in farm["features"]:  # as GeoJSON has it: within [-180, 180]
        geometry = feature["geometry"]
        geometry["coordinates"] = json.loads(
            json.dumps(geometry["coordinates"]),
            parse_float=lambda v: float(v) - 360.0 if float(v) > 180.0 else float(v),
        )
    (tmp_path / "farm.geojson").write_text(json.dumps(farm))
    out = tmp_path / "out"
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(tmp_path / "farm.geojson")]
    with caplog.at_level("WARNING", logger="dispatcher.mission.export"):
        assert main([*args, "--machines", "1", "--out", str(out), "--time-limit", "5"]) == 0
    lons = [c[0] for c in farm["features"][0]["geometry"]["coordinates"][0]]
    assert max(lons) - min(lons) > 180.0  # the field itself crosses it
    assert (out / "v1.waypoints").exists()
    assert json.loads((out / "v1.plan").read_text())["geoFence"]["polygons"] == []
    assert "the farm's fence crosses longitude 180" in caplog.text
    assert "not simple" not in caplog.text  # said first, not as a ring crossing itself


def test_a_farm_on_both_sides_of_the_antimeridian_is_said_to_be(tmp_path, caplog):
    """Fields on both sides of longitude 180, the garage on it (a review's farm): in
    lat/lon the fence crossed itself and was refused as "not simple", the antimeridian
    unsaid."""
    out = tmp_path / "out"
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(DATA / "antimeridian-farm.geojson")]
    with caplog.at_level("WARNING", logger="dispatcher.mission.export"):
        assert main([*args, "--out", str(out), "--time-limit", "3"]) == 0
    assert "the farm's fence crosses longitude 180" in caplog.text
    assert "not simple" not in caplog.text


def test_nothing_is_written_when_a_writer_fails(dispatch, tmp_path, monkeypatch):
    def broken(*_args):
        raise OSError("disk full")

    monkeypatch.setattr(export, "write_plan_kml", broken)
    with pytest.raises(OSError, match="disk full"):
        write_plan_files(dispatch, tmp_path / "out")
    assert list(tmp_path.iterdir()) == []


def plan_json(tmp_path: Path, farm: Path, *extra: str) -> dict:
    out = tmp_path / f"out-{farm.name}"
    # A generation limit, not the clock, ends the solver: the same seed gives the same plan.
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(farm), "--out", str(out)]
    assert main([*args, "--time-limit", "60", "--seed", "3", *extra]) == 0
    return json.loads((out / "plan.json").read_text())


def essentials(doc: dict) -> list:
    return [(m["id"], m["fields"], m["distance_m"], m["time_h"]) for m in doc["machines"]]


@pytest.mark.parametrize("fmt", ["kml", "shp-zip", "gpkg", "isoxml"])
def test_agrifleet_plan_plans_the_same_from_every_format(tmp_path, fmt):
    reference = plan_json(tmp_path, DATA / "tiny-farm.geojson")
    farm = convert(DATA / "tiny-farm.geojson", fmt, tmp_path / fmt)
    if fmt == "isoxml":  # no roads in ISOXML: compare with the farm without them
        doc = json.loads((DATA / "tiny-farm.geojson").read_text())
        doc["features"] = [f for f in doc["features"] if f["properties"]["kind"] != "road"]
        (tmp_path / "noroads.geojson").write_text(json.dumps(doc))
        reference = plan_json(tmp_path, tmp_path / "noroads.geojson")
        converted = plan_json(tmp_path, farm, "--id-field", "code")
    else:
        converted = plan_json(tmp_path, farm)
    assert essentials(converted) == essentials(reference)
    assert converted["totals"] == reference["totals"]


def test_the_scenario_gives_the_garage_and_the_id_field(tmp_path):
    doc = json.loads((DATA / "tiny-farm.geojson").read_text())
    garage = next(f for f in doc["features"] if f["properties"]["kind"] == "garage")
    doc["features"] = [f for f in doc["features"] if f is not garage]
    for f in doc["features"]:
        if f["properties"]["kind"] == "field":
            f["properties"]["PLOT"] = f["properties"].pop("id")
        else:
            f["properties"].pop("id", None)
    (tmp_path / "farm.geojson").write_text(json.dumps(doc))
    lon, lat = garage["geometry"]["coordinates"]
    text = (
        (DATA / "tiny.toml")
        .read_text()
        .replace(
            'farm = "tiny-farm.geojson"',
            f'farm = "farm.geojson"\ngarage = [{lon}, {lat}]\nid_field = "PLOT"',
        )
    )
    (tmp_path / "tiny.toml").write_text(text)
    scenario = load_scenario(tmp_path / "tiny.toml")
    assert scenario.farm.garage_lonlat == (lon, lat)
    assert [f.id for f in scenario.farm.fields] == ["A", "B", "C"]
    (tmp_path / "bad.toml").write_text(text.replace(f"garage = [{lon}, {lat}]", 'garage = "barn"'))
    with pytest.raises(
        ConfigError, match=r"bad.toml: key 'garage' must be \[longitude, latitude\]"
    ):
        load_scenario(tmp_path / "bad.toml")


def test_a_pond_in_a_field_is_an_exclusion_no_path_enters(tmp_path):
    def ring(x0, y0, w, h):  # metres east and north of 87.3 E, 44.0 N
        lon = lambda x: 87.3 + x / 80_190.0  # noqa: E731 (metres per degree at 44 N)
        lat = lambda y: 44.0 + y / 111_050.0  # noqa: E731
        return [
            [lon(x), lat(y)]
            for x, y in [(x0, y0), (x0 + w, y0), (x0 + w, y0 + h), (x0, y0 + h), (x0, y0)]
        ]

    doc = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"id": "P"},
                "geometry": {
                    "type": "Polygon",
                    "coordinates": [ring(0, 0, 160, 160), ring(50, 50, 60, 60)[::-1]],
                },
            },
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "Point", "coordinates": ring(-20, -20, 0, 0)[0]},
            },
        ],
    }
    (tmp_path / "pond.geojson").write_text(json.dumps(doc))
    out = tmp_path / "out"
    args = ["plan", str(DATA / "tiny.toml"), "--fields", str(tmp_path / "pond.geojson")]
    assert main([*args, "--machines", "1", "--out", str(out)]) == 0
    plan = json.loads((out / "v1.plan").read_text())
    exclusion = [p for p in plan["geoFence"]["polygons"] if p["inclusion"] is False]
    assert len(exclusion) == 1
    pond = Polygon([(lon, lat) for lat, lon in exclusion[0]["polygon"]])
    assert pond.area > 0
    items = [i for i in plan["mission"]["items"] if i["command"] == 16]
    assert not any(pond.contains(Point(i["params"][5], i["params"][4])) for i in items)
    # The map the live view and a GIS read shows it too (the outline alone before).
    scenario = load_scenario(DATA / "tiny.toml", tmp_path / "pond.geojson")
    dispatch = dispatch_for(scenario.with_machines(1), time_limit_s=2)
    shown = plan_geojson(dispatch)
    (field,) = [f for f in shown["features"] if f["properties"]["kind"] == "field"]
    assert len(field["geometry"]["coordinates"]) == 2
    # Every feature named and styled for Foxglove's Map panel (docs/recording.md).
    for feature in shown["features"]:
        props = feature["properties"]
        assert props["name"] and props["style"]["color"].startswith("#"), props
    # And so does the plan document, that review reads back from a log.
    (planned,) = dispatch.document.fields.values()
    assert [list(map(list, r)) for r in planned.rings] == field["geometry"]["coordinates"]
