"""A scenario: which farm, which fleet, how to solve. Loaded from TOML and checked.

Keys are documented in config/README.md. Paths inside a scenario are relative to the
scenario file. Every error names the file and the key (or machine) at fault: an unknown key
(with the nearest known one), a value of the wrong type (a bool is not a number; an integer
is a number), a number outside :data:`LIMITS`.
"""

from __future__ import annotations

import argparse
import difflib
import hashlib
import logging
import math
import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from importlib.resources import files
from pathlib import Path
from typing import Any, Final

from dispatcher.config.errors import ConfigError
from planner.choices import ALGORITHMS, DEFAULT_ALGORITHM, MAX_SLACK, Objective
from planner.errors import PlannerError
from planner.farm import Farm, FarmOptions, load_farm
from planner.problem import Machine

logger = logging.getLogger(__name__)

DEMO_SCENARIO = Path(str(files("agrifleet_config") / "changji.toml"))
"""The demo farm's scenario, shipped with agrifleet (config/ in a checkout)."""

# Ids become Zenoh key segments and file names: nothing that either would misread, and
# no leading '.' or '-' ("." and ".." are folders, ".x" a hidden file, "-x" an option).
SAFE_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")
SAFE_ID_RULE = "letters, digits, '_', '-' or '.', and begin with a letter, digit or '_'"

MACHINE_PARAMS = (
    "working_width_m",
    "capacity_m2h",
    "road_speed_kmh",
    "work_speed_kmh",
    "turn_time_h",
    "road_fuel_lh",
    "work_fuel_lh",
)
# A capacity up to this much above width x work speed is taken as rounding (the paper's
# Table 6 machines, their speed set to capacity / width to 3 decimals, come out 0.05 % above).
CAPACITY_TOLERANCE: Final = 1.01
# Optional machine keys and their defaults: 0 m turning radius = the paper's turn model,
# a hop between swath ends costing turn_time_h.
OPTIONAL_MACHINE_PARAMS = {"min_turn_radius_m": 0.0}


@dataclass(frozen=True)
class OtherUnit:
    """A machine key that gives a parameter of :data:`MACHINE_PARAMS` in another unit (the
    unit is in the key's name): ``value * factor`` is the parameter in its own unit."""

    param: str
    factor: float
    unit: str


OTHER_UNITS: dict[str, OtherUnit] = {
    # What a farmer reads off a spec sheet or a field log, beside the paper's units.
    "capacity_hah": OtherUnit("capacity_m2h", 10_000.0, "ha/h"),
    "turn_time_s": OtherUnit("turn_time_h", 1.0 / 3600.0, "s"),
}
"""Keys a fleet file may use instead of a parameter's own key (one of the two, not both)."""


@dataclass(frozen=True)
class Limit:
    """The values a number may take: ``low`` to ``high`` (both allowed), and why."""

    low: float
    high: float
    unit: str  # "" for a count
    why_low: str
    why_high: str


LIMITS: dict[str, Limit] = {
    # [[machine]]: what a real tractor (or field robot) and its implement could be.
    "working_width_m": Limit(
        0.5,
        60.0,
        "m",
        "the narrowest implement swaths are planned for",
        "wider than any implement built: the widest sprayer booms are about 55 m",
    ),
    "capacity_m2h": Limit(
        100.0,
        2_400_000.0,
        "m²/h",
        "a 0.5 m robot at 0.5 km/h works 250 m²/h",
        "60 m of implement at 40 km/h would work 2 400 000 m²/h",
    ),
    "work_speed_kmh": Limit(
        0.5, 40.0, "km/h", "slower than any field work", "the most a tractor could work at"
    ),
    "road_speed_kmh": Limit(
        1.0,
        70.0,
        "km/h",
        "slower than any machine drives between fields",
        "the fastest road tractors are limited to 60-70 km/h",
    ),
    "turn_time_h": Limit(
        0.0, 0.25, "h", "a time cannot be negative", "a U-turn takes seconds to minutes, not hours"
    ),
    "road_fuel_lh": Limit(
        0.0,
        200.0,
        "L/h",
        "fuel cannot be negative",
        "more than the largest tractors burn at full load",
    ),
    "work_fuel_lh": Limit(
        0.0,
        200.0,
        "L/h",
        "fuel cannot be negative",
        "more than the largest tractors burn at full load",
    ),
    "min_turn_radius_m": Limit(
        0.0,
        50.0,
        "m",
        "0 is the paper's hop between swath ends",
        "even articulated tractors with trailed implements turn on less",
    ),
    "system_id": Limit(1, 254, "", "MAVLink system ids start at 1", "255 is the dispatcher"),
    # [machine.implement]: what ArduPilot can drive.
    "channel (servo)": Limit(
        1, 32, "", "servo outputs are numbered from 1, SERVO1", "ArduPilot has 32 servo outputs"
    ),
    "channel (relay)": Limit(
        0, 15, "", "relays are numbered from 0, RELAY1", "ArduPilot has 16 relays"
    ),
    "pwm_down": Limit(800, 2200, "µs", "the shortest servo pulse", "the longest servo pulse"),
    "pwm_up": Limit(800, 2200, "µs", "the shortest servo pulse", "the longest servo pulse"),
    # [solver]
    "time_limit_s": Limit(
        0.1,
        3600.0,
        "s",
        "too short for the solver to improve on its first routes",
        "an hour: a plan the dispatcher waits longer for is no use in the field",
    ),
    "generations": Limit(1, 1_000_000, "", "at least one generation", "beyond any useful run"),
    "makespan_slack": Limit(
        0.0,
        MAX_SLACK,
        "",
        "a share of the makespan",
        "at most 10 % of the makespan given up for road distance",
    ),
    "finish_within_h": Limit(
        0.0,
        8760.0,
        "h",
        "a number of hours (0: no deadline)",
        "a year: a deadline beyond any season's work",
    ),
    # [dispatcher]
    "lost_after_s": Limit(
        1.0,
        600.0,
        "s",
        "vehicles send a heartbeat once a second",
        "ten minutes without a word from a vehicle at work",
    ),
    "stall_after_s": Limit(
        5.0,
        3600.0,
        "s",
        "a tractor may pause that long at a turn",
        "an hour in AUTO without getting anywhere",
    ),
    "lost_grace_s": Limit(
        1.0,
        3600.0,
        "s",
        "vehicles send a heartbeat once a second",
        "an hour for a lost vehicle to come back",
    ),
    "alive_after_s": Limit(
        1.0,
        86_400.0,
        "s",
        "a vehicle's first heartbeat comes within a second of its start",
        "a day for the fleet to be switched on",
    ),
    "window_items": Limit(
        0,
        100_000,
        "",
        "0 sends each mission whole",
        "more than any autopilot stores",
    ),
    "topup_lead_s": Limit(
        0.5,
        600.0,
        "s",
        "a top-up takes a few round trips at least",
        "ten minutes ahead is a whole mission on most radios",
    ),
}
"""Bounds of every number in a scenario or fleet file, by key (config/README.md lists them)."""
# The keys in other units have the bounds of their parameter, in their unit.
LIMITS.update(
    {
        key: Limit(
            LIMITS[other.param].low / other.factor,
            LIMITS[other.param].high / other.factor,
            other.unit,
            LIMITS[other.param].why_low,
            LIMITS[other.param].why_high,
        )
        for key, other in OTHER_UNITS.items()
    }
)

TOP_KEYS = (
    "farm_id",
    "farm",
    "garage",
    "id_field",
    "name_field",
    "fleet",
    "machines",
    "machine",
    "keys",
    "solver",
    "dispatcher",
)
FLEET_KEYS = ("machine",)
MACHINE_KEYS = (
    "id",
    "system_id",
    *MACHINE_PARAMS,
    *OTHER_UNITS,
    *OPTIONAL_MACHINE_PARAMS,
    "implement",
)
IMPLEMENT_KEYS = ("kind", "channel", "pwm_down", "pwm_up")
SOLVER_KEYS = (
    "algorithm",
    "objective",
    "time_limit_s",
    "generations",
    "seed",
    "makespan_slack",
    "finish_within_h",
)
WATCH_KEYS = (
    "lost_after_s",
    "stall_after_s",
    "lost_grace_s",
    "alive_after_s",
    "window_items",
    "topup_lead_s",
)
# Where a key misplaced in a table belongs (TOML puts every key after a [table] line in it).
_ELSEWHERE_AT_TOP = {
    **dict.fromkeys(MACHINE_KEYS, "in a [[machine]] table"),
    **dict.fromkeys(IMPLEMENT_KEYS, "in a [machine.implement] table"),
    **dict.fromkeys(SOLVER_KEYS, "in the [solver] table"),
    **dict.fromkeys(WATCH_KEYS, "in the [dispatcher] table"),
}
_ELSEWHERE_IN_SOLVER = {
    **dict.fromkeys(TOP_KEYS, "at the top of the file, above [solver]"),
    **dict.fromkeys(WATCH_KEYS, "in the [dispatcher] table"),
}
_ELSEWHERE_IN_DISPATCHER = {
    **dict.fromkeys(TOP_KEYS, "at the top of the file, above [dispatcher]"),
    **dict.fromkeys(SOLVER_KEYS, "in the [solver] table"),
}
_ELSEWHERE_IN_MACHINE = {
    **dict.fromkeys(TOP_KEYS, "at the top of the file, above the first table"),
    **dict.fromkeys(IMPLEMENT_KEYS, "in the machine's [machine.implement] table"),
}


@dataclass(frozen=True)
class Implement:
    """How the machine lowers and raises its implement."""

    kind: str  # "servo" or "relay"
    channel: int  # servo output channel (1-based), or relay number (0-based)
    pwm_down: int = 1900  # servo only
    pwm_up: int = 1100


@dataclass(frozen=True)
class Vehicle:
    """One machine of the fleet as the dispatcher knows it."""

    machine: Machine
    system_id: int
    implement: Implement

    @property
    def id(self) -> str:
        return self.machine.id


@dataclass(frozen=True)
class SolverSettings:
    algorithm: str = DEFAULT_ALGORITHM
    objective: str = "makespan"
    time_limit_s: float = 10.0
    generations: int = 2000
    seed: int = 1
    # ε > 0: a makespan up to (1 + ε) x the best found counts as equal to it late in the
    # solve, and the road distance decides (planner.choices.SLACK_SHARE); 0: the makespan
    # first, then the road distance. Under the makespan, with hybrid only.
    makespan_slack: float = 0.0
    # H > 0: a deadline; once a plan finishes within H hours, the road distance decides
    # among the plans that do (planner.solve.solve's finish_within_h); 0: none. Under the
    # makespan, with hybrid only, not with a makespan slack. It counts from the run's start:
    # a re-plan gets what is left of it (dispatcher.tools.replan.deadline_left_h).
    finish_within_h: float = 0.0


WINDOW_ITEMS = 250
"""Default ``[dispatcher] window_items``: missions go to the vehicles in windows of whole
fields of about this many items, the way home last (dispatcher/mission/window.py). At ~100
items a second over a farm radio a window is on board in a few seconds; most autopilots
store several hundred."""


TOPUP_LEAD_S = 10.0
"""Default ``[dispatcher] topup_lead_s``: wall seconds before a vehicle reaches the end of
the window of its mission it holds when its next window is sent, plus twice what the top-up
is expected to take (at the pace of its last upload)."""


@dataclass(frozen=True)
class WatchSettings:
    """When the dispatcher gives a vehicle up as lost (the scenario's ``[dispatcher]``)."""

    lost_after_s: float = 5.0  # wall seconds without any message from it
    stall_after_s: float = 60.0  # its own seconds driving in AUTO without getting anywhere
    lost_grace_s: float = 30.0  # wall seconds a lost vehicle has to come back
    # Wall seconds from the start for every vehicle to be heard (switched on, on the
    # network); one not heard by then is left out and its work re-planned.
    alive_after_s: float = 60.0
    # Missions are sent in windows of whole fields, about this many items, topped up as
    # the vehicle drives (dispatcher/mission/window.py); 0: each mission whole.
    window_items: int = WINDOW_ITEMS
    # A window is topped up when the vehicle is due at its end within this many wall
    # seconds, plus twice what the top-up should take at the pace of its last upload.
    topup_lead_s: float = TOPUP_LEAD_S


@dataclass(frozen=True)
class Scenario:
    farm_id: str
    farm: Farm
    vehicles: tuple[Vehicle, ...]
    solver: SolverSettings
    source: str
    watch: WatchSettings = WatchSettings()
    # The directory of the vehicles' MAVLink signing keys (dispatcher/link/keys.py), when
    # the scenario names one (relative to the scenario file); ``--keys`` overrides it.
    keys_dir: Path | None = None
    farm_options: FarmOptions = FarmOptions()  # garage, id_field, name_field

    def vehicle(self, vehicle_id: str) -> Vehicle:
        for v in self.vehicles:
            if v.id == vehicle_id:
                return v
        known = ", ".join(v.id for v in self.vehicles)
        raise ConfigError(f"{self.source}: unknown machine {vehicle_id!r} (the fleet has {known})")

    def with_machines(self, count: int) -> Scenario:
        """The first ``count`` machines of the fleet (``--machines K``)."""
        if not 1 <= count <= len(self.vehicles):
            raise ConfigError(
                f"{self.source}: --machines {count}: the fleet has {len(self.vehicles)} machines"
            )
        return replace(self, vehicles=self.vehicles[:count])

    def with_objective(self, name: str) -> Scenario:
        """The scenario with ``[solver] objective = name`` (``--objective``), checked as in
        the file: a known objective, and the file's makespan slack or deadline only with the
        makespan (else it would be dropped without a word)."""
        where = f"{self.source}: --objective {name}"
        try:
            Objective.parse(name)
        except ValueError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        solver = replace(self.solver, objective=name)
        for key in ("makespan_slack", "finish_within_h"):
            value = getattr(solver, key)
            if value > 0.0 and Objective.parse(name) is not Objective.MAKESPAN:
                raise ConfigError(
                    f"{where}: the scenario's solver.{key} = {value:g} applies to the "
                    "makespan only; drop it from [solver] or plan with --objective makespan"
                )
        return replace(self, solver=solver)

    def with_deadline(self, hours: float) -> Scenario:
        """The scenario with ``[solver] finish_within_h = hours`` (``--finish-within H``),
        checked as in the file: its bounds, the hybrid and the makespan, no slack."""
        where = f"{self.source}: --finish-within"
        value = _makespan_cap({"finish_within_h": hours}, "finish_within_h", self.solver, where)
        _one_cap(self.solver.makespan_slack, value, where)
        return replace(self, solver=replace(self.solver, finish_within_h=value))

    def with_farm(
        self,
        farm: str | Path | Farm,
        id_field: str | None = None,
        name_field: str | None = None,
    ) -> Scenario:
        """The fleet and settings on another farm (``--fields FARM``), or the same read with
        another ``--id-field`` or ``--name-field``; the scenario's garage is kept. The farm id
        is then the farm file's name, as a scenario's is its own file's without ``farm_id``
        (a farm built in code keeps the scenario's)."""
        options = replace(
            self.farm_options,
            id_field=id_field or self.farm_options.id_field,
            name_field=name_field or self.farm_options.name_field,
        )
        if not isinstance(farm, Farm):
            try:
                farm = load_farm(farm, options)
            except PlannerError as exc:
                raise ConfigError(str(exc)) from exc
        in_memory = farm.source.startswith("<")  # built in code: the scenario's id stays
        return replace(
            self,
            farm=farm,
            farm_options=options,
            farm_id=self.farm_id if in_memory else farm_id_for(farm.source),
        )


def add_fields_argument(p: argparse.ArgumentParser) -> None:
    """``--fields FARM`` of a simulator or a bridge: the farm file the dispatcher was given
    (``load_scenario(scenario, args.fields)``), whose name is then the farm id."""
    p.add_argument(
        "--fields",
        type=Path,
        default=None,
        metavar="FARM",
        help="the farm file the dispatcher was given with --fields (its farm id and garage)",
    )


def farm_id_for(path: str | Path) -> str:
    """A farm id (a Zenoh key segment) from a file's name: what :data:`SAFE_ID` does not
    allow becomes '-' ("Home farm.geojson" is "Home-farm"); a name with letters beyond
    ASCII gets a short hash of it too, so that two such names do not become one ("поля
    1.geojson" is "1-" and six hex digits, not "1")."""
    stem = Path(path).stem
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "-", stem).strip("-.") or "farm"
    if stem.isascii():
        return safe
    return f"{safe}-{hashlib.sha256(stem.encode()).hexdigest()[:6]}"


def load_scenario(
    path: str | Path,
    fields: str | Path | None = None,
    id_field: str | None = None,
    name_field: str | None = None,
) -> Scenario:
    """The scenario file at ``path``; on the farm file ``fields`` instead of its own when
    given (``--fields``: its own is then not read, and it or its key may be missing), the
    farm id then the farm file's name, as :meth:`Scenario.with_farm` has it; its farm read with
    ``id_field`` and ``name_field`` when given (``--id-field``, ``--name-field``)."""
    path = Path(path)
    doc = _read_toml(path)
    src = str(path)
    _check_keys(doc, TOP_KEYS, src, "the top level", _ELSEWHERE_AT_TOP)
    farm_id = doc.get("farm_id", farm_id_for(path))  # "my farm.toml": "my-farm"
    if not isinstance(farm_id, str) or not SAFE_ID.fullmatch(farm_id):
        raise ConfigError(
            f"{src}: farm_id {_shown(farm_id)} must be {SAFE_ID_RULE} "
            "(it is a Zenoh key segment and names the run's files)"
        )
    farm_key = doc.get("farm")
    if farm_key is None and fields is None:
        raise ConfigError(
            f"{src}: missing key 'farm' (the farm file: GeoJSON, KML, ...; or give one "
            "with --fields)"
        )
    if farm_key is not None and (not isinstance(farm_key, str) or not farm_key.strip()):
        raise ConfigError(
            f"{src}: key 'farm' must name the farm file (GeoJSON, KML, ...), not {_shown(farm_key)}"
        )
    farm_options = _farm_options(doc, src)
    farm_options = replace(
        farm_options,
        id_field=id_field or farm_options.id_field,
        name_field=name_field or farm_options.name_field,
    )
    if fields is not None:
        farm_id = farm_id_for(fields)
    try:
        farm = load_farm(path.parent / str(farm_key) if fields is None else fields, farm_options)
    except PlannerError as exc:
        pointed = " (the farm its key 'farm' names)" if fields is None else ""
        raise ConfigError(f"{exc}\n  read for {src}{pointed}") from exc
    machines = doc.get("machine")
    fleet_src = src
    if "fleet" in doc:
        if machines is not None:
            raise ConfigError(
                f"{src}: give either 'fleet' (a file) or [[machine]] tables, not both"
            )
        if not isinstance(doc["fleet"], str) or not doc["fleet"].strip():
            raise ConfigError(
                f"{src}: key 'fleet' must name a fleet file, not {_shown(doc['fleet'])}"
            )
        fleet_path = path.parent / doc["fleet"]
        fleet_src = str(fleet_path)
        try:
            fleet_doc = _read_toml(fleet_path)
        except ConfigError as exc:
            raise ConfigError(f"{exc}\n  read for {src} (the fleet its key 'fleet' names)") from exc
        _check_keys(
            fleet_doc,
            FLEET_KEYS,
            fleet_src,
            "the top level of a fleet file",
            {**_ELSEWHERE_AT_TOP, **dict.fromkeys(TOP_KEYS, "in the scenario file")},
        )
        machines = fleet_doc.get("machine")
    vehicles = _vehicles(machines, fleet_src)
    if not vehicles and fleet_src == src:
        raise ConfigError(f"{src}: no fleet: give 'fleet' (a fleet file) or [[machine]] tables")
    if not vehicles:
        raise ConfigError(f"{fleet_src}: the fleet is empty (no [[machine]] tables)")
    chosen = doc.get("machines")
    if chosen is not None:
        if not isinstance(chosen, list) or not all(isinstance(c, str) for c in chosen):
            raise ConfigError(
                f"{src}: key 'machines' must be a list of machine ids, not {_shown(chosen)}"
            )
        if not chosen:
            raise ConfigError(f"{src}: key 'machines' is empty: the fleet is empty")
        by_id = {v.id: v for v in vehicles}
        for k, ident in enumerate(chosen):
            if ident not in by_id:
                raise ConfigError(
                    f"{src}: key 'machines' references unknown machine {ident!r}"
                    f"{_suggest(ident, list(by_id))} (the fleet has {', '.join(by_id)})"
                )
            if ident in chosen[:k]:
                raise ConfigError(f"{src}: key 'machines' names machine {ident!r} twice")
        vehicles = tuple(by_id[c] for c in chosen)
    return Scenario(
        farm_id=farm_id,
        farm=farm,
        vehicles=vehicles,
        solver=_solver(doc.get("solver", {}), src),
        source=src,
        watch=_watch(doc.get("dispatcher", {}), src),
        keys_dir=_keys_dir(doc, path, src),
        farm_options=farm_options,
    )


def _farm_options(doc: dict[str, Any], src: str) -> FarmOptions:
    """``garage = [longitude, latitude]``, ``id_field``, ``name_field`` (config/README.md)."""
    garage = doc.get("garage")
    if garage is not None and (
        not isinstance(garage, list)
        or len(garage) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in garage)
    ):
        raise ConfigError(
            f"{src}: key 'garage' must be [longitude, latitude] in degrees, not {_shown(garage)}"
        )
    names = {}
    for key in ("id_field", "name_field"):
        value = doc.get(key)
        if value is not None and (not isinstance(value, str) or not value):
            raise ConfigError(
                f"{src}: key {key!r} must name a property (a string), not {_shown(value)}"
            )
        names[key] = value
    return FarmOptions(
        garage=None if garage is None else (float(garage[0]), float(garage[1])), **names
    )


def _keys_dir(doc: dict[str, Any], path: Path, src: str) -> Path | None:
    if "keys" not in doc:
        return None
    if not isinstance(doc["keys"], str) or not doc["keys"]:
        raise ConfigError(
            f"{src}: key 'keys' must name the signing key directory (a string), "
            f"not {_shown(doc['keys'])}"
        )
    return path.parent / doc["keys"]


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark or none
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: not UTF-8 text ({exc.reason})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    except ValueError as exc:  # e.g. an integer of more digits than Python reads
        raise ConfigError(f"{path}: not TOML we can read ({exc})") from exc


# --- checks shared by every table -------------------------------------------------------


def _shown(value: Any) -> str:
    """A value as the TOML file wrote it (``true``, ``"text"``, ``1e+308``), for messages."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        if value and all(isinstance(v, dict) for v in value):
            return "an array of tables ([[...]])"
        text = "[" + ", ".join(_shown(v) for v in value) + "]"
        return text if len(text) <= 60 else text[:56] + " ...]"
    if value is None:
        return "nothing"
    return repr(value)


def _suggest(key: str, known: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` for the known key nearest ``key`` (ignoring case), or ``""``."""
    lower = {k.lower(): k for k in known}
    close = difflib.get_close_matches(key.lower(), list(lower), n=1, cutoff=0.6)
    return f" (did you mean {lower[close[0]]!r}?)" if close else ""


def _check_keys(
    raw: dict[str, Any],
    known: Sequence[str],
    where: str,
    table: str,
    elsewhere: dict[str, str] | None = None,
) -> None:
    """Refuse keys not in ``known``, each with the nearest known key, or, for a key that
    belongs in another table (``elsewhere``: key -> where it goes), that table."""
    unknown = [key for key in raw if key not in known]
    if not unknown:
        return
    parts = []
    for key in unknown:
        hint = _suggest(key, known)
        if not hint and elsewhere and key in elsewhere:
            hint = f" (it belongs {elsewhere[key]})"
        parts.append(key + hint)
    raise ConfigError(
        f"{where}: unknown key(s) in {table}: {', '.join(parts)}; known keys: {', '.join(known)}"
    )


def _figure(value: float) -> str:
    return f"{value:,.0f}".replace(",", " ") if float(value).is_integer() else f"{value:g}"


def _within(value: float, limit_key: str, label: str, where: str) -> None:
    """Refuse ``value`` outside ``LIMITS[limit_key]``, naming ``label`` and the bound."""
    limit = LIMITS[limit_key]
    unit = f" {limit.unit}" if limit.unit else ""
    if value < limit.low:
        if limit.low > 0 and value <= 0:
            raise ConfigError(
                f"{where}: {label} must be a positive number; it is {_shown(value)} "
                f"(at least {_figure(limit.low)}{unit}: {limit.why_low})"
            )
        if limit.low == 0:
            raise ConfigError(
                f"{where}: {label} must not be negative; it is {_shown(value)} ({limit.why_low})"
            )
        raise ConfigError(
            f"{where}: {label} = {_shown(value)} is below {_figure(limit.low)}{unit} "
            f"({limit.why_low})"
        )
    if value > limit.high:
        raise ConfigError(
            f"{where}: {label} = {_shown(value)} is above {_figure(limit.high)}{unit} "
            f"({limit.why_high})"
        )


def _number(raw: dict[str, Any], key: str, where: str, label: str | None = None) -> float:
    """``raw[key]`` as a float within its limits: an integer or a float, never a bool."""
    label = label or key
    value = raw[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: key '{label}' must be a number, not {_shown(value)}")
    if not math.isfinite(value):
        raise ConfigError(f"{where}: {label} = {_shown(value)} is not a finite number")
    _within(value, key, label, where)
    return float(value)


def _integer(
    raw: dict[str, Any], key: str, where: str, label: str | None = None, limit: str | None = None
) -> int:
    """``raw[key]`` as an integer (not a float, not a bool) within its limits, if it has any."""
    label = label or key
    value = raw[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{where}: key '{label}' must be a whole number, not {_shown(value)}")
    if limit or key in LIMITS:
        _within(value, limit or key, label, where)
    return value


def _table(raw: Any, where: str, table: str) -> dict[str, Any]:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: {table} must be a table, not {_shown(raw)}")
    return raw


# --- the tables -------------------------------------------------------------------------


def _vehicles(machines: Any, src: str) -> tuple[Vehicle, ...]:
    if machines is None:
        return ()
    if not isinstance(machines, list):
        raise ConfigError(f"{src}: 'machine' must be an array of tables ([[machine]])")
    out: list[Vehicle] = []
    system_ids: dict[int, str] = {}
    for k, entry in enumerate(machines):
        entry = _table(entry, src, f"[[machine]] #{k + 1}")
        ident = entry.get("id")
        named = isinstance(ident, str) and ident
        where = f"{src}: machine {ident!r}" if named else f"{src}: [[machine]] #{k + 1}"
        _check_keys(entry, MACHINE_KEYS, where, "[[machine]]", _ELSEWHERE_IN_MACHINE)
        if not isinstance(ident, str) or not SAFE_ID.fullmatch(ident):
            raise ConfigError(
                f"{where}: key 'id' must be {SAFE_ID_RULE} (it names Zenoh keys and mission files)"
            )
        params = _machine_params(entry, where)
        try:
            machine = Machine(ident, **params)
        except PlannerError as exc:
            raise ConfigError(f"{src}: {exc}") from exc
        _check_capacity(
            machine, "capacity_hah" if "capacity_hah" in entry else "capacity_m2h", where
        )
        if ident in {v.id for v in out}:
            raise ConfigError(f"{where}: duplicate machine id")
        sysid = _integer(entry, "system_id", where)
        if sysid in system_ids:
            raise ConfigError(
                f"{where}: system_id {sysid} is already used by {system_ids[sysid]!r}"
            )
        system_ids[sysid] = ident
        out.append(Vehicle(machine, sysid, _implement(entry.get("implement"), where)))
        if "min_turn_radius_m" not in entry:  # once the machine is known good
            logger.warning(
                "%s: no min_turn_radius_m: turns are planned as hops between swath ends",
                where,
            )
    return tuple(out)


def _check_capacity(machine: Machine, key: str, where: str) -> None:
    """The area worked an hour (the plan's hours) at most what the implement's width covers
    at the work speed (the mission's): more, and the tractor takes longer than planned."""
    most = machine.working_width_m * machine.work_speed_kmh * 1000.0  # m2/h
    if machine.capacity_m2h > most * CAPACITY_TOLERANCE:
        raise ConfigError(
            f"{where}: {key} = {machine.capacity_m2h / 1e4:g} ha/h is more than the implement "
            f"covers at its work speed (working_width_m x work_speed_kmh = "
            f"{machine.working_width_m:g} m x {machine.work_speed_kmh:g} km/h = "
            f"{most / 1e4:.3g} ha/h): the swaths would take {machine.capacity_m2h / most:.2g} "
            "times the hours planned; give the field capacity (width x speed x field "
            "efficiency) or the speed driven along the swaths"
        )


def _machine_params(entry: dict[str, Any], where: str) -> dict[str, float]:
    """The machine's parameters in the planner's units, each from its own key or from the
    key of :data:`OTHER_UNITS` that gives it in another unit (not both)."""
    given_as = {other.param: key for key, other in OTHER_UNITS.items() if key in entry}
    for param, key in given_as.items():
        if param in entry:
            raise ConfigError(
                f"{where}: give {param} or {key}, not both (the same figure in "
                f"{LIMITS[param].unit} and in {LIMITS[key].unit})"
            )
    missing = [
        " or ".join([key, *(k for k, o in OTHER_UNITS.items() if o.param == key)])
        for key in (*MACHINE_PARAMS, "system_id")
        if key not in entry and key not in given_as
    ]
    if missing:
        raise ConfigError(f"{where}: missing key(s) {', '.join(missing)}")
    params = {}
    for param in (*MACHINE_PARAMS, *(k for k in OPTIONAL_MACHINE_PARAMS if k in entry)):
        key = given_as.get(param, param)
        factor = OTHER_UNITS[key].factor if key in OTHER_UNITS else 1.0
        params[param] = _number(entry, key, where) * factor
    return params


def _implement(raw: Any, where: str) -> Implement:
    if raw is None:
        raise ConfigError(f"{where}: missing table [machine.implement] (kind, channel)")
    raw = _table(raw, where, "[machine.implement]")
    _check_keys(
        raw,
        IMPLEMENT_KEYS,
        where,
        "[machine.implement]",
        dict.fromkeys(MACHINE_KEYS, "in [[machine]], above its [machine.implement] table"),
    )
    if "kind" not in raw:
        raise ConfigError(f'{where}: missing key implement.kind ("servo" or "relay")')
    kind = raw["kind"]
    if kind not in ("servo", "relay"):
        raise ConfigError(f'{where}: implement.kind must be "servo" or "relay", not {_shown(kind)}')
    if "channel" not in raw:
        raise ConfigError(f"{where}: missing key implement.channel")
    channel = _integer(raw, "channel", where, "implement.channel", f"channel ({kind})")
    if kind == "relay":
        pwm = [k for k in ("pwm_down", "pwm_up") if k in raw]
        if pwm:
            raise ConfigError(
                f"{where}: implement.{pwm[0]}: a relay has no PWM values "
                '(only kind = "servo" takes pwm_down and pwm_up)'
            )
    extra = {
        k: _integer(raw, k, where, f"implement.{k}") for k in ("pwm_down", "pwm_up") if k in raw
    }
    return Implement(kind=kind, channel=channel, **extra)


def _solver(raw: Any, src: str) -> SolverSettings:
    raw = _table(raw, src, "[solver]")
    _check_keys(raw, SOLVER_KEYS, src, "[solver]", _ELSEWHERE_IN_SOLVER)
    values: dict[str, Any] = {}
    for key in ("algorithm", "objective"):
        if key in raw:
            if not isinstance(raw[key], str):
                raise ConfigError(
                    f"{src}: key 'solver.{key}' must be a string, not {_shown(raw[key])}"
                )
            values[key] = raw[key]
    settings = SolverSettings(**values)
    if settings.algorithm not in ALGORITHMS:
        raise ConfigError(
            f"{src}: solver.algorithm must be one of {', '.join(ALGORITHMS)}, "
            f"not {_shown(settings.algorithm)}"
        )
    try:
        Objective.parse(settings.objective)
    except ValueError as exc:
        raise ConfigError(f"{src}: solver.objective: {exc}") from exc
    if "time_limit_s" in raw:
        values["time_limit_s"] = _number(raw, "time_limit_s", src, "solver.time_limit_s")
    if "generations" in raw:
        values["generations"] = _integer(raw, "generations", src, "solver.generations")
    if "seed" in raw:
        values["seed"] = _integer(raw, "seed", src, "solver.seed")
    for key in ("makespan_slack", "finish_within_h"):  # both cap the makespan
        if key in raw:
            values[key] = _makespan_cap(raw, key, settings, src)
    _one_cap(values.get("makespan_slack", 0.0), values.get("finish_within_h", 0.0), src)
    return SolverSettings(**values)


def _one_cap(slack: float, deadline: float, where: str) -> None:
    """A makespan slack or a deadline, not both (ConfigError naming ``where``)."""
    if slack and deadline:
        raise ConfigError(
            f"{where}: solver.makespan_slack and solver.finish_within_h both cap the makespan "
            "(a share of the best, or a deadline): give one"
        )


def _makespan_cap(raw: dict[str, Any], key: str, settings: SolverSettings, src: str) -> float:
    """``[solver] makespan_slack`` or ``finish_within_h``: a number within its limits, and
    if not 0, with the hybrid and the makespan."""
    value = _number(raw, key, src, f"solver.{key}")
    if value > 0.0 and settings.algorithm != "hybrid":
        raise ConfigError(
            f'{src}: solver.{key} needs solver.algorithm = "hybrid", '
            f"not {_shown(settings.algorithm)}"
        )
    if value > 0.0 and Objective.parse(settings.objective) is not Objective.MAKESPAN:
        raise ConfigError(
            f'{src}: solver.{key} applies to solver.objective = "makespan" only, '
            f"not {_shown(settings.objective)}"
        )
    return value


def _watch(raw: Any, src: str) -> WatchSettings:
    raw = _table(raw, src, "[dispatcher]")
    _check_keys(raw, WATCH_KEYS, src, "[dispatcher]", _ELSEWHERE_IN_DISPATCHER)
    values: dict[str, Any] = {
        k: _number(raw, k, src, f"dispatcher.{k}") for k in raw if k != "window_items"
    }
    if "window_items" in raw:
        values["window_items"] = _integer(raw, "window_items", src, "dispatcher.window_items")
    return WatchSettings(**values)
