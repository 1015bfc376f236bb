"""Farm files: every bad file refused with a GeometryError naming the file and the feature.

Unknown feature kinds, a number or string where a feature, geometry, ring or position
belongs, coordinates that look swapped, and a farm spread wider than
:data:`planner.farm.MAX_GARAGE_DISTANCE_M`.
"""

import contextlib
import copy
import json
import logging
import math
import re
from pathlib import Path
from typing import Any

import pytest
import shapely

from planner.errors import GeometryError
from planner.farm import KINDS, MAX_ABS_LATITUDE, Farm, FarmOptions, load_farm

DATA = Path(__file__).resolve().parents[1] / "data"
LON0, LAT0 = 10.0, 50.0  # central Germany: swapped, [50, 10] is in the Horn of Africa


def rect(lon0: float, lat0: float, w_m: float = 120.0, h_m: float = 80.0) -> list[list[float]]:
    dlon = w_m / (111320 * math.cos(math.radians(lat0)))
    dlat = h_m / 110540
    return [
        [lon0, lat0],
        [lon0 + dlon, lat0],
        [lon0 + dlon, lat0 + dlat],
        [lon0, lat0 + dlat],
        [lon0, lat0],
    ]


def feature(kind: Any, geometry: Any, **props: Any) -> dict[str, Any]:
    return {"type": "Feature", "properties": {"kind": kind, **props}, "geometry": geometry}


def field(fid: str, ring: list[list[float]]) -> dict[str, Any]:
    return feature("field", {"type": "Polygon", "coordinates": [ring]}, id=fid)


def point(kind: str, lon: float, lat: float, **props: Any) -> dict[str, Any]:
    return feature(kind, {"type": "Point", "coordinates": [lon, lat]}, **props)


def farm_doc(lon0: float = LON0, lat0: float = LAT0) -> dict[str, Any]:
    """Two fields, a garage, a road and a gate: every kind of feature."""
    east = lon0 + 200 / (111320 * math.cos(math.radians(lat0)))
    north = lat0 + 100 / 110540
    return {
        "type": "FeatureCollection",
        "features": [
            field("F1", rect(lon0, lat0)),
            field("F2", rect(east, lat0)),
            point("garage", lon0 - 0.0005, lat0 - 0.0005),
            feature(
                "road",
                {"type": "LineString", "coordinates": [[lon0 - 0.001, north], [east, north]]},
                id="lane",
            ),
            point("gate", lon0 + 0.0005, lat0 + 80 / 110540, field="F1"),
        ],
    }


def write(tmp_path: Path, doc: Any) -> Path:
    path = tmp_path / "farm.geojson"
    path.write_text(json.dumps(doc))
    return path


def refused(tmp_path: Path, doc: Any) -> str:
    path = write(tmp_path, doc)
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    message = str(err.value)
    assert message.startswith(f"{path}: "), message  # names the file
    return message


def test_the_good_farm_loads(tmp_path):
    farm = load_farm(write(tmp_path, farm_doc()))
    assert [f.id for f in farm.fields] == ["F1", "F2"]
    assert len(farm.roads) == 1 and len(farm.gates) == 1


@pytest.mark.parametrize(
    "path",
    [
        DATA / "tiny-farm.geojson",
        DATA / "sitl-farm.geojson",
        DATA.parents[1] / "config" / "changji.geojson",
        DATA.parents[1] / "benchmarks" / "sitl-farm4.geojson",
    ],
    ids=lambda p: p.name,
)
def test_shipped_farms_load(path):
    assert load_farm(path).fields


# --- kinds -------------------------------------------------------------------------------


def test_a_misspelled_kind_is_refused_naming_the_feature_and_the_known_kinds(tmp_path):
    doc = farm_doc()
    doc["features"][1]["properties"]["kind"] = "feild"
    message = refused(tmp_path, doc)
    assert "feature #1 (id 'F2'): unknown kind \"feild\" (did you mean 'field'?)" in message
    assert f"the known kinds are {', '.join(KINDS)}" in message


def test_a_feature_without_kind_takes_it_from_its_geometry(tmp_path):
    doc = farm_doc()
    for f in doc["features"]:
        del f["properties"]["kind"]  # polygons: fields, line: road, point with field: gate
    farm = load_farm(write(tmp_path, doc))
    assert [f.id for f in farm.fields] == ["F1", "F2"]
    assert len(farm.roads) == 1 and len(farm.gates) == 1


def test_a_feature_without_kind_nor_telling_geometry_is_refused(tmp_path):
    doc = farm_doc()
    del doc["features"][2]["properties"]["kind"]
    points = [[LON0, LAT0], [LON0 + 0.001, LAT0]]  # (one point is taken as a Point)
    doc["features"][2]["geometry"] = {"type": "MultiPoint", "coordinates": points}
    message = refused(tmp_path, doc)
    assert "feature #2 (no id): no properties.kind and no geometry that tells it" in message
    assert "field, garage, road, gate" in message


def test_a_kind_that_is_not_a_string_is_refused(tmp_path):
    doc = farm_doc()
    doc["features"][0]["properties"]["kind"] = 3
    assert "feature #0 (id 'F1'): unknown kind 3;" in refused(tmp_path, doc)


# --- a number or string where a feature, geometry, ring or position belongs ---------------


def set_at(doc: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    doc = copy.deepcopy(doc)
    node: Any = doc
    for step in path[:-1]:
        node = node[step]
    node[path[-1]] = value
    return doc


MISPLACED = {
    "number for a feature": (("features", 1), 7, "feature #1: a feature must be a GeoJSON object"),
    "string for a feature": (("features", 0), "F1", "feature #0: a feature must be a GeoJSON"),
    "string for properties": (
        ("features", 1, "properties"),
        "field",
        "feature #1: 'properties' must be an object, not \"field\"",
    ),
    "number for a geometry": (
        ("features", 0, "geometry"),
        5,
        "feature #0: 'geometry' must be an object, not 5",
    ),
    "number for a field's rings": (
        ("features", 1, "geometry", "coordinates"),
        12,
        "field 'F2': a Polygon's coordinates must be a list of rings, not 12",
    ),
    "string for a ring": (
        ("features", 1, "geometry", "coordinates", 0),
        "10,50 10,51",
        "field 'F2': ring 0 (outline) must be a list of [longitude, latitude] positions",
    ),
    "number for a position": (
        ("features", 0, "geometry", "coordinates", 0, 2),
        10.5,
        "field 'F1', ring 0 (outline) position 2: a position must be [longitude, latitude] or "
        "[longitude, latitude, altitude], numbers, not 10.5",
    ),
    "strings in a position": (
        ("features", 0, "geometry", "coordinates", 0, 1),
        ["10.1", "50.0"],
        "field 'F1', ring 0 (outline) position 1: a position must be [longitude, latitude]",
    ),
    "bools in a position": (
        ("features", 0, "geometry", "coordinates", 0, 1),
        [True, False],
        "position 1: a position must be [longitude, latitude] or [longitude, latitude, "
        "altitude], numbers, not [true, false]",
    ),
    "a string for an altitude": (
        ("features", 0, "geometry", "coordinates", 0, 1),
        [10.001, 50.0, "x"],
        "position 1: a position must be [longitude, latitude] or [longitude, latitude, "
        'altitude], numbers, not [10.001, 50.0, "x"]',
    ),
    "string for the garage's position": (
        ("features", 2, "geometry", "coordinates"),
        "10.0 50.0",
        "feature #2 (garage): a position must be [longitude, latitude] or [longitude, latitude, "
        'altitude], numbers, not "10.0 50.0"',
    ),
    "number for a road": (
        ("features", 3, "geometry", "coordinates"),
        3,
        "feature #3 (road 'lane'): a road needs at least 2 points",
    ),
    "null for a gate's position": (
        ("features", 4, "geometry", "coordinates"),
        None,
        "feature #4 (gate of 'F1'): a position must be [longitude, latitude] or [longitude, "
        "latitude, altitude], numbers, not null",
    ),
    "a ring of two points": (
        ("features", 1, "geometry", "coordinates", 0),
        [[10.0, 50.0], [10.001, 50.0]],
        "field 'F2': ring 0 (outline) has 2 distinct positions; a ring needs at least 3",
    ),
}


@pytest.mark.parametrize("case", sorted(MISPLACED))
def test_a_value_of_the_wrong_type_is_named_never_a_traceback(tmp_path, case):
    path, value, needle = MISPLACED[case]
    assert needle in refused(tmp_path, set_at(farm_doc(), path, value))


def test_a_fields_numbers_written_as_text_are_read_as_numbers(tmp_path):
    """KML's ExtendedData holds only text, and geojson.io's table writes what is typed as
    text: "45" and "2" were refused ("must be a number of degrees, not '45'")."""
    doc = farm_doc()
    doc["features"][0]["properties"] |= {"work_angle_deg": " 45", "headland_passes": "2"}
    field = load_farm(write(tmp_path, doc)).fields[0]
    assert (field.work_angle_deg, field.headland_passes) == (45.0, 2)
    doc["features"][0]["properties"] |= {"work_angle_deg": "NE"}
    assert "work_angle_deg must be a number of degrees (-360 to 360), not 'NE'" in refused(
        tmp_path, doc
    )
    doc["features"][0]["properties"] |= {"work_angle_deg": 1e300}
    assert "(-360 to 360), not 1e+300" in refused(tmp_path, doc)
    doc["features"][0]["properties"] |= {"work_angle_deg": "45", "headland_passes": "2.5"}
    assert "headland_passes must be a whole number >= 0, not 2.5" in refused(tmp_path, doc)


def rounded_valid(polygon: shapely.Polygon) -> bool:
    """Whether ``polygon`` stays valid written to 1e-7 degrees (plan.json, the GIS files)."""
    return shapely.transform(polygon, lambda xy: xy.round(7)).is_valid


def test_a_pond_drawn_onto_the_fields_edge_is_a_notch_and_a_bow_tie_is_still_refused(tmp_path):
    """A hole with an edge on the outline (a pond snapped to the edge in QGIS) is invalid as
    drawn in longitude/latitude, though the local metres may not show it: it was taken as
    it was, and writing the plan's KML then failed with a traceback (an outside review's
    farm). Now the outline less the pond, the same land; a polygon that is no such case
    is refused, naming the file and field, as before."""
    dlon, dlat = 1 / (111320 * math.cos(math.radians(LAT0))), 1 / 110540  # a metre
    ring = rect(LON0, LAT0, 200.0, 100.0)
    pond = [[LON0, LAT0 + 40 * dlat], [LON0 + 30 * dlon, LAT0 + 50 * dlat],
            [LON0, LAT0 + 60 * dlat], [LON0, LAT0 + 40 * dlat]]  # fmt: skip
    doc = farm_doc()
    doc["features"][0]["geometry"]["coordinates"] = [ring]
    whole = load_farm(write(tmp_path, doc)).fields[0].area_m2
    doc["features"][0]["geometry"]["coordinates"] = [ring, pond]
    assert not shapely.Polygon(ring, [pond]).is_valid
    field = load_farm(write(tmp_path, doc)).fields[0]
    assert field.boundary_lonlat.is_valid and rounded_valid(field.boundary_lonlat)
    assert len(field.boundary_lonlat.interiors) == 0  # a notch
    assert field.area_m2 == pytest.approx(whole * (1.0 - 300.0 / 20_000.0), rel=1e-3)
    assert field.boundary.is_valid and len(field.boundary.interiors) == 0
    bow_tie = [ring[0], ring[2], ring[1], ring[3], ring[0]]
    doc["features"][0]["geometry"]["coordinates"] = [bow_tie]
    assert "field 'F1': invalid polygon (Self-intersection" in refused(tmp_path, doc)


def test_a_pond_a_millimetre_inside_the_edge_stays_valid_as_written(tmp_path):
    """A hole valid as drawn, a millimetre from a slanting outline: rounded to 1e-7 degrees
    (~1 cm) for plan.json and the GIS files it met the outline, and the written polygon was
    invalid. Kept valid at that grid (a notch there)."""
    dlon, dlat = 1 / (111320 * math.cos(math.radians(LAT0))), 1 / 110540
    ring = [[LON0, LAT0], [LON0 + 200 * dlon, LAT0 - 4e-8], [LON0 + 200 * dlon, LAT0 + 100 * dlat],
            [LON0, LAT0 + 100 * dlat], [LON0, LAT0]]  # fmt: skip
    low = LAT0 - 1e-8  # above the outline's edge there by ~1 mm
    pond = [[LON0 + 80 * dlon, low], [LON0 + 80 * dlon, LAT0 + 25 * dlat],
            [LON0 + 120 * dlon, LAT0 + 25 * dlat], [LON0 + 120 * dlon, low],
            [LON0 + 80 * dlon, low]]  # fmt: skip
    assert shapely.Polygon(ring, [pond]).is_valid
    assert not rounded_valid(shapely.Polygon(ring, [pond]))
    doc = farm_doc()
    doc["features"][0]["geometry"]["coordinates"] = [ring, pond]
    field = load_farm(write(tmp_path, doc)).fields[0]
    assert field.boundary_lonlat.is_valid and rounded_valid(field.boundary_lonlat)
    assert field.boundary_lonlat.hausdorff_distance(shapely.Polygon(ring, [pond])) < 1e-7


def test_a_closed_line_is_a_field_when_said_so_else_a_road_with_a_warning(tmp_path, caplog):
    """A field drawn as a path round it (Google Earth), or a recorded boundary track: read as
    a road without a word, and the field not planned. Said kind 'field', it is the field;
    without a kind, a road still (a loop road is one), with a warning saying how."""
    doc = farm_doc()
    ring = rect(LON0 + 0.01, LAT0)
    loop = {"type": "Feature", "properties": {"name": "West"}}
    loop["geometry"] = {"type": "LineString", "coordinates": ring}
    doc["features"].append(loop)
    with caplog.at_level(logging.WARNING, logger="planner.farm"):
        farm = load_farm(write(tmp_path, doc))
    assert "West" in [r.id for r in farm.roads] and "West" not in [f.id for f in farm.fields]
    assert "(name 'West'): a closed line, read as a road; if it is a field's" in caplog.text
    loop["properties"]["kind"] = "field"
    west = load_farm(write(tmp_path, doc)).field("West")
    assert west.area_m2 == pytest.approx(120 * 80, rel=0.01)


def test_a_farm_across_the_antimeridian_is_where_it_is(tmp_path):
    """Its local frame was centred at longitude 0 (the middle of -179.998 and 179.998),
    20 000 km away in another UTM zone, turned upside down: the map showed the garage
    north of the field it is south of. The same farm moved to longitude 10 is the yardstick."""

    def farm_at(lon0: float) -> Farm:
        ring = [[lon0 - 0.002, -16.8], [lon0 + 0.002, -16.8], [lon0 + 0.002, -16.796],
                [lon0 - 0.002, -16.796], [lon0 - 0.002, -16.8]]  # fmt: skip
        ring = [[(lon + 180.0) % 360.0 - 180.0, lat] for lon, lat in ring]
        doc = {"type": "FeatureCollection", "features": [
            point("garage", (lon0 - 0.001 + 180.0) % 360.0 - 180.0, -16.801),
            field("AM", ring),
        ]}  # fmt: skip
        folder = tmp_path / str(lon0)
        folder.mkdir()
        return load_farm(write(folder, doc))

    across, moved = farm_at(180.0), farm_at(10.0)
    for farm in (across, moved):
        centre = farm.fields[0].boundary.centroid
        dx, dy = farm.garage[0] - centre.x, farm.garage[1] - centre.y
        assert dy == pytest.approx(-333.0, abs=5.0) and dx == pytest.approx(-106.0, abs=5.0)
    # (within the UTM scale: the antimeridian is a zone edge, longitude 10 near its meridian)
    assert across.fields[0].area_m2 == pytest.approx(moved.fields[0].area_m2, rel=3e-3)


def test_a_field_id_with_a_control_character_is_refused(tmp_path):
    """A line break in a field id broke the printed plan's table (review)."""
    doc = farm_doc()
    doc["features"][0]["properties"]["id"] = "F1\nnorth"
    assert "the field id 'F1\\nnorth' holds a control character" in refused(tmp_path, doc)
    for hidden in ("\u2028", "\u202e", "\u200b"):  # line separator, RTL override, ZWSP
        doc["features"][0]["properties"]["id"] = f"F1{hidden}north"
        assert "holds a control character" in refused(tmp_path, doc)
    # The invisible marks of scripts written with them are text (were refused): Persian's
    # zero-width non-joiner, a right-to-left mark, a soft hyphen.
    doc["features"][0]["properties"]["id"] = "F1"
    for name in ("زمین\u200cشمالی", "\u200fמזרח", "Acker\u00adrand"):
        doc["features"][1]["properties"]["id"] = name  # F2 (F1 has a gate)
        assert load_farm(write(tmp_path, doc)).fields[1].id == name


def nodes(value: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """The paths of every value in a JSON document."""
    out = [path] if path else []
    if isinstance(value, dict):
        for key, child in value.items():
            out += nodes(child, (*path, key))
    elif isinstance(value, list):
        for k, child in enumerate(value):
            out += nodes(child, (*path, k))
    return out


def test_any_value_replaced_by_any_other_type_is_a_geometry_error_or_loads(tmp_path):
    doc = farm_doc()
    for path in nodes(doc):
        for value in (7, "x", None, True, [], {}):
            bad = set_at(doc, path, value)
            # Anything but a GeometryError (a TypeError, a KeyError, ...) fails the test.
            with contextlib.suppress(GeometryError):
                load_farm(write(tmp_path, bad))


# --- swapped coordinates, a farm spread too wide -----------------------------------------


def swapped(ring: list[list[float]]) -> list[list[float]]:
    return [[lat, lon] for lon, lat in ring]


def test_one_field_with_a_latitude_beyond_90_is_named(tmp_path):
    doc = farm_doc(120.0, 30.0)  # a farm near 30 N 120 E: a swapped field has latitude 120
    load_farm(write(tmp_path, doc))
    ring = doc["features"][1]["geometry"]["coordinates"][0]
    doc["features"][1]["geometry"]["coordinates"][0] = swapped(ring)
    message = refused(tmp_path, doc)
    assert "field 'F2', ring 0 (outline) position 0: latitude 120.0" in message
    assert "swapped" in message


def test_one_field_swapped_near_the_rest_of_the_farm_is_named(tmp_path):
    doc = farm_doc()
    ring = doc["features"][1]["geometry"]["coordinates"][0]
    doc["features"][1]["geometry"]["coordinates"][0] = swapped(ring)
    message = refused(tmp_path, doc)
    assert "field 'F2': its corner " in message and " km from the garage (limit 50 km)" in message
    assert "its longitudes and latitudes look swapped" in message


@pytest.mark.parametrize(("east", "north", "sign"), [(1, -1, "latitude"), (-1, 1, "longitude")])
def test_a_garage_with_a_sign_lost_is_said_so(tmp_path, east, north, sign):
    """A garage in the other hemisphere (a farm at 34 S 19 E, the garage's minus sign lost):
    it was asked whether its longitude and latitude were swapped (an outside review's)."""
    doc = farm_doc(19.0, -34.0)
    garage = doc["features"][2]["geometry"]["coordinates"]
    doc["features"][2]["geometry"]["coordinates"] = [garage[0] * east, garage[1] * north]
    message = refused(tmp_path, doc)
    assert f"with the sign of its {sign} changed it would be 0.1 km from them" in message
    assert "swapped" not in message


def test_a_field_farther_than_the_limit_from_the_garage_is_named_with_its_distance(tmp_path):
    doc = farm_doc()
    east = LON0 + 60_000 / (111320 * math.cos(math.radians(LAT0)))  # 60 km east
    doc["features"].append(field("far", rect(east, LAT0)))
    message = refused(tmp_path, doc)
    assert "field 'far': its corner 1 [10.84019, 50.00000] is 60.1 km from the garage" in message
    assert "(limit 50 km)" in message
    assert "swapped" not in message


def test_a_field_across_the_antimeridian_is_where_it_is(tmp_path):
    """Its corners at 179.999 and -179.999 degrees: its centre is at 180, not at 0 (which
    put it 14 600 km from its garage)."""
    lat0 = -16.5
    across = [[lon - 360.0 if lon > 180.0 else lon, lat] for lon, lat in rect(179.9995, lat0)]
    doc = {
        "type": "FeatureCollection",
        "features": [field("F1", across), point("garage", 179.9990, lat0 - 0.0003)],
    }
    farm = load_farm(write(tmp_path, doc))
    assert farm.fields[0].area_m2 == pytest.approx(120.0 * 80.0, rel=0.01)
    assert farm.fields[0].boundary.distance(shapely.Point(farm.garage)) < 100.0


def test_a_road_far_from_the_farm_is_named(tmp_path):
    doc = farm_doc()
    doc["features"][3]["geometry"]["coordinates"][1] = [LAT0, LON0]  # one point swapped
    message = refused(tmp_path, doc)
    assert "feature #3 (road 'lane'): its point 1 [50.00000, 10.00000] is " in message
    assert "every field and road of a farm must lie within 50 km of its garage" in message


def test_a_garage_inside_a_field_is_said_so(tmp_path, caplog):
    # Every way out of it and back drives across the field: a farmyard drawn into a field,
    # or a point in the wrong place.
    doc = farm_doc()
    doc["features"][2]["geometry"]["coordinates"] = [LON0 + 0.0008, LAT0 + 0.0004]
    with caplog.at_level("WARNING", logger="planner.farm"):
        load_farm(write(tmp_path, doc))
    assert "the garage (10.0008000, 50.0004000) lies inside field 'F1'" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING", logger="planner.farm"):
        load_farm(write(tmp_path, farm_doc()))
    assert "lies inside field" not in caplog.text


def test_one_garage_given_twice_is_one_and_two_are_named_with_where(tmp_path, caplog):
    """An ISOXML's home base in each of its partfields: "2 garages (home base, home base)"
    refused a farm of one garage. Two places are refused still, saying where."""
    doc = farm_doc()
    garage = doc["features"][2]
    assert garage["properties"]["kind"] == "garage"
    doc["features"].append(json.loads(json.dumps(garage)))
    with caplog.at_level(logging.WARNING, logger="planner.farm"):
        farm = load_farm(write(tmp_path, doc))
    assert farm.garage_lonlat == tuple(garage["geometry"]["coordinates"])
    assert "the garage given 2 times at one place" in caplog.text
    doc["features"][-1]["geometry"]["coordinates"][0] += 0.001
    message = refused(tmp_path, doc)
    assert "2 garages (feature #2, feature #" in message and ") at (" in message


@pytest.mark.parametrize("rows", [1024, 1])
def test_a_swapped_garage_is_named(tmp_path, monkeypatch, rows):
    # (rows: the extent check counts its distances a block of fields at a time)
    monkeypatch.setattr("planner.farm.EXTENT_ROWS", rows)
    doc = farm_doc()
    doc["features"][2]["geometry"]["coordinates"] = [LAT0, LON0]
    message = refused(tmp_path, doc)
    assert "the garage is " in message and "from the nearest field (limit 50 km)" in message
    assert "swapped" in message


def test_a_farm_swapped_in_every_feature_is_refused_at_the_pole(tmp_path):
    farm = json.loads((DATA / "tiny-farm.geojson").read_text())  # 44.0 N 87.3 E

    def swap(value: Any) -> Any:
        if isinstance(value, list) and len(value) == 2 and all(isinstance(v, float) for v in value):
            return [value[1], value[0]]
        return [swap(v) for v in value] if isinstance(value, list) else value

    for f in farm["features"]:
        f["geometry"]["coordinates"] = swap(f["geometry"]["coordinates"])
    message = refused(tmp_path, farm)
    assert "field 'A' lies at latitude 87.30" in message
    assert f"limit {MAX_ABS_LATITUDE:g} degrees" in message and "swapped" in message


def test_overlapping_fields_are_named_with_the_overlap(tmp_path, caplog):
    doc = farm_doc()
    east = LON0 + 60 / (111320 * math.cos(math.radians(LAT0)))  # 60 m into F1 (120 m)
    doc["features"].append(field("F3", rect(east, LAT0)))
    with caplog.at_level(logging.WARNING, logger="planner.farm"):
        load_farm(write(tmp_path, doc))
    assert re.search(r"fields 'F1' and 'F3' overlap by 48\d\d m2", caplog.text)  # 60 x 80 m
    assert "'F2' and 'F3'" not in caplog.text  # F2 starts 200 m east: 20 m apart


def test_a_self_intersecting_field_is_said_where_in_longitude_and_latitude(tmp_path):
    doc = farm_doc()
    a = rect(LON0, LAT0)
    doc["features"][0]["geometry"]["coordinates"][0] = [a[0], a[2], a[1], a[3], a[0]]
    message = refused(tmp_path, doc)
    assert re.search(
        r"field 'F1': invalid polygon \(Self-intersection\[10\.000\d+ 50\.000\d+\]", message
    )


def test_a_duplicate_field_id_names_both_features(tmp_path):
    doc = farm_doc()
    doc["features"][1]["properties"]["id"] = "F1"
    message = refused(tmp_path, doc)
    assert "field 'F1': duplicate field id (feature #0 and feature #1)" in message
    # and where the ids come from (ArcMap's "Id" column: 0 for every feature drawn)
    assert "the ids are property 'id': give --id-field NAME" in message
    # one of the two a MultiPolygon (its parts F1.0, F1.1 beside F1): the same id twice
    ring = doc["features"][1]["geometry"]["coordinates"]
    doc["features"][1]["geometry"] = {"type": "MultiPolygon", "coordinates": [ring, ring]}
    assert "field 'F1': duplicate field id (feature #0 and feature #1)" in refused(tmp_path, doc)


def test_ids_alike_but_for_their_unicode_form_are_one_field_and_its_gate_finds_it(tmp_path):
    """ "Großer Schlag" with an "ö" of one character (NFC, as most keyboards type it) and
    of two ("o" and the combining diaeresis, NFD, as macOS file names hold it): printed
    alike, they were two fields, and the gate of one did not find the other."""
    composed, decomposed = "Gr\u00f6\u00dfer Schlag", "Gro\u0308\u00dfer Schlag"
    assert composed != decomposed
    doc = farm_doc()
    doc["features"][0]["properties"]["id"] = decomposed
    doc["features"][4]["properties"]["field"] = composed
    farm = load_farm(write(tmp_path, doc))
    assert farm.fields[0].id == composed and farm.gates[0].field_id == composed
    # Its ids from another column, the gate naming it by its "id" property (review).
    doc["features"][0]["properties"]["plot"] = "P1"
    doc["features"][1]["properties"]["plot"] = "P2"
    farm = load_farm(write(tmp_path, doc), FarmOptions(id_field="plot"))
    assert farm.gates[0].field_id == "P1"
    doc["features"][1]["properties"]["id"] = composed
    assert "duplicate field id (feature #0 and feature #1)" in refused(tmp_path, doc)


def test_roads_and_gates_as_others_draw_them(tmp_path, caplog):
    """A gate naming its field by a whole number, as a GIS column holds it; a lane along a
    field's fence is not a road through it, and a gate digitised inside another field is
    said; a MultiLineString road with no part is refused."""
    doc = farm_doc()
    doc["features"][0]["properties"]["id"] = 7
    doc["features"][4]["properties"]["field"] = 7
    south = LAT0  # along F1's southern edge, its fence
    doc["features"].append(
        feature(
            "road",
            {"type": "LineString", "coordinates": [[LON0 - 0.001, south], [LON0 + 0.004, south]]},
            id="fence lane",
        )
    )
    metre = 1 / (111320 * math.cos(math.radians(LAT0)))  # a metre east, in degrees
    doc["features"].append(field("F3", rect(LON0 + 125 * metre, LAT0, 60.0)))  # 5 m east of F1
    doc["features"].append(point("gate", LON0 + 135 * metre, LAT0 + 0.0004, field="7"))  # in F3
    with caplog.at_level(logging.WARNING, logger="planner.farm"):
        farm = load_farm(write(tmp_path, doc))
    assert [g.field_id for g in farm.gates] == ["7", "7"]
    assert "crosses field" not in caplog.text
    assert "(gate of '7'): the gate lies inside field 'F3'" in caplog.text
    doc["features"].append(
        feature("road", {"type": "MultiLineString", "coordinates": []}, id="nothing")
    )
    assert "road 'nothing'): a road needs at least 2 points" in refused(tmp_path, doc)
