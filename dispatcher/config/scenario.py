"""A scenario: which farm, which fleet, how to solve. Loaded from TOML and checked.

Keys are documented in config/README.md. Paths inside a scenario are relative to the
scenario file. Every error names the file and the key (or machine) at fault.
"""

from __future__ import annotations

import logging
import re
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from dispatcher.config.errors import ConfigError
from planner.choices import ALGORITHMS, Objective
from planner.errors import PlannerError
from planner.farm import Farm, load_farm
from planner.problem import Machine

logger = logging.getLogger(__name__)

# Ids become Zenoh key segments and file names: nothing that either would misread.
SAFE_ID = re.compile(r"[A-Za-z0-9_.-]+")

MACHINE_PARAMS = (
    "working_width_m",
    "capacity_m2h",
    "road_speed_kmh",
    "work_speed_kmh",
    "turn_time_h",
    "road_fuel_lh",
    "work_fuel_lh",
)
# Optional machine keys and their defaults: 0 m turning radius = the paper's turn model,
# a hop between swath ends costing turn_time_h.
OPTIONAL_MACHINE_PARAMS = {"min_turn_radius_m": 0.0}


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
    algorithm: str = "ighoa"
    objective: str = "makespan"
    time_limit_s: float = 10.0
    generations: int = 2000
    seed: int = 1


@dataclass(frozen=True)
class WatchSettings:
    """When the dispatcher gives a vehicle up as lost (the scenario's ``[dispatcher]``)."""

    lost_after_s: float = 5.0  # wall seconds without any message from it
    stall_after_s: float = 60.0  # its own seconds driving in AUTO without getting anywhere
    lost_grace_s: float = 30.0  # wall seconds a lost vehicle has to come back


@dataclass(frozen=True)
class Scenario:
    farm_id: str
    farm: Farm
    vehicles: tuple[Vehicle, ...]
    solver: SolverSettings
    source: str
    watch: WatchSettings = WatchSettings()

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

    def with_farm(self, path: str | Path) -> Scenario:
        try:
            return replace(self, farm=load_farm(path))
        except PlannerError as exc:
            raise ConfigError(str(exc)) from exc


def load_scenario(path: str | Path) -> Scenario:
    path = Path(path)
    doc = _read_toml(path)
    src = str(path)
    farm_id = doc.get("farm_id", path.stem)
    if not isinstance(farm_id, str) or not SAFE_ID.fullmatch(farm_id):
        raise ConfigError(
            f"{src}: farm_id {farm_id!r} must be letters, digits, '_', '-' or '.' "
            "(it is a Zenoh key segment)"
        )
    farm_key = doc.get("farm")
    if not isinstance(farm_key, str):
        raise ConfigError(f"{src}: key 'farm' must name the farm GeoJSON file")
    try:
        farm = load_farm(path.parent / farm_key)
    except PlannerError as exc:
        raise ConfigError(str(exc)) from exc
    machines = doc.get("machine")
    fleet_src = src
    if "fleet" in doc:
        if machines is not None:
            raise ConfigError(
                f"{src}: give either 'fleet' (a file) or [[machine]] tables, not both"
            )
        fleet_path = path.parent / str(doc["fleet"])
        fleet_src = str(fleet_path)
        machines = _read_toml(fleet_path).get("machine")
    vehicles = _vehicles(machines, fleet_src)
    chosen = doc.get("machines")
    if chosen is not None:
        if not isinstance(chosen, list) or not all(isinstance(c, str) for c in chosen):
            raise ConfigError(f"{src}: key 'machines' must be a list of machine ids")
        by_id = {v.id: v for v in vehicles}
        for ident in chosen:
            if ident not in by_id:
                raise ConfigError(
                    f"{src}: key 'machines' references unknown machine {ident!r} "
                    f"(the fleet has {', '.join(by_id)})"
                )
        vehicles = tuple(by_id[c] for c in chosen)
    if not vehicles:
        raise ConfigError(f"{src}: the fleet is empty")
    return Scenario(
        farm_id=farm_id,
        farm=farm,
        vehicles=vehicles,
        solver=_solver(doc.get("solver", {}), src),
        source=src,
        watch=_watch(doc.get("dispatcher", {}), src),
    )


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        return tomllib.loads(path.read_text())
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc


def _vehicles(machines: Any, src: str) -> tuple[Vehicle, ...]:
    if machines is None:
        return ()
    if not isinstance(machines, list):
        raise ConfigError(f"{src}: 'machine' must be an array of tables ([[machine]])")
    out: list[Vehicle] = []
    system_ids: dict[int, str] = {}
    for k, entry in enumerate(machines):
        ident = entry.get("id") if isinstance(entry, dict) else None
        where = f"{src}: machine {ident!r}" if ident else f"{src}: [[machine]] #{k + 1}"
        if not isinstance(ident, str) or not SAFE_ID.fullmatch(ident):
            raise ConfigError(
                f"{where}: key 'id' must be letters, digits, '_', '-' or '.' "
                "(it names Zenoh keys and mission files)"
            )
        missing = [key for key in (*MACHINE_PARAMS, "system_id") if key not in entry]
        if missing:
            raise ConfigError(f"{where}: missing key(s) {', '.join(missing)}")
        keys = [*MACHINE_PARAMS, *(k for k in OPTIONAL_MACHINE_PARAMS if k in entry)]
        for key in keys:
            if not isinstance(entry[key], int | float) or isinstance(entry[key], bool):
                raise ConfigError(f"{where}: key '{key}' must be a number")
        if "min_turn_radius_m" not in entry:
            logger.warning(
                "%s: no min_turn_radius_m: turns are planned as hops between swath ends",
                where,
            )
        try:
            machine = Machine(ident, **{key: float(entry[key]) for key in keys})
        except PlannerError as exc:
            raise ConfigError(f"{src}: {exc}") from exc
        sysid = entry["system_id"]
        if not isinstance(sysid, int) or not 1 <= sysid <= 254:
            raise ConfigError(
                f"{where}: key 'system_id' must be an integer 1..254 (255 is the dispatcher)"
            )
        if sysid in system_ids:
            raise ConfigError(
                f"{where}: system_id {sysid} is already used by {system_ids[sysid]!r}"
            )
        if ident in {v.id for v in out}:
            raise ConfigError(f"{where}: duplicate machine id")
        system_ids[sysid] = ident
        out.append(Vehicle(machine, sysid, _implement(entry.get("implement"), where)))
    return tuple(out)


def _implement(raw: Any, where: str) -> Implement:
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: missing table [machine.implement] (kind, channel)")
    kind = raw.get("kind")
    if kind not in ("servo", "relay"):
        raise ConfigError(f"{where}: implement.kind must be 'servo' or 'relay', not {kind!r}")
    channel = raw.get("channel")
    if not isinstance(channel, int) or isinstance(channel, bool):
        raise ConfigError(f"{where}: implement.channel must be an integer")
    extra = {k: raw[k] for k in ("pwm_down", "pwm_up") if k in raw}
    for key, value in extra.items():
        if not isinstance(value, int) or not 800 <= value <= 2200:
            raise ConfigError(f"{where}: implement.{key} must be a PWM value 800..2200")
    return Implement(kind=kind, channel=channel, **extra)


def _solver(raw: Any, src: str) -> SolverSettings:
    if not isinstance(raw, dict):
        raise ConfigError(f"{src}: [solver] must be a table")
    unknown = set(raw) - {"algorithm", "objective", "time_limit_s", "generations", "seed"}
    if unknown:
        raise ConfigError(f"{src}: unknown key(s) in [solver]: {', '.join(sorted(unknown))}")
    settings = SolverSettings(**raw)
    if settings.algorithm not in ALGORITHMS:
        raise ConfigError(f"{src}: solver.algorithm must be one of {', '.join(ALGORITHMS)}")
    try:
        Objective.parse(settings.objective)
    except ValueError as exc:
        raise ConfigError(f"{src}: solver.objective: {exc}") from exc
    if not (isinstance(settings.time_limit_s, int | float) and settings.time_limit_s > 0):
        raise ConfigError(f"{src}: solver.time_limit_s must be a positive number of seconds")
    if not (isinstance(settings.generations, int) and settings.generations >= 1):
        raise ConfigError(f"{src}: solver.generations must be a whole number >= 1")
    if not isinstance(settings.seed, int):
        raise ConfigError(f"{src}: solver.seed must be an integer")
    return settings


def _watch(raw: Any, src: str) -> WatchSettings:
    if not isinstance(raw, dict):
        raise ConfigError(f"{src}: [dispatcher] must be a table")
    names = {f.name for f in fields(WatchSettings)}
    unknown = set(raw) - names
    if unknown:
        raise ConfigError(
            f"{src}: unknown key(s) in [dispatcher]: {', '.join(sorted(unknown))} "
            f"(known: {', '.join(sorted(names))})"
        )
    for key, value in raw.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or not value > 0:
            raise ConfigError(f"{src}: dispatcher.{key} must be a positive number of seconds")
    return WatchSettings(**{k: float(v) for k, v in raw.items()})
