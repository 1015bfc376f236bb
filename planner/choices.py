"""What a scenario may choose for the solver: the objective and the algorithm.

Kept apart from the compiled kernels (:mod:`planner.cost`, :mod:`planner.solve`) so that
loading a scenario, a simulator or the bridge never imports numba.
"""

from __future__ import annotations

from enum import IntEnum

ALGORITHMS = ("ighoa", "ga", "hybrid")
DEFAULT_ALGORITHM = "hybrid"
"""``ighoa``: the paper's hybrid (simulated annealing, then the genetic algorithm with its
local search); ``ga``: the classic genetic algorithm it is compared with; ``hybrid`` (the
default since it beat ``ighoa`` on every cell measured, benchmarks/RESULTS.md): IGHOA with
Or-opt, 2-opt* between routes, a giant-tour individual and an iterated local search on the
elite (planner.hybrid, docs/ighoa.md)."""

SLACK_SHARE = 0.2
"""Under the makespan with a makespan slack ε > 0 (``[solver] makespan_slack``), the last
share of the time in which a makespan up to (1 + ε) times the best found by then counts as
equal to it and the road distance decides (``hybrid`` only:
:meth:`planner.hybrid.HybridParams.with_makespan_slack`)."""
MAX_SLACK = 0.1
"""The most makespan a slack may give up for road distance (10 %)."""


def check_makespan_slack(slack: float) -> float:
    """``slack`` if it is a makespan slack (within [0, :data:`MAX_SLACK`]); else ValueError."""
    if not 0.0 <= slack <= MAX_SLACK:
        raise ValueError(f"a makespan slack must be within [0, {MAX_SLACK:g}], not {slack:g}")
    return slack


class Objective(IntEnum):
    """What the solver minimises; the integer is what the kernels switch on."""

    DISTANCE = 0  # sum s_i, the paper's formula (3); "minsum" on TSPLIB
    TIME = 1  # sum t_i
    FUEL = 2  # sum c_i
    MAKESPAN = 3  # max t_i: when the whole farm is done
    MINMAX = 4  # max s_i: the longest route

    @classmethod
    def parse(cls, name: str | Objective) -> Objective:
        if isinstance(name, Objective):
            return name
        key = {"minsum": "distance", "min-sum": "distance", "min-max": "minmax"}.get(
            name.lower(), name.lower()
        )
        try:
            return cls[key.upper()]
        except KeyError:
            names = ", ".join(o.name.lower() for o in cls)
            raise ValueError(f"unknown objective {name!r}; choose one of {names}, minsum") from None
