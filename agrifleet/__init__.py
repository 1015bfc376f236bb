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

from agrifleet.api import Plan, __version__, kernels_cached, plan_farm
from dispatcher.config.scenario import DEMO_SCENARIO, Scenario, load_scenario
from planner.farm import Farm, load_farm

__all__ = [
    "DEMO_SCENARIO",
    "Farm",
    "Plan",
    "Scenario",
    "__version__",
    "kernels_cached",
    "load_farm",
    "load_scenario",
    "plan_farm",
]
