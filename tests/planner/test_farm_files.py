"""Farm files in the formats farmers have (planner/farm_files.py): the demo farm converted
to KML, GeoPackage (also in UTM), shapefiles (folder, zip) and ISOXML reads as the same
farm as its GeoJSON (within 1 cm); ids and names from the properties asked for; the
garage from the scenario; every error names the file and the feature."""

import json
import logging
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from helpers.farm_formats import (
    convert,
    farm_features,
    write_esri_json,
    write_gdal,
    write_isoxml,
    write_shapefiles,
    zip_folder,
)

from planner.errors import GeometryError
from planner.farm import Farm, FarmOptions, load_farm

REPO = Path(__file__).resolve().parents[2]
CHANGJI = REPO / "config" / "changji.geojson"
CM_DEG = 1e-7  # about 1 cm in degrees of latitude (and of longitude at 44 N, ~0.8 cm)


@pytest.fixture(scope="module")
def reference() -> Farm:
    return load_farm(CHANGJI)


def same_farm(farm: Farm, ref: Farm, roads: bool = True) -> None:
    assert [f.id for f in farm.fields] == [f.id for f in ref.fields]
    for f, r in zip(farm.fields, ref.fields, strict=True):
        assert f.boundary_lonlat.hausdorff_distance(r.boundary_lonlat) < CM_DEG, f.id
        assert f.boundary.hausdorff_distance(r.boundary) < 0.01, f.id  # metres
    assert farm.garage_lonlat == pytest.approx(ref.garage_lonlat, abs=CM_DEG)
    assert [(g.field_id, g.lonlat) for g in farm.gates] == [
        (g.field_id, pytest.approx(g.lonlat, abs=CM_DEG)) for g in ref.gates
    ]
    if roads:
        assert [r.id for r in farm.roads] == [r.id for r in ref.roads]
        for a, b in zip(farm.roads, ref.roads, strict=True):
            assert a.line_lonlat.hausdorff_distance(b.line_lonlat) < CM_DEG


@pytest.mark.parametrize(
    "fmt",
    [
        "kml",
        "gpkg",
        "gpkg-utm",
        "gpkg-osgb",
        "geojson-utm",
        "shp-folder",
        "shp-zip",
        "shp-zip-folder",
    ],
)
def test_the_demo_farm_reads_the_same_from_every_gdal_format(tmp_path, reference, fmt):
    farm = load_farm(convert(CHANGJI, fmt, tmp_path))
    same_farm(farm, reference)
    for f, r in zip(farm.fields, reference.fields, strict=True):  # the very same numbers,
        assert f.boundary_lonlat.equals_exact(r.boundary_lonlat, 0.0)  # so the same plan
    assert [f.name for f in farm.fields] == [f.name for f in reference.fields]


def test_a_projected_crs_is_converted_with_a_message(tmp_path, reference, caplog):
    with caplog.at_level(logging.WARNING, logger="planner.farm_files"):
        load_farm(convert(CHANGJI, "gpkg-utm", tmp_path))
    assert "converted from WGS 84 / UTM zone 45N to WGS84" in caplog.text


def test_isoxml_partfields_read_as_fields_with_gates_and_home_base(tmp_path, reference):
    path = convert(CHANGJI, "isoxml", tmp_path)
    by_code = load_farm(path, FarmOptions(id_field="code"))
    same_farm(by_code, reference, roads=False)  # ISOXML has no roads
    assert [f.name for f in by_code.fields] == [f.name for f in reference.fields]
    by_default = load_farm(path.parent)  # the folder holding TASKDATA.XML
    assert [f.id for f in by_default.fields][:3] == ["PFD1", "PFD2", "PFD3"]
    usb = load_farm(path.parent.parent)  # a USB stick's top: TASKDATA/TASKDATA.XML
    assert [f.id for f in usb.fields] == [f.id for f in by_default.fields]


def test_a_stick_with_two_taskdata_or_taskdata_and_other_files_is_refused(tmp_path):
    """Two seasons' exports on one USB stick (2023/TASKDATA.XML, 2024/...): the folder read
    the first, a zip of it the other, without a word; a TASKDATA beside shapefiles hid
    them. Refused, naming them: the farmer says which."""
    stick = tmp_path / "stick"
    for season in ("2023", "2024"):
        convert(CHANGJI, "isoxml", stick / season)  # stick/<season>/TASKDATA/TASKDATA.XML
    seasons = [stick / season / "TASKDATA" for season in ("2023", "2024")]
    both = tmp_path / "both"
    for season, folder in zip(("2023", "2024"), seasons, strict=True):
        (both / season).mkdir(parents=True)
        (both / season / "TASKDATA.XML").write_bytes((folder / "TASKDATA.XML").read_bytes())
    with pytest.raises(GeometryError, match=r"2 TASKDATA\.XML \(2023/TASKDATA\.XML, 2024/"):
        load_farm(both)
    with pytest.raises(GeometryError, match=r"2 TASKDATA\.XML in this archive"):
        load_farm(zip_folder(both, tmp_path / "both.zip"))
    assert load_farm(both / "2024").fields  # the one asked for
    (seasons[0].parent / "roads.geojson").write_text(CHANGJI.read_text())
    with pytest.raises(GeometryError, match=r"both a TASKDATA\.XML .* \(roads\.geojson\)"):
        load_farm(seasons[0].parent)
    with pytest.raises(GeometryError, match=r"both a TASKDATA\.XML .* \(roads\.geojson\) in"):
        load_farm(zip_folder(seasons[0].parent, tmp_path / "mixed.zip"))
    # One at the top and one a folder down: two, as a zip of them says.
    (both / "TASKDATA.XML").write_bytes((both / "2023" / "TASKDATA.XML").read_bytes())
    with pytest.raises(GeometryError, match=r"3 TASKDATA\.XML \(TASKDATA\.XML, 2023/"):
        load_farm(both)


def test_an_isoxml_partfield_without_a_boundary_is_skipped_with_its_gates(tmp_path, caplog):
    path = convert(CHANGJI, "isoxml", tmp_path)
    root = ET.parse(path).getroot()
    pfd = root.find("PFD[@A='PFD2']")
    assert pfd is not None and pfd.find("PNT[@A='3']") is not None  # it has a gate
    pfd.remove(pfd.find("PLN"))
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    with caplog.at_level(logging.WARNING, logger="planner.farm_files"):
        farm = load_farm(path)
    assert "PFD2" not in [f.id for f in farm.fields] and "PFD1" in [f.id for f in farm.fields]
    assert "partfield 'PFD2': no boundary polygon" in caplog.text


def test_geojson_as_others_write_it_reads_as_the_same_farm(tmp_path, reference):
    """Clockwise rings (the shapefile's rule), a byte-order mark, ids on the features
    (RFC 7946's "id") and a whole number of headland passes as a decimal."""
    doc = json.loads(CHANGJI.read_text())
    for feature in doc["features"]:
        geom = feature["geometry"]
        if geom["type"] == "Polygon":
            geom["coordinates"] = [ring[::-1] for ring in geom["coordinates"]]
        props = feature["properties"]
        if props.get("kind") == "field":
            feature["id"] = props.pop("id")
            props["headland_passes"] = 1.0
    path = tmp_path / "others.geojson"
    path.write_text(json.dumps(doc), encoding="utf-8-sig")
    farm = load_farm(path)
    same_farm(farm, reference)
    for f, r in zip(farm.fields, reference.fields, strict=True):
        assert f.boundary_lonlat.equals_exact(r.boundary_lonlat, 0.0)
        assert f.boundary.equals_exact(r.boundary, 0.0)
        assert f.headland_passes == 1


def test_isoxml_holes_and_a_bad_point_named(tmp_path):
    outer = [[10.0, 50.0], [10.003, 50.0], [10.003, 50.002], [10.0, 50.002], [10.0, 50.0]]
    hole = [[10.001, 50.0005], [10.002, 50.0005], [10.002, 50.0015], [10.001, 50.0015]]
    features = [
        {
            "type": "Feature",
            "properties": {"kind": "field", "id": "P", "name": "pond field"},
            "geometry": {"type": "Polygon", "coordinates": [outer, hole + hole[:1]]},
        },
        {
            "type": "Feature",
            "properties": {"kind": "garage"},
            "geometry": {"type": "Point", "coordinates": [9.999, 49.999]},
        },
    ]
    path = write_isoxml(features, tmp_path / "TASKDATA.XML")
    farm = load_farm(path)
    assert len(farm.fields[0].boundary.interiors) == 1
    assert farm.fields[0].name == "pond field"
    path.write_text(path.read_text().replace('C="50.000500000"', 'C="north"', 1))
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    assert str(path) in str(err.value) and "partfield 'PFD1'" in str(err.value)
    assert "C='north'" in str(err.value) and "line string #1 point #0" in str(err.value)
    # The hole first in the file: the bad point is in the file's line string #0.
    root = ET.parse(path).getroot()
    pln = root.find("PFD/PLN")
    hole = pln.findall("LSG")[1]
    pln.remove(hole)
    pln.insert(0, hole)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    with pytest.raises(GeometryError, match="polygon #0 line string #0 point #0: .*C='north'"):
        load_farm(path)


def test_a_multipolygon_is_split_into_fields_with_derived_ids(tmp_path):
    a = [[10.0, 50.0], [10.002, 50.0], [10.002, 50.001], [10.0, 50.001], [10.0, 50.0]]
    b = [[10.003, 50.0], [10.005, 50.0], [10.005, 50.001], [10.003, 50.001], [10.003, 50.0]]
    doc = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"id": "W", "name": "west"},
                "geometry": {"type": "MultiPolygon", "coordinates": [[a], [b]]},
            },
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "Point", "coordinates": [9.999, 49.999]},
            },
        ],
    }
    path = tmp_path / "farm.geojson"
    path.write_text(json.dumps(doc))
    farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["W.0", "W.1"]
    assert [f.name for f in farm.fields] == ["west (0)", "west (1)"]


def shapefile_farm(tmp_path: Path, **props: object) -> Path:
    ring = [[10.0, 50.0], [10.002, 50.0], [10.002, 50.001], [10.0, 50.001], [10.0, 50.0]]
    features = [
        {
            "type": "Feature",
            "properties": {"FIELD_NO": 7, "LABEL": "seven", **props},
            "geometry": {"type": "Polygon", "coordinates": [ring]},
        }
    ]
    write_gdal(features, tmp_path / "fields.shp", "ESRI Shapefile")
    return tmp_path / "fields.shp"


def test_id_and_name_fields_are_configurable_and_the_garage_comes_from_the_scenario(tmp_path):
    path = shapefile_farm(tmp_path)
    options = FarmOptions(id_field="FIELD_NO", name_field="LABEL", garage=(9.999, 49.999))
    farm = load_farm(path, options)
    assert [(f.id, f.name) for f in farm.fields] == [("7", "seven")]
    assert farm.garage_lonlat == (9.999, 49.999)
    defaulted = load_farm(path, FarmOptions(garage=(9.999, 49.999)))
    assert [f.id for f in defaulted.fields] == ["field-0"]  # no id property: its number


def test_a_missing_id_field_or_garage_is_refused_naming_file_and_feature(tmp_path):
    path = shapefile_farm(tmp_path)
    with pytest.raises(GeometryError) as err:
        load_farm(path, FarmOptions(id_field="PLOT", garage=(9.999, 49.999)))
    assert f"{path}: feature #0: a field without property 'PLOT'" in str(err.value)
    assert "FIELD_NO" in str(err.value)
    with pytest.raises(GeometryError, match="feature #0: a field whose property 'LABEL' .* empty"):
        load_farm(shapefile_farm(tmp_path, LABEL=None), FarmOptions(id_field="LABEL"))
    with pytest.raises(GeometryError, match="no garage .* or the scenario's garage"):
        load_farm(path)


def test_a_bad_feature_in_a_geopackage_names_the_layer_and_feature(tmp_path):
    features = farm_features(CHANGJI)
    features[3]["properties"]["kind"] = "feild"
    write_gdal(features[:5], tmp_path / "farm.gpkg", "GPKG", layer="fields")
    write_gdal(features[5:], tmp_path / "farm.gpkg", "GPKG", layer="rest", append=True)
    with pytest.raises(GeometryError) as err:
        load_farm(tmp_path / "farm.gpkg")
    message = str(err.value)
    assert f"{tmp_path / 'farm.gpkg'}: layer 'fields' feature #3" in message
    assert "did you mean 'field'?" in message


@pytest.mark.parametrize("name", ["farm.kml", "farm.gpkg", "farm.zip", "TASKDATA.XML"])
def test_a_file_that_is_not_what_its_name_says_is_refused_naming_it(tmp_path, name):
    path = tmp_path / name
    path.write_text("not a farm")
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    assert str(err.value).startswith(f"{path}: ")


@pytest.mark.parametrize("name", ["farm.gml", "farm.xml"])
def test_gml_reads_as_the_same_farm_also_when_named_xml(tmp_path, reference, name):
    """Some GIS exports name their GML ``.xml``, which was read as ISOXML and refused
    ("not ISO 11783-10 TaskData")."""
    path = tmp_path / name
    write_gdal(farm_features(CHANGJI), path, "GML", layer="farm")
    assert (tmp_path / "farm.xsd").exists()
    same_farm(load_farm(path), reference)


GOOGLE_EARTH_KML = """<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="http://www.opengis.net/kml/2.2"><Document><name>My farm</name>
<Folder><name>Fields</name>
<Placemark><name>North 40</name><Polygon><outerBoundaryIs><LinearRing><coordinates>
10.0,50.0,0 10.002,50.0,0 10.002,50.001,0 10.0,50.001,0 10.0,50.0,0
</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark>
<Placemark><name>Creek</name><MultiGeometry>
<Polygon><outerBoundaryIs><LinearRing><coordinates>
10.003,50.0 10.005,50.0 10.005,50.001 10.003,50.001 10.003,50.0
</coordinates></LinearRing></outerBoundaryIs></Polygon>
<Polygon><outerBoundaryIs><LinearRing><coordinates>
10.006,50.0 10.008,50.0 10.008,50.001 10.006,50.001 10.006,50.0
</coordinates></LinearRing></outerBoundaryIs></Polygon>
</MultiGeometry></Placemark>
</Folder>
<Placemark><name>Barn</name><Point><coordinates>9.999,49.999,0</coordinates></Point></Placemark>
</Document></kml>
"""


@pytest.mark.parametrize("suffix", [".kml", ".kmz"])
def test_a_farm_drawn_in_google_earth_reads_without_our_properties(tmp_path, suffix):
    """Placemarks with only a name, in folders, a MultiGeometry: no kind, no id needed."""
    path = tmp_path / f"farm{suffix}"
    if suffix == ".kmz":
        import zipfile

        with zipfile.ZipFile(path, "w") as kmz:
            kmz.writestr("doc.kml", GOOGLE_EARTH_KML)
    else:
        path.write_text(GOOGLE_EARTH_KML)
    farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["North 40", "Creek.0", "Creek.1"]
    assert farm.garage_lonlat == (9.999, 49.999)


TWO_PONDS = """<innerBoundaryIs><LinearRing><coordinates>
10.0002,50.0002 10.0006,50.0002 10.0006,50.0006 10.0002,50.0006 10.0002,50.0002
</coordinates></LinearRing>
<LinearRing><coordinates>
10.0012,50.0002 10.0016,50.0002 10.0016,50.0006 10.0012,50.0006 10.0012,50.0002
</coordinates></LinearRing></innerBoundaryIs></Polygon></Placemark>
<Placemark><name>Creek</name>"""


# Text a KML may hold that the mending must pass over as it is: a description (CDATA)
# naming the element, and an old outline of two rings commented out.
ASIDES = (
    "<description><![CDATA[holes go in <innerBoundaryIs>]]></description><!-- old: "
    "<outerBoundaryIs><LinearRing><coordinates>1,1 2,1 2,2 1,1</coordinates></LinearRing>"
    "<LinearRing><coordinates>1,1 2,1 2,2 1,1</coordinates></LinearRing></outerBoundaryIs> -->"
)


@pytest.mark.parametrize("layout", ["kml", "kml with asides", "kmz", "kmz linking a layer"])
def test_two_ponds_in_one_kml_inner_boundary_are_both_left_out(tmp_path, layout):
    """Some tools write a field's holes as rings of one innerBoundaryIs; GDAL kept the last
    and dropped the others without a word, and a pond would have been worked through. In a
    KMZ, every KML document GDAL may read (GDAL writes its layers as files the first links
    to); comments and CDATA sections are passed over (review)."""
    text = GOOGLE_EARTH_KML.replace(
        "</Polygon></Placemark>\n<Placemark><name>Creek</name>", TWO_PONDS
    )
    assert text.count("<LinearRing>") == GOOGLE_EARTH_KML.count("<LinearRing>") + 2
    path = tmp_path / f"farm.{layout[:3]}"
    if layout == "kml with asides":
        text = text.replace("<name>North 40</name>", "<name>North 40</name>" + ASIDES)
    if layout.startswith("kmz"):
        import zipfile

        link = "<NetworkLink><Link><href>layers/fields.kml</href></Link></NetworkLink>"
        with zipfile.ZipFile(path, "w") as kmz:
            if layout == "kmz":
                kmz.writestr("doc.kml", text)
            else:
                kmz.writestr(
                    "doc.kml", GOOGLE_EARTH_KML.split("<Folder>")[0] + link + "</Document></kml>"
                )
                kmz.writestr("layers/fields.kml", text)
            kmz.writestr("files/icon.png", b"not read")
    else:
        path.write_text(text)
    field = load_farm(path).fields[0]
    whole = load_farm(_written(tmp_path / "whole.kml", GOOGLE_EARTH_KML)).fields[0]
    assert field.id == "North 40"
    pond = 0.0004 * 111_320 * math.cos(math.radians(50.0)) * 0.0004 * 111_200
    assert whole.area_m2 - field.area_m2 == pytest.approx(2 * pond, rel=0.02)


def test_two_rings_in_one_kml_outer_boundary_are_refused_naming_the_placemark(tmp_path):
    text = GOOGLE_EARTH_KML.replace(
        "</LinearRing></outerBoundaryIs></Polygon></Placemark>\n<Placemark><name>Creek</name>",
        "</LinearRing><LinearRing><coordinates>10.1,50.1 10.2,50.1 10.2,50.2 10.1,50.1"
        "</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark>\n"
        "<Placemark><name>Creek</name>",
    )
    assert text != GOOGLE_EARTH_KML
    path = _written(tmp_path / "farm.kml", text)
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    assert str(err.value).startswith(
        f"{path}: placemark 'North 40': its outerBoundaryIs holds 2 rings"
    )


def _written(path, text):
    path.write_text(text)
    return path


def test_several_unmarked_points_are_named_and_the_scenario_garage_settles_it(tmp_path):
    well = (
        "<Placemark><name>Well</name>"
        "<Point><coordinates>10.001,50.002</coordinates></Point></Placemark>"
    )
    path = tmp_path / "farm.kml"
    path.write_text(GOOGLE_EARTH_KML.replace("</Document>", well + "</Document>"))
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    assert f"{path}: 2 garages (layer 'My farm' feature #0, layer 'My farm' feature #1)" in str(
        err.value
    )
    farm = load_farm(path, FarmOptions(garage=(9.999, 49.999)))
    assert farm.garage_lonlat == (9.999, 49.999)


# --- files as farmers' tools write them ---------------------------------------------------


def test_a_kml_saved_by_qgis_keeps_its_authors_ids(tmp_path, reference):
    """QGIS (GDAL) writes each placemark's XML id beside the author's id in ExtendedData;
    read back, GDAL names the first ``id`` and the author's ``id2``: every field was
    renamed "fields.N" and every gate refused."""
    path = tmp_path / "farm.kml"
    write_gdal(farm_features(CHANGJI), path, "KML", layer="fields")
    assert 'id="fields.1"' in path.read_text()
    same_farm(load_farm(path), reference)


@pytest.mark.parametrize("xml_ids", [False, True], ids=["plain", "with placemark ids"])
def test_a_kmls_ids_in_plain_extended_data_are_the_fields_ids(tmp_path, xml_ids):
    """``<Data name="id">`` in a placemark's ExtendedData (Google Earth's, or by hand), in
    folders, the placemarks with or without an XML id of their own: GDAL reads it as
    ``id``, beside an empty ``id2``. The ids were thrown away for the names (an outside
    review's farm: two fields both named "Wiese" were refused as one id)."""
    placemark = '<Placemark id="pm{k}">' if xml_ids else "<Placemark>"
    text = GOOGLE_EARTH_KML
    for k, (name, fid) in enumerate((("North 40", "F1"), ("Creek", "F2"))):
        data = f'<ExtendedData><Data name="id"><value>{fid}</value></Data></ExtendedData>'
        old = f"<Placemark><name>{name}</name>"
        text = text.replace(old, placemark.format(k=k) + f"<name>Wiese</name>{data}")
    path = tmp_path / "farm.kml"
    path.write_text(text)
    farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["F1", "F2.0", "F2.1"]
    assert [f.name for f in farm.fields] == ["Wiese", "Wiese (0)", "Wiese (1)"]


def test_an_unclosed_ring_read_through_gdal_is_closed(tmp_path):
    # A KML drawn by hand; the same ring in plain GeoJSON was taken already.
    text = GOOGLE_EARTH_KML.replace("10.0,50.001,0 10.0,50.0,0\n", "10.0,50.001,0\n")
    assert text != GOOGLE_EARTH_KML
    path = tmp_path / "farm.kml"
    path.write_text(text)
    farm = load_farm(path)
    assert farm.fields[0].id == "North 40"
    assert farm.fields[0].area_m2 == pytest.approx(143.0 * 111.2, rel=0.02)


@pytest.mark.parametrize(
    ("lost", "renamed", "said"),
    [
        ("south.shx", None, r"south\.shp has no south\.shx beside it"),
        ("south.shx", "SOUTH.SHX", r"south\.shp's \.shx is SOUTH\.SHX, .* rename it south\.shx"),
        ("south.dbf", None, r"south\.shp has no south\.dbf beside it .* its columns"),
        ("south.dbf", "South.dbf", r"south\.shp's \.dbf is South\.dbf, .* rename it south\.dbf"),
    ],
)
def test_a_shapefile_whose_shx_or_dbf_gdal_does_not_find_is_named(tmp_path, lost, renamed, said):
    """GDAL looks for a shapefile's .shx and .dbf under its own name, the ending in lower or
    upper case: a copy that wrote NORD.SHX for Nord.shp lost its fields without a word, one
    without its .dbf its ids, names and work angles."""
    folder = tmp_path / "farm"
    folder.mkdir()
    features = farm_features(CHANGJI)
    fields = [f for f in features if f["geometry"]["type"] == "Polygon"]
    write_gdal(fields[:5], folder / "north.shp", "ESRI Shapefile")
    write_gdal(fields[5:], folder / "south.shp", "ESRI Shapefile")
    points = [f for f in features if f["geometry"]["type"] == "Point"]
    write_gdal(points, folder / "points.shp", "ESRI Shapefile")
    if renamed is None:
        (folder / lost).unlink()
    else:
        (folder / lost).rename(folder / renamed)
    for path in (folder, folder / "south.shp", zip_folder(folder, tmp_path / "farm.zip")):
        with pytest.raises(GeometryError, match=said):
            load_farm(path)
    (folder / "north.SHX").write_bytes((folder / "north.shx").read_bytes())  # found too
    (folder / "north.shx").unlink()
    with pytest.raises(GeometryError, match=said):  # (the same error, not one for north)
        load_farm(folder)


@pytest.mark.parametrize(
    ("broken", "shown"),
    [
        ({"type": "Polgon"}, 'must be a Polygon or MultiPolygon .*, not "Polgon"'),
        ({"coordinates": "abc"}, 'coordinates must be a list of rings, not "abc"'),
    ],
)
def test_a_broken_geometry_in_a_geojson_with_a_crs_is_refused_not_left_out(tmp_path, broken, shown):
    """GeoJSON with a projected "crs" member is read through GDAL, which made a misspelt
    or non-numeric geometry none: the field was left out with a warning, where the same
    file without the crs is refused, naming it."""
    path = convert(CHANGJI, "geojson-utm", tmp_path)
    doc = json.loads(path.read_text())
    k = next(k for k, f in enumerate(doc["features"]) if f["geometry"]["type"] == "Polygon")
    doc["features"][k]["geometry"].update(broken)
    name = doc["features"][k]["properties"]["id"]
    path.write_text(json.dumps(doc))
    with pytest.raises(GeometryError, match=rf"field '{name}': .*{shown}"):
        load_farm(path)


def test_a_crs_member_of_the_epsg_form_is_read_and_one_not_understood_said(
    tmp_path, reference, caplog
):
    """GeoJSON 2008 names a CRS as {"type": "EPSG", "properties": {"code": N}} too, which
    GDAL reads: it was taken as WGS84 and refused as "projected metres"; a crs member not
    understood at all was taken as WGS84 without a word."""
    path = convert(CHANGJI, "geojson-utm", tmp_path)
    doc = json.loads(path.read_text())
    doc["crs"] = {"type": "EPSG", "properties": {"code": 32645}}
    path.write_text(json.dumps(doc))
    same_farm(load_farm(path), reference)
    plain = json.loads(CHANGJI.read_text())
    plain["crs"] = {"type": "link", "properties": {"href": "http://example.com/crs"}}
    (tmp_path / "plain.geojson").write_text(json.dumps(plain))
    with caplog.at_level(logging.WARNING, logger="planner.farm_files"):
        same_farm(load_farm(tmp_path / "plain.geojson"), reference)
    assert 'crs member {"type": "link", ' in caplog.text and "not understood" in caplog.text


def test_a_projected_field_with_a_pond_snapped_to_its_edge_reads_valid(tmp_path):
    """A hole with a corner on the outline (QGIS's snapping), valid as drawn in UTM: the
    conversion to longitude/latitude (rounded to 1e-7 degrees) and then to the local metres
    moved it across the outline by up to a centimetre in a third of the cases, and the
    field was refused as self-intersecting, its author blamed."""
    rng = np.random.default_rng(3)
    features = []
    for k in range(30):
        x0, y0 = 572_199.34 + 400.0 * k, 5_539_853.42
        a = float(rng.uniform(20.0, 200.0))  # where the pond's corner lies on the outline
        outline = [(x0, y0), (x0 + 300, y0), (x0 + 300, y0 + 300), (x0, y0 + 300), (x0, y0)]
        dx, dy = rng.uniform(0.1, 1.0, 2)
        hole = [(x0 + a, y0), (x0 + a + dx, y0 + 50), (x0 + a + 50, y0 + 50),
                (x0 + a + 50 + dy, y0 + 20), (x0 + a, y0)]  # fmt: skip
        geometry = {"type": "Polygon", "coordinates": [outline, hole]}
        features.append({"properties": {"id": f"F{k}"}, "geometry": geometry})
    garage = {"type": "Point", "coordinates": [572_150.0, 5_539_800.0]}
    features.append({"properties": {"kind": "garage"}, "geometry": garage})
    folder = tmp_path / "farm"
    folder.mkdir()
    write_gdal(
        features[:-1], folder / "fields.shp", "ESRI Shapefile", crs="EPSG:25832", projected=True
    )
    write_gdal(
        features[-1:], folder / "garage.shp", "ESRI Shapefile", crs="EPSG:25832", projected=True
    )
    farm = load_farm(folder)
    assert len(farm.fields) == 30
    for f in farm.fields:
        assert f.boundary.is_valid, f.id  # the pond a hole, or a notch in the outline
        assert 300 * 300 - 2_700 < f.area_m2 < 300 * 300 - 1_500, f.id


def test_a_zipped_folder_from_a_mac_and_a_date_column_read(tmp_path):
    """Finder's zip adds ``__MACOSX/farm/._*.shp``: two folders of shapefiles, refused as
    "not recognized"; a column of dates made a traceback in a message."""
    import zipfile

    folder = write_shapefiles(farm_features(CHANGJI), tmp_path / "farm")
    archive = tmp_path / "farm.zip"
    with zipfile.ZipFile(archive, "w") as z:  # as Finder zips a folder: farm/..., __MACOSX/
        for file in sorted(folder.iterdir()):
            z.write(file, f"farm/{file.name}")
            z.writestr(f"__MACOSX/farm/._{file.name}", b"\0\5\26\7")
    assert len(load_farm(archive).fields) == 15
    ring = [[10.0, 50.0], [10.002, 50.0], [10.002, 50.001], [10.0, 50.001], [10.0, 50.0]]
    import datetime

    feature = {
        "type": "Feature",
        "properties": {"sown": datetime.date(2024, 5, 1)},
        "geometry": {"type": "Polygon", "coordinates": [ring]},
    }
    write_gdal([feature], tmp_path / "dated.gpkg", "GPKG")
    farm = load_farm(tmp_path / "dated.gpkg", FarmOptions(id_field="sown", garage=(9.999, 49.999)))
    assert [f.id for f in farm.fields] == ["2024-05-01"]


ISOXML_PFD = """<PFD A="PFD1" C="Schlag 1"><PLN A="1"><LSG A="1">
<PNT A="2" C="50.0" D="10.0"/><PNT A="2" C="50.0" D="10.003"/>
<PNT A="2" C="50.002" D="10.003"/><PNT A="2" C="50.002" D="10.0"/></LSG></PLN>{more}</PFD>"""
POND = """<PLN A="3" B="Teich"><LSG A="1"><PNT A="2" C="50.0005" D="10.001"/>
<PNT A="2" C="50.0005" D="10.002"/><PNT A="2" C="50.0015" D="10.002"/>
<PNT A="2" C="50.0015" D="10.001"/></LSG></PLN>"""
TASKDATA = """<?xml version="1.0" encoding="UTF-8"?>
<ISO11783_TaskData VersionMajor="4" VersionMinor="2" DataTransferOrigin="1"{ns}>
{body}<PNT A="11" C="49.999" D="9.999"/></ISO11783_TaskData>"""


def test_an_isoxml_farm_without_a_home_base_or_partfields_is_told_in_isoxmls_words(tmp_path):
    """It was told of GeoJSON's Point features and properties.kind (an outside review's)."""
    path = tmp_path / "TASKDATA.XML"
    path.write_text(
        TASKDATA.format(ns="", body=ISOXML_PFD.format(more="")).replace('A="11"', 'A="9"')
    )
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    assert 'no garage (a home base point (PNT A="11"), or the scenario\'s garage' in str(err.value)
    path.write_text(TASKDATA.format(ns="", body=""))
    with pytest.raises(GeometryError) as err:
        load_farm(path)
    assert "kind" not in str(err.value) and "PFD" in str(err.value)


def test_isoxml_water_and_obstacles_are_not_worked(tmp_path):
    """A pond (PLN type 3) in a partfield was read as land: swaths drove through it."""
    path = tmp_path / "TASKDATA.XML"
    path.write_text(TASKDATA.format(ns="", body=ISOXML_PFD.format(more=POND)))
    (field,) = load_farm(path).fields
    assert len(field.boundary.interiors) == 1
    plain = tmp_path / "plain" / "TASKDATA.XML"
    plain.parent.mkdir()
    plain.write_text(TASKDATA.format(ns="", body=ISOXML_PFD.format(more="")))
    whole = load_farm(plain).fields[0]
    pond = 71.7 * 111.2  # 0.001 degrees of longitude by 0.001 of latitude, at 50 N
    assert whole.area_m2 - field.area_m2 == pytest.approx(pond, rel=0.01)


def test_isoxml_of_a_newer_version_than_known_is_read_with_a_warning(tmp_path, caplog):
    path = tmp_path / "TASKDATA.XML"
    for version, warned in (("4", False), ("3", False), ("5", True), ("v5", True)):
        text = TASKDATA.format(ns="", body=ISOXML_PFD.format(more=""))
        path.write_text(text.replace('VersionMajor="4"', f'VersionMajor="{version}"'))
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="planner.farm_files"):
            (field,) = load_farm(path).fields
        assert field.id == "PFD1"
        said = f"{path}: ISO 11783-10 VersionMajor '{version}', not one this reader knows (up to 4)"
        assert (said in caplog.text) == warned, version


BOWTIE = """<PLN A="4" B="Stall"><LSG A="1"><PNT A="2" C="50.0005" D="10.001"/>
<PNT A="2" C="50.0015" D="10.002"/><PNT A="2" C="50.0005" D="10.002"/>
<PNT A="2" C="50.0015" D="10.001"/></LSG></PLN>"""


def test_isoxml_a_bad_polygon_beside_water_is_named_and_a_field_all_water_is_said(tmp_path, caplog):
    """With water or obstacles in a partfield, a self-intersecting boundary or obstacle was
    a GEOS traceback (exit 1), not the error naming it that it is without them; a field
    the water covers whole was said to have "no boundary polygon"."""
    path = tmp_path / "TASKDATA.XML"
    path.write_text(TASKDATA.format(ns="", body=ISOXML_PFD.format(more=BOWTIE)))
    with pytest.raises(GeometryError, match=r"partfield 'PFD1' polygon #1 \(Stall\): invalid"):
        load_farm(path)
    bowtie_field = ISOXML_PFD.replace(
        'C="50.002" D="10.003"/><PNT A="2" C="50.002" D="10.0"',
        ('C="50.002" D="10.0"/><PNT A="2" C="50.002" D="10.003"'),
    )
    path.write_text(TASKDATA.format(ns="", body=bowtie_field.format(more=POND)))
    with pytest.raises(GeometryError, match=r"partfield 'PFD1' polygon #0: invalid"):
        load_farm(path)
    flood = ISOXML_PFD.format(more="").replace('<PLN A="1">', '<PLN A="3" B="See">')
    other = ISOXML_PFD.replace("PFD1", "PFD2").replace("10.0", "10.01")
    path.write_text(
        TASKDATA.format(
            ns="",
            body=ISOXML_PFD.format(more=flood[flood.index("<PLN") : -6]) + other.format(more=""),
        )
    )
    with caplog.at_level(logging.WARNING):
        farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["PFD2"]
    assert "'PFD1': its water, buildings and obstacles cover the whole boundary" in caplog.text


def test_isoxml_partfields_in_external_files_and_a_namespace_are_read(tmp_path):
    """Terminals keep partfields in files the TASKDATA names (XFR): "no fields" before."""
    folder = tmp_path / "TASKDATA"
    folder.mkdir()
    xfr = '<XFR A="PFD00001" B="1"/>'
    ns = ' xmlns="http://www.isobus.net/taskdata"'
    (folder / "TASKDATA.XML").write_text(TASKDATA.format(ns=ns, body=xfr))
    (folder / "PFD00001.XML").write_text(f"<XFC>{ISOXML_PFD.format(more=POND)}</XFC>")
    for path in (folder, zip_folder(folder, tmp_path / "taskdata.zip")):
        (field,) = load_farm(path).fields
        assert field.name == "Schlag 1" and len(field.boundary.interiors) == 1
    (folder / "PFD00001.XML").unlink()
    with pytest.raises(GeometryError, match="the external file PFD00001.XML it names"):
        load_farm(folder)


def test_a_garage_said_so_wins_over_points_without_a_kind_and_long_lists_are_cut(tmp_path, caplog):
    """A GeoPackage with a layer of 300 soil samples beside its garage: "301 garages (...)"
    in a message of 10 kB."""
    ring = [[10.0, 50.0], [10.002, 50.0], [10.002, 50.001], [10.0, 50.001], [10.0, 50.0]]
    field = {"properties": {"id": "A"}, "geometry": {"type": "Polygon", "coordinates": [ring]}}
    samples = [
        {"properties": {"depth": 30}, "geometry": {"type": "Point", "coordinates": [10.0, 50.0]}}
        for _ in range(300)
    ]
    garage = {
        "properties": {"kind": "garage"},
        "geometry": {"type": "Point", "coordinates": [9.999, 49.999]},
    }
    path = tmp_path / "farm.gpkg"
    write_gdal([{"type": "Feature", **field}], path, "GPKG", layer="fields")
    write_gdal([{"type": "Feature", **f} for f in samples], path, "GPKG", layer="soil", append=True)
    with pytest.raises(GeometryError) as err:  # no point says it is the garage
        load_farm(path)
    message = str(err.value)
    assert "300 garages (layer 'soil' feature #0, " in message and "and 295 more)" in message
    assert len(message) < 600
    write_gdal([{"type": "Feature", **garage}], path, "GPKG", layer="yard", append=True)
    with caplog.at_level("WARNING", logger="planner.farm"):
        farm = load_farm(path)
    assert farm.garage_lonlat == (9.999, 49.999)
    assert "300 points without a kind left out (layer 'soil' feature #0" in caplog.text
    assert "the garage is layer 'yard' feature #0" in caplog.text


def test_a_feature_without_geometry_is_left_out_and_named(tmp_path, caplog):
    """RFC 7946 allows a feature without geometry (a shapefile's null record): it refused
    the whole farm, "(no id)" though it had a name."""
    doc = json.loads(CHANGJI.read_text())
    doc["features"].append({"type": "Feature", "properties": {"name": "Hecke"}, "geometry": None})
    path = tmp_path / "farm.geojson"
    path.write_text(json.dumps(doc))
    with caplog.at_level("WARNING", logger="planner.farm"):
        farm = load_farm(path)
    assert len(farm.fields) == 15
    n = len(doc["features"]) - 1
    assert f"feature #{n} (name 'Hecke'): no geometry; left out" in caplog.text


def test_a_geopackages_primary_key_named_id_is_the_field_id(tmp_path):
    """GDAL takes a GeoPackage's primary key column as its feature numbers, not a column:
    the ids fell back to the names, and --id-field id was refused."""
    import pyogrio
    import shapely

    ring = [(10.0, 50.0), (10.002, 50.0), (10.002, 50.001), (10.0, 50.001), (10.0, 50.0)]
    fields = [shapely.Polygon([(x + 0.003 * k, y) for x, y in ring]) for k in range(2)]
    path = tmp_path / "farm.gpkg"
    pyogrio.raw.write(
        path,
        shapely.to_wkb(fields),
        [np.array(["Schlag 1", "Schlag 2"], dtype=object)],
        ["name"],
        driver="GPKG",
        layer="fields",
        geometry_type="Polygon",
        crs="EPSG:4326",
        layer_options={"FID": "id"},
    )
    farm = load_farm(path, FarmOptions(garage=(9.999, 49.999)))
    assert [(f.id, f.name) for f in farm.fields] == [("1", "Schlag 1"), ("2", "Schlag 2")]


def test_a_projected_shapefile_without_its_prj_is_named(tmp_path):
    """A copy that dropped the .prj: its UTM metres read as degrees, and the message spoke
    of GeoJSON and swapped coordinates."""
    folder = write_shapefiles(farm_features(CHANGJI), tmp_path / "farm", crs="EPSG:32645")
    for prj in folder.glob("*.prj"):
        prj.unlink()
    with pytest.raises(GeometryError, match=r"no coordinate system \(a shapefile's \.prj beside"):
        load_farm(folder)


def test_a_layer_in_a_local_grid_is_named_not_a_traceback(tmp_path):
    """A .prj of a farm's own grid (LOCAL_CS, no datum) could not be converted: a PROJ
    traceback, exit 1."""
    folder = write_shapefiles(farm_features(CHANGJI), tmp_path / "farm", crs="EPSG:32645")
    local = (
        'LOCAL_CS["Farm grid",LOCAL_DATUM["local",0],UNIT["metre",1],'
        'AXIS["X",EAST],AXIS["Y",NORTH]]'
    )
    for prj in folder.glob("*.prj"):
        prj.write_text(local)
    with pytest.raises(GeometryError, match=r"'Farm grid' cannot be converted to WGS84"):
        load_farm(folder)


def test_small_things_farm_files_say_better(tmp_path):
    # A file of no features: "no fields", not "no garage".
    empty = tmp_path / "empty.geojson"
    empty.write_text('{"type": "FeatureCollection", "features": []}')
    with pytest.raises(GeometryError, match="no fields"):
        load_farm(empty)
    # A KML road's name is its id (it was "road#1").
    lane = (
        "<Placemark><name>Feldweg Nord</name><LineString><coordinates>"
        "9.999,49.999 10.004,49.999</coordinates></LineString></Placemark>"
    )
    path = tmp_path / "farm.kml"
    path.write_text(GOOGLE_EARTH_KML.replace("</Document>", lane + "</Document>"))
    assert [r.id for r in load_farm(path).roads] == ["Feldweg Nord"]
    # An ISOXML point of NaN: not a number, not "swapped".
    taskdata = tmp_path / "TASKDATA.XML"
    taskdata.write_text(
        TASKDATA.format(ns="", body=ISOXML_PFD.format(more="")).replace(
            'C="50.002" D="10.003"', 'C="NaN" D="10.003"'
        )
    )
    with pytest.raises(GeometryError, match="latitude in C and longitude in D as numbers"):
        load_farm(taskdata)


def test_a_zip_of_one_folder_a_field_says_so(tmp_path):
    """Some farm-management exports: one folder per field. GDAL said "not recognized"."""
    import zipfile

    features = farm_features(CHANGJI)
    archive = tmp_path / "export.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for k, name in enumerate(("north", "south")):
            folder = write_shapefiles(features[k : k + 1], tmp_path / name)
            for file in folder.iterdir():
                z.write(file, f"farm/{name}/{file.name}")
    with pytest.raises(GeometryError, match=r"shapefiles in 2 folders of the archive \(farm/north"):
        load_farm(archive)


def test_shapes_other_tools_save_a_farm_in_are_read(tmp_path):
    """A KML placemark of a polygon and its label point (a GeometryCollection), a garage
    as a MultiPoint of one point, a GeoJSON of one Feature: each refused the farm."""
    label = GOOGLE_EARTH_KML.replace(
        "<Placemark><name>North 40</name><Polygon>",
        "<Placemark><name>North 40</name><MultiGeometry>"
        "<Point><coordinates>10.001,50.0005</coordinates></Point><Polygon>",
    ).replace(
        "</coordinates></LinearRing></outerBoundaryIs></Polygon></Placemark>\n<Placemark>"
        "<name>Creek</name>",
        "</coordinates></LinearRing></outerBoundaryIs></Polygon></MultiGeometry></Placemark>"
        "\n<Placemark><name>Creek</name>",
    )
    assert label.count("<MultiGeometry>") == 2
    path = tmp_path / "farm.kml"
    path.write_text(label)
    farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["North 40", "Creek.0", "Creek.1"]
    ring = [[10.0, 50.0], [10.002, 50.0], [10.002, 50.001], [10.0, 50.001], [10.0, 50.0]]
    field = {
        "type": "Feature",
        "properties": {"id": "A"},
        "geometry": {"type": "Polygon", "coordinates": [ring]},
    }
    garage = {
        "type": "Feature",
        "properties": {"kind": "garage"},
        "geometry": {"type": "MultiPoint", "coordinates": [[9.999, 49.999]]},
    }
    doc = tmp_path / "farm.geojson"
    doc.write_text(json.dumps({"type": "FeatureCollection", "features": [field, garage]}))
    assert load_farm(doc).garage_lonlat == (9.999, 49.999)
    doc.write_text(json.dumps(field))
    one = load_farm(doc, FarmOptions(garage=(9.999, 49.999)))
    assert [f.id for f in one.fields] == ["A"]


def test_an_esri_json_export_of_the_fields_reads_as_the_same_fields(tmp_path, reference):
    """ArcGIS's own JSON (a FeatureSet in Web Mercator, features of attributes): the fields
    as the GeoJSON has them, the garage from the scenario."""
    path = write_esri_json(farm_features(CHANGJI), tmp_path / "Fields.json")
    farm = load_farm(path, FarmOptions(garage=reference.garage_lonlat))
    assert [(f.id, f.name) for f in farm.fields] == [(f.id, f.name) for f in reference.fields]
    for f, r in zip(farm.fields, reference.fields, strict=True):
        assert f.boundary_lonlat.hausdorff_distance(r.boundary_lonlat) < CM_DEG, f.id
