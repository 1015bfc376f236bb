"""Scenario and fleet files: every bad file refused, naming the file and the key at fault.

Unknown keys at every table level (with the nearest known key), exact types (a bool is not a
number), the bounds of :data:`dispatcher.config.scenario.LIMITS`, and the command line's
exit code 2 for them.
"""

import argparse
import copy
import json
import math
import re
import subprocess
import sys
import time
import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from dispatcher.cli.main import main
from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import (
    LIMITS,
    OTHER_UNITS,
    SOLVER_KEYS,
    WATCH_KEYS,
    SolverSettings,
    WatchSettings,
    farm_id_for,
    load_scenario,
)
from planner.choices import DEFAULT_ALGORITHM

REPO = Path(__file__).resolve().parents[2]
DATA = REPO / "tests" / "data"


def machine(
    ident: str, sysid: int, kind: str = "servo", channel: int = 9, width: float = 8.0
) -> dict[str, Any]:
    return {
        "id": ident,
        "system_id": sysid,
        "working_width_m": width,
        "min_turn_radius_m": 0.0,
        "capacity_m2h": int(width * 5000),
        "work_speed_kmh": 5.0,
        "road_speed_kmh": 15,
        "turn_time_h": 0.001,
        "road_fuel_lh": 3.0,
        "work_fuel_lh": 7.0,
        "implement": {"kind": kind, "channel": channel},
    }


def scenario_doc() -> dict[str, Any]:
    """tests/data/tiny.toml as a dict, with every table the loader reads."""
    return {
        "farm_id": "tiny",
        "farm": str(DATA / "tiny-farm.geojson"),
        "machines": ["v1", "v2"],
        "machine": [machine("v1", 11), machine("v2", 12, "relay", 1, 6.0)],
        "solver": {
            "algorithm": DEFAULT_ALGORITHM,
            "time_limit_s": 1.0,
            "generations": 100,
            "seed": 3,
        },
        "dispatcher": {"lost_after_s": 5.0, "stall_after_s": 60.0, "lost_grace_s": 30.0},
    }


def toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return repr(value)


def to_toml(doc: dict[str, Any]) -> str:
    """Enough of a TOML writer for these files: scalars, tables, [[machine]] with subtables."""
    lines = []
    tables = {}
    for key, value in doc.items():
        if isinstance(value, dict) or (
            isinstance(value, list) and value and all(isinstance(v, dict) for v in value)
        ):
            tables[key] = value
        else:
            lines.append(f"{key} = {toml_value(value)}")

    def table(name: str, body: dict[str, Any], header: str) -> None:
        lines.append(header)
        subs = {}
        for key, value in body.items():
            if isinstance(value, dict):
                subs[key] = value
            else:
                lines.append(f"{key} = {toml_value(value)}")
        for key, value in subs.items():
            table(f"{name}.{key}", value, f"[{name}.{key}]")

    for name, value in tables.items():
        for body in value if isinstance(value, list) else [value]:
            table(name, body, f"[[{name}]]" if isinstance(value, list) else f"[{name}]")
    return "\n".join(lines) + "\n"


def write(tmp_path: Path, doc: dict[str, Any], name: str = "scenario.toml") -> Path:
    path = tmp_path / name
    path.write_text(to_toml(doc))
    return path


def refused(tmp_path: Path, doc: dict[str, Any]) -> str:
    path = write(tmp_path, doc)
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    message = str(err.value)
    assert str(path) in message  # names the file
    return message


def test_a_scenario_without_a_farm_key_plans_the_farm_given_with_fields(tmp_path):
    """``--fields FARM`` stands for the scenario's farm; a scenario kept for many farms need
    not name one (it was refused: missing key 'farm'). Without ``--fields`` it must."""
    doc = scenario_doc()
    del doc["farm"]
    scenario = load_scenario(write(tmp_path, doc), DATA / "tiny-farm.geojson")
    assert scenario.farm_id == "tiny-farm" and len(scenario.farm.fields) > 0
    message = refused(tmp_path, doc)
    assert "missing key 'farm'" in message and "--fields" in message


def test_the_test_writer_reproduces_tiny_toml(tmp_path):
    scenario = load_scenario(write(tmp_path, scenario_doc()))
    tiny = load_scenario(DATA / "tiny.toml")
    assert scenario.vehicles == tiny.vehicles and scenario.solver == tiny.solver


def scenario_files() -> list[Path]:
    files = sorted((REPO / "config").glob("*.toml")) + sorted(DATA.glob("*.toml"))
    return [f for f in files if "farm" in tomllib.loads(f.read_text())]


@pytest.mark.parametrize("path", scenario_files(), ids=lambda p: p.name)
def test_every_shipped_scenario_loads(path):
    scenario = load_scenario(path)
    assert scenario.vehicles and scenario.farm.fields


def test_the_key_lists_match_the_settings():
    assert tuple(f.name for f in fields(SolverSettings)) == SOLVER_KEYS
    assert tuple(f.name for f in fields(WatchSettings)) == WATCH_KEYS


# --- unknown keys, at every table level --------------------------------------------------


def rename(table: dict[str, Any], old: str, new: str) -> None:
    table[new] = table.pop(old)


UNKNOWN = {
    "top level": (
        lambda d: rename(d, "machines", "machnes"),
        "unknown key(s) in the top level: machnes (did you mean 'machines'?)",
    ),
    "[[machine]]": (
        lambda d: rename(d["machine"][1], "work_speed_kmh", "work_sped_kmh"),
        "machine 'v2': unknown key(s) in [[machine]]: work_sped_kmh "
        "(did you mean 'work_speed_kmh'?)",
    ),
    "[machine.implement]": (
        lambda d: d["machine"][0]["implement"].update(pwm_dwon=1900),
        "machine 'v1': unknown key(s) in [machine.implement]: pwm_dwon (did you mean 'pwm_down'?)",
    ),
    "[solver]": (
        lambda d: rename(d["solver"], "time_limit_s", "time_limt_s"),
        "unknown key(s) in [solver]: time_limt_s (did you mean 'time_limit_s'?)",
    ),
    "[dispatcher]": (
        lambda d: rename(d["dispatcher"], "lost_grace_s", "lost_grace"),
        "unknown key(s) in [dispatcher]: lost_grace (did you mean 'lost_grace_s'?)",
    ),
    "no suggestion": (
        lambda d: d["solver"].update(colour="red"),
        "unknown key(s) in [solver]: colour; known keys: algorithm, objective",
    ),
    "machine key after its implement table": (
        lambda d: d["machine"][0]["implement"].update(
            min_turn_radius_m=d["machine"][0].pop("min_turn_radius_m")
        ),
        "machine 'v1': unknown key(s) in [machine.implement]: min_turn_radius_m (it belongs "
        "in [[machine]], above its [machine.implement] table)",
    ),
    "top-level key under [solver]": (
        lambda d: d["solver"].update(machines=d.pop("machines")),
        "unknown key(s) in [solver]: machines (it belongs at the top of the file",
    ),
}


@pytest.mark.parametrize("case", sorted(UNKNOWN))
def test_unknown_keys_are_refused_with_the_nearest_known_one(tmp_path, case):
    change, needle = UNKNOWN[case]
    doc = scenario_doc()
    change(doc)
    assert needle in refused(tmp_path, doc)


def test_unknown_key_in_a_fleet_file_names_the_fleet_file(tmp_path):
    doc = scenario_doc()
    fleet = {"machines": doc.pop("machine")}  # [[machines]]: a misspelled [[machine]]
    del doc["machines"]
    doc["fleet"] = "fleet.toml"
    write(tmp_path, fleet, "fleet.toml")
    path = write(tmp_path, doc)
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert (
        f"{tmp_path / 'fleet.toml'}: unknown key(s) in the top level of a fleet file: machines "
        "(did you mean 'machine'?)"
    ) in str(err.value)


def test_a_misspelled_machine_list_does_not_plan_with_the_whole_fleet(tmp_path, capsys):
    doc = scenario_doc()
    doc["machine"].append(machine("v3", 13))
    doc["machines"] = ["v1"]
    rename(doc, "machines", "machine_ids")
    path = write(tmp_path, doc)
    out = tmp_path / "out"
    assert main(["plan", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "scenario.toml: unknown key(s) in the top level: machine_ids" in err
    assert not out.exists()


# --- types: exact ------------------------------------------------------------------------


TYPES = {
    "bool for a float": (
        lambda d: d["machine"][0].update(work_speed_kmh=True),
        "machine 'v1': key 'work_speed_kmh' must be a number, not true",
    ),
    "string for a float": (
        lambda d: d["machine"][1].update(road_fuel_lh="3.0"),
        "machine 'v2': key 'road_fuel_lh' must be a number, not \"3.0\"",
    ),
    "float for an int": (
        lambda d: d["machine"][0].update(system_id=11.0),
        "machine 'v1': key 'system_id' must be a whole number, not 11.0",
    ),
    "bool for an int": (
        lambda d: d["machine"][1]["implement"].update(channel=True),
        "machine 'v2': key 'implement.channel' must be a whole number, not true",
    ),
    "float pwm": (
        lambda d: d["machine"][0]["implement"].update(pwm_up=1100.5),
        "machine 'v1': key 'implement.pwm_up' must be a whole number, not 1100.5",
    ),
    "bool seed": (
        lambda d: d["solver"].update(seed=False),
        "key 'solver.seed' must be a whole number, not false",
    ),
    "float generations": (
        lambda d: d["solver"].update(generations=100.0),
        "key 'solver.generations' must be a whole number, not 100.0",
    ),
    "number for a string": (
        lambda d: d["solver"].update(algorithm=1),
        "key 'solver.algorithm' must be a string, not 1",
    ),
    "bool seconds": (
        lambda d: d["dispatcher"].update(lost_after_s=True),
        "key 'dispatcher.lost_after_s' must be a number, not true",
    ),
    "nan": (
        lambda d: d["machine"][0].update(work_fuel_lh=math.nan),
        "machine 'v1': work_fuel_lh = nan is not a finite number",
    ),
    "inf": (
        lambda d: d["solver"].update(time_limit_s=math.inf),
        "solver.time_limit_s = inf is not a finite number",
    ),
    "table for a table array": (
        lambda d: d.update(machine=["v1", "v2"]),
        '[[machine]] #1 must be a table, not "v1"',
    ),
    "number for a table": (
        lambda d: d.__setitem__("solver", 3),
        "[solver] must be a table, not 3",
    ),
    "number for the fleet file": (
        lambda d: (d.pop("machine"), d.update(fleet=1)),
        "key 'fleet' must name a fleet file, not 1",
    ),
}


@pytest.mark.parametrize("case", sorted(TYPES))
def test_types_are_exact(tmp_path, case):
    change, needle = TYPES[case]
    doc = scenario_doc()
    change(doc)
    assert needle in refused(tmp_path, doc)


def test_an_integer_is_a_number(tmp_path):
    doc = scenario_doc()
    doc["machine"][0].update(working_width_m=8, work_fuel_lh=7, min_turn_radius_m=0)
    doc["solver"]["time_limit_s"] = 2
    scenario = load_scenario(write(tmp_path, doc))
    v1 = scenario.vehicles[0].machine
    assert (v1.working_width_m, v1.work_fuel_lh, v1.min_turn_radius_m) == (8.0, 7.0, 0.0)
    assert isinstance(v1.working_width_m, float)
    assert scenario.solver.time_limit_s == 2.0


@pytest.mark.parametrize(("key", "value"), [("makespan_slack", 0.01), ("finish_within_h", 40.0)])
def test_a_makespan_cap_is_read_and_refused_where_it_cannot_apply(tmp_path, key, value):
    """``[solver] makespan_slack`` (the hybrid's ε-lexicographic makespan) and
    ``finish_within_h`` (its deadline): the bounds are checked with the others (LIMITS),
    here the algorithm and the objective they need."""
    doc = scenario_doc()
    doc["solver"].update({key: value})
    assert getattr(load_scenario(write(tmp_path, doc)).solver, key) == value
    assert getattr(load_scenario(write(tmp_path, scenario_doc())).solver, key) == 0.0
    doc["solver"].update(algorithm="ighoa")
    assert f'solver.{key} needs solver.algorithm = "hybrid", not "ighoa"' in refused(tmp_path, doc)
    doc["solver"].update(algorithm="hybrid", objective="distance")
    message = refused(tmp_path, doc)
    assert f'solver.{key} applies to solver.objective = "makespan" only' in message
    doc["solver"].update({key: 0})  # none: any algorithm, any objective
    assert getattr(load_scenario(write(tmp_path, doc)).solver, key) == 0.0


def test_a_makespan_slack_and_a_deadline_together_are_refused(tmp_path):
    doc = scenario_doc()
    doc["solver"].update(makespan_slack=0.01, finish_within_h=40.0)
    message = refused(tmp_path, doc)
    assert "solver.makespan_slack and solver.finish_within_h both cap the makespan" in message
    doc["solver"].pop("finish_within_h")  # the same from the command line (--finish-within)
    with_slack = load_scenario(write(tmp_path, doc))
    with pytest.raises(ConfigError, match="--finish-within: solver.makespan_slack and solver"):
        with_slack.with_deadline(40.0)
    assert with_slack.with_deadline(0.0).solver.finish_within_h == 0.0


@pytest.mark.parametrize(("key", "value"), [("makespan_slack", 0.01), ("finish_within_h", 40.0)])
def test_another_objective_from_the_command_line_is_checked_as_in_the_file(tmp_path, key, value):
    """``--objective``: a name the file would refuse is refused, and so is an objective the
    file's makespan cap cannot apply to (the cap was dropped without a word)."""
    doc = scenario_doc()
    doc["solver"].update({key: value})
    scenario = load_scenario(write(tmp_path, doc))
    assert scenario.with_objective("makespan").solver == scenario.solver
    for name in ("distance", "fuel", "minmax"):
        with pytest.raises(ConfigError, match=f"--objective {name}: the scenario's solver.{key}"):
            scenario.with_objective(name)
    with pytest.raises(ConfigError, match="--objective makespam: unknown objective"):
        scenario.with_objective("makespam")
    plain = load_scenario(write(tmp_path, scenario_doc()))
    assert plain.with_objective("fuel").solver.objective == "fuel"


# --- bounds ------------------------------------------------------------------------------


def where_is(limit_key: str) -> tuple[tuple[Any, ...], str, str]:
    """Where the number of a ``LIMITS`` key goes in the document, the label messages give
    it, and what they say it belongs to."""
    if limit_key in SOLVER_KEYS:
        return ("solver", limit_key), f"solver.{limit_key}", ""
    if limit_key in WATCH_KEYS:
        return ("dispatcher", limit_key), f"dispatcher.{limit_key}", ""
    if limit_key == "channel (relay)":
        return ("machine", 1, "implement", "channel"), "implement.channel", "machine 'v2': "
    if limit_key == "channel (servo)":
        return ("machine", 0, "implement", "channel"), "implement.channel", "machine 'v1': "
    if limit_key in ("pwm_down", "pwm_up"):
        return ("machine", 0, "implement", limit_key), f"implement.{limit_key}", "machine 'v1': "
    return ("machine", 0, limit_key), limit_key, "machine 'v1': "


def put(doc: dict[str, Any], path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    doc = copy.deepcopy(doc)
    node = doc
    for step in path[:-1]:
        node = node[step]
    node[path[-1]] = value
    if path[-1] in OTHER_UNITS:  # in place of the parameter's own key
        del node[OTHER_UNITS[path[-1]].param]
    return doc


def beyond(limit_key: str) -> tuple[Any, Any]:
    """A value below the lower bound and one above the upper, of the key's type."""
    limit = LIMITS[limit_key]
    if isinstance(limit.low, int) and isinstance(limit.high, int):
        return limit.low - 1, limit.high + 1
    return (limit.low / 2 if limit.low > 0 else -1.0), limit.high * 1.5


@pytest.mark.parametrize("limit_key", sorted(LIMITS))
def test_every_bound_is_enforced_naming_file_and_key(tmp_path, limit_key):
    path, label, owner = where_is(limit_key)
    low, high = beyond(limit_key)
    message = refused(tmp_path, put(scenario_doc(), path, high))
    assert f"{owner}{label} = {toml_value(high)} is above" in message
    message = refused(tmp_path, put(scenario_doc(), path, low))
    assert f"{owner}{label}" in message
    assert any(word in message for word in ("is below", "must not be negative", "positive"))


def room_for(doc: dict[str, Any], path: tuple[Any, ...]) -> dict[str, Any]:
    """``doc`` with the machine at ``path`` (if any) given a width and work speed that
    cover any capacity, or a capacity any width and speed cover, whichever ``path`` sets."""
    if path[0] != "machine":
        return doc
    machine = doc["machine"][path[1]]
    if path[-1] in ("capacity_m2h", "capacity_hah"):
        machine.update(working_width_m=LIMITS["working_width_m"].high, work_speed_kmh=40.0)
    elif path[-1] in ("working_width_m", "work_speed_kmh"):
        machine["capacity_m2h"] = LIMITS["capacity_m2h"].low
    return doc


@pytest.mark.parametrize("limit_key", sorted(LIMITS))
def test_the_bounds_themselves_are_allowed(tmp_path, limit_key):
    path, _, _ = where_is(limit_key)
    limit = LIMITS[limit_key]
    for value in (limit.low, limit.high):
        doc = room_for(put(scenario_doc(), path, value), path)
        if limit_key == "system_id" and value == 12:
            continue  # v2's
        load_scenario(write(tmp_path, doc))


def test_a_capacity_the_implement_cannot_reach_at_its_work_speed_is_refused(tmp_path):
    # 6 m at 5 km/h covers 3 ha/h: 10 ha/h planned, the swaths would take 3.3 times as long.
    doc = scenario_doc()
    doc["machine"][0].update(working_width_m=6.0, work_speed_kmh=5.0, capacity_m2h=100_000)
    message = refused(tmp_path, doc)
    assert "machine 'v1': capacity_m2h = 10 ha/h is more than the implement covers" in message
    assert "6 m x 5 km/h = 3 ha/h" in message
    doc["machine"][0].pop("capacity_m2h")
    doc["machine"][0]["capacity_hah"] = 3.02  # rounding: within 1 %
    assert load_scenario(write(tmp_path, doc)).vehicles[0].machine.capacity_m2h == 30_200.0
    doc["machine"][0]["capacity_hah"] = 3.1
    assert "machine 'v1': capacity_hah = 3.1 ha/h is more" in refused(tmp_path, doc)


ABSURD = {
    "work speed of a million km/h": (
        ("machine", 1, "work_speed_kmh"),
        1000000,
        "machine 'v2': work_speed_kmh = 1000000 is above 40 km/h (the most a tractor could "
        "work at)",
    ),
    "fuel rate of 1e308": (
        ("machine", 0, "road_fuel_lh"),
        1e308,
        "machine 'v1': road_fuel_lh = 1e+308 is above 200 L/h",
    ),
    "1 mm working width": (
        ("machine", 0, "working_width_m"),
        0.001,
        "machine 'v1': working_width_m = 0.001 is below 0.5 m",
    ),
    "negative turning radius": (
        ("machine", 0, "min_turn_radius_m"),
        -2.0,
        "machine 'v1': min_turn_radius_m must not be negative",
    ),
    "zero seconds": (
        ("dispatcher", "lost_after_s"),
        0,
        "dispatcher.lost_after_s must be a positive number",
    ),
}


@pytest.mark.parametrize("case", sorted(ABSURD))
def test_absurd_values_are_refused(tmp_path, case):
    path, value, needle = ABSURD[case]
    assert needle in refused(tmp_path, put(scenario_doc(), path, value))


# --- other checks of the same tables ------------------------------------------------------


def test_a_relay_has_no_pwm(tmp_path):
    doc = scenario_doc()
    doc["machine"][1]["implement"]["pwm_down"] = 1900
    assert "machine 'v2': implement.pwm_down: a relay has no PWM values" in refused(tmp_path, doc)


def test_the_machine_list_names_each_machine_once(tmp_path):
    doc = scenario_doc()
    doc["machines"] = ["v1", "v1"]
    assert "key 'machines' names machine 'v1' twice" in refused(tmp_path, doc)
    doc["machines"] = ["v1", "V2"]
    assert "unknown machine 'V2' (did you mean 'v2'?)" in refused(tmp_path, doc)


def test_a_wrong_array_is_shown_as_written(tmp_path):
    # "must be a list of machine ids, not an array": the message said what it refused.
    doc = scenario_doc()
    doc["machines"] = ["v1", 3]
    assert "key 'machines' must be a list of machine ids, not [\"v1\", 3]" in refused(tmp_path, doc)
    doc = scenario_doc()
    doc["garage"] = [10.0, 52.0, 100]
    assert "key 'garage' must be [longitude, latitude] in degrees, not [10.0, 52.0, 100]" in (
        refused(tmp_path, doc)
    )


def naming(key: str, value: str) -> dict[str, Any]:
    """The scenario with its ``farm`` or ``fleet`` (in place of its machines) ``value``."""
    doc = scenario_doc()
    if key == "fleet":
        del doc["machine"], doc["machines"]
    doc[key] = value
    return doc


@pytest.mark.parametrize("key", ["farm", "fleet"])
def test_a_bad_file_a_key_names_is_said_with_the_scenario_and_key(tmp_path, key):
    # "../basic.geojson: not valid TOML", of a file the user had not named on the command line.
    (tmp_path / "wrong.txt").write_text("= not this\n")
    message = refused(tmp_path, naming(key, "wrong.txt"))
    assert message.startswith(str(tmp_path / "wrong.txt"))
    assert f"read for {tmp_path / 'scenario.toml'} (the {key} its key '{key}' names)" in message


def test_a_copied_machine_is_named_a_duplicate_not_a_system_id_clash(tmp_path):
    doc = scenario_doc()
    doc["machine"].append(dict(doc["machine"][0]))
    assert "machine 'v1': duplicate machine id" in refused(tmp_path, doc)


@pytest.mark.parametrize("ident", [".", "..", ".hidden", "-x"])
def test_an_id_that_a_path_or_a_command_line_would_misread_is_refused(tmp_path, ident):
    """Ids name folders and files (the store, the mission files): "." and ".." wrote the
    state database outside its folder, ".x" a file that file dialogs hide."""
    doc = scenario_doc()
    doc["farm_id"] = ident
    assert f'farm_id "{ident}" must be letters, digits' in refused(tmp_path, doc)
    doc = scenario_doc()
    doc["machine"][0]["id"] = doc["machines"][0] = ident
    message = refused(tmp_path, doc)
    assert "key 'id' must be letters, digits, '_', '-' or '.', and begin with a letter" in message
    doc["machine"][0]["id"] = doc["machines"][0] = "v1.a-b_c"
    assert load_scenario(write(tmp_path, doc)).vehicles[0].id == "v1.a-b_c"


def test_a_farm_id_from_a_file_name_never_begins_with_a_dot(tmp_path):
    for name, expected in ((".farm.toml", "farm"), ("...toml", "farm"), ("-x-.toml", "x")):
        assert farm_id_for(tmp_path / name) == expected


@pytest.mark.parametrize("key", ["farm", "fleet"])
def test_an_empty_file_name_is_named(tmp_path, key):
    """`farm = ""` was read as the scenario's folder ("'.' not recognized as ...")."""
    assert f"key '{key}' must name " in refused(tmp_path, naming(key, ""))


def test_a_scenario_without_a_fleet_says_how_to_give_one(tmp_path):
    doc = scenario_doc()
    del doc["machine"], doc["machines"]
    assert "no fleet: give 'fleet' (a fleet file) or [[machine]] tables" in refused(tmp_path, doc)


def test_missing_implement_keys_are_named(tmp_path):
    doc = scenario_doc()
    del doc["machine"][0]["implement"]["kind"]
    assert "machine 'v1': missing key implement.kind" in refused(tmp_path, doc)
    doc = scenario_doc()
    del doc["machine"][0]["implement"]["channel"]
    assert "machine 'v1': missing key implement.channel" in refused(tmp_path, doc)


# --- the command line ---------------------------------------------------------------------


def test_plan_with_one_fields_lat_lon_swapped_exits_2_naming_the_field(tmp_path):
    farm = json.loads((DATA / "tiny-farm.geojson").read_text())
    for feature in farm["features"]:
        if feature["properties"] == {"kind": "field", "id": "B"}:
            ring = feature["geometry"]["coordinates"][0]
            feature["geometry"]["coordinates"][0] = [[lat, lon] for lon, lat in ring]
    (tmp_path / "farm.geojson").write_text(json.dumps(farm))
    doc = scenario_doc()
    doc["farm"] = "farm.geojson"
    path = write(tmp_path, doc)
    out = tmp_path / "out"
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "dispatcher.cli", "plan", str(path), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=5,
        cwd=REPO,
    )
    assert time.monotonic() - started < 5
    assert done.returncode == 2, done.stderr
    assert f"{tmp_path / 'farm.geojson'}: field 'B'" in done.stderr
    assert "look swapped" in done.stderr
    assert "Traceback" not in done.stderr
    assert not out.exists() or not any(out.iterdir())


# --- units -------------------------------------------------------------------------------


def test_a_farmers_units_give_the_same_machine_as_the_papers(tmp_path):
    paper = load_scenario(write(tmp_path, scenario_doc(), "paper.toml")).vehicles[0].machine
    doc = scenario_doc()
    v1 = doc["machine"][0]
    v1["capacity_hah"] = v1.pop("capacity_m2h") / 10_000  # 4 ha/h
    v1["turn_time_s"] = v1.pop("turn_time_h") * 3600  # 3.6 s
    farmer = load_scenario(write(tmp_path, doc, "farmer.toml")).vehicles[0].machine
    assert farmer.capacity_m2h == pytest.approx(paper.capacity_m2h)
    assert farmer.turn_time_h == pytest.approx(paper.turn_time_h)


def test_one_figure_in_two_units_is_refused(tmp_path):
    doc = scenario_doc()
    doc["machine"][0]["turn_time_s"] = 4
    assert "machine 'v1': give turn_time_h or turn_time_s, not both" in refused(tmp_path, doc)
    del doc["machine"][0]["turn_time_s"], doc["machine"][0]["capacity_m2h"]
    assert "missing key(s) capacity_m2h or capacity_hah" in refused(tmp_path, doc)


@pytest.mark.parametrize(
    "endpoint", ["garbage", "tcp/127.0.0.1:99999", "tcp/127.0.0.1", "pigeon/127.0.0.1:7447"]
)
def test_a_bad_endpoint_is_named_before_anything_is_planned(endpoint):
    """Zenoh refused a bad --listen only when the session opened, after planning and
    storing a run, with a traceback."""
    import argparse

    from dispatcher.config.errors import ConfigError
    from dispatcher.link import wire

    parser = argparse.ArgumentParser()
    wire.add_zenoh_arguments(parser)
    for flag in ("--listen", "--connect"):
        args = parser.parse_args([flag, endpoint])
        with pytest.raises(ConfigError, match=f"{flag} '{re.escape(endpoint)}': an endpoint is"):
            wire.zenoh_options(args, default_listen=flag == "--listen")
    ok = parser.parse_args(["--listen", "tcp/[::1]:0", "--connect", "tls/farm.example:7447"])
    wire.zenoh_options(ok, default_listen=True)


def test_plain_tcp_beyond_loopback_is_refused_whoever_asks_for_it(tmp_path):
    """--cfg 'listen/endpoints:[...]' and a --zenoh-config file (its own endpoints, or none:
    Zenoh's default of every interface) got round --listen's rule: plain TCP on 0.0.0.0
    without --insecure-listen, silently (review)."""
    from dispatcher.config.errors import ConfigError
    from dispatcher.link import wire

    cfg = ('listen/endpoints:["tcp/0.0.0.0:7447"]',)
    with pytest.raises(ConfigError, match=r"--cfg listens on tcp/0\.0\.0\.0:7447 without TLS"):
        wire.ZenohOptions(extra=cfg).config()
    wire.ZenohOptions(extra=cfg, insecure_listen=True).config()
    file = tmp_path / "zenoh.json5"
    file.write_text('{mode: "peer"}')
    with pytest.raises(ConfigError, match=r"--zenoh-config .*zenoh\.json5 listens on tcp/\[::\]"):
        wire.ZenohOptions(config_file=str(file)).config()
    file.write_text('{listen: {endpoints: ["tcp/127.0.0.1:0"]}}')
    conf = wire.ZenohOptions(config_file=str(file)).config()  # loopback: fine
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    # The file's endpoints are its own, not replaced by the default listener.
    parser = argparse.ArgumentParser()
    wire.add_zenoh_arguments(parser)
    args = parser.parse_args(["--zenoh-config", str(file)])
    assert wire.zenoh_options(args, default_listen=True).listen == ()


def test_zenoh_refusing_its_configuration_or_a_port_is_named_not_a_traceback(tmp_path):
    """A --zenoh-config file that is not there or not JSON5, a --cfg value Zenoh refuses,
    and a listener's port in use: a ConfigError (exit 2) naming the option or endpoint."""
    import socket

    from dispatcher.config.errors import ConfigError
    from dispatcher.link import wire

    missing = tmp_path / "none.json5"
    with pytest.raises(ConfigError, match=f"--zenoh-config {re.escape(str(missing))}: No such"):
        wire.ZenohOptions(config_file=str(missing)).config()
    with pytest.raises(ConfigError, match=r"--cfg mode:\[1: not JSON5 \(expected"):
        wire.ZenohOptions(extra=("mode:[1",)).config()
    with pytest.raises(ConfigError, match="--cfg wants KEY:VALUE"):
        wire.ZenohOptions(extra=("mode",)).config()
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        endpoint = f"tcp/127.0.0.1:{taken.getsockname()[1]}"
        with pytest.raises(ConfigError, match=f"on {endpoint}: .*Address already in use"):
            wire.ZenohOptions(listen=(endpoint,)).open()
        # Said before anything is planned (serve checks it first).
        with pytest.raises(ConfigError, match=f"--listen {endpoint}: Address already in use"):
            wire.ZenohOptions(listen=(endpoint,)).check_listen_free()
    wire.ZenohOptions(listen=(endpoint,)).check_listen_free()  # free again
