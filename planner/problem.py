"""The task-allocation problem: machines, tasks (fields), where each machine starts and ends.

Everything here is immutable and checked once at construction; the solver kernels only
see the numpy arrays of :class:`Problem`. Units follow the paper's Table 1: distances in
metres, speeds in km/h, areas in m², capacities in m²/h, times in hours, fuel in L/h.

A problem is built from the paper's parameters with :func:`Problem.build`; the
per-machine, per-task work (turns, hours) defaults to the paper's rectangle model and can
be replaced by real coverage geometry (``turns=`` and ``work_hours=``).
Each machine has its own start and end point, so a re-plan can start vehicles where they
are (:meth:`Problem.starting_at`); the paper's garage is the case where all of them are the
same point. A machine may also be busy for ``ready_h`` hours before it can start (the rest
of the swath it is on), and a task may be pinned to the machine already working it
(``pinned_machine``): every solution then keeps it first in that machine's route.
A machine that is not available is simply left out of the problem
(:meth:`Problem.only_machines`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from planner.errors import ProblemError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
XY = tuple[float, float]
NOT_PINNED = -1


@dataclass(frozen=True)
class Machine:
    """One agricultural machine, with the parameters of the paper's Table 1."""

    id: str
    working_width_m: float  # d_i
    capacity_m2h: float  # w_i, area worked per hour
    road_speed_kmh: float  # v_i, speed when not working
    turn_time_h: float  # t_T(i), one U-turn
    road_fuel_lh: float  # c_vi, fuel when not working (also charged for turns, formula 5)
    work_fuel_lh: float  # c_wi, fuel when working
    work_speed_kmh: float = 8.0  # v_ai, speed along a swath (missions; not in formulas 1-6)
    # Smallest radius the machine (with its implement) can turn on; 0 = the paper's model,
    # where a U-turn is a hop between swath ends costing t_T.
    min_turn_radius_m: float = 0.0

    def __post_init__(self) -> None:
        _check_id("machine", self.id)
        for name in ("working_width_m", "capacity_m2h", "road_speed_kmh", "work_speed_kmh"):
            _check_positive(f"machine {self.id!r}: {name}", getattr(self, name))
        for name in ("turn_time_h", "road_fuel_lh", "work_fuel_lh", "min_turn_radius_m"):
            _check_non_negative(f"machine {self.id!r}: {name}", getattr(self, name))


@dataclass(frozen=True)
class Task:
    """One field to work: its position and the rectangle of the paper's model."""

    id: str
    x: float  # metres in the local frame (or TSPLIB units)
    y: float
    area_m2: float = 0.0  # S_j
    width_m: float = 0.0  # d_Tj, across the working direction
    length_m: float = 0.0  # l_Tj, along the working direction

    def __post_init__(self) -> None:
        _check_id("task", self.id)
        _check_finite(f"task {self.id!r}: x", self.x)
        _check_finite(f"task {self.id!r}: y", self.y)
        for name in ("area_m2", "width_m", "length_m"):
            _check_non_negative(f"task {self.id!r}: {name}", getattr(self, name))


def swaths_across(field_width_m: float, working_width_m: float) -> int:
    """Parallel swaths of width d_i that cover a rectangle ``field_width_m`` (d_T) across:
    ceil(d_T / d_i); 0 for a task of no width (a TSPLIB city)."""
    if field_width_m <= 0.0:
        return 0
    return math.ceil(field_width_m / working_width_m - 1e-9)


def rectangle_turns(field_width_m: float, working_width_m: float) -> int:
    """The paper's n_turn(i, j) of formulas (5) and (6): ceil(d_T / d_i), a U-turn a swath.

    The paper gives no formula for it. Its own Tables 8 and 10 (Σt of four routes, to four
    decimals, from the assignments it prints) come out with this count and Table 7's first
    column ("Lengths") as d_T, and with no other rule tried (the turns between swaths,
    ceil(d_T / d_i) - 1, of either column, gave 0.42 h more; docs/ighoa.md). Real fields
    count their turns from the coverage laid out (:mod:`planner.coverage`)."""
    return swaths_across(field_width_m, working_width_m)


@dataclass(frozen=True)
class Problem:
    """An immutable problem instance, arrays indexed [machine, task] or [task, task].

    ``dist[j, k]`` is the driving distance from task j to task k; ``start_dist[i, j]`` from
    machine i's start to task j and ``end_dist[i, j]`` from task j to machine i's end.
    ``turns[i, j]`` and ``work_hours[i, j]`` are what task j costs machine i inside the field.
    ``ready_h[i]`` is how long machine i is busy before it can start its route (added to its
    route time t_i when the route has a task; an idle machine costs nothing, so a busy but
    idle machine never sets the makespan). ``pinned_machine[j]`` is the machine task j must
    stay with, first in its route, or :data:`NOT_PINNED`; at most one task per machine.
    Both default to "none" (an empty array given is read as that).
    """

    machines: tuple[Machine, ...]
    tasks: tuple[Task, ...]
    dist: FloatArray
    start_dist: FloatArray
    end_dist: FloatArray
    turns: FloatArray
    work_hours: FloatArray
    min_tasks_per_machine: int = 1
    name: str = "problem"
    depot: tuple[float, float] | None = field(default=None)
    ready_h: FloatArray = field(default_factory=lambda: np.zeros(0))
    pinned_machine: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        m, n = len(self.machines), len(self.tasks)
        if isinstance(self.ready_h, np.ndarray) and self.ready_h.size == 0 and m:
            object.__setattr__(self, "ready_h", np.zeros(m))
        if isinstance(self.pinned_machine, np.ndarray) and self.pinned_machine.size == 0 and n:
            object.__setattr__(self, "pinned_machine", np.full(n, NOT_PINNED, dtype=np.int64))
        if m == 0:
            raise ProblemError("no machines: the fleet is empty")
        if n == 0:
            raise ProblemError("no tasks: there is nothing to plan")
        _check_unique("machine", [mc.id for mc in self.machines])
        _check_unique("task", [t.id for t in self.tasks])
        if self.min_tasks_per_machine not in (0, 1):
            raise ProblemError(
                f"min_tasks_per_machine must be 0 or 1, not {self.min_tasks_per_machine}"
            )
        if self.min_tasks_per_machine * m > n:
            raise ProblemError(
                f"{m} machines need at least one task each but there are only {n} tasks"
            )
        for name, shape in (
            ("dist", (n, n)),
            ("start_dist", (m, n)),
            ("end_dist", (m, n)),
            ("turns", (m, n)),
            ("work_hours", (m, n)),
        ):
            arr = getattr(self, name)
            if not isinstance(arr, np.ndarray) or arr.dtype != np.float64 or arr.shape != shape:
                raise ProblemError(f"{name} must be a float64 array of shape {shape}")
            if not np.all(np.isfinite(arr)):
                raise ProblemError(f"{name} has a NaN or infinite entry")
            if np.any(arr < 0):
                raise ProblemError(f"{name} has a negative entry")
            arr.setflags(write=False)
        ready = self.ready_h
        if not isinstance(ready, np.ndarray) or ready.dtype != np.float64 or ready.shape != (m,):
            raise ProblemError(f"ready_h must be a float64 array of shape ({m},)")
        for i, value in enumerate(ready):
            _check_non_negative(f"machine {self.machines[i].id!r}: ready_h", float(value))
        ready.setflags(write=False)
        self._check_pins()

    def _check_pins(self) -> None:
        m, n = len(self.machines), len(self.tasks)
        pins = self.pinned_machine
        if not isinstance(pins, np.ndarray) or pins.dtype != np.int64 or pins.shape != (n,):
            raise ProblemError(f"pinned_machine must be an int64 array of shape ({n},)")
        holder: dict[int, str] = {}
        for j, i in enumerate(pins.tolist()):
            if i == NOT_PINNED:
                continue
            task = self.tasks[j].id
            if not 0 <= i < m:
                raise ProblemError(f"task {task!r} is pinned to machine {i}, not one of 0..{m - 1}")
            if i in holder:
                raise ProblemError(
                    f"machine {self.machines[i].id!r} has two pinned tasks, "
                    f"{holder[i]!r} and {task!r}: it works one field at a time"
                )
            holder[i] = task
        pins.setflags(write=False)

    @classmethod
    def build(
        cls,
        machines: Sequence[Machine],
        tasks: Sequence[Task],
        depot: tuple[float, float],
        *,
        dist: FloatArray | None = None,
        depot_dist: FloatArray | None = None,
        turns: FloatArray | None = None,
        work_hours: FloatArray | None = None,
        min_tasks_per_machine: int = 1,
        name: str = "problem",
    ) -> Problem:
        """A problem where every machine starts and ends at ``depot`` (the paper's garage).

        Distances default to the straight line of formula (2); turns and work hours to the
        paper's rectangle model: n_turn from d_T and d_i (:func:`rectangle_turns`), work
        hours S_j / w_i.
        """
        machines, tasks = tuple(machines), tuple(tasks)
        if not machines:
            raise ProblemError("no machines: the fleet is empty")
        if not tasks:
            raise ProblemError("no tasks: there is nothing to plan")
        for label, value in (("depot x", depot[0]), ("depot y", depot[1])):
            _check_finite(label, value)
        xy = np.array([[t.x, t.y] for t in tasks], dtype=np.float64)
        if dist is None:
            dist = euclidean_matrix(xy)
        if depot_dist is None:
            depot_dist = np.hypot(xy[:, 0] - depot[0], xy[:, 1] - depot[1])
        m = len(machines)
        start = np.tile(np.asarray(depot_dist, dtype=np.float64), (m, 1))
        if turns is None:
            turns = np.array(
                [
                    [rectangle_turns(t.width_m, mc.working_width_m) for t in tasks]
                    for mc in machines
                ],
                dtype=np.float64,
            )
        if work_hours is None:
            work_hours = np.array(
                [[t.area_m2 / mc.capacity_m2h for t in tasks] for mc in machines],
                dtype=np.float64,
            )
        return cls(
            machines=machines,
            tasks=tasks,
            dist=np.array(dist, dtype=np.float64),
            start_dist=start,
            end_dist=start.copy(),
            turns=np.array(turns, dtype=np.float64),
            work_hours=np.array(work_hours, dtype=np.float64),
            min_tasks_per_machine=min_tasks_per_machine,
            name=name,
            depot=(float(depot[0]), float(depot[1])),
        )

    @property
    def num_machines(self) -> int:
        return len(self.machines)

    @property
    def num_tasks(self) -> int:
        return len(self.tasks)

    def machine_array(self, attr: str) -> FloatArray:
        """One machine parameter as an array over the fleet."""
        return np.array([getattr(mc, attr) for mc in self.machines], dtype=np.float64)

    @property
    def has_pins(self) -> bool:
        return bool(np.any(self.pinned_machine != NOT_PINNED))

    def starting_at(
        self,
        positions: Sequence[XY | None],
        *,
        ready_h: Sequence[float] | None = None,
        distance: Callable[[XY, Task], float] | None = None,
    ) -> Problem:
        """The same problem with machine i starting at ``positions[i]`` now (``None``: where
        it started before), and busy for ``ready_h[i]`` hours first; ends are unchanged
        (the garage for a problem from :meth:`build`). Distances from a position to a task
        are straight lines to the task's point, or ``distance(position, task)``."""
        m = self.num_machines
        if len(positions) != m:
            raise ProblemError(f"{len(positions)} start positions given for {m} machines")
        start = np.array(self.start_dist, dtype=np.float64)
        for i, pos in enumerate(positions):
            if pos is None:
                continue
            label = f"machine {self.machines[i].id!r}: start"
            _check_finite(f"{label} x", pos[0])
            _check_finite(f"{label} y", pos[1])
            for j, task in enumerate(self.tasks):
                start[i, j] = (
                    distance(pos, task)
                    if distance
                    else math.hypot(task.x - pos[0], task.y - pos[1])
                )
        ready = self.ready_h if ready_h is None else np.array(ready_h, dtype=np.float64)
        return replace(self, start_dist=start, ready_h=np.array(ready, dtype=np.float64))

    def pinned(self, pins: dict[int, int]) -> Problem:
        """The same problem with task j pinned to machine i for each ``{j: i}`` (others
        as they were)."""
        arr = np.array(self.pinned_machine, dtype=np.int64)
        for j, i in pins.items():
            if not 0 <= j < self.num_tasks:
                raise ProblemError(f"cannot pin task {j}: there are {self.num_tasks} tasks")
            arr[j] = i
        return replace(self, pinned_machine=arr)

    def only_machines(self, keep: Sequence[int]) -> Problem:
        """The same tasks for a subset of the machines (the available ones), in ``keep``
        order; pins to a machine left out are dropped (the task becomes an ordinary one)."""
        idx = [int(i) for i in keep]
        if not idx:
            raise ProblemError("no machines: the fleet is empty")
        new_index = {old: new for new, old in enumerate(idx)}
        pins = np.array(
            [new_index.get(int(i), NOT_PINNED) for i in self.pinned_machine], dtype=np.int64
        )
        min_tasks = self.min_tasks_per_machine if len(idx) <= self.num_tasks else 0
        return replace(
            self,
            machines=tuple(self.machines[i] for i in idx),
            start_dist=np.array(self.start_dist[idx]),
            end_dist=np.array(self.end_dist[idx]),
            turns=np.array(self.turns[idx]),
            work_hours=np.array(self.work_hours[idx]),
            ready_h=np.array(self.ready_h[idx]),
            pinned_machine=pins,
            min_tasks_per_machine=min_tasks,
        )


def euclidean_matrix(xy: FloatArray) -> FloatArray:
    """Formula (2): straight-line distances between all pairs of points."""
    diff = xy[:, None, :] - xy[None, :, :]
    return np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))


def _check_id(kind: str, value: object) -> None:
    if not isinstance(value, str) or not value:
        raise ProblemError(f"{kind} id must be a non-empty string, not {value!r}")


def _check_finite(label: str, value: float) -> None:
    if not isinstance(value, int | float) or not math.isfinite(value):
        raise ProblemError(f"{label} must be a finite number, not {value!r}")


def _check_positive(label: str, value: float) -> None:
    _check_finite(label, value)
    if value <= 0:
        raise ProblemError(f"{label} must be positive, not {value!r}")


def _check_non_negative(label: str, value: float) -> None:
    _check_finite(label, value)
    if value < 0:
        raise ProblemError(f"{label} must not be negative, not {value!r}")


def _check_unique(kind: str, ids: Sequence[str]) -> None:
    seen: set[str] = set()
    for ident in ids:
        if ident in seen:
            raise ProblemError(f"duplicate {kind} id {ident!r}")
        seen.add(ident)
