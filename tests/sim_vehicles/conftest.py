"""Fixtures for the simulator tests: a tiny real mission, its machine, a MAVLink wire."""

from __future__ import annotations

import pytest
from helpers.mavlink_wire import Wire

from dispatcher.config.scenario import Implement, Vehicle
from dispatcher.mission.build import (
    FieldVisit,
    LatLon,
    Mission,
    MissionSpec,
    build_mission,
)
from planner.problem import Machine

VEHICLE_SYSTEM = 7
GARAGE = LatLon(44.0030000, 87.2995000)  # near the Changji demo farm
SERVO = Implement(kind="servo", channel=9, pwm_down=1900, pwm_up=1100)

# One field, three ~160 m swaths going east/west 6 m apart, ~200 m north of the garage.
FIELD = FieldVisit(
    field_id="f1",
    swaths=(
        (LatLon(44.0045000, 87.3000000), LatLon(44.0045000, 87.3020000)),
        (LatLon(44.0045540, 87.3020000), LatLon(44.0045540, 87.3000000)),
        (LatLon(44.0046080, 87.3000000), LatLon(44.0046080, 87.3020000)),
    ),
)


@pytest.fixture
def wire() -> Wire:
    return Wire(VEHICLE_SYSTEM)


@pytest.fixture
def home_lonlat() -> tuple[float, float]:
    return GARAGE.lon, GARAGE.lat


@pytest.fixture
def mission() -> Mission:
    """13 items: home, road speed, entry (= first swath start), work speed, implement
    down, 5 swath waypoints, implement up, road speed, garage."""
    spec = MissionSpec(
        machine_id="t7",
        home=GARAGE,
        road_speed_kmh=10.0,
        work_speed_kmh=3.6,
        implement=SERVO,
        visits=(FIELD,),
    )
    return build_mission(spec)


@pytest.fixture
def vehicle() -> Vehicle:
    machine = Machine(
        "t7",
        working_width_m=6.0,
        capacity_m2h=20000.0,
        road_speed_kmh=10.0,
        turn_time_h=0.004,
        road_fuel_lh=3.0,
        work_fuel_lh=7.0,
        work_speed_kmh=3.6,
    )
    return Vehicle(machine, VEHICLE_SYSTEM, SERVO)
