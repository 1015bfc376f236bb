"""A farm as the operator draws it: fields, garage, roads and gates in WGS84 GeoJSON (RFC 7946),
or any file :mod:`planner.farm_files` reads (KML, shapefile, GeoPackage, ISOXML, ...),
which turns it into the same GeoJSON-shaped document checked here.

Fields are ``Polygon`` or ``MultiPolygon`` features (holes allowed; a MultiPolygon's parts
become fields ``<id>.0``, ...) with ``properties.kind = "field"`` and an id (``properties.id``,
or :data:`ID_FIELDS`, or ``FarmOptions.id_field``); the garage is a ``Point`` with
``properties.kind = "garage"``, or comes from the scenario. A feature without a kind takes
it from its geometry (polygon: field, line: road, point: gate if it names a field, else
the garage).
Optional field properties: ``name``, ``work_angle_deg`` (fixed swath direction, degrees
counter-clockwise from true east; turned into the frame's grid by :meth:`Farm.grid_angle_deg`),
``headland_passes``.

Optional: roads, ``LineString`` or ``MultiLineString`` features with ``properties.kind =
"road"``, and gates, ``Point`` features with ``properties.kind = "gate"`` and
``properties.field = "<field id>"`` (a field may have several, each at most
:data:`MAX_GATE_DISTANCE_M` from its field). :mod:`planner.roads` routes the transit between
fields on them. Everything is projected once into a local metric frame (:mod:`planner.geo`)
and checked; errors name the file and feature.

Refused before anything is projected: a feature of another kind than :data:`KINDS`, a value
of the wrong type anywhere (a number where a feature, geometry, ring or position belongs),
a field or road farther than :data:`MAX_GARAGE_DISTANCE_M` from the garage (saying when its
longitude and latitude look swapped), a farm nearer a pole than :data:`MAX_ABS_LATITUDE`.
"""

from __future__ import annotations

import difflib
import json
import logging
import math
import unicodedata
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry
from shapely.geometry.polygon import orient
from shapely.validation import explain_validity

from planner.errors import GeometryError
from planner.farm_files import CONVERTED_DECIMALS, MARKS_KEY, WHERE_KEY, read_farm_document
from planner.geo import LocalFrame, check_wgs84

MAX_GARAGE_DISTANCE_M = 50_000.0
"""Every corner of a field's outline and every point of a road lies within this of the garage."""
MAX_GATE_DISTANCE_M = 50.0  # a gate lies on its field's boundary or this close to it
MAX_ABS_LATITUDE = 75.0
"""No farmland lies nearer a pole (the northernmost fields, in Norway and Finland, are below
71 N): a farm beyond it has [latitude, longitude] where GeoJSON wants [longitude, latitude]."""
KINDS = ("field", "garage", "road", "gate")
"""The feature kinds (``properties.kind``) a farm file may hold; any other is refused."""
EARTH_RADIUS_M = 6_371_000.0
ID_FIELDS = ("id", "field_id", "fieldid", "name")
"""Where a field's id is looked for, first found first (``--id-field`` names another);
a field with none is ``field-<k>``, k its feature number. Numbers are taken as text."""
NAME_FIELDS = ("name", "field_name", "fieldname", "designator", "title")
"""Where a field's name is looked for (``--name-field`` names another); default: its id."""
DBASE_NAME_LENGTH = 10  # a shapefile's column names are cut to this many characters

log = logging.getLogger(__name__)

NOT_IN_AN_ID: Final = ("Cc", "Cs", "Co", "Cn", "Zl", "Zp")
"""Unicode categories a field id may not hold: controls (a line break, a tab), surrogates,
private and unassigned code points, line and paragraph separators."""
MARKS_IN_AN_ID: Final = frozenset("\u200c\u200d\u200e\u200f\u061c\u00ad")
"""The invisible format characters a field id may hold, as scripts are written with them:
zero-width non-joiner and joiner, left-to-right, right-to-left and Arabic letter marks,
soft hyphen. Not the others (a zero-width space makes "F1" two ids that look one; a
right-to-left override turns the printed tables round)."""
EXTENT_ROWS: Final = 1024
"""Fields whose distances to all others the extent check holds at once."""
SAME_GARAGE_M: Final = 1.0
"""Garages given this close together are the one garage given more than once."""
SNAP_M: Final = 0.001
"""A field valid as drawn but not in the local metres (a hole's corner snapped onto the
outline, moved across it by the last digits of a projection) is mended when that moves
nothing further than this."""
CROSSING_M = 0.5
"""A road, a gate or a way onto the roads is in a field where it lies deeper inside than
this (a lane along the fence is not)."""
OVERLAP_WARN_M2 = 1.0
"""Fields overlapping by more than this many square metres are named in a warning."""


@dataclass(frozen=True)
class Field:
    """One field: its boundary in the farm's local frame (metres) and in lon/lat."""

    id: str
    name: str
    boundary: Polygon
    boundary_lonlat: Polygon
    work_angle_deg: float | None = None
    headland_passes: int | None = None  # None: as many as the machine's turns need

    @property
    def area_m2(self) -> float:
        return float(self.boundary.area)


@dataclass(frozen=True)
class Road:
    """One road (a polyline; a MultiLineString feature gives one per part), local metres."""

    id: str
    line: LineString
    line_lonlat: LineString


@dataclass(frozen=True)
class Gate:
    """Where machines enter and leave ``field_id``, in local metres."""

    field_id: str
    xy: tuple[float, float]
    lonlat: tuple[float, float]


@dataclass(frozen=True)
class Farm:
    """The fields, the garage and the roads and gates of one farm, in one local frame."""

    fields: tuple[Field, ...]
    garage: tuple[float, float]  # local metres
    garage_lonlat: tuple[float, float]
    frame: LocalFrame
    source: str = "<memory>"
    roads: tuple[Road, ...] = ()
    gates: tuple[Gate, ...] = ()

    def field(self, field_id: str) -> Field:
        for f in self.fields:
            if f.id == field_id:
                return f
        raise KeyError(field_id)

    def grid_angle_deg(self, field_id: str, true_deg: float) -> float:
        """A direction in field ``field_id``, ``true_deg`` counter-clockwise from true east
        (how a farmer gives a work angle), as the frame's: from its ``x`` axis, grid east
        (:meth:`planner.geo.LocalFrame.convergence_deg` at the field's centre)."""
        centre = self.field(field_id).boundary_lonlat.centroid
        return true_deg + self.frame.convergence_deg(centre.x, centre.y)

    def true_angle_deg(self, field_id: str, grid_deg: float) -> float:
        """The inverse of :meth:`grid_angle_deg`, within [0, 180) (a swath direction)."""
        centre = self.field(field_id).boundary_lonlat.centroid
        return (grid_deg - self.frame.convergence_deg(centre.x, centre.y)) % 180.0

    def gates_of(self, field_id: str) -> tuple[Gate, ...]:
        """The gates of one field (empty: entered where it is nearest to the roads)."""
        return tuple(g for g in self.gates if g.field_id == field_id)


@dataclass(frozen=True)
class FarmOptions:
    """How to read a farm file: which properties hold a field's id and name (default: the
    first of :data:`ID_FIELDS` and :data:`NAME_FIELDS` a field has), and the garage (lon,
    lat) when it comes from the scenario instead of the file."""

    id_field: str | None = None
    name_field: str | None = None
    garage: tuple[float, float] | None = None


def load_farm(path: str | Path, options: FarmOptions | None = None) -> Farm:
    """Read and check a farm file: GeoJSON, any format GDAL reads (KML, shapefile,
    GeoPackage, ...) or ISO 11783-10 TaskData (:mod:`planner.farm_files`)."""
    options = options or FarmOptions()
    path = Path(path)
    doc = read_farm_document(path)
    try:
        return farm_from_geojson(doc, str(path), options)
    except OverflowError as exc:  # an integer too large for a float, where a number belongs
        raise GeometryError(f"{path}: a number too large to be a coordinate or angle") from exc


def farm_from_geojson(
    doc: Any, source: str = "<memory>", options: FarmOptions | None = None
) -> Farm:
    """Build a :class:`Farm` from a parsed GeoJSON FeatureCollection (see :func:`load_farm`)."""
    options = options or FarmOptions()
    if isinstance(doc, dict) and doc.get("type") == "Feature":  # one field, as some tools save
        doc = {"type": "FeatureCollection", "features": [doc]}
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise GeometryError(f"{source}: expected a GeoJSON FeatureCollection")
    features = doc.get("features")
    if not isinstance(features, list):
        raise GeometryError(f"{source}: 'features' must be a list")
    raw_fields: list[tuple[str, dict[str, Any], list[Any]]] = []
    garages: list[tuple[float, float]] = []
    garage_wheres: list[str] = []
    said_garage: list[bool] = []  # by its kind, not taken for one as a point without
    raw_roads: list[tuple[str, str, list[tuple[float, float]]]] = []  # id, where, points
    raw_gates: list[tuple[str, str, tuple[float, float]]] = []  # field id, where, lon/lat
    seen: dict[str, str] = {}  # field id -> the feature it came from (for messages)
    given: dict[str, str] = {}  # the same for the ids as given, before a MultiPolygon's split
    # A gate names its field as the file does (properties.id, an ISOXML PFD's id): which
    # fields (parts of a MultiPolygon) that is, when the field id is another property.
    aliases: dict[str, list[str]] = {}
    for k, feature in enumerate(features):
        where = f"{source}: feature #{k}"
        if not isinstance(feature, dict):
            raise GeometryError(
                f"{where}: a feature must be a GeoJSON object, not {_shown(feature)}"
            )
        if isinstance(feature.get(WHERE_KEY), str):  # named by its reader (layer, partfield)
            where = f"{source}: {feature[WHERE_KEY]}"
        if feature.get("type") != "Feature":
            raise GeometryError(
                f"{where}: 'type' must be \"Feature\", not {_shown(feature.get('type'))}"
            )
        props = feature.get("properties")
        if props is None:
            props = {}
        if not isinstance(props, dict):
            raise GeometryError(f"{where}: 'properties' must be an object, not {_shown(props)}")
        geom = feature.get("geometry")
        if geom is None:  # RFC 7946's unlocated feature; a shapefile's null record
            log.warning("%s%s: no geometry; left out", where, _named(props))
            continue
        if not isinstance(geom, dict):
            raise GeometryError(f"{where}: 'geometry' must be an object, not {_shown(geom)}")
        geom = _simplest(geom)
        kind = _kind(props, geom, where)
        if kind == "garage":
            if geom.get("type") != "Point":
                raise GeometryError(f"{where}: the garage must be a Point")
            lon, lat = _lonlat(geom.get("coordinates"), f"{where} (garage)")
            garages.append((lon, lat))
            garage_wheres.append(where.removeprefix(f"{source}: "))
            said_garage.append(_prop(props, "kind") is not None)
        elif kind == "field":
            if _prop(props, "id") is None and feature.get("id") is not None:
                props = {**props, "id": feature["id"]}  # RFC 7946's id of the feature
            field_id = _field_id(props, options.id_field, k, where)
            name = _field_name(props, options.name_field, field_id, where)
            feature_where = where.removeprefix(f"{source}: ")
            where = f"{source}: field {field_id!r}"
            if _closed_line(geom):  # a boundary drawn as a path (Google Earth), said a field
                geom = {"type": "Polygon", "coordinates": [geom["coordinates"]]}
            gtype = geom.get("type")
            if gtype not in ("Polygon", "MultiPolygon"):
                raise GeometryError(
                    f"{where}: geometry must be a Polygon or MultiPolygon (or a closed "
                    f"LineString), not {_shown(gtype)}"
                )
            parts = (
                geom.get("coordinates") if gtype == "MultiPolygon" else [geom.get("coordinates")]
            )
            if not isinstance(parts, list) or not parts:
                raise GeometryError(
                    f"{where}: a MultiPolygon's coordinates must be a list of polygons, "
                    f"not {_shown(parts)}"
                )
            if field_id in given:  # one of them split: PFD1 beside PFD1.0 and PFD1.1
                raise GeometryError(
                    f"{where}: duplicate field id ({given[field_id]} and {feature_where})"
                    f"{_id_source(props, options.id_field)}"
                )
            given[field_id] = feature_where
            part_ids = (
                [field_id]
                if len(parts) == 1
                else [part_name(field_id, n) for n in range(len(parts))]
            )
            for alias in {field_id, _text(_prop(props, "id")) or field_id}:
                aliases.setdefault(alias, []).extend(part_ids)
            for n, rings in enumerate(parts):
                part_id = part_ids[n]
                here = f"{source}: field {part_id!r}"
                if part_id in seen:
                    raise GeometryError(
                        f"{here}: duplicate field id ({seen[part_id]} and {feature_where})"
                        f"{_id_source(props, options.id_field)}"
                    )
                seen[part_id] = feature_where
                if not isinstance(rings, list) or not rings:
                    raise GeometryError(
                        f"{here}: a Polygon's coordinates must be a list of rings, "
                        f"not {_shown(rings)}"
                    )
                part_props = {**props, "name": name if len(parts) == 1 else f"{name} ({n})"}
                raw_fields.append(
                    (part_id, part_props, [_ring(r, m, here) for m, r in enumerate(rings)])
                )
        elif kind == "road":
            if _closed_line(geom) and _prop(props, "kind") is None:
                log.warning(
                    "%s%s: a closed line, read as a road; if it is a field's boundary (a "
                    "path drawn round it), give it kind 'field'",
                    where,
                    _named(props),
                )
            raw_roads += _road_parts(k, props, geom, where)
        else:  # a gate
            named = _text(_prop(props, "field"))  # a whole number too, as field ids are
            if named is None:
                raise GeometryError(
                    f"{where} (gate): a gate needs properties.field, the id of its field"
                )
            field_id = named
            if geom.get("type") != "Point":
                raise GeometryError(f"{where} (gate of {field_id!r}): a gate must be a Point")
            where = f"{where} (gate of {field_id!r})"
            raw_gates.append((field_id, where, _lonlat(geom.get("coordinates"), where)))
    if options.garage is not None:
        if garages:
            log.warning("%s: the scenario's garage replaces the garage in the farm file", source)
        lon, lat = _lonlat(list(options.garage), f"{source}: the scenario's garage")
        garages = [(lon, lat)]
    marks = {
        "fields": "Polygon features with properties.kind 'field'",
        "garage": "a Point feature with properties.kind 'garage'",
    } | doc.get(MARKS_KEY, {})
    if not raw_fields:  # before the garage: a file of no fields has no garage either
        raise GeometryError(f"{source}: no fields ({marks['fields']})")
    if not garages:
        raise GeometryError(
            f"{source}: no garage ({marks['garage']}, "
            "or the scenario's garage = [longitude, latitude])"
        )
    if len(garages) > 1 and said_garage.count(True) == 1:
        # One point says it is the garage; the others say nothing (soil samples, a well).
        k = said_garage.index(True)
        log.warning(
            "%s: %d points without a kind left out (%s); the garage is %s",
            source,
            len(garages) - 1,
            _some([w for j, w in enumerate(garage_wheres) if j != k]),
            garage_wheres[k],
        )
        garages = [garages[k]]
    same = all(_distance_m(*garages[0], *g) <= SAME_GARAGE_M for g in garages[1:])
    if len(garages) > 1 and all(said_garage) and same:
        # One garage said more than once (the home base of each partfield of an ISOXML).
        log.warning(
            "%s: the garage given %d times at one place (%s)",
            source,
            len(garages),
            _some(garage_wheres),
        )
        garages = garages[:1]
    if len(garages) > 1:
        at = ", ".join(f"({lon:.7f}, {lat:.7f})" for lon, lat in garages[:5])
        raise GeometryError(
            f"{source}: {len(garages)} garages ({_some(garage_wheres)}) at {at}; exactly one "
            "is supported: give the other points a kind (a gate names its field), leave "
            "them out, or give the scenario's garage = [longitude, latitude]"
        )

    _check_extent(source, garages[0], raw_fields, raw_roads)
    lons = np.array([p[0] for _, _, rings in raw_fields for p in rings[0]])
    lats = [p[1] for _, _, rings in raw_fields for p in rings[0]]
    # Longitudes about the first (a farm across the antimeridian, 179.99° and -179.99°, is
    # there: its frame was centred at longitude 0, 20 000 km away, turned upside down).
    about = _wrapped(lons - lons[0])
    centre = _wrapped(lons[0] + (about.min() + about.max()) / 2)
    frame = LocalFrame.around(float(centre), (min(lats) + max(lats)) / 2)
    fields = tuple(_field(frame, source, fid, props, rings) for fid, props, rings in raw_fields)
    glon, glat = garages[0]
    gx, gy = frame.to_local(glon, glat)
    nearest = min(f.boundary.distance(Point(gx, gy)) for f in fields)
    if nearest > MAX_GARAGE_DISTANCE_M:
        raise GeometryError(
            f"{source}: the garage is {nearest / 1000:.0f} km from the nearest field "
            f"(limit {MAX_GARAGE_DISTANCE_M / 1000:.0f} km); are its longitude and latitude "
            "swapped? GeoJSON wants [longitude, latitude]"
        )
    _warn_of_overlaps(source, fields)
    by_id = {f.id: f for f in fields}
    # Each field shrunk by CROSSING_M, once: what a road or a gate is in when inside it.
    inner = {f.id: f.boundary.buffer(-CROSSING_M) for f in fields}
    for f in fields:
        if inner[f.id].contains(Point(gx, gy)):
            log.warning(
                "%s: the garage (%.7f, %.7f) lies inside field %r: the way out of the garage "
                "and back to it drives across that field (is the garage where it should be?)",
                source,
                glon,
                glat,
                f.id,
            )
    roads = tuple(_road(frame, rid, where, points) for rid, where, points in raw_roads)
    gates = tuple(
        _gate(frame, by_id, inner, aliases.get(fid, [fid]), where, lonlat)
        for fid, where, lonlat in raw_gates
    )
    for road in roads:
        for f in fields:
            # Through it, not along its border (a lane beside the fence is what roads are).
            if road.line.intersection(inner[f.id]).length > 1.0:
                log.warning(
                    "%s: road %r crosses field %r; transit may drive through it",
                    source,
                    road.id,
                    f.id,
                )
    return Farm(
        fields=fields,
        garage=(gx, gy),
        garage_lonlat=(glon, glat),
        frame=frame,
        source=source,
        roads=roads,
        gates=gates,
    )


def _road_parts(
    k: int, props: dict[str, Any], geom: dict[str, Any], where: str
) -> list[tuple[str, str, list[tuple[float, float]]]]:
    """The checked lon/lat polylines of one road feature (one per part)."""
    road_id = _prop(props, "id")
    if road_id is not None and (isinstance(road_id, bool) or not isinstance(road_id, str | int)):
        raise GeometryError(
            f"{where} (road): properties.id must be a string, not {_shown(road_id)}"
        )
    name = _text(_prop(props, "name"))  # a KML placemark's, a GIS layer's
    road_id = str(road_id) if road_id is not None else name or f"road#{k}"
    where = f"{where} (road {road_id!r})"
    kind = geom.get("type")
    coords = geom.get("coordinates")
    if kind == "LineString":
        parts = [coords]
    elif kind == "MultiLineString" and isinstance(coords, list):
        parts = coords
    else:
        raise GeometryError(f"{where}: a road must be a LineString or MultiLineString, not {kind}")
    if not parts:
        raise GeometryError(f"{where}: a road needs at least 2 points (this one has no part)")
    out = []
    for n, part in enumerate(parts):
        here = where if kind == "LineString" else f"{where} part {n}"
        if not isinstance(part, list) or len(part) < 2:
            raise GeometryError(f"{here}: a road needs at least 2 points")
        points = [_lonlat(p, here) for p in part]
        if len(set(points)) < 2:
            raise GeometryError(f"{here}: a road needs at least 2 distinct points")
        out.append((road_id if len(parts) == 1 else part_name(road_id, n), here, points))
    return out


def _road(frame: LocalFrame, road_id: str, where: str, points: list[tuple[float, float]]) -> Road:
    xs, ys = frame.to_local(np.array([p[0] for p in points]), np.array([p[1] for p in points]))
    line = LineString(list(zip(xs.tolist(), ys.tolist(), strict=True)))
    if line.length <= 0.0:
        raise GeometryError(f"{where}: the road has no length")
    return Road(id=road_id, line=line, line_lonlat=LineString(points))


def _gate(
    frame: LocalFrame,
    fields: dict[str, Field],
    inner: dict[str, BaseGeometry],
    field_ids: list[str],
    where: str,
    lonlat: tuple[float, float],
) -> Gate:
    """A gate of the field it names (of the nearest part of a split MultiPolygon); said
    when it lies in another field (``inner``: each field shrunk by :data:`CROSSING_M`)."""
    x, y = frame.to_local(*lonlat)
    named = [fields[f] for f in field_ids if f in fields]
    if not named:
        known = ", ".join(sorted(fields))
        raise GeometryError(f"{where}: no field {field_ids[0]!r} in this farm (fields: {known})")
    field = min(named, key=lambda f: f.boundary.boundary.distance(Point(x, y)))
    field_id = field.id
    off = field.boundary.boundary.distance(Point(x, y))
    if off > MAX_GATE_DISTANCE_M:
        raise GeometryError(
            f"{where}: the gate is {off:.0f} m from the boundary of field {field_id!r} "
            f"(limit {MAX_GATE_DISTANCE_M:.0f} m); a gate lies on its field's boundary"
        )
    for other in fields.values():
        if other.id != field_id and inner[other.id].contains(Point(x, y)):
            log.warning(
                "%s: the gate lies inside field %r: transit to field %r drives through it "
                "(is the gate where it should be?)",
                where,
                other.id,
                field_id,
            )
    return Gate(field_id=field_id, xy=(x, y), lonlat=lonlat)


def part_name(ident: str, n: int) -> str:
    """The id of part ``n`` of a multi-part feature (MultiPolygon field, MultiLineString road)."""
    return f"{ident}.{n}"


def _prop(props: dict[str, Any], key: str) -> Any:
    """A property by name: as written, else in any case, else cut to a shapefile column's
    length (``work_angle_deg`` is ``work_angle`` in a shapefile)."""
    if key in props:
        return props[key]
    for name in (key.lower(), key[:DBASE_NAME_LENGTH].lower()):
        for have, value in props.items():
            if have.lower() == name:
                return value
    return None


def _number_text(value: Any) -> Any:
    """A number written as text as that number: KML's ExtendedData holds only text, and
    geojson.io's property table writes what is typed as text. Anything else as it is."""
    if isinstance(value, str):
        try:
            return float(value.strip())
        except ValueError:
            return value
    return value


def _simplest(geom: dict[str, Any]) -> dict[str, Any]:
    """A geometry as the farm reads it: a MultiPoint of one point is that Point (a layer of
    multi-points holding a garage); a GeometryCollection with polygons is their
    (Multi)Polygon, its points and lines (a KML placemark's label point) left out."""
    kind, coords = geom.get("type"), geom.get("coordinates")
    if kind == "MultiPoint" and isinstance(coords, list) and len(coords) == 1:
        return {"type": "Point", "coordinates": coords[0]}
    parts = geom.get("geometries")
    if kind != "GeometryCollection" or not isinstance(parts, list):
        return geom
    polygons: list[Any] = []  # each a polygon's rings
    for part in parts:
        if not isinstance(part, dict):
            continue
        if part.get("type") == "Polygon":
            polygons.append(part.get("coordinates"))
        elif part.get("type") == "MultiPolygon" and isinstance(part.get("coordinates"), list):
            polygons += part["coordinates"]
    if len(polygons) == 1:
        return {"type": "Polygon", "coordinates": polygons[0]}
    return {"type": "MultiPolygon", "coordinates": polygons} if polygons else geom


def _some(names: Sequence[str], most: int = 5) -> str:
    """``names`` for a message: the first ``most``, and how many more."""
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown} and {len(names) - most} more"


def _named(props: dict[str, Any]) -> str:
    """`` (id 'X')`` or `` (name 'X')`` of a feature, for a message; '' if it has neither."""
    for key in ("id", "name"):
        value = _prop(props, key)
        if value is not None:
            return f" ({key} {value!r})"
    return ""


def _closed_line(geom: dict[str, Any]) -> bool:
    """Whether ``geom`` is a LineString that ends where it starts, round some land."""
    coords = geom.get("coordinates")
    return (
        geom.get("type") == "LineString"
        and isinstance(coords, list)
        and len(coords) >= 4
        and coords[0] == coords[-1]
    )


def _kind(props: dict[str, Any], geom: dict[str, Any], where: str) -> str:
    """The feature's kind: ``properties.kind``, else what its geometry says (a polygon is
    a field, a line a road, a point with ``properties.field`` a gate, any other point the
    garage)."""
    kind = _prop(props, "kind")
    if isinstance(kind, str) and kind.lower() in KINDS:
        return kind.lower()
    if kind is None:
        gtype = geom.get("type")
        if gtype in ("Polygon", "MultiPolygon"):
            return "field"
        if gtype in ("LineString", "MultiLineString"):
            return "road"
        if gtype == "Point":
            return "gate" if _prop(props, "field") is not None else "garage"
    named = f"{where}{_named(props) or ' (no id)'}"
    what = (
        f"no properties.kind and no geometry that tells it ({_shown(geom.get('type'))})"
        if kind is None
        else f"unknown kind {_shown(kind)}"
    )
    close = difflib.get_close_matches(kind, KINDS, n=1, cutoff=0.6) if isinstance(kind, str) else []
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise GeometryError(f"{named}: {what}{hint}; the known kinds are {', '.join(KINDS)}")


def _text(value: Any) -> str | None:
    """An id or name as text: a string, or a whole number (shapefile and GeoPackage
    columns are often integers); None for anything else. Taken in Unicode's composed form
    (NFC): "Großer Schlag" typed on one machine and copied from a macOS file name on
    another (decomposed, NFD) look alike and are one field, whose gate finds it."""
    if isinstance(value, str) and value.strip():
        return unicodedata.normalize("NFC", value.strip())
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return None


def _field_id(props: dict[str, Any], id_field: str | None, k: int, where: str) -> str:
    """The field's id (:func:`_field_id_of`), without control characters: a line break in
    one broke the printed plan's table, and it goes into every file written (review). The
    invisible marks of scripts written with them are no control characters: Persian
    needs the zero-width non-joiner, right-to-left text its marks, and a soft hyphen is
    text (all refused before). In Unicode's composed form, as :func:`_text` gives it."""
    found = _field_id_of(props, id_field, k, where)
    if any(
        unicodedata.category(c) in NOT_IN_AN_ID
        or (unicodedata.category(c) == "Cf" and c not in MARKS_IN_AN_ID)
        for c in found
    ):
        raise GeometryError(
            f"{where}: the field id {found!r} holds a control character (a line break, a "
            "tab, an invisible space or a direction override): ids are printed in tables and "
            "written into every file made of the plan"
        )
    return found


def _field_id_of(props: dict[str, Any], id_field: str | None, k: int, where: str) -> str:
    if id_field is not None:
        value = _prop(props, id_field)
        if value is None:
            have = ", ".join(sorted(props)) or "none"
            what = (
                f"a field whose property {id_field!r} (the --id-field) is empty"
                if any(name.lower() == id_field.lower() for name in props)
                else f"a field without property {id_field!r} (the --id-field)"
            )
            raise GeometryError(f"{where}: {what}; its properties: {have}")
        found = _text(value)
        if found is None:
            raise GeometryError(
                f"{where}: the field id {id_field!r} must be text or a whole number, "
                f"not {_shown(value)}"
            )
        return found
    for key in ID_FIELDS:
        value = _prop(props, key)
        if value is None:
            continue
        found = _text(value)
        if found is None:
            raise GeometryError(
                f"{where}: a field needs a non-empty string properties.{key} "
                f"(the field id), not {_shown(value)}"
            )
        return found
    return f"field-{k}"


def _id_source(props: dict[str, Any], id_field: str | None) -> str:
    """Where the field ids come from, and how to take them from elsewhere, for a message
    on two alike (ArcMap's "Id" column holds 0 for every feature drawn)."""
    key = id_field or next((k for k in ID_FIELDS if _prop(props, k) is not None), None)
    if key is None:
        return ""
    return (
        f'; the ids are property {key!r}: give --id-field NAME (id_field = "NAME" in the '
        "scenario) to take them from another"
    )


def _field_name(props: dict[str, Any], name_field: str | None, field_id: str, where: str) -> str:
    if name_field is not None:
        value = _prop(props, name_field)
        if value is None:
            raise GeometryError(
                f"{where} (field {field_id!r}): no property {name_field!r} (the --name-field)"
            )
        return str(value)
    for key in NAME_FIELDS:
        value = _prop(props, key)
        if value is not None and str(value).strip():
            return str(value)
    return field_id


def _shown(value: Any) -> str:
    """A JSON value as the file wrote it, shortened, for messages."""
    text = json.dumps(value, default=str) if value is not None else "null"
    return text if len(text) <= 40 else text[:37] + "..."


def _lonlat(value: Any, where: str) -> tuple[float, float]:
    # RFC 7946 3.1.1: two or more numbers, the third an altitude (kept by no one here, but
    # a string there is a broken file all the same: it was taken without a word).
    if (
        not isinstance(value, list | tuple)
        or len(value) < 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise GeometryError(
            f"{where}: a position must be [longitude, latitude] or [longitude, latitude, "
            f"altitude], numbers, not {_shown(value)}"
        )
    lon, lat = float(value[0]), float(value[1])
    check_wgs84(lon, lat, where)
    return lon, lat


def _ring(value: Any, n: int, where: str) -> list[tuple[float, float]]:
    """One ring of a Polygon (``n`` = 0: the outline, then the holes), checked."""
    what = "outline" if n == 0 else f"hole {n}"
    if not isinstance(value, list):
        raise GeometryError(
            f"{where}: ring {n} ({what}) must be a list of [longitude, latitude] positions, "
            f"not {_shown(value)}"
        )
    points = [_lonlat(p, f"{where}, ring {n} ({what}) position {k}") for k, p in enumerate(value)]
    if len(set(points)) < 3:
        raise GeometryError(
            f"{where}: ring {n} ({what}) has {len(set(points))} distinct positions; "
            "a ring needs at least 3 corners"
        )
    return points


def _distance_m(lon1: Any, lat1: Any, lon2: Any, lat2: Any) -> Any:
    """Great-circle distance in metres (haversine on a sphere; numbers or numpy arrays)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    a = (
        np.sin((p2 - p1) / 2) ** 2
        + np.cos(p1) * np.cos(p2) * np.sin(np.radians(np.subtract(lon2, lon1)) / 2) ** 2
    )
    return 2 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def _km(metres: float) -> str:
    if metres >= 100_000:
        return f"{metres / 1000:,.0f} km".replace(",", " ")
    return f"{metres / 1000:.1f} km".replace(".0 km", " km")


def _ring_centre(ring: list[tuple[float, float]]) -> tuple[float, float]:
    """The mean of a ring's corners (lon, lat), its longitudes taken about the first one: a
    field across the antimeridian (179.99° and -179.99°) is there, not at longitude 0."""
    lonlat = np.asarray(ring, dtype=np.float64)
    first = lonlat[0, 0]
    lon = first + float(np.mean(_wrapped(lonlat[:, 0] - first)))
    return float(_wrapped(lon)), float(np.mean(lonlat[:, 1]))


def _wrapped(lon: Any) -> Any:
    """Longitudes (or their differences) in [-180, 180) degrees: numbers or arrays."""
    return (np.asarray(lon) + 180.0) % 360.0 - 180.0


def _check_extent(
    source: str,
    garage: tuple[float, float],
    raw_fields: list[tuple[str, dict[str, Any], list[list[tuple[float, float]]]]],
    raw_roads: list[tuple[str, str, list[tuple[float, float]]]],
) -> None:
    """Refuse a farm spread wider than :data:`MAX_GARAGE_DISTANCE_M` or nearer a pole than
    :data:`MAX_ABS_LATITUDE`, naming the garage, field or road at fault and saying when its
    longitude and latitude look swapped. Done on the lon/lat, before any projection: a
    field thousands of kilometres away would make the planner's local frame meaningless.

    The farm is where most of its features are: the field (or garage) with the most others
    within the limit. A garage away from it is at fault; otherwise every field and road
    must lie within the limit of the garage.
    """
    limit = MAX_GARAGE_DISTANCE_M
    centres = np.array(
        [_ring_centre(rings[0]) for _, _, rings in raw_fields] + [garage], dtype=np.float64
    )
    lon, lat = centres[:, 0], centres[:, 1]
    # Counted a block of rows at a time: the whole matrix of a land registry's 20 000
    # parcels took 12 GB (memory grew with the square of the fields).
    near = np.empty(len(lon), dtype=np.int64)
    for k in range(0, len(lon), EXTENT_ROWS):
        rows = slice(k, k + EXTENT_ROWS)
        apart = _distance_m(lon[rows, None], lat[rows, None], lon[None, :], lat[None, :])
        near[rows] = (apart <= limit).sum(axis=1)
    farm = int(np.argmax(near))  # ties: the first field
    glon, glat = garage
    to_garage = _distance_m(lon, lat, glon, glat)
    if to_garage[farm] > limit:
        nearest = float(to_garage[:-1].min())
        swapped = float(_distance_m(glat, glon, lon[farm], lat[farm]))
        signs = {
            what: float(_distance_m(glon * east, glat * north, lon[farm], lat[farm]))
            for what, east, north in (
                ("latitude", 1.0, -1.0),
                ("longitude", -1.0, 1.0),
                ("longitude and latitude", -1.0, -1.0),
            )
        }
        sign, signed = min(signs.items(), key=lambda item: item[1])
        if swapped <= limit:
            hint = (
                f"with longitude and latitude swapped it would be {_km(swapped)} from them: "
                "either the garage or the fields have [latitude, longitude] where GeoJSON "
                "wants [longitude, latitude]"
            )
        elif signed <= limit:
            hint = (
                f"with the sign of its {sign} changed it would be {_km(signed)} from them: "
                "a minus sign missing or too many? (south latitudes and west longitudes are "
                "negative)"
            )
        else:
            hint = "are its longitude and latitude swapped? GeoJSON wants [longitude, latitude]"

        raise GeometryError(
            f"{source}: the garage is {_km(nearest)} from the nearest field "
            f"(limit {_km(limit)}); {hint}"
        )
    for field_id, _, rings in raw_fields:
        _check_near(f"{source}: field {field_id!r}", "corner", rings[0], garage)
    for _, where, points in raw_roads:
        _check_near(where, "point", points, garage)
    for k, (field_id, _, _) in enumerate(raw_fields):
        if abs(lat[k]) > MAX_ABS_LATITUDE:
            raise GeometryError(
                f"{source}: field {field_id!r} lies at latitude {lat[k]:.2f}, nearer the pole "
                f"than any farmland (limit {MAX_ABS_LATITUDE:g} degrees north or south); are "
                "longitude and latitude swapped? GeoJSON wants [longitude, latitude]"
            )


def _check_near(
    where: str, what: str, points: list[tuple[float, float]], garage: tuple[float, float]
) -> None:
    """Refuse a field or road (``where``) with a point (``what``) farther than the limit
    from the garage, naming the farthest; say so when the points look swapped."""
    limit = MAX_GARAGE_DISTANCE_M
    lon, lat = np.array(points, dtype=np.float64).T
    glon, glat = garage
    off = _distance_m(lon, lat, glon, glat)
    worst = int(np.argmax(off))
    if off[worst] <= limit:
        return
    swapped = (
        float(np.max(_distance_m(lat, lon, glon, glat)))
        if np.all(np.abs(lon) <= 90.0)
        else math.inf
    )
    hint = (
        f"; its longitudes and latitudes look swapped: as [latitude, longitude] it would lie "
        f"within {_km(swapped)} of the garage (GeoJSON wants [longitude, latitude])"
        if swapped <= limit
        else f"; every field and road of a farm must lie within {_km(limit)} of its garage"
    )
    raise GeometryError(
        f"{where}: its {what} {worst} [{lon[worst]:.5f}, {lat[worst]:.5f}] is "
        f"{_km(float(off[worst]))} from the garage (limit {_km(limit)}){hint}"
    )


def _warn_of_overlaps(source: str, fields: tuple[Field, ...]) -> None:
    """Say which fields overlap, by more than :data:`OVERLAP_WARN_M2`: the overlap is
    worked once for each (a double dose of spray or fertiliser), and the planner cannot
    tell which field it belongs to. Not refused: two layers of one farm (a field and a
    plot drawn inside it) may be meant, and a slight overlap along a shared border is
    common in digitised boundaries."""
    boundaries = [f.boundary for f in fields]
    tree = shapely.STRtree(boundaries)
    for a, b in zip(*tree.query(boundaries, predicate="intersects"), strict=True):
        if a < b:
            area = boundaries[a].intersection(boundaries[b]).area
            if area > OVERLAP_WARN_M2:
                log.warning(
                    "%s: fields %r and %r overlap by %.0f m2, which is worked once for each "
                    "(a double dose): correct the boundaries or leave one of them out",
                    source,
                    fields[a].id,
                    fields[b].id,
                    area,
                )


def _mended(
    boundary: Polygon, to_metres: Callable[[Polygon], Polygon] = lambda polygon: polygon
) -> Polygon:
    """``boundary`` made valid when that moves nothing by more than SNAP_M (measured in
    ``to_metres`` of it): its outline less its holes (a hole's corner snapped onto the
    outline, or put across it by the last digits of a projection; a hole drawn with an edge
    on the outline): a notch in the outline then, the same land. Else ``boundary`` itself."""
    mended = shapely.make_valid(boundary, method="structure")
    if isinstance(mended, shapely.MultiPolygon):  # slivers of the crossing, if any
        mended = max(mended.geoms, key=lambda part: part.area)
    if not (isinstance(mended, Polygon) and mended.is_valid):
        return boundary
    before, after = to_metres(boundary), to_metres(mended)
    if (
        abs(after.area - before.area) <= SNAP_M * before.length
        and after.hausdorff_distance(before) <= SNAP_M
    ):
        return orient(mended, sign=1.0)
    return boundary


def _to_local(frame: LocalFrame, polygon: Polygon) -> Polygon:
    """``polygon`` (longitude, latitude) in ``frame``'s metres."""
    return shapely.transform(polygon, lambda lonlat: np.column_stack(frame.to_local(*lonlat.T)))


def _written_valid(lonlat: Polygon) -> Polygon:
    """``lonlat`` as it stays valid when written to CONVERTED_DECIMALS (plan.json, the GIS
    files, the fences): a hole within a centimetre of the outline meets it there once
    rounded, and a GIS or GDAL refuses the polygon; snapped to that grid (the rim between
    them gone, a notch) when rounding would make it invalid."""
    step = 10.0**-CONVERTED_DECIMALS
    rounded = shapely.transform(lonlat, lambda xy: np.round(xy, CONVERTED_DECIMALS))
    if rounded.is_valid:
        return lonlat
    snapped = shapely.set_precision(lonlat, step)
    if isinstance(snapped, shapely.MultiPolygon):
        snapped = max(snapped.geoms, key=lambda part: part.area)
    if isinstance(snapped, Polygon) and snapped.is_valid and not snapped.is_empty:
        return orient(snapped, sign=1.0)
    return lonlat


def _field(
    frame: LocalFrame,
    source: str,
    field_id: str,
    props: dict[str, Any],
    rings: list[list[tuple[float, float]]],
) -> Field:
    where = f"{source}: field {field_id!r}"
    local_rings = []
    for ring in rings:
        xs, ys = frame.to_local(np.array([p[0] for p in ring]), np.array([p[1] for p in ring]))
        local_rings.append(list(zip(xs.tolist(), ys.tolist(), strict=True)))
    try:
        # Outline counter-clockwise, holes clockwise (RFC 7946), whatever the file has: the
        # same field gives the same plan from every format (GDAL's readers orient it so).
        boundary = orient(Polygon(local_rings[0], local_rings[1:]), sign=1.0)
        lonlat = orient(Polygon(rings[0], rings[1:]), sign=1.0)
    except (ValueError, shapely.errors.ShapelyError) as exc:
        raise GeometryError(f"{where}: not a polygon: {exc}") from exc
    if boundary.is_empty or boundary.area <= 0.0:
        raise GeometryError(f"{where}: the polygon has no area")
    # Where, in the file's longitude and latitude (the local metres mean nothing to whoever
    # drew it), unless only the local frame shows it.
    invalid = f"{where}: invalid polygon ({{}}); is its boundary self-intersecting?"
    if not lonlat.is_valid:
        # A hole drawn onto the outline (a pond snapped to the field's edge in a GIS): its
        # outline less its holes, a notch, when that is the same land.
        notched = _mended(lonlat, lambda polygon: _to_local(frame, polygon))
        if notched is lonlat:
            raise GeometryError(invalid.format(explain_validity(lonlat)))
        lonlat, boundary = notched, orient(_to_local(frame, notched), sign=1.0)
    if not boundary.is_valid:
        boundary = _mended(boundary)
    if not boundary.is_valid:
        raise GeometryError(invalid.format(explain_validity(boundary)))
    lonlat = _written_valid(lonlat)
    angle = _number_text(_prop(props, "work_angle_deg"))
    if angle is not None and (
        isinstance(angle, bool) or not isinstance(angle, int | float) or not abs(angle) <= 360.0
    ):
        # (1e300 degrees, taken modulo 180, was a direction no one meant)
        raise GeometryError(
            f"{where}: work_angle_deg must be a number of degrees (-360 to 360), not {angle!r}"
        )
    passes = _number_text(_prop(props, "headland_passes"))
    if isinstance(passes, float) and passes.is_integer():
        passes = int(passes)  # 2.0: a GIS's numeric column (QGIS's default type is real)
    if passes is not None and (
        not isinstance(passes, int) or isinstance(passes, bool) or passes < 0
    ):
        raise GeometryError(f"{where}: headland_passes must be a whole number >= 0, not {passes!r}")
    name = props["name"]
    return Field(
        id=field_id,
        name=str(name),
        boundary=boundary,
        boundary_lonlat=lonlat,
        work_angle_deg=None if angle is None else float(angle),
        headland_passes=passes,
    )
