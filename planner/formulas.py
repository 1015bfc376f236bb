"""The paper's formula (5), a machine's fuel, in plain arithmetic.

    c_i = s_i / v_i * c_vi + sum_j n_turn(i,j) * t_T(i) * c_vi + sum_j S_j / w_i * c_wi  (5)

Driving (s_i / v_i) and turning burn at the road rate c_v, working (S / w) at the work
rate c_w. The solver's tables (:class:`planner.cost.CostTables`), a plan's figures
(:func:`planner.field_plan.machine_figures`) and the review of a log (what was driven)
all charge fuel through :func:`fuel_l`; it takes floats or numpy arrays alike and loads
no solver, so the review needs no numba.
"""

from __future__ import annotations

from typing import overload

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@overload
def fuel_l(  # type: ignore[overload-overlap]  # floats in, a float out
    road_h: float, turn_h: float, work_h: float, road_fuel_lh: float, work_fuel_lh: float
) -> float: ...
@overload
def fuel_l(
    road_h: float | Array,
    turn_h: float | Array,
    work_h: float | Array,
    road_fuel_lh: float | Array,
    work_fuel_lh: float | Array,
) -> Array: ...
def fuel_l(
    road_h: float | Array,
    turn_h: float | Array,
    work_h: float | Array,
    road_fuel_lh: float | Array,
    work_fuel_lh: float | Array,
) -> float | Array:
    """Formula (5): litres for ``road_h`` hours driven and ``turn_h`` turning at the road
    rate ``road_fuel_lh``, and ``work_h`` working at ``work_fuel_lh`` (L/h)."""
    return (road_h + turn_h) * road_fuel_lh + work_h * work_fuel_lh
