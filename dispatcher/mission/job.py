"""What the daemon dispatches, and all of it: the plan document, each machine's mission as
it is uploaded, and the plan's picture as GeoJSON.

A :class:`DispatchJob` is made from a fresh plan (:meth:`DispatchPlan.job
<dispatcher.mission.plan.DispatchPlan.job>`) or read back from the dispatcher's store on a
restart (:mod:`dispatcher.daemon.store`): the daemon needs nothing of the planner, so a
resumed run is dispatched exactly as it was planned, without planning again.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import astuple, dataclass, fields
from typing import Any

from dispatcher.link.mission_item import MissionItem
from dispatcher.mission.build import Mission, Trace
from dispatcher.mission.document import PlanDocument, PlanDocumentError

ITEM_COLUMNS = tuple(f.name for f in fields(MissionItem))
"""A mission item stored as a JSON array: MISSION_ITEM_INT's fields in this order."""


@dataclass(frozen=True)
class DispatchJob:
    document: PlanDocument
    missions: Mapping[str, Mission]  # by vehicle id
    geojson: Mapping[str, Any]

    @property
    def plan_id(self) -> str:
        return self.document.plan_id

    @property
    def farm_id(self) -> str:
        return self.document.farm_id

    def items_json(self, vehicle: str) -> list[list[Any]]:
        """A mission's items as JSON arrays (:data:`ITEM_COLUMNS`)."""
        return [list(astuple(item)) for item in self.missions[vehicle].items]

    @classmethod
    def from_parts(
        cls,
        document: PlanDocument,
        items: Mapping[str, Sequence[Sequence[Any]]],
        geojson: Mapping[str, Any],
    ) -> DispatchJob:
        """A job from its stored parts: the document, each mission's items as JSON arrays
        (:meth:`items_json`), the GeoJSON. The items must be the document's, item by item
        (:class:`~dispatcher.mission.document.PlanDocumentError` says where they differ)."""
        missions = {}
        for machine in document.machines:
            if machine.id not in items:
                raise PlanDocumentError(f"no mission stored for machine {machine.id!r}")
            rows = items[machine.id]
            if len(rows) != len(machine.items):
                raise PlanDocumentError(
                    f"machine {machine.id!r}: {len(rows)} mission items stored, "
                    f"the plan has {len(machine.items)}"
                )
            mission_items = []
            for row, planned in zip(rows, machine.items, strict=True):
                if len(row) != len(ITEM_COLUMNS):
                    raise PlanDocumentError(
                        f"machine {machine.id!r} item {planned.seq}: {len(row)} values, "
                        f"expected {len(ITEM_COLUMNS)} ({', '.join(ITEM_COLUMNS)})"
                    )
                item = MissionItem(*row)
                if (item.seq, item.command, item.x, item.y) != (
                    planned.seq,
                    planned.command,
                    planned.x,
                    planned.y,
                ):
                    raise PlanDocumentError(
                        f"machine {machine.id!r} item {planned.seq}: the stored mission "
                        "is not the plan's"
                    )
                mission_items.append(item)
            traces = tuple(Trace(i.field_id, i.swath_index, i.role) for i in machine.items)  # type: ignore[arg-type]
            missions[machine.id] = Mission(machine.id, tuple(mission_items), traces)
        return cls(document=document, missions=missions, geojson=geojson)
