"""The plan document: one typed owner of ``plan.json`` and of the plan published on Zenoh.

:class:`PlanDocument` holds per machine its fields, figures and every mission item with the
field, swath and role it serves; the fields' outlines; totals; and the plan id, a content
hash. :meth:`PlanDocument.to_json` / :meth:`PlanDocument.from_json` are the only code that
writes or reads the JSON: ``agrifleet plan`` writes it, the daemon publishes and records it,
review reads it back from a log. The JSON layout (``schema`` 1)::

    {"plan_id", "farm_id", "objective", "algorithm", "seed", "garage": {"lat", "lon"},
     "fields": {id: {"name", "area_m2", "polygon": [[lon, lat], ...],
                     "holes": [[[lon, lat], ...], ...]}},  # holes only if it has any
     "machines": [{"id", "system_id", "working_width_m", "params": {...}, "fields": [...],
                   "distance_m", "fuel_l", "time_h", "work_h", "turns", "visits": [...],
                   "mission_items", "items": [[seq, field, swath, role, x, y, command,
                                               param1, param2], ...]}],
     "totals": {"distance_m", "fuel_l", "time_h", "makespan_h"}}

Items are arrays in the order of :data:`ITEM_FIELDS` (a plan has thousands of them); x and
y are latitude and longitude in degrees times 1e7, as in MISSION_ITEM_INT.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any, Final

import numpy as np
from pyproj import Geod

from dispatcher.config.errors import DispatcherError
from dispatcher.link import mavlink as mc

ITEM_FIELDS: Final = (
    "seq",
    "field_id",
    "swath_index",
    "role",
    "x",
    "y",
    "command",
    "param1",
    "param2",
    "segment",
)


_GEOD = Geod(ellps="WGS84")


class PlanDocumentError(DispatcherError, ValueError):
    """A plan document that cannot be read; the message names the key at fault."""


@dataclass(frozen=True)
class PlannedItem:
    """One mission item as the plan records it: what it is and which field and swath it
    serves (``role`` as in :class:`dispatcher.mission.build.Trace`)."""

    seq: int
    field_id: str | None
    swath_index: int | None
    role: str
    x: int  # latitude * 1e7
    y: int  # longitude * 1e7
    command: int
    param1: float = 0.0
    param2: float = 0.0
    # The segment of the field (swath, or headland ring edge) this item serves, numbered as
    # in the field's first planned layout: the same segment keeps its number through
    # re-plans, where ``swath_index`` counts within one visit.
    segment: int | None = None

    @property
    def lat(self) -> float:
        return self.x / 1e7

    @property
    def lon(self) -> float:
        return self.y / 1e7

    @property
    def is_nav(self) -> bool:
        """A waypoint the vehicle drives to (and reports reached)."""
        return self.command == mc.MAV_CMD_NAV_WAYPOINT

    def to_json(self) -> list[Any]:
        return [getattr(self, name) for name in ITEM_FIELDS]


@dataclass(frozen=True)
class PlannedVisit:
    field: str
    corner: int
    swaths: int
    headland_rings: int
    turn_m: float
    angle_deg: float  # the swaths' direction, degrees counter-clockwise from true east
    # The rest of a field begun before (a re-plan's): its items' segments are numbered in
    # the layout the field was begun in, not in this visit's own (a field laid out whole).
    rest: bool = False


@dataclass(frozen=True)
class PlannedMachine:
    """One machine's part of the plan: its Table 1 parameters, route, figures, mission."""

    id: str
    system_id: int
    working_width_m: float
    params: Mapping[str, float]
    fields: tuple[str, ...]
    distance_m: float
    fuel_l: float
    time_h: float
    work_h: float
    turns: float
    visits: tuple[PlannedVisit, ...]
    items: tuple[PlannedItem, ...]

    def param(self, name: str) -> float:
        """A machine parameter (0 when the plan does not give it)."""
        return float(self.params.get(name, 0.0))

    def planned_times(self) -> list[float] | None:
        """Seconds from setting off to reaching each item, driving the mission's legs
        (geodesic, WGS84) at the speeds its DO_CHANGE_SPEED items set, the road speed
        before the first one. None when a leg's speed is not known."""
        if not self.items:
            return None
        nav = [item for item in self.items[1:] if item.is_nav]
        lats = np.array([self.items[0].lat] + [i.lat for i in nav])
        lons = np.array([self.items[0].lon] + [i.lon for i in nav])
        legs = iter(_GEOD.inv(lons[:-1], lats[:-1], lons[1:], lats[1:])[2].tolist())
        speed = self.param("road_speed_kmh") / 3.6
        out = [0.0]
        t = 0.0
        for item in self.items[1:]:
            if item.command == mc.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0:
                speed = item.param2
            elif item.is_nav:
                leg = next(legs)
                if leg > 0:
                    if speed <= 0:
                        return None
                    t += leg / speed
            out.append(t)
        return out


@dataclass(frozen=True)
class PlannedField:
    name: str
    area_m2: float
    polygon: tuple[tuple[float, float], ...]  # (lon, lat), closed
    # What inside the outline is not worked (a pond, a building), each ring closed; a key
    # of the JSON only when there is one, so that plans of fields without keep their ids.
    holes: tuple[tuple[tuple[float, float], ...], ...] = ()

    @property
    def rings(self) -> tuple[tuple[tuple[float, float], ...], ...]:
        """The outline, then the holes."""
        return (self.polygon, *self.holes)


@dataclass(frozen=True)
class PlanDocument:
    """The plan as published and stored (module doc); ``plan_id`` hashes everything else."""

    farm_id: str
    objective: str
    algorithm: str
    seed: int
    garage: tuple[float, float]  # (lat, lon)
    fields: Mapping[str, PlannedField]
    machines: tuple[PlannedMachine, ...]
    totals: Mapping[str, float]
    plan_id: str = field(default="")

    def __post_init__(self) -> None:
        if not self.plan_id:
            object.__setattr__(self, "plan_id", self.content_hash())

    def content_hash(self) -> str:
        """The plan id: a hash of the document without its id."""
        body = self._body()
        return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()[:16]

    def machine(self, machine_id: str) -> PlannedMachine:
        for m in self.machines:
            if m.id == machine_id:
                return m
        raise KeyError(machine_id)

    @property
    def makespan_h(self) -> float:
        return float(
            self.totals.get("makespan_h", max((m.time_h for m in self.machines), default=0))
        )

    # --- JSON ------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"plan_id": self.plan_id, **self._body()}

    def to_json(self, indent: int | None = None) -> str:
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    def _body(self) -> dict[str, Any]:
        return {
            "farm_id": self.farm_id,
            "objective": self.objective,
            "algorithm": self.algorithm,
            "seed": self.seed,
            "garage": {"lat": self.garage[0], "lon": self.garage[1]},
            "fields": {fid: _field_json(f) for fid, f in self.fields.items()},
            "machines": [
                {
                    "id": m.id,
                    "system_id": m.system_id,
                    "working_width_m": m.working_width_m,
                    "params": dict(m.params),
                    "fields": list(m.fields),
                    "distance_m": m.distance_m,
                    "fuel_l": m.fuel_l,
                    "time_h": m.time_h,
                    "work_h": m.work_h,
                    "turns": m.turns,
                    "visits": [
                        {f.name: getattr(v, f.name) for f in fields(PlannedVisit)} for v in m.visits
                    ],
                    "mission_items": len(m.items),
                    "items": [item.to_json() for item in m.items],
                }
                for m in self.machines
            ],
            "totals": dict(self.totals),
        }

    @classmethod
    def from_json(cls, doc: str | bytes | Mapping[str, Any]) -> PlanDocument:
        """Read a plan document (text or parsed JSON); :class:`PlanDocumentError` names what
        is wrong. The plan id is taken as written (a log holds what was dispatched)."""
        if isinstance(doc, str | bytes):
            try:
                doc = json.loads(doc)
            except ValueError as exc:
                raise PlanDocumentError(f"plan document: not JSON ({exc})") from exc
        r = _Reader(doc, "plan document")
        garage = r.sub("garage")
        fields_doc = r.get("fields", dict)
        planned_fields = {}
        for fid, f in fields_doc.items():
            fr = _Reader(f, f"fields.{fid}")
            planned_fields[str(fid)] = PlannedField(
                str(fr.get("name", str, default=fid)),
                fr.number("area_m2", 0.0),
                _ring(fr.get("polygon", list)),
                tuple(_ring(h) for h in fr.get("holes", list, default=[]) if isinstance(h, list)),
            )
        machines = []
        for k, m in enumerate(r.get("machines", list)):
            mr = _Reader(m, f"machines[{k}]")
            items = []
            for n, raw in enumerate(mr.get("items", list)):
                if not isinstance(raw, list) or len(raw) < 7:
                    raise PlanDocumentError(f"machines[{k}].items[{n}]: not an item array")
                values = dict(zip(ITEM_FIELDS, raw, strict=False))
                if values["seq"] != n:
                    raise PlanDocumentError(
                        f"machines[{k}].items[{n}]: seq {values['seq']!r}, expected {n}"
                    )
                try:
                    items.append(
                        PlannedItem(
                            seq=n,
                            field_id=values["field_id"]
                            if isinstance(values["field_id"], str)
                            else None,
                            swath_index=values["swath_index"]
                            if isinstance(values["swath_index"], int)
                            else None,
                            role=str(values["role"]),
                            x=int(values["x"]),
                            y=int(values["y"]),
                            command=int(values["command"]),
                            param1=float(values.get("param1", 0.0) or 0.0),
                            param2=float(values.get("param2", 0.0) or 0.0),
                            segment=_segment(values),
                        )
                    )
                except (TypeError, ValueError) as exc:
                    raise PlanDocumentError(f"machines[{k}].items[{n}]: {exc}") from exc
            visits = tuple(
                PlannedVisit(
                    field=str(v.get("field", "")),
                    corner=int(v.get("corner", 0)),
                    swaths=int(v.get("swaths", 0)),
                    headland_rings=int(v.get("headland_rings", 0)),
                    turn_m=float(v.get("turn_m", 0.0)),
                    angle_deg=float(v.get("angle_deg", 0.0)),
                    rest=v.get("rest", False) is True,
                )
                for v in mr.get("visits", list, default=[])
                if isinstance(v, dict)
            )
            params = {
                str(key): value
                for key, value in mr.get("params", dict, default={}).items()
                if _finite(value)
            }
            machines.append(
                PlannedMachine(
                    id=mr.get("id", str),
                    system_id=int(mr.number("system_id", 0)),
                    working_width_m=mr.number("working_width_m", 0.0),
                    params=params,
                    fields=tuple(str(f) for f in mr.get("fields", list)),
                    distance_m=mr.number("distance_m", 0.0),
                    fuel_l=mr.number("fuel_l", 0.0),
                    time_h=mr.number("time_h", 0.0),
                    work_h=mr.number("work_h", 0.0),
                    turns=mr.number("turns", 0.0),
                    visits=visits,
                    items=tuple(items),
                )
            )
        totals = {
            str(key): value
            for key, value in r.get("totals", dict, default={}).items()
            if _finite(value)
        }
        plan_id = r.get("plan_id", str, default="")
        return cls(
            farm_id=r.get("farm_id", str, default=""),
            objective=r.get("objective", str, default=""),
            algorithm=r.get("algorithm", str, default=""),
            seed=int(r.number("seed", 0)),
            garage=(garage.number("lat", math.nan), garage.number("lon", math.nan)),
            fields=planned_fields,
            machines=tuple(machines),
            totals=totals,
            plan_id=plan_id,
        )

    def with_id(self) -> PlanDocument:
        """The same document with its id recomputed from its content."""
        return replace(self, plan_id=self.content_hash())


_MISSING = object()


class _Reader:
    """Typed access to one JSON object, errors naming ``where`` and the key."""

    def __init__(self, doc: object, where: str) -> None:
        if not isinstance(doc, dict):
            raise PlanDocumentError(f"{where}: expected an object, got {type(doc).__name__}")
        self.doc = doc
        self.where = where

    def get(self, key: str, kind: type, default: Any = _MISSING) -> Any:
        value = self.doc.get(key, _MISSING)
        if value is _MISSING or value is None:
            if default is _MISSING:
                raise PlanDocumentError(f"{self.where}: missing key {key!r}")
            return default
        if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
            raise PlanDocumentError(
                f"{self.where}.{key}: expected {kind.__name__}, got {type(value).__name__}"
            )
        return value

    def number(self, key: str, default: float) -> float:
        """The number at ``key`` as written (an int stays an int, so the document hashes
        the same after a round trip), else ``default``."""
        value = self.doc.get(key)
        return value if isinstance(value, int | float) and _finite(value) else default

    def sub(self, key: str) -> _Reader:
        return _Reader(self.get(key, dict, default={}), f"{self.where}.{key}")


def _finite(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _field_json(f: PlannedField) -> dict[str, Any]:
    doc: dict[str, Any] = {
        "name": f.name,
        "area_m2": f.area_m2,
        "polygon": [list(p) for p in f.polygon],
    }
    if f.holes:
        doc["holes"] = [[list(p) for p in hole] for hole in f.holes]
    return doc


def _ring(points: list[Any]) -> tuple[tuple[float, float], ...]:
    """A ring's (lon, lat) pairs as read, what is not one left out."""
    return tuple((float(p[0]), float(p[1])) for p in points if _pair(p))


def _pair(value: object) -> bool:
    return (
        isinstance(value, list | tuple) and len(value) >= 2 and all(_finite(v) for v in value[:2])
    )


def _segment(values: dict[str, Any]) -> int | None:
    """An item's segment; documents written before there was one: its swath index."""
    segment = values.get("segment", values["swath_index"])
    return segment if isinstance(segment, int) and not isinstance(segment, bool) else None
