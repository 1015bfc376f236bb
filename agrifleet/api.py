"""Plan a farm from files or objects and get the plan back: what `agrifleet plan` does,
as functions (the command line calls these too)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import DEMO_SCENARIO, LIMITS, Scenario, load_scenario
from dispatcher.mission.document import PlanDocument
from dispatcher.mission.plan import DispatchPlan, dispatch_plan, plan_geojson, write_plan_files
from planner.farm import Farm

GenerationCallback = Callable[[int, float, float], None]
"""``(generation, best cost, elapsed s)``, after every generation of the solver."""


@dataclass(frozen=True)
class Plan:
    """A planned farm: the plan document with its missions, GeoJSON and map."""

    dispatch: DispatchPlan

    @property
    def document(self) -> PlanDocument:
        """The plan document, as `agrifleet plan` writes it to plan.json."""
        return self.dispatch.document

    @property
    def makespan_h(self) -> float:
        """Hours until the whole farm is done (the slowest machine's time)."""
        return self.document.makespan_h

    def to_dict(self) -> dict[str, Any]:
        """The plan document as plain JSON data."""
        return self.document.to_dict()

    def to_json(self, indent: int | None = None) -> str:
        """The plan document as JSON text (plan.json, `agrifleet plan --json`)."""
        return self.document.to_json(indent=indent)

    def to_geojson(self) -> dict[str, Any]:
        """Fields, garage and each machine's route as a GeoJSON FeatureCollection (WGS84)."""
        return plan_geojson(self.dispatch)

    def save_map(self, path: str | Path) -> Path:
        """Draw the map of the plan (as `agrifleet plan` does) to a PNG file."""
        from dispatcher.mission.map import draw_plan_map

        draw_plan_map(self.dispatch.plan, path, title=self.document.farm_id)
        return Path(path)

    def write(self, out_dir: str | Path) -> list[Path]:
        """plan.json, plan.geojson, plan.kml, per machine ``.waypoints`` and ``.plan``,
        map.png; all or nothing."""
        return write_plan_files(self.dispatch, out_dir)

    def table(self) -> str:
        """Per machine: working width, fields, road km, turns, fuel, hours and field order."""
        return plan_table(self.document)

    def __str__(self) -> str:
        return self.table()


def scenario_for(
    scenario: str | Path | Scenario,
    fields: str | Path | Farm | None = None,
    machines: int | None = None,
    id_field: str | None = None,
    name_field: str | None = None,
) -> Scenario:
    """A scenario (a file or one loaded) on another farm (``fields``: a farm file or a
    loaded :class:`Farm`; the farm id is then the file's name) with its first ``machines``;
    ``id_field``/``name_field``: the properties that hold a field's id and name."""
    if not isinstance(scenario, Scenario):
        # Its farm read once, as asked: on another farm file, its own is not read (it may
        # be missing).
        on_file = None if fields is None or isinstance(fields, Farm) else fields
        scenario = load_scenario(scenario, on_file, id_field, name_field)
        if on_file is not None or fields is None:
            id_field = name_field = None  # done
            fields = None
    if fields is not None:
        scenario = scenario.with_farm(fields, id_field, name_field)
    elif id_field or name_field:  # the scenario's own farm file, read another way
        farm_id = scenario.farm_id
        scenario = replace(
            scenario.with_farm(scenario.farm.source, id_field, name_field), farm_id=farm_id
        )
    if machines is not None:
        scenario = scenario.with_machines(machines)
    return scenario


def dispatch_for(
    scenario: Scenario,
    objective: str | None = None,
    time_limit_s: float | None = None,
    seed: int | None = None,
    on_generation: GenerationCallback | None = None,
) -> DispatchPlan:
    """Plan ``scenario`` (its solver settings unless overridden) into missions."""
    from planner.field_plan import plan_farm as plan_fields
    from planner.kernels import compile_kernels
    from planner.solve import stop_after

    if objective is not None:
        scenario = scenario.with_objective(objective)  # checked as in the file
    solver = scenario.solver
    machines = [v.machine for v in scenario.vehicles]
    objective = solver.objective
    seed = solver.seed if seed is None else seed
    # Compile (first run) or load the kernels before the clock starts: the time limit is
    # then the plan's alone, and the first plan after installing is the one later runs make.
    compile_kernels()
    plan = plan_fields(
        scenario.farm,
        machines,
        objective,
        solver.algorithm,
        stop_after(solver.generations, time_limit_s or solver.time_limit_s),
        seed=seed,
        on_generation=on_generation,
        makespan_slack=solver.makespan_slack,
        finish_within_h=solver.finish_within_h,
    )
    return dispatch_plan(scenario, plan)


def plan_farm(
    scenario: str | Path | Scenario = DEMO_SCENARIO,
    *,
    fields: str | Path | Farm | None = None,
    machines: int | None = None,
    objective: str | None = None,
    time_limit_s: float | None = None,
    seed: int | None = None,
    on_generation: GenerationCallback | None = None,
) -> Plan:
    """Plan the work of a fleet on a farm.

    ``scenario``: a scenario TOML (config/README.md) or a loaded :class:`Scenario`
    (default: the demo farm); ``fields``: another farm for the same fleet, a file or a
    loaded :class:`Farm`; ``machines``: use the fleet's first K; ``objective`` (makespan,
    distance, time, fuel, minmax), ``time_limit_s`` (wall seconds for the whole plan) and
    ``seed`` override the scenario's ``[solver]``. Bad input raises
    :class:`dispatcher.config.errors.ConfigError` (or a :class:`planner.errors.PlannerError`)
    naming the file and the key at fault (or the argument)."""
    _check_arguments(machines, time_limit_s, seed)
    chosen = scenario_for(scenario, fields, machines)
    return Plan(dispatch_for(chosen, objective, time_limit_s, seed, on_generation))


def _check_arguments(machines: Any, time_limit_s: Any, seed: Any) -> None:
    """:func:`plan_farm`'s numbers as the scenario's are checked: a ConfigError naming the
    argument (a ValueError or TypeError came out of the depths)."""
    limit = LIMITS["time_limit_s"]
    for name, value in (("machines", machines), ("seed", seed)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            raise ConfigError(f"plan_farm({name}={value!r}): a whole number, or None")
    if machines is not None and machines < 1:
        raise ConfigError(f"plan_farm(machines={machines}): at least 1")
    if time_limit_s is not None and (
        isinstance(time_limit_s, bool)
        or not isinstance(time_limit_s, int | float)
        or not limit.low <= time_limit_s <= limit.high
    ):
        raise ConfigError(
            f"plan_farm(time_limit_s={time_limit_s!r}): seconds from {limit.low:g} to "
            f"{limit.high:g}, or None for the scenario's"
        )


def plan_table(doc: PlanDocument) -> str:
    """The plan as `agrifleet plan` prints it: one line per machine, then the totals."""
    lines = [
        f"plan {doc.plan_id} for {doc.farm_id}: objective {doc.objective}, "
        f"{len(doc.machines)} machines, {len(doc.fields)} fields",
        f"{'machine':8} {'width m':>7} {'fields':>6} {'road km':>8} {'turns':>6} "
        f"{'fuel L':>8} {'time h':>7}  order",
    ]
    for m in doc.machines:
        lines.append(
            f"{m.id:8} {m.working_width_m:7.1f} {len(m.fields):6d} "
            f"{m.distance_m / 1000:8.2f} {m.turns:6.0f} {m.fuel_l:8.1f} {m.time_h:7.2f}  "
            + " ".join(m.fields)
        )
    t = doc.totals
    lines.append(
        f"{'total':8} {'':7} {len(doc.fields):6d} {t['distance_m'] / 1000:8.2f} "
        f"{sum(m.turns for m in doc.machines):6.0f} {t['fuel_l']:8.1f} {t['time_h']:7.2f}  "
        f"makespan {t['makespan_h']:.2f} h"
    )
    return "\n".join(lines)
