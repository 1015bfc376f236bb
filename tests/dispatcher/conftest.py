"""A small plan of the tiny farm (tests/data/tiny.toml), shared by the dispatcher's tests."""

from pathlib import Path

import pytest

from dispatcher.config.scenario import load_scenario
from dispatcher.mission.plan import DispatchPlan, dispatch_plan
from planner.field_plan import plan_farm
from planner.solve import stop_after

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="session")
def dispatch() -> DispatchPlan:
    scenario = load_scenario(DATA / "tiny.toml")
    machines = [v.machine for v in scenario.vehicles]
    plan = plan_farm(scenario.farm, machines, "makespan", "ighoa", stop_after(20), seed=1)
    return dispatch_plan(scenario, plan)
