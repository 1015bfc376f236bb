"""The plan document: the one owner of plan.json and the published plan."""

import json
from dataclasses import replace
from pathlib import Path

import pytest

from dispatcher.mission.document import PlanDocument, PlanDocumentError
from dispatcher.mission.plan import write_plan_files

DATA = Path(__file__).resolve().parents[1] / "data"


def test_round_trip_through_json_is_identical(dispatch, tmp_path):
    doc = dispatch.document
    again = PlanDocument.from_json(doc.to_json())
    assert again == doc and again.plan_id == doc.plan_id == again.content_hash()
    write_plan_files(dispatch, tmp_path / "out")
    from_file = PlanDocument.from_json((tmp_path / "out" / "plan.json").read_text())
    assert from_file == doc


def test_items_trace_every_mission_item(dispatch):
    for machine in dispatch.document.machines:
        mission = dispatch.missions[machine.id]
        assert len(machine.items) == len(mission)
        for planned, item, trace in zip(machine.items, mission.items, mission.traces, strict=True):
            assert (planned.seq, planned.x, planned.y, planned.command) == (
                item.seq,
                item.x,
                item.y,
                item.command,
            )
            assert (planned.field_id, planned.role) == (trace.field_id, trace.role)
            assert planned.is_nav == item.is_waypoint


def test_the_plan_id_changes_with_the_content(dispatch):
    doc = dispatch.document
    other = replace(doc, seed=doc.seed + 1).with_id()
    assert other.plan_id != doc.plan_id


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (lambda d: d.pop("machines"), "missing key 'machines'"),
        (lambda d: d["machines"][0].update(id=7), "machines[0].id"),
        (lambda d: d["machines"][0]["items"].__setitem__(1, [5]), "machines[0].items[1]"),
        (lambda d: d["machines"][0]["items"][2].__setitem__(0, 9), "seq 9, expected 2"),
        (lambda d: d.update(fields=[]), "fields"),
    ],
)
def test_a_bad_document_names_the_key(dispatch, edit, named):
    doc = json.loads(dispatch.document.to_json())
    edit(doc)
    with pytest.raises(PlanDocumentError, match=named.replace("[", r"\[").replace("]", r"\]")):
        PlanDocument.from_json(doc)
    with pytest.raises(PlanDocumentError, match="not JSON"):
        PlanDocument.from_json("{")


def test_no_infinity_is_written(dispatch):
    bad = replace(dispatch.document, totals={"fuel_l": float("inf")})
    with pytest.raises(ValueError):
        bad.to_json()


def test_a_fields_holes_are_kept_and_a_field_without_has_no_key(dispatch):
    """A pond inside a field goes through plan.json and back; fields without holes are
    written as before (no ``holes`` key), so that their plans keep their ids."""
    doc = dispatch.document
    fid, field = next(iter(doc.fields.items()))
    lon, lat = field.polygon[0]
    pond = ((lon, lat), (lon + 1e-4, lat), (lon + 1e-4, lat + 1e-4), (lon, lat))
    with_pond = replace(doc, fields={**doc.fields, fid: replace(field, holes=(pond,))}).with_id()
    written = json.loads(with_pond.to_json())
    assert written["fields"][fid]["holes"] == [[list(p) for p in pond]]
    assert all("holes" not in f for k, f in written["fields"].items() if k != fid)
    again = PlanDocument.from_json(with_pond.to_json())
    assert again == with_pond and again.fields[fid].rings == (field.polygon, pond)
    assert with_pond.plan_id != doc.plan_id
    assert "holes" not in json.loads(doc.to_json())["fields"][fid]
