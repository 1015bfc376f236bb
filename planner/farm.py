"""A farm as the operator draws it: fields, garage, roads and gates in WGS84 GeoJSON (RFC 7946).

Fields are ``Polygon`` features (holes allowed) with ``properties.kind = "field"`` and a
string ``properties.id``; the garage is a ``Point`` with ``properties.kind = "garage"``.
Optional field properties: ``name``, ``work_angle_deg`` (fixed swath direction, degrees
counter-clockwise from east), ``headland_passes``.

Optional: roads, ``LineString`` or ``MultiLineString`` features with ``properties.kind =
"road"``, and gates, ``Point`` features with ``properties.kind = "gate"`` and
``properties.field = "<field id>"`` (a field may have several, each at most
:data:`MAX_GATE_DISTANCE_M` from its field). :mod:`planner.roads` routes the transit between
fields on them. Everything is projected once into a local metric frame (:mod:`planner.geo`)
and checked; errors name the file and feature.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.validation import explain_validity

from planner.errors import GeometryError
from planner.geo import LocalFrame, check_wgs84

MAX_GARAGE_DISTANCE_M = 50_000.0
MAX_GATE_DISTANCE_M = 50.0  # a gate lies on its field's boundary or this close to it

log = logging.getLogger(__name__)


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

    def gates_of(self, field_id: str) -> tuple[Gate, ...]:
        """The gates of one field (empty: entered where it is nearest to the roads)."""
        return tuple(g for g in self.gates if g.field_id == field_id)


def load_farm(path: str | Path) -> Farm:
    """Read and check a farm GeoJSON file."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise GeometryError(f"{path}: cannot read the farm: {exc.strerror}") from exc
    except json.JSONDecodeError as exc:
        raise GeometryError(f"{path}: not JSON (line {exc.lineno}: {exc.msg})") from exc
    return farm_from_geojson(doc, str(path))


def farm_from_geojson(doc: Any, source: str = "<memory>") -> Farm:
    """Build a :class:`Farm` from a parsed GeoJSON FeatureCollection."""
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise GeometryError(f"{source}: expected a GeoJSON FeatureCollection")
    features = doc.get("features")
    if not isinstance(features, list):
        raise GeometryError(f"{source}: 'features' must be a list")
    raw_fields: list[tuple[str, dict[str, Any], list[Any]]] = []
    garages: list[tuple[float, float]] = []
    raw_roads: list[tuple[str, str, list[tuple[float, float]]]] = []  # id, where, points
    raw_gates: list[tuple[str, str, tuple[float, float]]] = []  # field id, where, lon/lat
    seen: set[str] = set()
    for k, feature in enumerate(features):
        where = f"{source}: feature #{k}"
        props = (feature or {}).get("properties") or {}
        geom = (feature or {}).get("geometry") or {}
        kind = props.get("kind")
        if kind == "garage":
            if geom.get("type") != "Point":
                raise GeometryError(f"{where}: the garage must be a Point")
            lon, lat = _lonlat(geom.get("coordinates"), f"{where} (garage)")
            garages.append((lon, lat))
        elif kind == "field":
            field_id = props.get("id")
            if not isinstance(field_id, str) or not field_id:
                raise GeometryError(f"{where}: a field needs a non-empty string properties.id")
            where = f"{source}: field {field_id!r}"
            if field_id in seen:
                raise GeometryError(f"{where}: duplicate field id")
            seen.add(field_id)
            if geom.get("type") != "Polygon":
                raise GeometryError(f"{where}: geometry must be a Polygon, not {geom.get('type')}")
            rings = geom.get("coordinates")
            if not isinstance(rings, list) or not rings:
                raise GeometryError(f"{where}: a Polygon needs at least one ring")
            checked = [[_lonlat(p, where) for p in ring] for ring in rings]
            raw_fields.append((field_id, props, checked))
        elif kind == "road":
            raw_roads += _road_parts(k, props, geom, where)
        elif kind == "gate":
            field_id = props.get("field")
            if not isinstance(field_id, str) or not field_id:
                raise GeometryError(
                    f"{where} (gate): a gate needs properties.field, the id of its field"
                )
            if geom.get("type") != "Point":
                raise GeometryError(f"{where} (gate of {field_id!r}): a gate must be a Point")
            where = f"{where} (gate of {field_id!r})"
            raw_gates.append((field_id, where, _lonlat(geom.get("coordinates"), where)))
    if not garages:
        raise GeometryError(f"{source}: no garage (a Point feature with properties.kind 'garage')")
    if len(garages) > 1:
        raise GeometryError(f"{source}: {len(garages)} garages; exactly one is supported")
    if not raw_fields:
        raise GeometryError(f"{source}: no fields (Polygon features with properties.kind 'field')")

    lons = [p[0] for _, _, rings in raw_fields for p in rings[0]]
    lats = [p[1] for _, _, rings in raw_fields for p in rings[0]]
    frame = LocalFrame.around((min(lons) + max(lons)) / 2, (min(lats) + max(lats)) / 2)
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
    by_id = {f.id: f for f in fields}
    roads = tuple(_road(frame, rid, where, points) for rid, where, points in raw_roads)
    gates = tuple(_gate(frame, by_id, fid, where, lonlat) for fid, where, lonlat in raw_gates)
    for road in roads:
        for f in fields:
            if road.line.intersection(f.boundary).length > 1.0:
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
    road_id = props.get("id")
    road_id = str(road_id) if road_id is not None else f"road#{k}"
    where = f"{where} (road {road_id!r})"
    kind = geom.get("type")
    coords = geom.get("coordinates")
    if kind == "LineString":
        parts = [coords]
    elif kind == "MultiLineString" and isinstance(coords, list):
        parts = coords
    else:
        raise GeometryError(f"{where}: a road must be a LineString or MultiLineString, not {kind}")
    out = []
    for n, part in enumerate(parts):
        here = where if kind == "LineString" else f"{where} part {n}"
        if not isinstance(part, list) or len(part) < 2:
            raise GeometryError(f"{here}: a road needs at least 2 points")
        points = [_lonlat(p, here) for p in part]
        if len(set(points)) < 2:
            raise GeometryError(f"{here}: a road needs at least 2 distinct points")
        out.append((road_id if len(parts) == 1 else f"{road_id}.{n}", here, points))
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
    field_id: str,
    where: str,
    lonlat: tuple[float, float],
) -> Gate:
    field = fields.get(field_id)
    if field is None:
        known = ", ".join(sorted(fields))
        raise GeometryError(f"{where}: no field {field_id!r} in this farm (fields: {known})")
    x, y = frame.to_local(*lonlat)
    off = field.boundary.boundary.distance(Point(x, y))
    if off > MAX_GATE_DISTANCE_M:
        raise GeometryError(
            f"{where}: the gate is {off:.0f} m from the boundary of field {field_id!r} "
            f"(limit {MAX_GATE_DISTANCE_M:.0f} m); a gate lies on its field's boundary"
        )
    return Gate(field_id=field_id, xy=(x, y), lonlat=lonlat)


def _lonlat(value: Any, where: str) -> tuple[float, float]:
    if (
        not isinstance(value, list | tuple)
        or len(value) < 2
        or not all(isinstance(v, int | float) for v in value[:2])
    ):
        raise GeometryError(f"{where}: a position must be [longitude, latitude], got {value!r}")
    lon, lat = float(value[0]), float(value[1])
    check_wgs84(lon, lat, where)
    return lon, lat


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
        boundary = Polygon(local_rings[0], local_rings[1:])
        lonlat = Polygon(rings[0], rings[1:])
    except (ValueError, shapely.errors.ShapelyError) as exc:
        raise GeometryError(f"{where}: not a polygon: {exc}") from exc
    if boundary.is_empty or boundary.area <= 0.0:
        raise GeometryError(f"{where}: the polygon has no area")
    if not boundary.is_valid:
        raise GeometryError(
            f"{where}: invalid polygon ({explain_validity(boundary)}); "
            "is its boundary self-intersecting?"
        )
    angle = props.get("work_angle_deg")
    if angle is not None and (not isinstance(angle, int | float) or not math.isfinite(angle)):
        raise GeometryError(f"{where}: work_angle_deg must be a number of degrees, not {angle!r}")
    passes = props.get("headland_passes")
    if passes is not None and (
        not isinstance(passes, int) or isinstance(passes, bool) or passes < 0
    ):
        raise GeometryError(f"{where}: headland_passes must be a whole number >= 0, not {passes!r}")
    name = props.get("name", field_id)
    return Field(
        id=field_id,
        name=str(name),
        boundary=boundary,
        boundary_lonlat=lonlat,
        work_angle_deg=None if angle is None else float(angle),
        headland_passes=passes,
    )
