"""Farm files in the formats farmers have, read into the GeoJSON-shaped document that
:func:`planner.farm.farm_from_geojson` checks and builds a farm from.

* GeoJSON (``.geojson``, ``.json``): parsed as JSON, so that every error names the feature
  at fault (GDAL unifies the properties of all features into typed columns and refuses a
  bad feature without saying which). A GeoJSON file with a ``crs`` member (GeoJSON 2008)
  in another CRS is read through GDAL, as below; so is an Esri JSON file (ArcGIS's export
  of a layer: features of ``attributes`` and ``geometry``, in its ``spatialReference``).
* Everything GDAL reads (through pyogrio): KML/KMZ, shapefile (``.shp``, a folder of
  them, or a ``.zip`` of them), GeoPackage, and the rest; every layer with geometry, each
  reprojected from its CRS to WGS84 with a message.
* ISO 11783-10 TaskData (``TASKDATA.XML``, a folder or ``.zip`` holding one): the
  partfields (:func:`read_isoxml`, docs/farm-files.md lists the subset read).
"""

from __future__ import annotations

import datetime
import io
import json
import logging
import math
import re
import tempfile
import warnings
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import pyproj
import shapely
from shapely.geometry import Polygon, mapping

from planner.errors import GeometryError

log = logging.getLogger(__name__)

GEOJSON_SUFFIXES = (".geojson", ".json")
ISOXML_NAME = "TASKDATA.XML"
# The newest ISO 11783-10 (TaskData) version this reader knows (VersionMajor; the partfield,
# polygon, line-string and point elements read here are the same in versions 3 and 4).
ISOXML_MAJOR = 4
WGS84 = pyproj.CRS.from_epsg(4326)
CONVERTED_DECIMALS = 7
"""Converted lon/lat are rounded to 1e-7 degrees (~1 cm, a MAVLink position's step): a
farm drawn in WGS84 and converted there and back reads as the same numbers, so plans the
same (the solver is deterministic on its inputs, and 1e-14 degrees of conversion noise
changes its choices). 1e-9 absorbed the noise of a projection of the same datum but not
the ~1e-8 degrees of a datum shift there and back (OSGB36, EPSG:27700; DHDN, EPSG:31468)."""

# ISO 11783-10 codes read (ISOXML attributes are one-letter names in the element's order).
PLN_BOUNDARY = "1"  # PLN A: partfield boundary
PLN_NOT_WORKED = ("3", "4", "6")  # PLN A: water surface, building, obstacle: out of the field
LSG_EXTERIOR = "1"  # LSG A: polygon exterior
LSG_INTERIOR = "2"  # LSG A: polygon interior (a hole)
PNT_FIELD_ACCESS = "3"  # PNT A: field access (our gate)
PNT_HOMEBASE = "11"  # PNT A: home base (our garage)

Document = dict[str, Any]
WHERE_KEY = "_where"
"""A feature's name in messages (``layer 'fields' feature #3``, ``partfield 'PFD2'``), set
by the readers of formats whose features a plain index would not find."""
MARKS_KEY = "_marks"
"""A document's way of marking its fields and its garage, in the format's own words, for the
messages of a farm without them (``{"fields": ..., "garage": ...}``); GeoJSON's without."""


def read_farm_document(path: Path) -> Document:
    """The farm file at ``path`` as a GeoJSON FeatureCollection in WGS84 (dicts, lists)."""
    if path.is_dir():
        if _isoxml_in_dir(path) is not None:
            return read_isoxml(path)
        return read_gdal(path)
    suffix = path.suffix.lower()
    if suffix in GEOJSON_SUFFIXES:
        doc = read_json(path)
        if _is_esri_json(doc):
            return read_gdal(path)
        if (
            isinstance(doc, dict)
            and doc.get("crs") is not None
            and not _crs_is_wgs84(doc["crs"], path)
        ):
            converted = read_gdal(path)
            # The features' own ids (RFC 7946), which GDAL takes as its feature numbers.
            given = doc.get("features")
            if isinstance(given, list) and len(given) == len(converted["features"]):
                for feature, original in zip(converted["features"], given, strict=True):
                    if not isinstance(original, dict):
                        continue
                    if original.get("id") is not None:
                        feature["id"] = original["id"]
                    if original.get("geometry") is not None and feature["geometry"] is None:
                        # GDAL made it none (a misspelt type, coordinates not numbers), and
                        # the field was left out: as written, it is refused, naming what is
                        # wrong with it, as without a crs.
                        feature["geometry"] = original["geometry"]
            return converted
        return doc  # type: ignore[no-any-return]
    if suffix == ".xml" and _is_gml(path):
        return read_gdal(path)  # GML some tools name .xml
    if suffix == ".xml" or (suffix == ".zip" and _isoxml_in_zip(path) is not None):
        return read_isoxml(path)
    return read_gdal(path)


GML_NAMESPACE = b"http://www.opengis.net/gml"
"""What every GML document's root declares (GML 2 and 3 alike, 3.2 with ``/3.2``)."""


def _is_gml(path: Path) -> bool:
    """Whether the ``.xml`` file at ``path`` is GML (a GIS export named ``.xml``), not
    ISOXML: its start declares GML's namespace and its root is no TaskData."""
    try:
        with path.open("rb") as f:
            start = f.read(1 << 16)
    except OSError:
        return False  # read_isoxml says what is wrong
    return GML_NAMESPACE in start and b"ISO11783_TaskData" not in start


def read_json(path: Path) -> Any:
    """A JSON file, or a :class:`GeometryError` naming the file and what is wrong."""
    try:
        return json.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark or none
    except OSError as exc:
        raise GeometryError(f"{path}: cannot read the farm: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise GeometryError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from exc
    except json.JSONDecodeError as exc:
        raise GeometryError(f"{path}: not JSON (line {exc.lineno}: {exc.msg})") from exc
    except ValueError as exc:  # e.g. an integer of more digits than Python reads
        raise GeometryError(f"{path}: not JSON we can read ({exc})") from exc


def _is_esri_json(doc: Any) -> bool:
    """Whether ``doc`` is Esri JSON (a FeatureSet: ``geometryType``, ``spatialReference``,
    features of ``attributes`` and ``geometry``), which GDAL reads, and not GeoJSON."""
    if not isinstance(doc, dict) or doc.get("type") is not None:
        return False
    if "geometryType" in doc or "spatialReference" in doc:
        return True
    features = doc.get("features")
    return isinstance(features, list) and any(
        isinstance(f, dict) and "attributes" in f and "type" not in f for f in features
    )


def _crs_is_wgs84(crs: Any, path: Path) -> bool:
    """Whether a GeoJSON's ``crs`` member (GeoJSON 2008) names WGS84; one not understood
    (not a named CRS, or a name pyproj does not know) is taken as WGS84, as RFC 7946 has
    every GeoJSON, and said (the checks of longitude and latitude follow)."""
    properties = crs.get("properties") if isinstance(crs, dict) else None
    name = properties.get("name") if isinstance(properties, dict) else None
    if isinstance(crs, dict) and crs.get("type") == "EPSG" and isinstance(properties, dict):
        name = f"EPSG:{properties.get('code')}"  # GeoJSON 2008's other form, GDAL reads too
    if isinstance(name, str):
        try:
            return pyproj.CRS.from_user_input(name).equals(WGS84, ignore_axis_order=True)
        except pyproj.exceptions.CRSError:
            pass
    shown = json.dumps(crs, ensure_ascii=False)
    log.warning(
        "%s: its crs member %s is not understood (a named CRS is, as "
        '{"type": "name", "properties": {"name": "EPSG:25832"}}); taken as WGS84 '
        "longitude/latitude",
        path,
        shown if len(shown) <= 80 else shown[:77] + "...",
    )
    return True


# --- GDAL (pyogrio) ----------------------------------------------------------------------


def read_gdal(path: Path) -> Document:
    """Every layer with geometry of a file GDAL reads, reprojected to WGS84; each feature
    named ``layer 'NAME' feature #k`` when the file has several layers."""
    if not path.exists():
        raise GeometryError(f"{path}: cannot read the farm: No such file or directory")
    mended = _kml_holes_apart(path)
    if mended is None:
        return _read_gdal(path, path)
    # GDAL is given a copy, under the same name, with every hole in a boundary of its own.
    with tempfile.TemporaryDirectory(prefix="agrifleet-kml-") as scratch:
        copy = Path(scratch) / path.name
        copy.write_bytes(mended)
        return _read_gdal(path, copy)


def _read_gdal(path: Path, readable: Path) -> Document:
    """:func:`read_gdal` of ``path``, whose content GDAL reads from ``readable``."""
    import pyogrio
    from pyogrio.errors import DataLayerError, DataSourceError

    source: Path | str = readable

    def as_given(text: object) -> str:
        """GDAL's words, naming the file as given, not its mended copy."""
        return str(text).replace(str(readable), str(path))

    _check_shapefiles_whole(path, source)
    try:
        layers = [str(name) for name, geom in pyogrio.list_layers(readable) if geom is not None]
    except (DataSourceError, DataLayerError, OSError) as exc:
        folder = _shapefile_folder_in_zip(path)
        if folder is None:
            folders = _shapefile_folders_in_zip(path)
            if len(folders) > 1:
                raise GeometryError(
                    f"{path}: shapefiles in {len(folders)} folders of the archive "
                    f"({', '.join(sorted(folders)[:5])}{', ...' if len(folders) > 5 else ''}): "
                    "a farm is one folder of them (fields, roads, points); put them together"
                ) from exc
            raise GeometryError(
                f"{path}: not a farm file GDAL can read ({as_given(_first_line(exc))})"
            ) from exc
        source = f"/vsizip/{path}/{folder}"  # a zipped folder of shapefiles
        _check_shapefiles_whole(path, source)
        layers = [str(name) for name, geom in pyogrio.list_layers(source) if geom is not None]
    if path.is_dir():
        layers.sort()  # a folder lists its files in whatever order its file system keeps
    if not layers:
        raise GeometryError(f"{path}: no layer with geometry in this file")
    features: list[dict[str, Any]] = []
    for layer in layers:
        try:
            # The read's warnings (GDAL's) said in our log, naming the file (a geometry it
            # made none is named again, or refused); the rings it finds open are closed below.
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always")
                meta, fids, geometry, values = pyogrio.raw.read(
                    source, layer=layer, return_fids=True
                )
                key = str(pyogrio.read_info(source, layer=layer).get("fid_column") or "")
        except (DataSourceError, DataLayerError, OSError) as exc:
            raise GeometryError(
                f"{path}: layer {layer!r}: cannot be read ({as_given(_first_line(exc))})"
            ) from exc
        for warning in said:
            if "Non closed ring" not in str(warning.message):
                log.warning("%s: layer %r: reading it: %s", path, layer, as_given(warning.message))
        names = _column_names(path, [str(n) for n in meta["fields"]], values)
        if key and key not in names:  # a GeoPackage's primary key named by its author
            names, values = [*names, key], [*values, fids]
        where = f"layer {layer!r} feature" if len(layers) > 1 else "feature"
        # Rings as RFC 7946 has them (outline counter-clockwise), whatever the format's
        # rule (a shapefile's outline is clockwise): the same farm gives the same plan.
        geoms = shapely.orient_polygons(_from_wkb(geometry, f"{path}: {where}"))
        geoms = _to_wgs84(geoms, meta.get("crs"), f"{path}: layer {layer!r}")
        for k, geom in enumerate(geoms):
            props = {name: _plain(column[k]) for name, column in zip(names, values, strict=True)}
            features.append(
                {
                    "type": "Feature",
                    WHERE_KEY: f"{where} #{k}",
                    "properties": props,
                    "geometry": None if geom is None else json.loads(shapely.to_geojson(geom)),
                }
            )
    return {"type": "FeatureCollection", "features": features}


# A KML polygon's boundaries (any namespace prefix), a boundary holding one LinearRing;
# or a comment or a CDATA section (a description's text), taken as they are.
_KML_BOUNDARY = re.compile(
    rb"<!--.*?-->|<!\[CDATA\[.*?\]\]>|"
    rb"<((?:[A-Za-z_][\w.-]*:)?)(outer|inner)BoundaryIs(?:\s[^>]*)?(?<!/)>(.*?)</\1\2BoundaryIs\s*>",
    re.DOTALL,
)
_KML_RING = re.compile(rb"<((?:[A-Za-z_][\w.-]*:)?)LinearRing\b.*?</\1LinearRing\s*>", re.DOTALL)
_KML_PLACEMARK = re.compile(rb"<(?:[A-Za-z_][\w.-]*:)?Placemark\b")
_KML_NAME = re.compile(rb"<((?:[A-Za-z_][\w.-]*:)?)name\s*>(.*?)</\1name\s*>", re.DOTALL)


def _kml_holes_apart(path: Path) -> bytes | None:
    """A KML or KMZ file whose polygons hold several holes in one ``innerBoundaryIs``, as
    some tools write them, mended: each hole in a boundary of its own, as KML has it (a
    KMZ with every KML document in it so mended); None for any other file. GDAL keeps the last
    ring of such a boundary and drops the others without a word: a pond in the field
    would be worked through. Several rings in one ``outerBoundaryIs`` (a polygon has one
    outline) are refused, naming the placemark."""
    suffix = path.suffix.lower()
    if suffix not in (".kml", ".kmz") or not path.is_file():
        return None
    try:
        if suffix == ".kml":
            return _kml_mended(path.read_bytes(), path)
        with zipfile.ZipFile(path) as archive:
            # Every KML document in it: GDAL reads the first, and those it links to.
            mended = {
                info.filename: _kml_mended(archive.read(info), f"{path}: {info.filename}")
                for info in archive.infolist()
                if info.filename.lower().endswith(".kml")
            }
            if all(document is None for document in mended.values()):
                return None
            out = io.BytesIO()
            with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as copy:
                for info in archive.infolist():
                    copy.writestr(info, mended.get(info.filename) or archive.read(info))
            return out.getvalue()
    except (OSError, zipfile.BadZipFile):
        return None  # GDAL says what is wrong with it


def _kml_mended(text: bytes, path: Path | str) -> bytes | None:
    """``text`` (a KML document) with each hole in a boundary of its own, or None when
    every boundary holds one ring already (see :func:`_kml_holes_apart`)."""
    if b"BoundaryIs" not in text:
        return None
    changed = False

    def apart(match: re.Match[bytes]) -> bytes:
        nonlocal changed
        if match.group(2) is None:  # a comment or a CDATA section
            return match.group(0)
        prefix, which, inside = match.group(1), match.group(2), match.group(3)
        rings = [ring.group(0) for ring in _KML_RING.finditer(inside)]
        if len(rings) <= 1:
            return match.group(0)
        if which == b"outer":
            raise GeometryError(
                f"{path}: {_kml_placemark_at(text, match.start())}: its outerBoundaryIs "
                f"holds {len(rings)} rings, and a polygon has one outline: make each its "
                "own Polygon (a MultiGeometry holds several), or a hole an innerBoundaryIs"
            )
        changed = True
        boundary = prefix + b"innerBoundaryIs>"
        return b"".join(b"<" + boundary + ring + b"</" + boundary for ring in rings)

    mended = _KML_BOUNDARY.sub(apart, text)
    return mended if changed else None


def _kml_placemark_at(text: bytes, at: int) -> str:
    """The placemark of a KML document that holds position ``at``, by its name."""
    starts = [m.start() for m in _KML_PLACEMARK.finditer(text, 0, at)]
    if not starts:
        return f"the polygon at byte {at}"
    name = _KML_NAME.search(text, starts[-1], at)
    if name is None:
        return f"the placemark at byte {starts[-1]}"
    return f"placemark {name.group(2).decode('utf-8', 'replace').strip()!r}"


def _from_wkb(geometry: Any, where: str) -> Any:
    """GDAL's WKB as shapely geometries, rings left open closed (a KML drawn by hand, a
    GeoJSON of 2008); a geometry that cannot be one (a ring of two points) named by its
    feature, not a traceback."""
    try:
        return shapely.from_wkb(geometry, on_invalid="fix")
    except shapely.errors.GEOSException:
        pass
    for k, wkb in enumerate(geometry):
        try:
            shapely.from_wkb(wkb, on_invalid="fix")
        except shapely.errors.GEOSException as exc:
            raise GeometryError(
                f"{where} #{k}: its geometry is not one ({_first_line(exc)}): a ring needs "
                "at least three distinct points"
            ) from exc
    raise AssertionError("unreachable: one geometry failed together but none alone")


def _column_names(path: Path, names: list[str], values: Sequence[Any]) -> list[str]:
    """The columns as the file's author named them. A KML written by GDAL (QGIS's "Save
    as KML") holds each placemark's XML id, which GDAL reads back as column ``id``, and the
    author's ``id`` in its ExtendedData's SchemaData, read as ``id2``: the author's is
    ``id``. An ``id`` in plain ``<Data name="id">`` (Google Earth's, or written by hand) GDAL
    reads as ``id`` itself, leaving ``id2`` empty: then ``id`` is the author's as it is."""
    if path.suffix.lower() in (".kml", ".kmz") and "id" in names and "id2" in names:
        given = values[names.index("id2")]
        if any(v is not None and str(v).strip() for v in given):
            return ["kml_placemark_id" if n == "id" else "id" if n == "id2" else n for n in names]
    return names


def _check_shapefiles_whole(path: Path, source: Path | str) -> None:
    """A shapefile without its ``.shx`` or ``.dbf`` beside it, named exactly as GDAL looks
    for them (its own name, the ending in lower or upper case): GDAL skips a ``.shp``
    without its ``.shx`` without a word, and reads one without its ``.dbf`` without its
    columns (ids, names, work angles). A copy by mail or USB stick that dropped one, or
    wrote ``NORD.SHX`` for ``Nord.shp``: refused, naming it, rather than its fields lost."""
    if isinstance(source, str):  # a folder in a zip
        folder = source.split("/vsizip/", 1)[1][len(str(path)) + 1 :]
        files = [Path(n).name for n in _zip_names(path) if str(Path(n).parent) == folder]
    elif path.is_dir():
        files = [p.name for p in path.iterdir()]
    elif path.suffix.lower() == ".shp":
        files = [p.name for p in path.parent.iterdir()]
        files = [f for f in files if Path(f).stem.lower() == path.stem.lower()] or [path.name]
    else:  # a zip's top (nothing for any other file)
        files = [n for n in _zip_names(path) if "/" not in n]
    present = set(files)
    for f in sorted(files):
        stem = Path(f).stem
        if Path(f).suffix.lower() != ".shp":
            continue
        for ending, holds in ((".shx", "its features"), (".dbf", "its columns (ids, names)")):
            if f"{stem}{ending}" in present or f"{stem}{ending.upper()}" in present:
                continue
            other = [g for g in files if g.lower() == f"{stem}{ending}".lower()]
            if other:
                raise GeometryError(
                    f"{path}: {f}'s {ending} is {other[0]}, a name that differs in case, "
                    f"under which it is not found: rename it {stem}{ending}"
                )
            raise GeometryError(
                f"{path}: {f} has no {stem}{ending} beside it (a shapefile is its .shp, "
                f".shx, .dbf and .prj together: copy them all), so {holds} cannot be read"
            )


def _zip_names(path: Path) -> list[str]:
    """The files of a .zip, without what macOS's Finder adds (``__MACOSX/``, ``._``
    resource forks); none for anything that is not a zip."""
    if path.suffix.lower() != ".zip":
        return []
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return []
    return [n for n in names if not n.startswith("__MACOSX/") and not Path(n).name.startswith("._")]


def _shapefile_folder_in_zip(path: Path) -> str | None:
    """The one folder of a .zip that holds its shapefiles (zipping a folder puts them there,
    where GDAL, opening the archive's top, does not look; macOS's ``__MACOSX`` copies left
    out); None if not exactly one."""
    folders = _shapefile_folders_in_zip(path)
    folders.discard(".")
    return folders.pop() if len(folders) == 1 else None


def _shapefile_folders_in_zip(path: Path) -> set[str]:
    """The folders of a .zip that hold shapefiles ("." its top; macOS's copies left out)."""
    return {str(Path(n).parent) for n in _zip_names(path) if n.lower().endswith(".shp")}


def _to_wgs84(geoms: Any, crs: str | None, where: str) -> Any:
    """The geometries in WGS84 lon/lat; a layer in another CRS is converted, said in a
    message. A layer without a CRS is taken as WGS84 (the checks of lon/lat follow)."""
    if not crs:
        bounds = shapely.total_bounds(geoms)
        if np.all(np.isfinite(bounds)) and (
            max(abs(bounds[0]), abs(bounds[2])) > 180.0
            or max(abs(bounds[1]), abs(bounds[3])) > 90.0
        ):
            raise GeometryError(
                f"{where}: no coordinate system (a shapefile's .prj beside it, or the "
                f"layer's CRS), and coordinates that are not longitude and latitude "
                f"(x {bounds[0]:.0f} to {bounds[2]:.0f}, y {bounds[1]:.0f} to {bounds[3]:.0f}): "
                "copy its .prj with it, or save it with its CRS"
            )
        return geoms
    source = pyproj.CRS.from_user_input(crs)
    if source.equals(WGS84, ignore_axis_order=True):
        return geoms
    try:
        to_wgs84 = pyproj.Transformer.from_crs(source, WGS84, always_xy=True)
    except pyproj.exceptions.ProjError as e:  # a local grid (LOCAL_CS), no datum to go by
        raise GeometryError(
            f"{where}: its coordinate system {source.name!r} cannot be converted to WGS84 "
            f"longitude/latitude ({e}): save the layer in a geographic or projected CRS "
            "(EPSG:4326, or its UTM zone)"
        ) from None
    log.warning("%s: converted from %s to WGS84 longitude/latitude", where, source.name)
    exact = shapely.transform(geoms, lambda xy: np.column_stack(to_wgs84.transform(*xy.T)))
    rounded = shapely.transform(exact, lambda xy: np.round(xy, CONVERTED_DECIMALS))
    # A polygon the rounding made invalid (a hole's corner snapped onto the outline, moved
    # across it by up to a centimetre) keeps its exact coordinates: valid as the file has
    # it, it reads valid (it was refused as self-intersecting, its author blamed).
    broken = shapely.is_valid(exact) & ~shapely.is_valid(rounded)
    return np.where(broken, exact, rounded)


def _plain(value: Any) -> Any:
    """A value of a GDAL column as JSON would hold it: None for a missing value, a date
    or time as ISO 8601 text."""
    if isinstance(value, np.datetime64):
        return None if np.isnat(value) else str(value)
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, datetime.date | datetime.time):
        return value.isoformat()
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value


def _first_line(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


# --- ISO 11783-10 TaskData ---------------------------------------------------------------


FARM_SUFFIXES: Final = (".shp", ".gpkg", ".kml", ".kmz", ".geojson", ".gml")
"""Files of a farm GDAL or we read, which a folder of a TASKDATA.XML must not hold too."""


def _isoxml_in_dir(path: Path) -> Path | None:
    """The TASKDATA.XML in ``path``, or in a folder of it (a terminal's USB stick holds
    ``TASKDATA/TASKDATA.XML``); one found beside other farm files, or in several folders
    (two seasons' exports on a stick), is refused, naming them: one was read, silently."""
    children = sorted(path.iterdir())
    found = [c for c in children if c.name.upper() == ISOXML_NAME and c.is_file()]
    found += [
        inner
        for child in children
        if child.is_dir()
        for inner in sorted(child.iterdir())
        if inner.name.upper() == ISOXML_NAME and inner.is_file()
    ]
    if not found:
        return None
    if len(found) > 1:
        raise GeometryError(
            f"{path}: {len(found)} {ISOXML_NAME} "
            f"({', '.join(str(f.relative_to(path)) for f in found[:5])}): which farm? give "
            "the one to read (its folder, or the file)"
        )
    others = [c.name for c in children if c.suffix.lower() in FARM_SUFFIXES]
    if others:
        raise GeometryError(
            f"{path}: both a {ISOXML_NAME} ({found[0].relative_to(path)}) and other farm "
            f"files ({', '.join(others[:5])}): which farm? give the one to read"
        )
    return found[0]


def _isoxml_in_zip(path: Path) -> str | None:
    """The TASKDATA.XML in a .zip (at any depth); several refused, naming them."""
    names = _zip_names(path)
    found = sorted(n for n in names if Path(n).name.upper() == ISOXML_NAME)
    if len(found) > 1:
        raise GeometryError(
            f"{path}: {len(found)} {ISOXML_NAME} in this archive ({', '.join(found[:5])}): "
            "which farm? give an archive of one"
        )
    others = [n for n in names if Path(n).suffix.lower() in FARM_SUFFIXES]
    if found and others:
        raise GeometryError(
            f"{path}: both a {ISOXML_NAME} ({found[0]}) and other farm files "
            f"({', '.join(others[:5])}) in this archive: which farm? give an archive of one"
        )
    return found[0] if found else None


def read_isoxml(path: Path) -> Document:
    """The partfields of a TASKDATA.XML (or a folder or .zip holding one) as GeoJSON
    features: each PFD with a boundary PLN (type 1) is a field with properties ``id``
    (PFD A), ``code`` (B) and ``name`` (C, the designator); its outer LSG (type 1) and holes
    (type 2) are the rings, from their PNTs (C latitude, D longitude). Several boundary
    PLNs make a multi-part field. PNTs of type 3 (field access) in a PFD are its gates, a
    PNT of type 11 (home base) is the garage. A VersionMajor this reader does not know
    (above :data:`ISOXML_MAJOR`, or not a number) is read as version :data:`ISOXML_MAJOR`,
    with a warning."""
    source = path
    main = ISOXML_NAME  # the TASKDATA.XML: in a zip, its name there
    try:
        if path.is_dir():
            found = _isoxml_in_dir(path)
            if found is None:
                raise GeometryError(f"{path}: no {ISOXML_NAME} in this folder")
            source = found
            data = found.read_bytes()
        elif path.suffix.lower() == ".zip":
            with zipfile.ZipFile(path) as archive:
                name = _isoxml_in_zip(path)
                if name is None:
                    raise GeometryError(f"{path}: no {ISOXML_NAME} in this archive")
                data = archive.read(name)
            main = name
        else:
            data = path.read_bytes()
    except (OSError, zipfile.BadZipFile) as exc:
        raise GeometryError(f"{path}: cannot read the farm: {exc}") from exc
    root = _isoxml_root(data, source, "ISO11783_TaskData")
    version = (root.get("VersionMajor") or "").strip()
    if version and not (version.isdigit() and int(version) <= ISOXML_MAJOR):
        log.warning(
            "%s: ISO 11783-10 VersionMajor %r, not one this reader knows (up to %d); read as "
            "version %d: check the fields it gives",
            source, version, ISOXML_MAJOR, ISOXML_MAJOR,
        )  # fmt: skip
    for xfr in root.findall("XFR"):  # partfields and the rest kept in external files
        name = f"{xfr.get('A', '')}.XML"
        try:
            beside = _beside(path, source, main, name)
            external = _isoxml_root(beside, f"{source}: {name}", "XFC")
        except (OSError, zipfile.BadZipFile) as exc:
            raise GeometryError(
                f"{source}: the external file {name} it names (XFR) cannot be read: {exc}"
            ) from exc
        root.extend(list(external))
    features: list[dict[str, Any]] = []
    for k, pfd in enumerate(root.iter("PFD")):
        pfd_id = pfd.get("A") or f"PFD#{k}"
        where = f"{source}: partfield {pfd_id!r}"
        props = {"kind": "field", "id": pfd_id, "code": pfd.get("B"), "name": pfd.get("C")}
        boundaries = [
            (_isoxml_polygon(pln, f"{where} polygon #{n}"), f"polygon #{n}")
            for n, pln in enumerate(pfd.findall("PLN"))
            if pln.get("A") == PLN_BOUNDARY
        ]
        obstacles = [
            (
                _isoxml_polygon(pln, f"{where} polygon #{n}"),
                f"polygon #{n}" + (f" ({pln.get('B')})" if pln.get("B") else ""),
            )
            for n, pln in enumerate(pfd.findall("PLN"))
            if pln.get("A") in PLN_NOT_WORKED
        ]
        polygons = [rings for rings, _ in boundaries]
        if boundaries and obstacles:
            polygons = _without(boundaries, obstacles, where)
            if not polygons:
                log.warning(
                    "%s: its water, buildings and obstacles cover the whole boundary; skipped, "
                    "with its gates",
                    where,
                )
                continue
        if polygons:
            geometry = (
                {"type": "Polygon", "coordinates": polygons[0]}
                if len(polygons) == 1
                else {"type": "MultiPolygon", "coordinates": polygons}
            )
            features.append(
                {
                    "type": "Feature",
                    WHERE_KEY: f"partfield {pfd_id!r}",
                    "properties": props,
                    "geometry": geometry,
                }
            )
        else:
            log.warning("%s: no boundary polygon (PLN of type 1); skipped, with its gates", where)
            continue
        for pnt in pfd.findall("PNT"):
            if pnt.get("A") == PNT_FIELD_ACCESS:
                features.append(
                    _isoxml_point(
                        pnt,
                        f"partfield {pfd_id!r} field access",
                        source,
                        {"kind": "gate", "field": pfd_id},
                    )
                )
    for pnt in root.iter("PNT"):
        if pnt.get("A") == PNT_HOMEBASE:
            features.append(_isoxml_point(pnt, "home base", source, {"kind": "garage"}))
    marks = {
        "fields": f'partfields (PFD) with a boundary polygon (PLN A="{PLN_BOUNDARY}")',
        "garage": f'a home base point (PNT A="{PNT_HOMEBASE}")',
    }
    return {"type": "FeatureCollection", "features": features, MARKS_KEY: marks}


def _beside(path: Path, source: Path, main: str, name: str) -> bytes:
    """The file ``name`` beside the TASKDATA.XML (``source``; in the zip ``path``, its
    member ``main``), in whatever case a terminal wrote it."""
    if path.suffix.lower() == ".zip" and not path.is_dir():
        wanted = str(Path(main).parent / name).upper().removeprefix("./")
        with zipfile.ZipFile(path) as archive:
            for member in archive.namelist():
                if member.upper() == wanted:
                    return archive.read(member)
        raise FileNotFoundError(f"no {name} in the archive")
    for child in source.parent.iterdir():
        if child.name.upper() == name.upper():
            return child.read_bytes()
    raise FileNotFoundError(f"no {name} in {source.parent}")


def _isoxml_root(data: bytes, source: Path | str, tag: str) -> ET.Element:
    """The root element of an ISOXML file, which must be ``tag``."""
    try:
        root = ET.parse(io.BytesIO(data)).getroot()
    except ET.ParseError as exc:
        raise GeometryError(f"{source}: not XML ({exc})") from exc
    for element in root.iter():  # a namespace some writers give: the names are the same
        element.tag = element.tag.rpartition("}")[2]
    if root.tag != tag:
        raise GeometryError(
            f"{source}: not ISO 11783-10 TaskData (the root element is {root.tag!r}, not {tag!r})"
        )
    return root


def _without(
    boundaries: list[tuple[list[list[list[float]]], str]],
    obstacles: list[tuple[list[list[list[float]]], str]],
    where: str,
) -> list[list[list[list[float]]]]:
    """The boundary polygons with the partfield's water, buildings and obstacles taken out
    (holes, or a smaller outline where one crosses the boundary): no swath drives there.
    Each is checked first (the overlay fails on a self-intersecting one), named as in the
    file when it is not a valid polygon."""

    def shape(rings: list[list[list[float]]], name: str) -> Polygon:
        try:
            polygon = Polygon(rings[0], rings[1:])
        except ValueError as e:  # a ring of fewer than three distinct points
            raise GeometryError(f"{where} {name}: not a polygon ({e})") from None
        if not polygon.is_valid:
            why = shapely.is_valid_reason(polygon)
            raise GeometryError(
                f"{where} {name}: invalid polygon ({why}); is its outline self-intersecting?"
            )
        return polygon

    field = shapely.union_all([shape(rings, name) for rings, name in boundaries])
    for rings, name in obstacles:
        obstacle = shape(rings, name)
        if not field.intersects(obstacle):
            log.warning(
                "%s: %s (water, building or obstacle) lies outside the field; not read",
                where,
                name,
            )
            continue
        field = field.difference(obstacle)
        log.info("%s: %s taken out of the field (not worked)", where, name)
    parts = [field] if field.geom_type == "Polygon" else list(getattr(field, "geoms", []))
    out = []
    for part in parts:
        if part.geom_type == "Polygon" and not part.is_empty:
            doc = mapping(part)
            out.append([[list(xy)[:2] for xy in ring] for ring in doc["coordinates"]])
    return out


def _isoxml_polygon(pln: ET.Element, where: str) -> list[list[list[float]]]:
    outer = [lsg for lsg in pln.findall("LSG") if lsg.get("A") == LSG_EXTERIOR]
    holes = [lsg for lsg in pln.findall("LSG") if lsg.get("A") == LSG_INTERIOR]
    if len(outer) != 1:
        raise GeometryError(
            f"{where}: a polygon needs exactly one outer line string (LSG of type 1), "
            f"not {len(outer)}"
        )
    number = {id(lsg): n for n, lsg in enumerate(pln.findall("LSG"))}  # as in the file
    return [_isoxml_ring(lsg, f"{where} line string #{number[id(lsg)]}") for lsg in outer + holes]


def _isoxml_ring(lsg: ET.Element, where: str) -> list[list[float]]:
    ring = [_isoxml_lonlat(pnt, f"{where} point #{n}") for n, pnt in enumerate(lsg.findall("PNT"))]
    if ring and ring[0] != ring[-1]:
        ring.append(ring[0])  # ISOXML closes a polygon's rings implicitly
    return ring


def _isoxml_lonlat(pnt: ET.Element, where: str) -> list[float]:
    try:
        lat, lon = float(pnt.get("C", "")), float(pnt.get("D", ""))
        if not (math.isfinite(lat) and math.isfinite(lon)):
            raise ValueError
    except ValueError:
        raise GeometryError(
            f"{where}: a point needs its latitude in C and longitude in D as numbers, "
            f"not C={pnt.get('C')!r} D={pnt.get('D')!r}"
        ) from None
    return [lon, lat]


def _isoxml_point(pnt: ET.Element, what: str, source: Path, props: dict[str, Any]) -> Document:
    return {
        "type": "Feature",
        WHERE_KEY: what,
        "properties": props,
        "geometry": {"type": "Point", "coordinates": _isoxml_lonlat(pnt, f"{source}: {what}")},
    }
