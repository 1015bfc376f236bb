"""Fuzzing the farm readers of other formats (planner/farm_files.py): random bytes under
every name a reader is chosen by, and ISO 11783-10 TaskData with attributes replaced and
elements removed. Only GeometryError, naming the file, may come out."""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from fuzz.test_fuzz_loaders import FUZZ, base_farm
from helpers.farm_formats import write_isoxml
from hypothesis import event, given
from hypothesis import strategies as st

from planner.errors import PlannerError
from planner.farm import load_farm

SUFFIXES = [".kml", ".kmz", ".gpkg", ".zip", ".shp", ".xml", ".gml"]


def refused_or_loaded(path: Path) -> None:
    try:
        load_farm(path)
    except PlannerError as exc:
        assert str(path) in str(exc)  # the message names the file
        event("farm refused")
    else:
        event("farm loaded")


@FUZZ
@given(data=st.binary(max_size=300), suffix=st.sampled_from(SUFFIXES))
def test_every_reader_takes_any_bytes(data, suffix):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"farm{suffix}"
        path.write_bytes(data)
        refused_or_loaded(path)


def base_taskdata() -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        return write_isoxml(base_farm()["features"], Path(tmp) / "TASKDATA.XML").read_bytes()


BASE = base_taskdata()
VALUES = st.one_of(
    st.sampled_from(["1", "2", "3", "11", "0", "", "PFD1", "44.0", "87.3", "-91", "nan", "1e999"]),
    st.text(max_size=8),
)


@st.composite
def mutated_taskdata(draw: st.DrawFn) -> bytes:
    root = ET.fromstring(BASE)
    for _ in range(draw(st.integers(1, 4))):
        elements = list(root.iter())
        element = draw(st.sampled_from(elements))
        action = draw(st.integers(0, 2))
        if action == 0 and element.attrib:
            key = draw(st.sampled_from(sorted(element.attrib)))
            element.set(key, draw(VALUES))
        elif action == 1 and element.attrib:
            del element.attrib[draw(st.sampled_from(sorted(element.attrib)))]
        else:  # an element removed (not the root)
            parent = next((p for p in root.iter() if element in list(p)), None)
            if parent is not None:
                parent.remove(element)
    return ET.tostring(root, encoding="utf-8")


@FUZZ
@given(data=mutated_taskdata())
def test_the_isoxml_reader_raises_only_geometry_errors(data):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "TASKDATA.XML"
        path.write_bytes(data)
        refused_or_loaded(path)


def test_the_base_taskdata_loads():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "TASKDATA.XML"
        path.write_bytes(BASE)
        farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["PFD1", "PFD2"] and len(farm.gates) == 1
