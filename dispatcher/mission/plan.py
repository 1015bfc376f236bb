"""From a farm plan to what leaves the planner: missions, plan.json and the files of
`agrifleet plan` (per machine ``.waypoints`` and ``.plan``, and ``map.png``).

Files are written into a temporary folder beside the output folder and moved into place
only when all of them are written, so a failure leaves nothing half-done behind.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shapely.geometry import LinearRing

from dispatcher.config.scenario import Scenario, Vehicle
from dispatcher.mission.build import (
    FieldVisit,
    LatLon,
    Mission,
    MissionSpec,
    Trace,
    build_mission,
)
from dispatcher.mission.document import (
    PlanDocument,
    PlannedField,
    PlannedItem,
    PlannedMachine,
    PlannedVisit,
)
from dispatcher.mission.files import Fence, write_qgc_plan, write_waypoints
from dispatcher.mission.job import DispatchJob
from planner.farm import Farm
from planner.field_plan import FarmPlan, MachinePlan, Visit


@dataclass(frozen=True)
class DispatchPlan:
    """A farm plan with its missions and its JSON document; what the daemon dispatches."""

    scenario: Scenario
    plan: FarmPlan
    missions: dict[str, Mission]  # by vehicle id
    document: PlanDocument

    @property
    def plan_id(self) -> str:
        return self.document.plan_id

    def job(self) -> DispatchJob:
        """What the daemon dispatches (and its store keeps): document, missions, GeoJSON."""
        return DispatchJob(self.document, self.missions, plan_geojson(self))


def visit_lonlat(farm: Farm, visit: Visit) -> FieldVisit:
    """A field visit in WGS84: swaths in driving order, then the headland rings' edges;
    the in-field links of the moves between swaths, the planned turns between swaths and
    onto each ring; the road points of the approach."""
    segments = [(s.start, s.end) for s in visit.swaths]
    for ring in visit.headland:
        segments += list(zip(ring[:-1], ring[1:], strict=True))

    def latlon(x: float, y: float) -> LatLon:
        lon, lat = farm.frame.to_lonlat(x, y)
        return LatLon(lat, lon)

    swaths = tuple((latlon(*a), latlon(*b)) for a, b in segments)
    # the links onto each ring (around a hole between two rings) after the swaths' own
    links_xy = list(visit.links) + [()] * (len(visit.swaths) - 1 - len(visit.links))
    for ring, onto in zip(visit.headland, visit.coverage.headland_link(visit.corner), strict=True):
        links_xy += [onto] + [()] * (len(ring) - 2)
    links = tuple(tuple(latlon(*p) for p in via) for via in links_xy)
    moves = list(visit.coverage.turn(visit.corner))
    if visit.coverage.turn_radius_m > 0.0:  # planned turns: also onto each ring, not along it
        moves += [()] * (len(visit.swaths) - 1 - len(moves))
        for ring, onto in zip(
            visit.headland, visit.coverage.headland_move(visit.corner), strict=True
        ):
            moves += [onto] + [()] * (len(ring) - 2)
    turns = tuple(tuple(latlon(*p) for p in via) for via in moves)
    return FieldVisit(
        field_id=visit.field.id,
        swaths=swaths,
        links=links,
        turns=turns,
        approach=tuple(latlon(*p) for p in visit.approach),
    )


def mission_for(farm: Farm, vehicle: Vehicle, route: MachinePlan) -> Mission:
    glon, glat = farm.garage_lonlat

    def latlon(x: float, y: float) -> LatLon:
        lon, lat = farm.frame.to_lonlat(x, y)
        return LatLon(lat, lon)

    spec = MissionSpec(
        machine_id=vehicle.id,
        home=LatLon(glat, glon),
        road_speed_kmh=vehicle.machine.road_speed_kmh,
        work_speed_kmh=vehicle.machine.work_speed_kmh,
        implement=vehicle.implement,
        visits=tuple(visit_lonlat(farm, v) for v in route.visits),
        return_path=tuple(latlon(*p) for p in route.return_path),
    )
    return build_mission(spec)


def dispatch_plan(scenario: Scenario, plan: FarmPlan) -> DispatchPlan:
    """Missions for every machine and the plan document, with its id (a content hash)."""
    vehicles = {v.id: v for v in scenario.vehicles}
    missions = {
        r.machine.id: mission_for(scenario.farm, vehicles[r.machine.id], r) for r in plan.machines
    }
    doc = plan_document(scenario, plan, missions)
    return DispatchPlan(scenario=scenario, plan=plan, missions=missions, document=doc)


def plan_document(scenario: Scenario, plan: FarmPlan, missions: dict[str, Mission]) -> PlanDocument:
    """plan.json: per machine its fields, figures and traceable mission items; totals."""
    farm = scenario.farm
    vehicles = {v.id: v for v in scenario.vehicles}
    machines = []
    for route in plan.machines:
        mission = missions[route.machine.id]
        original = _original_segments(route)
        machine = route.machine
        machines.append(
            PlannedMachine(
                id=machine.id,
                system_id=vehicles[machine.id].system_id,
                working_width_m=machine.working_width_m,
                params={
                    "capacity_m2h": machine.capacity_m2h,
                    "work_speed_kmh": machine.work_speed_kmh,
                    "road_speed_kmh": machine.road_speed_kmh,
                    "turn_time_h": machine.turn_time_h,
                    "road_fuel_lh": machine.road_fuel_lh,
                    "work_fuel_lh": machine.work_fuel_lh,
                    "min_turn_radius_m": machine.min_turn_radius_m,
                },
                fields=tuple(route.field_ids),
                distance_m=round(route.road_m, 3),
                fuel_l=round(route.fuel_l, 4),
                time_h=round(route.time_h, 5),
                work_h=round(route.work_h, 5),
                turns=route.turns,
                visits=tuple(
                    PlannedVisit(
                        field=v.field.id,
                        corner=v.corner,
                        swaths=len(v.swaths),
                        headland_rings=len(v.headland),
                        turn_m=round(v.coverage.turn_length_m(v.corner), 2),
                        angle_deg=round(farm.true_angle_deg(v.field.id, v.coverage.angle_deg), 3),
                        rest=bool(v.original_segments),
                    )
                    for v in route.visits
                ),
                items=tuple(
                    PlannedItem(
                        seq=item.seq,
                        field_id=tr.field_id,
                        swath_index=tr.swath_index,
                        role=tr.role,
                        x=item.x,
                        y=item.y,
                        command=item.command,
                        param1=item.param1,
                        param2=item.param2,
                        segment=_segment(original, tr),
                    )
                    for item, tr in zip(mission.items, mission.traces, strict=True)
                ),
            )
        )
    glon, glat = farm.garage_lonlat
    return PlanDocument(
        farm_id=scenario.farm_id,
        objective=plan.objective.name.lower(),
        algorithm=plan.solver.algorithm,
        seed=plan.solver.seed,
        garage=(glat, glon),
        fields={
            f.id: PlannedField(
                name=f.name,
                area_m2=round(f.area_m2, 2),
                polygon=_lonlat7(f.boundary_lonlat.exterior),
                holes=tuple(_lonlat7(hole) for hole in f.boundary_lonlat.interiors),
            )
            for f in farm.fields
        },
        machines=tuple(machines),
        totals={
            "distance_m": round(plan.distance_m, 3),
            "fuel_l": round(plan.fuel_l, 4),
            "time_h": round(plan.time_h, 5),
            "makespan_h": round(plan.makespan_h, 5),
        },
    )


def _original_segments(route: MachinePlan) -> dict[str, tuple[int, ...]]:
    """A route's fields whose segments a re-plan numbered anew: ``Visit.original_segments``
    (the first visit of a field that has them), by field."""
    out: dict[str, tuple[int, ...]] = {}
    for visit in route.visits:
        if visit.original_segments:
            out.setdefault(visit.field.id, visit.original_segments)
    return out


def _segment(original: dict[str, tuple[int, ...]], trace: Trace) -> int | None:
    """The segment an item serves, numbered as in its field's first layout (a re-plan's
    rest of a field maps its own numbers back: ``original``, :func:`_original_segments`)."""
    if trace.field_id is None or trace.swath_index is None:
        return None
    first = original.get(trace.field_id)
    return first[trace.swath_index] if first is not None else trace.swath_index


def _round7(value: float) -> float:
    return round(value, 7)


def _lonlat7(ring: LinearRing) -> tuple[tuple[float, float], ...]:
    """A ring's (lon, lat) corners to 1e-7 degrees (a MAVLink position's step)."""
    return tuple((_round7(lon), _round7(lat)) for lon, lat in ring.coords)


def write_plan_files(dispatch: DispatchPlan, out_dir: str | Path) -> list[Path]:
    """Write plan.json, the missions, map.png and the plan for GIS (plan.geojson,
    plan.kml) into ``out_dir``, all or nothing."""
    from dispatcher.mission.export import fence_polygons, write_plan_geojson, write_plan_kml
    from dispatcher.mission.map import draw_plan_map

    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}-", dir=out_dir.parent))
    try:
        (staging / "plan.json").write_text(dispatch.document.to_json(indent=1) + "\n")
        inclusion, exclusion = fence_polygons(dispatch)
        glon, glat = dispatch.scenario.farm.garage_lonlat
        fence = Fence(inclusion, exclusion, rally=[(glat, glon)])
        for vehicle_id, mission in dispatch.missions.items():
            write_waypoints(mission, staging / f"{vehicle_id}.waypoints")
            write_qgc_plan(mission, staging / f"{vehicle_id}.plan", fence)
        write_plan_geojson(dispatch, staging / "plan.geojson")
        write_plan_kml(dispatch, staging / "plan.kml")
        draw_plan_map(dispatch.plan, staging / "map.png", title=dispatch.scenario.farm_id)
        out_dir.mkdir(exist_ok=True)
        # Missions of machines no longer in the plan must not stay beside it: those the
        # plan.json there (an earlier plan's) lists; any other file is the user's, kept.
        new = {item.name for item in staging.iterdir()}
        for name in _earlier_missions(out_dir / "plan.json") - new:
            (out_dir / name).unlink(missing_ok=True)
        written = []
        for item in sorted(staging.iterdir()):
            target = out_dir / item.name
            os.replace(item, target)
            written.append(target)
        return written
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _earlier_missions(plan_json: Path) -> set[str]:
    """The mission files (``<machine>.waypoints``, ``<machine>.plan``) of the plan that
    ``plan_json`` holds; none when there is none, or it is not a plan of ours."""
    try:
        machines = json.loads(plan_json.read_text())["machines"]
        ids = {str(m["id"]) for m in machines}
    except (OSError, ValueError, KeyError, TypeError):
        return set()
    names = {f"{vid}{suffix}" for vid in ids for suffix in (".waypoints", ".plan")}
    return {name for name in names if Path(name).name == name}  # in that folder only


def plan_geojson(dispatch: DispatchPlan) -> dict[str, Any]:
    """Fields, garage and each machine's planned route as GeoJSON (lon, lat), for
    Foxglove's Map panel and any GIS."""
    from dispatcher.mission.map import FIELD_EDGE, colour

    farm = dispatch.scenario.farm
    features: list[dict[str, Any]] = [
        {
            "type": "Feature",
            "properties": {
                "kind": "field",
                "id": f.id,
                "name": f.name,
                "style": {"color": FIELD_EDGE, "weight": 1, "fillOpacity": 0.1},
            },
            "geometry": {
                "type": "Polygon",
                "coordinates": [  # the outline, then the holes (a pond is not worked)
                    [list(p) for p in _lonlat7(ring)]
                    for ring in (f.boundary_lonlat.exterior, *f.boundary_lonlat.interiors)
                ],
            },
        }
        for f in farm.fields
    ]
    features.append(
        {
            "type": "Feature",
            "properties": {"kind": "garage", "name": "garage", "style": {"color": "#000000"}},
            "geometry": {"type": "Point", "coordinates": list(farm.garage_lonlat)},
        }
    )
    for k, route in enumerate(dispatch.plan.machines):
        mission = dispatch.missions[route.machine.id]
        line = [[_round7(it.lon), _round7(it.lat)] for it in mission.items if it.is_waypoint]
        features.append(
            {
                "type": "Feature",
                "properties": {
                    "kind": "route",
                    "name": f"{route.machine.id}: {' '.join(route.field_ids) or 'no field'}",
                    "machine": route.machine.id,
                    "fields": route.field_ids,
                    "style": {"color": colour(k), "weight": 2},
                },
                "geometry": {"type": "LineString", "coordinates": line},
            }
        )
    return {"type": "FeatureCollection", "features": features}
