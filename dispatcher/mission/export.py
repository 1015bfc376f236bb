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

The GeoJSON file is one layer; the KML file has a folder ``farm`` and one per machine.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry

if TYPE_CHECKING:
    from dispatcher.mission.plan import DispatchPlan

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
FENCE_MARGIN_M = 10.0
"""How far the inclusion fence lies outside the fields, roads and planned paths."""
FENCE_SIMPLIFY_M = 1.0  # fewer fence vertices (autopilots store few), never inside the margin
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
                    "fields": " ".join(machine.fields),
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
    """The farm in folder ``farm``, then one folder per machine (its route and swaths)."""
    _write(path, farm_features(dispatch), "LIBKML", layer=FARM_LAYER, options={"FOLDER": "YES"})
    for machine_id, features in machine_features(dispatch).items():
        _write(path, features, "LIBKML", layer=machine_id, options={"FOLDER": "YES"}, append=True)


def _write(
    path: PathLike,
    features: list[PlanFeature],
    driver: str,
    layer: str | None,
    options: dict[str, str],
    append: bool = False,
) -> None:
    import pyogrio

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
        list(PROPERTIES),
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
    """The farm as fence polygons in (lat, lon): inclusion polygons around the fields, the
    roads, the garage and every planned path, :data:`FENCE_MARGIN_M` outside them (without
    holes), and an exclusion polygon for each hole of a field (a pond), shrunk by the
    margin and less the planned paths."""
    farm = dispatch.scenario.farm
    paths: list[BaseGeometry] = [Point(farm.garage)]
    for mission in dispatch.missions.values():
        lonlat = np.array([(it.lon, it.lat) for it in mission.items if it.is_waypoint])
        if len(lonlat) > 1:
            xs, ys = farm.frame.to_local(lonlat[:, 0], lonlat[:, 1])
            paths.append(LineString(np.column_stack([xs, ys])))
    driven = shapely.union_all([p.buffer(FENCE_MARGIN_M) for p in paths])
    farm_parts = [f.boundary for f in farm.fields] + [r.line for r in farm.roads]
    area = shapely.union_all([driven, *(p.buffer(FENCE_MARGIN_M) for p in farm_parts)])
    ponds = [
        Polygon(hole).buffer(-FENCE_MARGIN_M).difference(driven)
        for f in farm.fields
        for hole in f.boundary.interiors
    ]

    def latlon(polygon: Polygon) -> list[tuple[float, float]]:
        xy = np.asarray(polygon.exterior.coords)[:-1]  # QGroundControl's are not closed
        lon, lat = farm.frame.to_lonlat(xy[:, 0], xy[:, 1])
        return [(round(float(a), 7), round(float(o), 7)) for a, o in zip(lat, lon, strict=True)]

    inclusion = [latlon(p) for p in _polygons(area.simplify(FENCE_SIMPLIFY_M))]
    exclusion = [latlon(p) for pond in ponds for p in _polygons(pond.simplify(FENCE_SIMPLIFY_M))]
    return inclusion, exclusion


def _polygons(geometry: BaseGeometry) -> list[Polygon]:
    """The polygons of a Polygon, MultiPolygon or collection (none of an empty one)."""
    if isinstance(geometry, Polygon):
        return [] if geometry.is_empty else [geometry]
    return [p for g in getattr(geometry, "geoms", []) for p in _polygons(g)]


def _seconds(t: float) -> float:
    return round(float(t), SECONDS_DECIMALS)
