"""Fuzzing the loaders: the scenario loader (dispatcher.config.scenario.load_scenario) on
random TOML built from its valid keys with random values and random extra keys, and the
farm loader (planner.farm.load_farm) on random GeoJSON-ish JSON and random bytes. Only the
project's documented errors may come out — ConfigError (a DispatcherError) from the
scenario loader, GeometryError (a PlannerError) from the farm loader — never another
exception.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from dispatcher.config import scenario as sc
from dispatcher.config.errors import ConfigError
from planner.errors import PlannerError
from planner.farm import load_farm

UNFILTERED = os.environ.get("FUZZ_UNFILTERED") == "1"
FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

# ----------------------------------------------------------------------------- values


def _scalars(big: bool = True) -> st.SearchStrategy[Any]:
    ints = st.one_of(st.integers(-5, 70_000), st.integers(-(2**63), 2**63 - 1))
    if big:  # JSON has no integer limit
        ints = st.one_of(ints, st.sampled_from([10**400, -(10**400)]))
    return st.one_of(
        st.none(),
        st.booleans(),
        ints,
        st.floats(allow_nan=True, allow_infinity=True),
        st.sampled_from([0.0, -0.0, 1e-300, 1e308, 87.3, 44.0, 90.0, 180.0]),
        st.text(max_size=12),
        st.sampled_from(["field", "garage", "road", "gate", "Polygon", "Point", "servo", ""]),
    )


json_values = st.recursive(
    _scalars(),
    lambda inner: st.one_of(
        st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=8), inner, max_size=5)
    ),
    max_leaves=20,
)

# ----------------------------------------------------------------------------- farm files


def square(lon: float, lat: float, d: float = 0.002) -> list[list[float]]:
    return [[lon, lat], [lon + d, lat], [lon + d, lat + d], [lon, lat + d], [lon, lat]]


def base_farm() -> dict[str, Any]:
    """A valid farm: a garage, two fields, a road and a gate."""
    return {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"kind": "garage"},
                "geometry": {"type": "Point", "coordinates": [87.299, 43.999]},
            },
            {
                "type": "Feature",
                "properties": {"kind": "field", "id": "F1", "headland_passes": 1},
                "geometry": {"type": "Polygon", "coordinates": [square(87.300, 44.000)]},
            },
            {
                "type": "Feature",
                "properties": {"kind": "field", "id": "F2", "work_angle_deg": 30},
                "geometry": {"type": "Polygon", "coordinates": [square(87.303, 44.000)]},
            },
            {
                "type": "Feature",
                "properties": {"kind": "road", "id": "lane"},
                "geometry": {
                    "type": "LineString",
                    "coordinates": [[87.299, 43.999], [87.305, 43.999]],
                },
            },
            {
                "type": "Feature",
                "properties": {"kind": "gate", "field": "F1"},
                "geometry": {"type": "Point", "coordinates": [87.301, 44.000]},
            },
        ],
    }


def paths_of(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every path (keys and indices) into ``doc``."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += paths_of(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += paths_of(v, (*prefix, i))
    return out


def set_at(doc: Any, path: tuple, value: Any) -> Any:
    if not path:
        return value
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = value
    return doc


@st.composite
def mutated_farm(draw: st.DrawFn) -> Any:
    """The valid farm with a few of its values replaced, keys added or removed."""
    doc = base_farm()
    for _ in range(draw(st.integers(1, 4))):
        paths = paths_of(doc)
        path = draw(st.sampled_from(paths))
        action = draw(st.integers(0, 3))
        if action == 0:
            doc = set_at(doc, path, draw(json_values))
        elif action == 1 and isinstance(_get(doc, path), dict):
            _get(doc, path)[draw(st.text(max_size=10))] = draw(json_values)
        elif action == 2 and path and isinstance(_get(doc, path[:-1]), dict):
            del _get(doc, path[:-1])[path[-1]]
        else:  # a number nudged: coordinates swapped, far, off
            value = _get(doc, path)
            if isinstance(value, float):
                doc = set_at(doc, path, draw(st.sampled_from([value * 2, -value, value + 40.0])))
    return doc


def _get(doc: Any, path: tuple) -> Any:
    for key in path:
        doc = doc[key]
    return doc


def load_farm_text(text: str | bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "farm.geojson"
        if isinstance(text, bytes):
            path.write_bytes(text)
        else:
            path.write_text(text)
        try:
            load_farm(path)
        except PlannerError as exc:
            assert str(path) in str(exc)  # the message names the file
            event(f"farm refused: {type(exc).__name__}")
        else:
            event("farm loaded")


def dumps(doc: Any) -> str:
    """JSON as a file may hold it: NaN and Infinity included (json.loads reads them)."""
    return json.dumps(doc)


HUGE = "1" + "0" * 5000  # an integer literal longer than Python's int() takes (4300 digits)

# Crashes fuzzing found in the loaders (fixed): each input is refused with the loader's
# error naming the file.
FARM_CRASHES = [
    pytest.param(b"\xff\xfe{}", id="farm not UTF-8: UnicodeDecodeError"),
    pytest.param(
        b'{"type": "FeatureCollection", "features": ' + HUGE.encode() + b"}",
        id="farm: 5000-digit integer: ValueError",
    ),
    pytest.param(
        json.dumps(base_farm()).replace("[87.299, 43.999]}", f"[{10**400}, 43.999]}}", 1),
        id="farm: a coordinate too big for a float: OverflowError",
    ),
    pytest.param(
        json.dumps(base_farm()).replace('"work_angle_deg": 30', f'"work_angle_deg": {10**400}'),
        id="farm: work_angle_deg too big for a float: OverflowError",
    ),
]


@pytest.mark.parametrize("text", FARM_CRASHES)
def test_inputs_that_once_crashed_the_farm_loader_are_refused(text):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "farm.geojson"
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        with pytest.raises(PlannerError, match=re.escape(str(path))):
            load_farm(path)


@FUZZ
@given(doc=st.one_of(mutated_farm(), json_values))
@example(doc=base_farm())
@example(doc={"type": "FeatureCollection", "features": [{"type": "Feature"}]})
def test_the_farm_loader_raises_only_geometry_errors(doc):
    load_farm_text(dumps(doc))


@FUZZ
@given(data=st.one_of(st.text(max_size=300).map(str.encode), st.binary(max_size=300)))
def test_the_farm_loader_takes_any_bytes(data):
    load_farm_text(data)


def test_the_valid_farm_loads():
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "farm.geojson"
        path.write_text(json.dumps(base_farm()))
        farm = load_farm(path)
    assert [f.id for f in farm.fields] == ["F1", "F2"] and len(farm.gates) == 1


# ----------------------------------------------------------------------------- scenarios


def toml_key(key: str) -> str:
    bare = key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key)
    return key if bare else toml_string(key)


def toml_string(s: str) -> str:
    out = []
    for c in s:
        if c in '"\\':
            out.append("\\" + c)
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04x}")
        elif 0xD800 <= ord(c) <= 0xDFFF:
            out.append("?")
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


def toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_doc(doc: dict[str, Any]) -> str:
    """A TOML document of ``doc``: scalars and inline tables at the top, then [tables]
    and [[arrays of tables]] (with their own sub-tables)."""
    lines: list[str] = []

    def table(name: str, body: dict[str, Any], header: str) -> None:
        lines.append(f"{header[0]}{name}{header[1]}")
        subs = []
        for k, v in body.items():
            if isinstance(v, dict) and v and k == "implement":
                subs.append((k, v))
            else:
                lines.append(f"{toml_key(k)} = {toml_value(v)}")
        for k, v in subs:
            table(f"{name}.{toml_key(k)}", v, ("[", "]"))

    tables = []
    for k, v in doc.items():
        if isinstance(v, dict) and k in ("solver", "dispatcher"):
            tables.append((k, v, False))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v) and k == "machine":
            tables.append((k, v, True))
        else:
            lines.append(f"{toml_key(k)} = {toml_value(v)}")
    for k, v, many in tables:
        for body in v if many else [v]:
            table(toml_key(k), body, ("[[", "]]") if many else ("[", "]"))
    return "\n".join(lines) + "\n"


toml_scalars = st.one_of(
    st.booleans(),
    st.integers(-(2**63), 2**63 - 1),
    st.integers(-3, 70_000),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.1, 0.5, 6.9, 10.0, 3600.0, 1e308]),
    st.text(max_size=10),
    st.sampled_from(["ighoa", "ga", "makespan", "distance", "servo", "relay", "t1", ""]),
)
toml_values = st.recursive(
    toml_scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)
VALID_MACHINE: dict[str, Any] = {
    "id": "t1",
    "system_id": 1,
    "working_width_m": 6.9,
    "min_turn_radius_m": 6.0,
    "capacity_m2h": 7000,
    "work_speed_kmh": 1.014,
    "road_speed_kmh": 10,
    "turn_time_h": 0.004,
    "road_fuel_lh": 3.0,
    "work_fuel_lh": 7.0,
    "implement": {"kind": "servo", "channel": 9, "pwm_down": 1900, "pwm_up": 1100},
}


@st.composite
def table_of(draw: st.DrawFn, keys: tuple[str, ...], valid: dict[str, Any]) -> dict[str, Any]:
    """``keys``, each mostly its valid value, now and then a random one or left out, and
    now and then a stray key (one of another table, a misspelt one, any)."""
    out: dict[str, Any] = {}
    for key in keys:
        choice = draw(st.integers(0, 19))
        if choice <= 15 and key in valid:
            out[key] = valid[key]
        elif choice <= 18:
            out[key] = draw(toml_values)
    if draw(st.integers(0, 7)) == 0:
        stray = st.sampled_from([*sc.TOP_KEYS, *sc.SOLVER_KEYS, "Working_Width_m", "x"])
        out[draw(st.one_of(stray, st.text(max_size=6)))] = draw(toml_values)
    return out


@st.composite
def scenario_doc(draw: st.DrawFn) -> dict[str, Any]:
    machine_keys = tuple(k for k in sc.MACHINE_KEYS if k != "implement")
    machines = []
    for k in range(draw(st.sampled_from([0, 1, 1, 2, 3]))):
        m = draw(table_of(machine_keys, {**VALID_MACHINE, "id": f"t{k + 1}", "system_id": k + 1}))
        if draw(st.integers(0, 4)):
            m["implement"] = draw(table_of(sc.IMPLEMENT_KEYS, VALID_MACHINE["implement"]))
        machines.append(m)
    valid_top = {"farm_id": "fuzz", "farm": "farm.geojson", "machines": ["t1"]}
    doc = draw(
        table_of(
            tuple(
                k
                for k in sc.TOP_KEYS
                if k not in ("machine", "fleet", "solver", "dispatcher", "keys")
            ),
            valid_top,
        )
    )
    doc.setdefault("farm", "farm.geojson")
    if machines:
        doc["machine"] = machines
    if draw(st.booleans()):
        doc["solver"] = draw(
            table_of(
                sc.SOLVER_KEYS,
                {"algorithm": "ighoa", "objective": "makespan", "time_limit_s": 1.0, "seed": 2},
            )
        )
    if draw(st.booleans()):
        doc["dispatcher"] = draw(
            table_of(sc.WATCH_KEYS, {"lost_after_s": 5.0, "stall_after_s": 60.0})
        )
    if not machines or draw(st.integers(0, 9)) == 0:  # a fleet file instead (or both)
        doc["fleet"] = draw(st.sampled_from(["fleet.toml", "fleet.toml", "missing.toml", 3]))
    return doc


def load_scenario_text(doc: dict[str, Any], fleet: str | None = None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "farm.geojson").write_text(json.dumps(base_farm()))
        (folder / "fleet.toml").write_text(fleet or toml_doc({"machine": [VALID_MACHINE]}))
        path = folder / "scenario.toml"
        path.write_text(toml_doc(doc))
        try:
            sc.load_scenario(path)
        except ConfigError as exc:
            assert tmp in str(exc)  # the message names the file
            event("scenario refused")
        except PlannerError:
            event("scenario refused (PlannerError)")  # also documented
        else:
            event("scenario loaded")


@FUZZ
@given(doc=scenario_doc())
@example(doc={"farm": "farm.geojson", "machine": [VALID_MACHINE]})
@example(doc={"farm": "farm.geojson", "fleet": "fleet.toml", "solver": {"seed": 2**63 - 1}})
def test_the_scenario_loader_raises_only_config_errors(doc):
    load_scenario_text(doc)


@FUZZ
@given(fleet=scenario_doc().map(lambda d: {"machine": d.get("machine", []), **d}))
def test_a_fleet_file_raises_only_config_errors(fleet):
    load_scenario_text({"farm": "farm.geojson", "fleet": "fleet.toml"}, toml_doc(fleet))


SCENARIO_CRASHES = [
    pytest.param(
        f'farm = "farm.geojson"\n[solver]\nseed = {HUGE}\n',
        id="scenario: 5000-digit integer: ValueError",
    ),
]


@pytest.mark.parametrize("text", SCENARIO_CRASHES)
def test_inputs_that_once_crashed_the_scenario_loader_are_refused(text):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scenario.toml"
        path.write_text(text)
        with pytest.raises(ConfigError):
            sc.load_scenario(path)


@FUZZ
@given(data=st.one_of(st.text(max_size=200).map(str.encode), st.binary(max_size=200)))
def test_the_scenario_loader_takes_any_bytes(data):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scenario.toml"
        path.write_bytes(data)
        with pytest.raises(ConfigError):
            sc.load_scenario(path)


def test_the_valid_scenario_loads():
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "farm.geojson").write_text(json.dumps(base_farm()))
        path = folder / "scenario.toml"
        path.write_text(toml_doc({"farm": "farm.geojson", "machine": [VALID_MACHINE]}))
        scenario = sc.load_scenario(path)
    assert [v.id for v in scenario.vehicles] == ["t1"]
