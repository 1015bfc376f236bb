"""A farm as the operator draws it: field polygons and a garage in WGS84 GeoJSON (RFC 7946).

Fields are ``Polygon`` features (holes allowed) with ``properties.kind = "field"`` and a
string ``properties.id``; the garage is a ``Point`` with ``properties.kind = "garage"``.
Optional field properties: ``name``, ``work_angle_deg`` (fixed swath direction, degrees
counter-clockwise from east), ``headland_passes``. Everything is projected once into a
local metric frame (:mod:`planner.geo`) and checked; errors name the file and feature.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry import Point, Polygon
from shapely.validation import explain_validity

from planner.errors import GeometryError
from planner.geo import LocalFrame, check_wgs84

MAX_GARAGE_DISTANCE_M = 50_000.0


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
class Farm:
    """The fields and the garage of one farm, in one local frame."""

    fields: tuple[Field, ...]
    garage: tuple[float, float]  # local metres
    garage_lonlat: tuple[float, float]
    frame: LocalFrame
    source: str = "<memory>"

    def field(self, field_id: str) -> Field:
        for f in self.fields:
            if f.id == field_id:
                return f
        raise KeyError(field_id)


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
    return Farm(
        fields=fields, garage=(gx, gy), garage_lonlat=(glon, glat), frame=frame, source=source
    )


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
    if passes is not None and (not isinstance(passes, int) or isinstance(passes, bool) or passes < 0):
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
