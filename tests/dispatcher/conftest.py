"""A small plan of the tiny farm (tests/data/tiny.toml), shared by the dispatcher's tests."""

import dataclasses
from pathlib import Path

import pytest

from dispatcher.config.scenario import Scenario, load_scenario
from dispatcher.mission.plan import DispatchPlan, dispatch_plan
from planner.field_plan import plan_farm
from planner.solve import stop_after

DATA = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture(scope="session")
def dispatch() -> DispatchPlan:
    return _tiny_plan(load_scenario(DATA / "tiny.toml"))


@pytest.fixture(scope="session")
def dispatch_turning() -> DispatchPlan:
    """The same, v1 turning on arcs of 2 m (its implement raised for each turn and lowered
    again after it, ``implement_lower``); the tiny farm's machines turn on the spot."""
    scenario = load_scenario(DATA / "tiny.toml")
    v1, *others = scenario.vehicles
    turning = dataclasses.replace(v1.machine, min_turn_radius_m=2.0)
    vehicles = [dataclasses.replace(v1, machine=turning), *others]
    return _tiny_plan(dataclasses.replace(scenario, vehicles=tuple(vehicles)))


def _tiny_plan(scenario: Scenario) -> DispatchPlan:
    machines = [v.machine for v in scenario.vehicles]
    plan = plan_farm(scenario.farm, machines, "makespan", "ighoa", stop_after(20), seed=1)
    return dispatch_plan(scenario, plan)
