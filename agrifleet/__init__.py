"""agrifleet's Python API: plan a farm's work in one call.

    import agrifleet

    plan = agrifleet.plan_farm("config/changji.toml", machines=3)
    print(plan.table())              # per machine: fields, road km, turns, fuel, hours
    plan.document                    # the plan document (plan.json), typed
    plan.to_geojson()                # fields, garage and routes as a GeoJSON FeatureCollection
    plan.save_map("map.png")         # the map `agrifleet plan` draws
    plan.write("out/p3")             # plan.json, missions (.waypoints, .plan), map.png

Files or objects: a scenario file or a loaded :class:`Scenario`; ``fields=`` a farm file or a
loaded :class:`Farm`. docs/api.md walks through it.
"""

# Loaded on first use, so that `agrifleet --version` and the light commands (sim, bridge on a
# tractor's companion computer) do not load the planner and its solver.
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from agrifleet.version import __version__

if TYPE_CHECKING:  # the names below, for type checkers (re-exported: `X as X`)
    from agrifleet.api import Plan as Plan
    from agrifleet.api import plan_farm as plan_farm
    from dispatcher.config.scenario import DEMO_SCENARIO as DEMO_SCENARIO
    from dispatcher.config.scenario import Scenario as Scenario
    from dispatcher.config.scenario import load_scenario as load_scenario
    from planner.farm import Farm as Farm
    from planner.farm import load_farm as load_farm
    from planner.kernels import compile_kernels as compile_kernels

_OWNERS = {
    "Plan": "agrifleet.api",
    "plan_farm": "agrifleet.api",
    "DEMO_SCENARIO": "dispatcher.config.scenario",
    "Scenario": "dispatcher.config.scenario",
    "load_scenario": "dispatcher.config.scenario",
    "Farm": "planner.farm",
    "load_farm": "planner.farm",
    "compile_kernels": "planner.kernels",
}

__all__ = ["__version__", *_OWNERS]


def __getattr__(name: str) -> Any:
    if name in _OWNERS:
        return getattr(importlib.import_module(_OWNERS[name]), name)
    raise AttributeError(f"module 'agrifleet' has no attribute {name!r}")
