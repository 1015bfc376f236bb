"""A farm GeoJSON converted to the other formats farmers have, for the reader tests:
through GDAL (pyogrio) to KML, GeoPackage, shapefiles, and by hand to ISO 11783-10
TaskData as the standard structures it (ISO11783_TaskData > PFD > PLN > LSG > PNT)."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pyogrio
import pyproj
import shapely
import shapely.geometry

GEOMETRY_LAYERS = {"Polygon": "fields", "LineString": "roads", "Point": "points"}


def farm_features(path: Path) -> list[dict[str, Any]]:
    """The features of a farm GeoJSON, without properties a shapefile could not name."""
    features = json.loads(path.read_text())["features"]
    keep = ("kind", "id", "name", "field", "work_angle_deg", "headland_passes")
    return [
        {**f, "properties": {k: f["properties"][k] for k in keep if k in f["properties"]}}
        for f in features
    ]


def write_gdal(
    features: list[dict[str, Any]],
    path: Path,
    driver: str,
    layer: str | None = None,
    crs: str = "EPSG:4326",
    append: bool = False,
    projected: bool = False,
) -> None:
    """One layer of ``features`` (any geometry types) with their properties as columns;
    their coordinates are longitude/latitude, converted to ``crs``, or already in it
    (``projected``)."""
    keys: list[str] = []
    for f in features:
        keys += [k for k in f["properties"] if k not in keys]
    geoms = shapely.from_geojson([json.dumps(f["geometry"]) for f in features])
    if crs != "EPSG:4326" and not projected:
        to = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        geoms = shapely.transform(geoms, lambda xy: np.column_stack(to.transform(*xy.T)))
    columns = [np.array([f["properties"].get(k) for f in features], dtype=object) for k in keys]
    pyogrio.raw.write(
        path,
        shapely.to_wkb(geoms),
        columns,
        keys,
        driver=driver,
        layer=layer,
        geometry_type="Unknown",
        crs=crs,
        append=append,
    )


def write_shapefiles(features: list[dict[str, Any]], folder: Path, crs: str = "EPSG:4326") -> Path:
    """One shapefile per geometry type (a shapefile holds one) in ``folder``, in ``crs``."""
    folder.mkdir(parents=True, exist_ok=True)
    for gtype, name in GEOMETRY_LAYERS.items():
        part = [f for f in features if f["geometry"]["type"] == gtype]
        if part:
            write_gdal(part, folder / f"{name}.shp", "ESRI Shapefile", crs=crs)
    return folder


def write_esri_json(features: list[dict[str, Any]], path: Path, wkid: int = 3857) -> Path:
    """The polygons of ``features`` as ArcGIS exports a layer (Esri JSON, a FeatureSet in
    ``wkid``, Web Mercator by default): outlines clockwise, holes counter-clockwise."""
    to = pyproj.Transformer.from_crs("EPSG:4326", f"EPSG:{wkid}", always_xy=True)
    out = []
    for k, f in enumerate(f for f in features if f["geometry"]["type"] == "Polygon"):
        polygon = shapely.orient_polygons(shapely.geometry.shape(f["geometry"]), exterior_cw=True)
        rings = [polygon.exterior, *polygon.interiors]
        out.append(
            {
                "attributes": {"OBJECTID": k + 1, **f["properties"]},
                "geometry": {
                    "rings": [[list(to.transform(x, y)) for x, y in ring.coords] for ring in rings]
                },
            }
        )
    doc = {
        "displayFieldName": "name",
        "geometryType": "esriGeometryPolygon",
        "spatialReference": {"wkid": wkid, "latestWkid": wkid},
        "fields": [{"name": "OBJECTID", "type": "esriFieldTypeOID", "alias": "OBJECTID"}]
        + [
            {"name": key, "type": "esriFieldTypeString", "alias": key, "length": 64}
            for key in ("kind", "id", "name")
        ],
        "features": out,
    }
    path.write_text(json.dumps(doc))
    return path


def zip_folder(folder: Path, archive: Path) -> Path:
    return Path(shutil.make_archive(str(archive.with_suffix("")), "zip", folder))


def write_isoxml(features: list[dict[str, Any]], path: Path) -> Path:
    """TASKDATA.XML: each field a PFD (A id, B code = our id, C designator = our name) with
    a boundary PLN (A = 1) of an outer LSG (A = 1) and holes (A = 2) of PNTs (A = 2 other,
    C latitude, D longitude); its gates as PNTs of type 3 (field access), the garage a
    PNT of type 11 (home base) of the first partfield. Roads have no place in it."""
    root = ET.Element(
        "ISO11783_TaskData",
        VersionMajor="4",
        VersionMinor="3",
        DataTransferOrigin="1",
        ManagementSoftwareManufacturer="agrifleet tests",
    )
    gates = [f for f in features if f["properties"].get("kind") == "gate"]
    garage = next(f for f in features if f["properties"].get("kind") == "garage")
    fields = [f for f in features if f["properties"].get("kind") == "field"]
    for n, f in enumerate(fields, start=1):
        props = f["properties"]
        pfd = ET.SubElement(
            root,
            "PFD",
            A=f"PFD{n}",
            B=props["id"],
            C=props.get("name", ""),
            D=str(round(shapely.from_geojson(json.dumps(f["geometry"])).area)),
        )
        pln = ET.SubElement(pfd, "PLN", A="1")
        for k, ring in enumerate(f["geometry"]["coordinates"]):
            lsg = ET.SubElement(pln, "LSG", A="1" if k == 0 else "2")
            for lon, lat in ring[:-1]:  # ISOXML closes a ring implicitly
                ET.SubElement(lsg, "PNT", A="2", C=f"{lat:.9f}", D=f"{lon:.9f}")
        for g in gates:
            if g["properties"]["field"] == props["id"]:
                lon, lat = g["geometry"]["coordinates"]
                ET.SubElement(pfd, "PNT", A="3", C=f"{lat:.9f}", D=f"{lon:.9f}")
        if n == 1:
            lon, lat = garage["geometry"]["coordinates"]
            ET.SubElement(pfd, "PNT", A="11", B="garage", C=f"{lat:.9f}", D=f"{lon:.9f}")
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    return path


def convert(source: Path, fmt: str, out: Path) -> Path:
    """The farm GeoJSON ``source`` as ``fmt`` under ``out``: the path to read."""
    features = farm_features(source)
    out.mkdir(parents=True, exist_ok=True)
    if fmt == "kml":
        write_gdal(features, out / "farm.kml", "LIBKML", layer="farm")
        return out / "farm.kml"
    if fmt == "gpkg":
        write_gdal(features, out / "farm.gpkg", "GPKG", layer="farm")
        return out / "farm.gpkg"
    if fmt == "gpkg-utm":  # a projected CRS, converted back when read
        write_gdal(features, out / "utm.gpkg", "GPKG", layer="farm", crs="EPSG:32645")
        return out / "utm.gpkg"
    if fmt == "geojson-utm":  # GeoJSON 2008 with a "crs" member: read through GDAL
        write_gdal(features, out / "utm.geojson", "GeoJSON", crs="EPSG:32645")
        return out / "utm.geojson"
    if fmt == "shp-folder":
        return write_shapefiles(features, out / "shapes")
    if fmt == "gpkg-osgb":  # another datum: a Helmert shift there and back
        write_gdal(features, out / "osgb.gpkg", "GPKG", layer="farm", crs="EPSG:27700")
        return out / "osgb.gpkg"
    if fmt == "shp-zip":
        return zip_folder(write_shapefiles(features, out / "zipped"), out / "farm.zip")
    if fmt == "shp-zip-folder":  # a folder zipped: its files one folder down in the archive
        write_shapefiles(features, out / "zipped" / "Farm Hof")
        return zip_folder(out / "zipped", out / "farm.zip")
    if fmt == "isoxml":
        return write_isoxml(features, out / "TASKDATA" / "TASKDATA.XML")
    raise ValueError(fmt)
