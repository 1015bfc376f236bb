"""A plan as GIS files (GeoJSON for QGIS, KML for Google Earth) and the farm as the fence
and rally point of the QGroundControl ``.plan`` files (docs/farm-files.md).

Features, all in WGS84 lon/lat, with the properties of :data:`PROPERTIES` (missing: null):

* ``field``: each field's outline; ``machine`` that works it, ``order`` (1 = its first
  field), ``start_s`` / ``end_s`` (seconds from setting off: first and last item there);
* ``garage`` (a point) and ``road`` (the farm's roads);
* ``route``: each machine's whole mission path (home, transit, swaths, turns, return);
  ``fields`` (its order, space-separated), ``end_s``, ``time_h``, ``distance_m``, ``fuel_l``;
* ``swath``: each worked segment (swath or headland ring edge) in driving order:
  ``machine``, ``field``, ``order`` (1 = the machine's first), ``start_s``, ``end_s``.

The GeoJSON file is one layer; the KML file has a folder ``farm`` and one per machine, and
calls ``id`` :data:`KML_ID_PROPERTY` (see there).
"""

from __future__ import annotations

import json
import logging
import os
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

if TYPE_CHECKING:
    from dispatcher.mission.plan import DispatchPlan
    from planner.geo import LocalFrame

logger = logging.getLogger(__name__)

PROPERTIES = (
    "kind",
    "id",
    "name",
    "machine",
    "field",
    "order",
    "fields",
    "start_s",
    "end_s",
    "time_h",
    "distance_m",
    "fuel_l",
)
WHOLE_PROPERTIES = frozenset({"order"})
NUMBER_PROPERTIES = frozenset({"start_s", "end_s", "time_h", "distance_m", "fuel_l"})
FARM_LAYER = "farm"
KML_ID_PROPERTY = "feature_id"
"""plan.kml's name for ``id``. GDAL's KML writer puts a column ``id`` as it is into the
placemark's XML ``id`` attribute: a field id such as ``Schlag 3 & 4`` (a Google Earth
placemark's name) made the file unreadable, and an XML id may hold no space nor start with
a digit anyway. Under another name it is written as the other properties are
(``ExtendedData``, quoted); the placemarks get GDAL's own ids (``farm.1``, ...)."""
_NOT_IN_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")
"""Characters XML 1.0 cannot hold, even escaped (a control character in a shapefile's id)."""
FENCE_MARGIN_M = 10.0
"""How far the inclusion fence lies outside the fields, roads and planned paths."""
FENCE_SIMPLIFY_M = 1.0  # fewer fence vertices (autopilots store few), never inside the margin
FENCE_DECIMALS = 7  # the .plan's degrees: about 1 cm
FENCE_REPAIR_M = (0.05, 0.1, 0.2, 0.5, 1.0)
"""How far a fence polygon is grown (an exclusion: shrunk), in turn, when its outline in
lat/lon rounded to :data:`FENCE_DECIMALS` crosses itself. Where a road runs at twice
:data:`FENCE_MARGIN_M` from a field their margins touch, and the outline passes twice within
a millimetre of one point: rounding can make it cross there, and an autopilot's
point-in-polygon test is then wrong about some places. Growing closes such a pinch; the
fence then covers a little more (or the exclusion a little less), never less."""
SECONDS_DECIMALS = 1

PathLike = str | os.PathLike[str]


@dataclass(frozen=True)
class PlanFeature:
    geometry: BaseGeometry  # WGS84 lon/lat
    properties: dict[str, Any]


def farm_features(dispatch: DispatchPlan) -> list[PlanFeature]:
    """Fields (with who works them, in which order, when), the garage and the roads."""
    farm = dispatch.scenario.farm
    worked: dict[str, dict[str, Any]] = {}
    for machine in dispatch.document.machines:
        times = machine.planned_times() or [0.0] * len(machine.items)
        for order, field_id in enumerate(machine.fields, start=1):
            at = [t for it, t in zip(machine.items, times, strict=True) if it.field_id == field_id]
            worked[field_id] = {
                "machine": machine.id,
                "order": order,
                "start_s": _seconds(min(at)) if at else None,
                "end_s": _seconds(max(at)) if at else None,
            }
    out = [
        PlanFeature(
            f.boundary_lonlat, {"kind": "field", "id": f.id, "name": f.name, **worked.get(f.id, {})}
        )
        for f in farm.fields
    ]
    out.append(PlanFeature(Point(farm.garage_lonlat), {"kind": "garage"}))
    out += [PlanFeature(r.line_lonlat, {"kind": "road", "id": r.id}) for r in farm.roads]
    return out


def machine_features(dispatch: DispatchPlan) -> dict[str, list[PlanFeature]]:
    """Per machine: its route, then its swaths in driving order."""
    out: dict[str, list[PlanFeature]] = {}
    for machine in dispatch.document.machines:
        times = machine.planned_times() or [0.0] * len(machine.items)
        nav = [
            (it, t) for it, t in zip(machine.items, times, strict=True) if it.is_nav or it.seq == 0
        ]
        route = LineString([(it.lon, it.lat) for it, _ in nav])
        features = [
            PlanFeature(
                route,
                {
                    "kind": "route",
                    "name": f"{machine.id} route",
                    "machine": machine.id,
                    # A JSON array as text (ids may hold spaces): GDAL writes it into
                    # GeoJSON as the array, into KML as the text.
                    "fields": json.dumps(list(machine.fields), ensure_ascii=False),
                    "start_s": 0.0,
                    "end_s": _seconds(times[-1]),
                    "time_h": machine.time_h,
                    "distance_m": machine.distance_m,
                    "fuel_l": machine.fuel_l,
                },
            )
        ]
        start: tuple[Any, float] | None = None
        for it, t in nav:
            if it.role == "swath_start":
                start = (it, t)
            elif it.role == "swath_end" and start is not None:
                first, t0 = start
                features.append(
                    PlanFeature(
                        LineString([(first.lon, first.lat), (it.lon, it.lat)]),
                        {
                            "kind": "swath",
                            "name": f"{it.field_id} swath {len(features)}",
                            "machine": machine.id,
                            "field": it.field_id,
                            "order": len(features),
                            "start_s": _seconds(t0),
                            "end_s": _seconds(t),
                        },
                    )
                )
                start = None
        out[machine.id] = features
    return out


def write_plan_geojson(dispatch: DispatchPlan, path: PathLike) -> None:
    """Fields, garage, roads, routes and swaths as one GeoJSON layer (RFC 7946)."""
    features = farm_features(dispatch)
    for machine in machine_features(dispatch).values():
        features += machine
    _write(path, features, "GeoJSON", layer=None, options={"RFC7946": "YES"})


def write_plan_kml(dispatch: DispatchPlan, path: PathLike) -> None:
    """The farm in folder ``farm``, then one folder per machine (its route and swaths); ``id``
    named :data:`KML_ID_PROPERTY`, and text XML cannot hold made so (:func:`_kml_text`)."""
    layers = {FARM_LAYER: farm_features(dispatch), **machine_features(dispatch)}
    names = [KML_ID_PROPERTY if key == "id" else key for key in PROPERTIES]
    for k, (layer, features) in enumerate(layers.items()):
        kml = [
            PlanFeature(f.geometry, {key: _kml_text(v) for key, v in f.properties.items()})
            for f in features
        ]
        options = {"FOLDER": "YES"}
        _write(path, kml, "LIBKML", layer=layer, options=options, append=k > 0, names=names)


def _kml_text(value: Any) -> Any:
    """A property as GDAL's KML writer can write it: it quotes text holding ``&<>"'`` as
    ``<![CDATA[...]]>``, which ``]]>`` in the text would end early (a space parts it), and
    characters XML cannot hold are left out. Anything but text is as it is."""
    if not isinstance(value, str):
        return value
    return _NOT_IN_XML.sub("", value).replace("]]>", "]] >")


def _write(
    path: PathLike,
    features: list[PlanFeature],
    driver: str,
    layer: str | None,
    options: dict[str, str],
    append: bool = False,
    names: list[str] | None = None,
) -> None:
    """Write ``features`` with the properties of :data:`PROPERTIES` as columns, named
    ``names`` (as the properties if None)."""
    import pyogrio

    names = list(PROPERTIES) if names is None else names
    geometry = shapely.to_wkb(np.array([f.geometry for f in features], dtype=object))
    columns, masks = [], []
    for key in PROPERTIES:
        values = [f.properties.get(key) for f in features]
        missing = np.array([v is None for v in values])
        if key in WHOLE_PROPERTIES or key in NUMBER_PROPERTIES:
            dtype = np.int64 if key in WHOLE_PROPERTIES else np.float64
            columns.append(np.array([0 if v is None else v for v in values], dtype=dtype))
        else:
            columns.append(np.array(values, dtype=object))
        masks.append(missing)
    pyogrio.raw.write(
        path,
        geometry,
        columns,
        names,
        field_mask=masks,
        driver=driver,
        layer=layer,
        geometry_type="Unknown",
        crs="EPSG:4326",
        append=append,
        layer_options=options,
    )


def fence_polygons(
    dispatch: DispatchPlan,
) -> tuple[list[list[tuple[float, float]]], list[list[tuple[float, float]]]]:
    """The farm as fence polygons in (lat, lon): one inclusion polygon around the fields,
    the roads, the garage and every planned path, :data:`FENCE_MARGIN_M` outside them
    (without holes; of fields and roads apart from the rest, none), and an exclusion
    polygon for each hole of a field (a pond), shrunk by the margin and less the planned
    paths. Each is a simple polygon in (lon, lat) as written,
    rounded (:func:`_fence_rings`)."""
    farm = dispatch.scenario.farm
    paths: list[BaseGeometry] = [Point(farm.garage)]
    for mission in dispatch.missions.values():
        lonlat = np.array([(it.lon, it.lat) for it in mission.items if it.is_waypoint])
        if len(lonlat) > 1:
            xs, ys = farm.frame.to_local(lonlat[:, 0], lonlat[:, 1])
            paths.append(LineString(np.column_stack([xs, ys])))
    driven = _grown(paths)
    farm_parts = [f.boundary for f in farm.fields] + [r.line for r in farm.roads]
    area = shapely.union_all([driven, _grown(farm_parts)])
    # One inclusion polygon: ArduPilot keeps a vehicle inside every inclusion polygon at
    # once (AC_PolyFence_loader::breached, unless FENCE_OPTIONS asks for their union), so
    # two apart put it in breach everywhere. Every planned path leaves the garage: the part
    # with the garage holds them all; the rest (a road or field apart that no path reaches)
    # is not driven.
    area = next(p for p in _polygons(area) if p.intersects(paths[0]))
    if _across_antimeridian(area, farm.frame):
        # ArduPilot tests a fence on raw longitudes: one across ±180 would go round the
        # world the other way (and QGroundControl's file has no other way to say it). Said
        # before the rings are made: in lat/lon they cross themselves, and were refused as
        # "not simple" instead (review).
        logger.warning(ANTIMERIDIAN)
        return [], []
    ponds = [
        Polygon(hole).buffer(-FENCE_MARGIN_M).difference(driven)
        for f in farm.fields
        for hole in f.boundary.interiors
    ]
    inclusion = [
        ring
        for p in _polygons(area.simplify(FENCE_SIMPLIFY_M))
        for ring in _fence_rings(p, farm.frame, inclusion=True)
    ]
    exclusion = [
        ring
        for pond in ponds
        for p in _polygons(pond.simplify(FENCE_SIMPLIFY_M))
        for ring in _fence_rings(p, farm.frame, inclusion=False)
    ]
    return inclusion, exclusion


ANTIMERIDIAN = (
    "the farm's fence crosses longitude 180 (the antimeridian), which an ArduPilot fence "
    "cannot hold: left out of the .plan files (set one by hand if needed)"
)


def _across_antimeridian(area: Polygon, frame: LocalFrame) -> bool:
    """Whether the polygon (local metres) spans longitude ±180."""
    xy = np.asarray(area.exterior.coords)
    lon, _ = frame.to_lonlat(xy[:, 0], xy[:, 1])
    return bool(len(lon) and float(np.max(lon) - np.min(lon)) > 180.0)


def _grown(shapes: list[BaseGeometry]) -> BaseGeometry:
    """The union of ``shapes`` grown by :data:`FENCE_MARGIN_M`: each simplified first to
    within half :data:`FENCE_SIMPLIFY_M` and grown by that much more, so that it still
    holds the shape (a GPS track's noise, every vertex buffered, took 18 s and 2 GB for
    one road: review)."""
    slack = FENCE_SIMPLIFY_M / 2.0
    return shapely.union_all(
        [shape.simplify(slack).buffer(FENCE_MARGIN_M + slack) for shape in shapes]
    )


def _fence_rings(
    polygon: Polygon, frame: LocalFrame, inclusion: bool
) -> list[list[tuple[float, float]]]:
    """The outline of a fence polygon (local metres) in (lat, lon) rounded to
    :data:`FENCE_DECIMALS`, not closed (as QGroundControl writes them), and simple as
    rounded: grown (an exclusion: shrunk, maybe into parts) by :data:`FENCE_REPAIR_M` in
    turn until it is. Last resorts: an inclusion's convex hull (more, not less), no
    exclusion (with a warning; the paths keep out of the pond anyway)."""
    for grow in (0.0, *FENCE_REPAIR_M):
        if grow == 0.0:
            parts = [Polygon(polygon.exterior)]
        elif inclusion:  # one polygon still: its outline
            parts = [Polygon(polygon.buffer(grow, join_style="mitre").exterior)]
        else:
            parts = _polygons(polygon.buffer(-grow, join_style="mitre"))
        rings = [_latlon(p, frame) for p in parts]
        if all(_is_simple(ring) for ring in rings):
            return rings
    if inclusion:
        ring = _latlon(Polygon(polygon.convex_hull.exterior), frame)
        if _is_simple(ring):
            return [ring]
    logger.warning(
        "a fence %s polygon of %d corners is not simple in lat/lon rounded to %d decimals, "
        "whatever its growth: left out of the .plan files",
        "inclusion" if inclusion else "exclusion",
        len(polygon.exterior.coords) - 1,
        FENCE_DECIMALS,
    )
    return []


def _latlon(polygon: Polygon, frame: LocalFrame) -> list[tuple[float, float]]:
    xy = np.asarray(polygon.exterior.coords)[:-1]  # QGroundControl's are not closed
    lon, lat = frame.to_lonlat(xy[:, 0], xy[:, 1])
    return [
        (round(float(a), FENCE_DECIMALS), round(float(o), FENCE_DECIMALS))
        for a, o in zip(lat, lon, strict=True)
    ]


def _is_simple(ring: list[tuple[float, float]]) -> bool:
    """Whether a (lat, lon) outline is a valid polygon in (lon, lat): at least 3 corners,
    some area, no crossing nor touching of itself."""
    return len(ring) >= 3 and Polygon([(lon, lat) for lat, lon in ring]).is_valid


def _polygons(geometry: BaseGeometry) -> list[Polygon]:
    """The polygons of a Polygon, MultiPolygon or collection (none of an empty one)."""
    if isinstance(geometry, Polygon):
        return [] if geometry.is_empty else [geometry]
    return [p for g in getattr(geometry, "geoms", []) for p in _polygons(g)]


def _seconds(t: float) -> float:
    return round(float(t), SECONDS_DECIMALS)
