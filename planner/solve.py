"""The planner's one entry point: ``solve(problem, objective, algorithm, stop, seed)``.

Python drives the generations; each generation is one compiled call. Stopping criteria
are small callables started on their first call, so numba's compilation (done by
:func:`warm_up` before the clock starts) is never charged to a time limit.

The search is anytime: a :class:`StopFlag` set from another thread (a re-plan that must
answer now) is looked at between generations, between the steps of one, and between the
individuals of the initial population, so :func:`solve` returns the best solution found so
far soon after (well under 100 ms on a farm's few dozen fields, once the kernels are
compiled); the compiled phases see it through their clock (:func:`planner.local_search.
stop_on`). A warm start (``initial_routes``, e.g. the remaining routes of the plan being
carried out) enters the first population, so the result is never worse than it. With
``hybrid`` it is a re-plan's starting point: the tasks of no route (a machine gone) are put
where they cost least, and the rest of the first population are variants of it (ruin and
recreate) instead of annealed random tours.

A time limit (:class:`MaxRuntime`, or :class:`UntilDeadline`: the rest of a whole plan's
limit, :func:`planner.field_plan.plan_farm`) is looked at in the same places as the flag,
and inside the local search (its kernels take the moment as a deadline), so on a huge
instance too the search returns soon after the limit with its best so far: the initial
population's SA pre-planning gives way to random orders, a generation's polishing stops.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from planner import ga, hybrid, ighoa
from planner.choices import ALGORITHMS, DEFAULT_ALGORITHM, check_makespan_slack
from planner.cost import (
    CostTables,
    Figures,
    Objective,
    evaluate,
    evaluate_population,
    figures,
    split_routes,
)
from planner.cyclic_exchange import cyclic_exchange
from planner.errors import Deadline
from planner.local_search import (
    allocation_search,
    improve_allocation,
    nearest_neighbours,
    optimal_split,
    stop_on,
)
from planner.moves import recreate
from planner.operators import improve_routes
from planner.pins import repair_pins
from planner.population import random_counts
from planner.problem import Problem
from planner.relaxation import hour_weights
from planner.rng import make_state, randint, shuffle
from planner.sa import AnnealingParams, anneal

log = logging.getLogger(__name__)

ILS_CHUNK = 20  # ILS steps between two looks at the stop criteria (hybrid)


class MaxGenerations:
    """Stop after ``limit`` generations (the paper's MAXGEN); 0 returns the best of the
    initial population (with a warm start: the warm start, unless beaten)."""

    def __init__(self, limit: int) -> None:
        if limit < 0:
            raise ValueError(f"the generation limit must not be negative, not {limit}")
        self.limit = limit
        self.done = 0

    def start(self) -> None:
        self.done = 0

    def __call__(self, best_cost: float) -> bool:
        self.done += 1
        return self.done >= self.limit

    def progress(self) -> float:
        return min(self.done / self.limit, 1.0)


class MaxRuntime:
    """Stop once ``seconds`` of wall-clock time have passed since the first call."""

    def __init__(self, seconds: float) -> None:
        if not seconds > 0:
            raise ValueError(f"the time limit must be positive, not {seconds}")
        self.seconds = seconds
        self.started: float | None = None

    def start(self) -> None:
        self.started = time.perf_counter()

    def __call__(self, best_cost: float) -> bool:
        if self.started is None:
            self.start()
        return self.elapsed() >= self.seconds

    def elapsed(self) -> float:
        return 0.0 if self.started is None else time.perf_counter() - self.started

    def progress(self) -> float:
        return min(self.elapsed() / self.seconds, 1.0)

    def expired(self) -> bool:
        """Whether the limit has passed (never before the clock is started)."""
        return self.started is not None and self.elapsed() >= self.seconds

    def deadline(self) -> float:
        """The end of the limit on :func:`time.monotonic` (infinite before the start)."""
        if self.started is None:
            return math.inf
        return time.monotonic() + self.seconds - self.elapsed()


class UntilDeadline:
    """Stop once ``deadline`` has passed: a moment fixed before the search starts (the end
    of a whole plan's time limit, of which coverage has used a part); progress is the
    share of the time left at the start that has gone."""

    def __init__(self, deadline: Deadline) -> None:
        self.deadline = deadline
        self.started: float | None = None
        self.budget = math.inf

    def start(self) -> None:
        self.started = time.monotonic()
        self.budget = self.deadline.at - self.started

    def __call__(self, best_cost: float) -> bool:
        return self.deadline.expired()

    def expired(self) -> bool:
        return self.deadline.expired()

    def progress(self) -> float:
        if self.started is None or not math.isfinite(self.budget):
            return 0.0
        if self.budget <= 0.0:
            return 1.0
        return min((time.monotonic() - self.started) / self.budget, 1.0)


class StopFlag:
    """Stop as soon as ``event`` is set, from any thread (the search returns its best so
    far); a flag already set when the run starts stops it before the first generation."""

    def __init__(self, event: threading.Event | None = None) -> None:
        self.event = event if event is not None else threading.Event()

    def set(self) -> None:
        self.event.set()

    def is_set(self) -> bool:
        return self.event.is_set()

    def start(self) -> None:
        """Nothing to reset: a flag is the caller's to clear."""

    def __call__(self, best_cost: float) -> bool:
        return self.event.is_set()

    def progress(self) -> float:
        return 0.0


Criterion = MaxGenerations | MaxRuntime | UntilDeadline | StopFlag

FLAG_ONLY_S = 1e9
"""The deadline the kernels are given when a stop flag is the only thing that ends a run
(31 years: never, but finite, so that they look at the clock)."""


class AnyOf:
    """Stop as soon as any criterion says so; progress is the furthest along."""

    def __init__(self, *criteria: Criterion) -> None:
        if not criteria:
            raise ValueError("give at least one stopping criterion")
        self.criteria = criteria

    def start(self) -> None:
        for criterion in self.criteria:
            criterion.start()

    def __call__(self, best_cost: float) -> bool:
        # Call every criterion so that each one's clock and counter advance.
        return any([criterion(best_cost) for criterion in self.criteria])

    def progress(self) -> float:
        return max(criterion.progress() for criterion in self.criteria)

    @property
    def max_generations(self) -> int:
        limits = [c.limit for c in self.criteria if isinstance(c, MaxGenerations)]
        return min(limits) if limits else 1_000_000

    @property
    def time_limit_s(self) -> float | None:
        """The shortest :class:`MaxRuntime` limit among the criteria (``None``: none)."""
        limits = [c.seconds for c in self.criteria if isinstance(c, MaxRuntime)]
        return min(limits) if limits else None

    def interrupted(self) -> bool:
        """Whether a :class:`StopFlag` among the criteria is set or a time limit has
        passed (looked at mid-generation)."""
        for c in self.criteria:
            if isinstance(c, StopFlag):
                if c.is_set():
                    return True
            elif isinstance(c, MaxRuntime | UntilDeadline) and c.expired():
                return True
        return False

    @property
    def flags(self) -> tuple[threading.Event, ...]:
        """The events of the :class:`StopFlag` criteria."""
        return tuple(c.event for c in self.criteria if isinstance(c, StopFlag))

    def deadline(self) -> float:
        """The earliest end of a time limit among the criteria, on :func:`time.monotonic`
        (infinite: none), for the compiled local search to look at; with a stop flag and no
        limit, :data:`FLAG_ONLY_S` from now, so that the kernels look at the clock, which
        sees the flag (:func:`planner.local_search.stop_on`)."""
        ends = [c.deadline() for c in self.criteria if isinstance(c, MaxRuntime)]
        ends += [c.deadline.at for c in self.criteria if isinstance(c, UntilDeadline)]
        if not ends and self.flags:
            ends.append(time.monotonic() + FLAG_ONLY_S)
        return min(ends, default=math.inf)

    def within(self, deadline: Deadline) -> AnyOf:
        """These criteria and :class:`UntilDeadline` ``deadline`` (these alone when it
        never passes)."""
        if not deadline.limited:
            return self
        return AnyOf(*self.criteria, UntilDeadline(deadline))


def stop_after(
    generations: int | None = 2000,
    seconds: float | None = None,
    flag: StopFlag | threading.Event | None = None,
) -> AnyOf:
    """The usual criterion: MAXGEN generations or a wall-clock limit, whichever first, or
    as soon as ``flag`` is set."""
    criteria: list[Criterion] = []
    if generations is not None:
        criteria.append(MaxGenerations(generations))
    if seconds is not None:
        criteria.append(MaxRuntime(seconds))
    if flag is not None:
        criteria.append(flag if isinstance(flag, StopFlag) else StopFlag(flag))
    return AnyOf(*criteria)


@dataclass(frozen=True)
class Result:
    """A solution with every cost figure and the search's history."""

    problem: Problem
    objective: Objective
    algorithm: str
    seed: int
    routes: tuple[tuple[int, ...], ...]  # task indices per machine, in driving order
    figures: Figures
    # Best objective value after each generation (hybrid under the makespan: in the last
    # distance_share of the time up to distance_slack above the best before, and under a
    # deadline up to it once a plan meets it, for distance).
    history: tuple[float, ...]
    generations: int
    elapsed_s: float
    stats: dict[str, float] = field(default_factory=dict)

    @property
    def cost(self) -> float:
        """The objective's figure for this solution (no tie-breaker)."""
        return self.figures.value(self.objective)

    def route_ids(self) -> list[list[str]]:
        return [[self.problem.tasks[j].id for j in route] for route in self.routes]


GenerationCallback = Callable[[int, float, float], None]


def solve(
    problem: Problem,
    objective: str | Objective = Objective.DISTANCE,
    algorithm: str = DEFAULT_ALGORITHM,
    stop: AnyOf | Criterion | None = None,
    seed: int = 1,
    params: ighoa.IGHOAParams | hybrid.HybridParams | ga.GAParams | None = None,
    annealing: AnnealingParams | None = None,
    on_generation: GenerationCallback | None = None,
    initial_routes: Sequence[Sequence[int]] | None = None,
    makespan_slack: float = 0.0,
    finish_within_h: float = 0.0,
) -> Result:
    """Allocate and order the tasks of ``problem`` over its machines.

    ``on_generation(generation, best_cost, elapsed_s)`` is called after every generation.
    ``initial_routes`` (task indices per machine, in driving order) is a warm start put
    into the first population: see :func:`warm_chromosome` for how an incomplete one is
    completed. The result is never worse than it, and equal to it when no generation runs
    (``MaxGenerations(0)``, or a :class:`StopFlag` already set) and nothing in the first
    population beats it.

    ``makespan_slack`` ε > 0 (``hybrid`` with its defaults: no ``params``) makes the
    makespan and the road distance ε-lexicographic
    (:meth:`planner.hybrid.HybridParams.with_makespan_slack`); under the other objectives
    it does nothing.

    ``finish_within_h`` > 0 (``hybrid``) is a deadline on the makespan: once a plan
    finishes within that many hours, every plan that does counts as equal and the road
    distance decides between them (the ε-constraint form of the two objectives); until
    then the makespan is minimised as without it, and if none is found in time the answer
    is the shortest makespan found. Under the other objectives it does nothing.
    """
    obj = Objective.parse(objective)
    if algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {algorithm!r}; choose one of {', '.join(ALGORITHMS)}")
    check_makespan_slack(makespan_slack)
    if makespan_slack > 0.0:
        if algorithm != "hybrid":
            raise ValueError(f"a makespan slack needs algorithm hybrid, not {algorithm}")
        if params is not None:
            raise ValueError("a makespan slack sets hybrid's params: give one or the other")
        if obj is Objective.MAKESPAN:
            params = hybrid.HybridParams.with_makespan_slack(makespan_slack)
    if finish_within_h:
        _check_finish_within(finish_within_h, algorithm, makespan_slack)
        if obj is not Objective.MAKESPAN:
            finish_within_h = 0.0  # a deadline on the makespan: nothing to the others
    if stop is None:
        stop = stop_after()
    elif not isinstance(stop, AnyOf):
        stop = AnyOf(stop)
    if algorithm == "hybrid":
        params = params or hybrid.HybridParams()
        if not isinstance(params, hybrid.HybridParams):
            raise TypeError("hybrid takes HybridParams")
    elif algorithm == "ighoa":
        params = params or ighoa.IGHOAParams()
        if not isinstance(params, ighoa.IGHOAParams):
            raise TypeError("ighoa takes IGHOAParams")
    else:
        params = params or ga.GAParams()
        if not isinstance(params, ga.GAParams):
            raise TypeError("ga takes GAParams")
    annealing = annealing or AnnealingParams()
    warm = None if initial_routes is None else warm_chromosome(problem, initial_routes)
    warm_up()

    started = time.perf_counter()
    stop.start()
    stop_on(stop.flags)
    cost_tables = CostTables.of(problem)
    if (
        isinstance(params, hybrid.HybridParams)
        and obj is Objective.MAKESPAN
        and any(step != 0.0 for step in params.squeeze_steps)
        and params.weigh_hours
    ):
        cost_tables = replace(cost_tables, hour_weights=hour_weights(cost_tables, stop.deadline()))
    tables = cost_tables.kernel_args()
    pins = cost_tables.pinned_machine
    state = make_state(seed)
    n, m, pop = problem.num_tasks, problem.num_machines, params.population
    if isinstance(params, hybrid.HybridParams):
        pop = params.population_for(n)
    min_count = problem.min_tasks_per_machine
    perms = np.empty((pop, n), dtype=np.int64)
    counts = np.empty((pop, m), dtype=np.int64)
    neighbours = nearest_neighbours(problem.dist, getattr(params, "neighbours", 1))
    if warm is not None and isinstance(params, hybrid.HybridParams) and pop > 1:
        # A re-plan: the plan being carried out, its orphans (tasks of a machine gone) put
        # where they cost least, is individual 0; the warm start as given (orphans at the
        # end of the shortest route) individual 1; the rest are variants of individual 0
        # (ruin and recreate), not annealed random tours, which take most of a re-plan's
        # second and are far worse than the plan it starts from.
        perms[0], counts[0] = warm
        perms[1], counts[1] = warm
        orphans = _orphans(problem, warm, initial_routes)
        recreate(state, perms[0], counts[0], int(obj), tables, pins, orphans)
        hybrid.warm_population(
            state, perms, counts, 2, int(obj), tables, neighbours, max(params.ruin, params.perturb),
            min_count, pins,
        )  # fmt: skip
    else:
        _initial_population(
            state, perms, counts, min_count, pins, tables, annealing, stop,
            algorithm in ("ighoa", "hybrid"),
        )  # fmt: skip
        if isinstance(params, hybrid.HybridParams) and params.giant_tour and not stop.interrupted():
            hybrid.giant_tour(
                state,
                perms[pop - 1],
                counts[pop - 1],
                int(obj),
                tables,
                neighbours,  # the same lists (params.neighbours of hybrid)
                min_count,
                pins,
                stop.deadline(),
                params.tour_kicks * n,
                _tour_end(stop, params.tour_share),
            )
        if (
            isinstance(params, hybrid.HybridParams)
            and params.sweep
            and obj in (Objective.MINMAX, Objective.MAKESPAN)
            and pop > 1
            and not stop.interrupted()
        ):
            order = hybrid.sweep_order(problem)
            if order is not None:
                hybrid.sweep(
                    state,
                    perms[pop - 2],
                    counts[pop - 2],
                    order,
                    int(obj),
                    tables,
                    neighbours,
                    min_count,
                    pins,
                    stop.deadline(),
                    params.tour_kicks,
                    _tour_end(stop, params.tour_share),
                )
        if warm is not None:
            perms[0], counts[0] = warm
    costs = np.empty(pop)
    route_costs = np.empty((pop, m))
    evaluate_population(perms, counts, int(obj), tables, costs, route_costs)
    best = int(np.argmin(costs))
    if warm is not None and costs[0] <= costs[best]:
        best = 0  # a tie keeps the warm start
    elite_perm, elite_counts = perms[best].copy(), counts[best].copy()
    elite_route, elite_cost = route_costs[best].copy(), float(costs[best])
    # The ILS's walk (hybrid): starts at the elite, goes back to it when left behind.
    walk_perm, walk_counts = elite_perm.copy(), elite_counts.copy()
    walk_route, walk_cost = elite_route.copy(), elite_cost
    history: list[float] = []
    stats = {
        "crossovers": 0.0,
        "mutations": 0.0,
        "polish_gains": 0.0,
        "route_gains": 0.0,
        "other_gains": 0.0,
        "cyclic_exchange_gains": 0.0,
        "squeeze_exchange_gains": 0.0,
    }
    gen = 0
    # hybrid's makespan cap (0: none yet): finish_within_h once a plan is within it, or in
    # the last share of the time under a makespan slack.
    cap = 0.0
    # hybrid on the sums: the population starts again when its elite has not improved for
    # ``restart`` of the run; the best before (the record) is kept aside.
    restart = params.restart if isinstance(params, hybrid.HybridParams) else 0.0
    if obj in (Objective.MINMAX, Objective.MAKESPAN) or warm is not None:
        restart = 0.0
    record_perm, record_counts = elite_perm.copy(), elite_counts.copy()
    # Without restarts there is no record: the elite is the answer (under a makespan slack
    # it may give up some makespan for road distance in the last share of the time).
    record_cost = elite_cost if restart > 0.0 else math.inf
    # hybrid under the makespan: the elite with its roads shortened (cyclic_exchange).
    exchange_rounds = (
        params.cyclic_exchange_rounds
        if isinstance(params, hybrid.HybridParams) and obj == Objective.MAKESPAN
        else 0
    )
    exchanged_perm, exchanged_counts = elite_perm.copy(), elite_counts.copy()
    exchanged_route, exchanged_cost = elite_route.copy(), elite_cost
    exchange_state = make_state(seed + 0x5EED)
    exchanged_done = False
    # The elite's cost when it last improved, and the progress of the run then.
    improved_cost, improved_at = elite_cost, 0.0
    stats["restarts"] = 0.0
    while not stop.interrupted() and stop.max_generations > 0:
        gen += 1
        # hybrid under the makespan: the last distance_share of the time shortens the roads,
        # a makespan up to the cap (distance_slack over the best by then) counting as equal.
        late = (
            isinstance(params, hybrid.HybridParams)
            and obj == Objective.MAKESPAN
            and stop.progress() >= 1.0 - params.distance_share
        )
        if late and cap == 0.0:
            assert isinstance(params, hybrid.HybridParams)
            cap = float(elite_route.max()) * (1.0 + params.distance_slack)
        if cap == 0.0 and 0.0 < float(elite_route.max()) <= finish_within_h:
            cap = finish_within_h
        if isinstance(params, ighoa.IGHOAParams):
            sp = ighoa.adaptive_tolerance(
                stop.progress(), pop, stop.max_generations, params.tol_min, params.tol_max
            )
            cx, mu = ighoa.generation(
                state,
                perms,
                counts,
                costs,
                route_costs,
                int(obj),
                tables,
                min_count,
                pins,
                sp,
                params.pc_min,
                params.pc_mid,
                params.pc_max,
                params.pm,
                params.tournament_size,
                params.shift_counts,
                elite_perm,
                elite_counts,
                elite_route,
                elite_cost,
            )
            stats["crossovers"] += cx
            stats["mutations"] += mu
            _polish(
                stop,
                state,
                perms,
                counts,
                costs,
                route_costs,
                int(obj),
                tables,
                params,
                neighbours,
                min_count,
                pins,
                stats,
                cap,
            )
        else:
            ga.generation(
                state,
                perms,
                counts,
                costs,
                route_costs,
                int(obj),
                tables,
                min_count,
                pins,
                params.crossover_rate,
                params.mutation_rate,
                params.tournament_size,
                elite_perm,
                elite_counts,
                elite_route,
                elite_cost,
            )
        best = int(np.argmin(costs))
        if _capped(costs[best], route_costs[best], cap) < _capped(elite_cost, elite_route, cap):
            elite_perm[:], elite_counts[:] = perms[best], counts[best]
            elite_route[:], elite_cost = route_costs[best], float(costs[best])
        if (
            isinstance(params, hybrid.HybridParams)
            and (params.ils_on_sums or obj in (Objective.MINMAX, Objective.MAKESPAN))
            and not stop.interrupted()
        ):
            before = improved = _capped(elite_cost, elite_route, cap)
            walk_cost = _capped(walk_cost, walk_route, cap)
            # The walk goes back to the elite when left behind.
            if not hybrid.within_accept(walk_cost, before, cap, params.accept):
                walk_perm[:], walk_counts[:] = elite_perm, elite_counts
                walk_route[:], walk_cost = elite_route, before
            # Under the makespan (not in the slack's last share) the ILS is the squeeze.
            squeeze = params.squeeze_at(gen) if obj == Objective.MAKESPAN and cap == 0.0 else 0.0
            if squeeze != 0.0 and params.squeeze_exchange_rounds > 0:
                # The squeeze's walk first handed round by cyclic exchanges under its figure,
                # no route past the walk's makespan (a walk that comes out ahead of the
                # elite on the makespan is the new elite).
                target = float(elite_route.max()) * (1.0 - squeeze)
                if cyclic_exchange(
                    state, walk_perm, walk_counts, tables, pins, float(walk_route.max()),
                    params.squeeze_exchange_rounds, stop.deadline(), target,
                    float(params.squeeze_exchange_road), float(params.squeeze_exchange_empty),
                    min_count,
                ) > 0.0:  # fmt: skip
                    improve_routes(walk_perm, walk_counts, tables[0], tables[1], tables[2],
                                   neighbours, pins)  # fmt: skip
                    walk_cost = float(
                        evaluate(walk_perm, walk_counts, int(obj), tables, walk_route)
                    )
                    stats["squeeze_exchange_gains"] += 1.0
                    if walk_cost < improved:
                        elite_perm[:], elite_counts[:] = walk_perm, walk_counts
                        elite_route[:], improved = walk_route, walk_cost
            # In chunks, so that a stop flag is seen between them.
            for done in range(0, params.ils_steps, ILS_CHUNK):
                if stop.interrupted():
                    break
                improved, walk_cost = hybrid.ils_step(
                    state,
                    elite_perm,
                    elite_counts,
                    elite_route,
                    improved,
                    walk_perm,
                    walk_counts,
                    walk_route,
                    walk_cost,
                    int(obj),
                    tables,
                    neighbours,
                    min_count,
                    pins,
                    min(ILS_CHUNK, params.ils_steps - done),
                    params.perturb,
                    stop.deadline(),
                    params.move_mask,
                    params.lexicographic,
                    params.accept,
                    params.ruin,
                    params.ils_or_opt,
                    obj in (Objective.MINMAX, Objective.MAKESPAN) and cap == 0.0,
                    cap,
                    squeeze,
                )
            walk_cost -= _capped(0.0, walk_route, cap)
            if improved < before:
                elite_cost = float(improved) - _capped(0.0, elite_route, cap)
                _replace_worst(perms, counts, route_costs, costs, elite_perm, elite_counts,
                               elite_route, elite_cost)  # fmt: skip
        if (
            isinstance(params, hybrid.HybridParams)
            and params.route_kicks > 0
            and not stop.interrupted()
        ):
            # The elite's longest route (min-max: the one that sets the cost), or each in
            # turn (the sums), ordered again by the giant tour's ILS; under min-max one
            # other route in turn too: shorter routes that do not set the cost leave room
            # for the longest one's tasks, and the fleet's distance (the second objective)
            # falls.
            minmax = obj in (Objective.MINMAX, Objective.MAKESPAN)
            longest = int(np.argmax(elite_route)) if minmax else (gen - 1) % m
            turns = [(longest, "route_gains")]
            if minmax and params.other_routes and (gen - 1) % m != longest:
                turns.append(((gen - 1) % m, "other_gains"))
            for route, gains in turns:
                if stop.interrupted():
                    break
                kicks = params.route_kicks * int(elite_counts[route])
                if hybrid.route_ils(
                    state, elite_perm, elite_counts, route, tables, neighbours, pins, kicks,
                    stop.deadline(),
                ) > 0.0:  # fmt: skip
                    elite_cost = float(
                        evaluate(elite_perm, elite_counts, int(obj), tables, elite_route)
                    )
                    stats[gains] += 1.0
                    _replace_worst(perms, counts, route_costs, costs, elite_perm, elite_counts,
                                   elite_route, elite_cost)  # fmt: skip
        if exchange_rounds > 0 and not stop.interrupted():
            # The answer's roads: a copy of the elite (again whenever the elite beats it)
            # shortened by cyclic exchanges, no route past its makespan or the cap; once a
            # generation's rounds find nothing, none run until the elite changes. A copy,
            # with its own random stream: the elite's search goes as without it (applied
            # to the elite, the exchanges filled routes up to the makespan and the
            # makespan came out 0.1 % longer).
            if _capped(elite_cost, elite_route, cap) < _capped(
                exchanged_cost, exchanged_route, cap
            ):
                exchanged_perm[:], exchanged_counts[:] = elite_perm, elite_counts
                exchanged_route[:], exchanged_cost = elite_route, elite_cost
                exchanged_done = False
            if not exchanged_done:
                limit = max(cap, float(exchanged_route.max()))
                if cyclic_exchange(
                    exchange_state, exchanged_perm, exchanged_counts, tables, pins, limit,
                    exchange_rounds, stop.deadline(),
                ) > 0.0:  # fmt: skip
                    improve_routes(exchanged_perm, exchanged_counts, tables[0], tables[1],
                                   tables[2], neighbours, pins)  # fmt: skip
                    exchanged_cost = float(
                        evaluate(
                            exchanged_perm, exchanged_counts, int(obj), tables, exchanged_route
                        )
                    )
                    stats["cyclic_exchange_gains"] += 1.0
                else:
                    exchanged_done = True
        if restart > 0.0 and elite_cost < record_cost:
            record_perm[:], record_counts[:], record_cost = elite_perm, elite_counts, elite_cost
        if restart > 0.0 and not stop.interrupted():
            now = stop.progress()
            if elite_cost < improved_cost * (1.0 - 1e-9):
                improved_cost, improved_at = elite_cost, now
            elif now - improved_at >= restart and now <= 1.0 - 0.5 * restart:
                # A new population, as the first (annealed random orders): the GA breeds
                # away from the record, which it would otherwise fill the population with.
                _initial_population(
                    state, perms, counts, min_count, pins, tables, annealing, stop, True
                )
                evaluate_population(perms, counts, int(obj), tables, costs, route_costs)
                best = int(np.argmin(costs))
                elite_perm[:], elite_counts[:] = perms[best], counts[best]
                elite_route[:], elite_cost = route_costs[best], float(costs[best])
                walk_perm[:], walk_counts[:] = elite_perm, elite_counts  # ILS: from it too
                walk_route[:], walk_cost = elite_route, elite_cost
                improved_cost, improved_at = elite_cost, now
                stats["restarts"] += 1.0
        best_cost = min(elite_cost, record_cost)  # a restart's first elite may be worse
        history.append(best_cost)
        if on_generation is not None:
            on_generation(gen, best_cost, time.perf_counter() - started)
        if stop(best_cost):
            break
    if record_cost < elite_cost:
        elite_perm, elite_counts = record_perm, record_counts
    if exchange_rounds > 0 and _capped(exchanged_cost, exchanged_route, cap) < _capped(
        elite_cost, elite_route, cap
    ):
        elite_perm, elite_counts = exchanged_perm, exchanged_counts
    elapsed = time.perf_counter() - started
    routes = tuple(tuple(r) for r in split_routes(elite_perm, elite_counts))
    figs = figures(problem, routes)
    log.debug(
        "%s on %s: %.6g after %d generations, %.2fs",
        algorithm,
        problem.name,
        figs.value(obj),
        gen,
        elapsed,
    )
    return Result(
        problem=problem,
        objective=obj,
        algorithm=algorithm,
        seed=seed,
        routes=routes,
        figures=figs,
        history=tuple(history),
        generations=gen,
        elapsed_s=elapsed,
        stats=stats,
    )


def _check_finish_within(hours: float, algorithm: str, slack: float) -> None:
    """ValueError unless ``hours`` is a deadline :func:`solve` can take."""
    if not (math.isfinite(hours) and hours > 0.0):
        raise ValueError(f"finish_within_h must be a positive number of hours, not {hours:g}")
    if algorithm != "hybrid":
        raise ValueError(f"finish_within_h needs algorithm hybrid, not {algorithm}")
    if slack > 0.0:
        raise ValueError("finish_within_h and makespan_slack both cap the makespan: give one")


def _capped(cost: float, route_cost: np.ndarray, cap: float) -> float:
    """A min-max ``cost`` with its figure (``route_cost.max()``) taken as at least ``cap``
    (:func:`planner.cost.fleet_value`); 0: the cost as it is."""
    return float(cost) + max(0.0, cap - float(route_cost.max())) if cap > 0.0 else float(cost)


def _replace_worst(  # type: ignore[no-untyped-def]
    perms, counts, route_costs, costs, perm, cnt, route, cost: float
) -> None:
    """An improved elite (hybrid's ILS, its route ILS) enters the population in place of
    its worst chromosome, so that the GA breeds from it too."""
    worst = int(np.argmax(costs))
    perms[worst], counts[worst] = perm, cnt
    route_costs[worst], costs[worst] = route, cost


def _tour_end(stop: AnyOf, share: float) -> float:
    """When the giant tour's and the sweep's ILS stop kicking: after ``share`` of the time,
    or, when a generation limit is among the criteria, at the run's deadline alone (their
    kicks decide, not how fast this machine is: the same seed gives the same plan when the
    generations end the run)."""
    if any(isinstance(c, MaxGenerations) for c in stop.criteria):
        return stop.deadline()
    return _share_of(stop.deadline(), share)


def _share_of(deadline: float, share: float) -> float:
    """The moment ``share`` of the time from now to ``deadline`` (monotonic) has gone."""
    now = time.monotonic()
    return now + share * (deadline - now) if math.isfinite(deadline) else math.inf


def _polish(  # type: ignore[no-untyped-def]
    stop,
    state,
    perms,
    counts,
    costs,
    route_costs,
    objective,
    tables,
    params,
    neighbours,
    min_count,
    pins,
    stats,
    cap=0.0,
) -> None:
    """§4.5 on the generation's best (and, with the extended local search, on
    ``params.memetic`` random others); a polished chromosome replaces its original.
    Skipped as soon as ``stop`` is interrupted. ``cap``: hybrid's makespan cap in the last
    share of the time (:attr:`planner.hybrid.HybridParams.distance_share`; 0: none), up
    to which a makespan counts as equal."""
    targets = [int(np.argmin(costs))]
    if params.local_search == "extended" and params.memetic:
        targets += [randint(state, len(costs)) for _ in range(params.memetic)]
    for idx in dict.fromkeys(targets):
        if stop.interrupted():
            return
        perm, cnt, route = perms[idx].copy(), counts[idx].copy(), route_costs[idx].copy()
        route_nn = neighbours if params.local_search == "extended" else neighbours[:, :0]
        cost = ighoa.polish(
            state,
            perm,
            cnt,
            objective,
            tables,
            params.two_opt_tries,
            route,
            route_nn,
            pins,
            min_count,
        )
        if params.local_search == "extended":
            deadline = stop.deadline()
            if idx == targets[0]:
                optimal_split(perm, cnt, objective, tables, min_count, pins, deadline)
            if isinstance(params, hybrid.HybridParams):
                allocation_search(
                    perm, cnt, objective, tables, neighbours, min_count, 50, pins, deadline,
                    np.zeros(len(perm), dtype=np.bool_), False, params.move_mask,
                    params.lexicographic, cap,
                )  # fmt: skip
            else:
                improve_allocation(
                    perm, cnt, objective, tables, neighbours, min_count, 50, pins, deadline
                )
            if isinstance(params, hybrid.HybridParams) and params.or_opt:
                hybrid.or_opt_routes(perm, cnt, tables[0], tables[1], tables[2], neighbours, pins)
            cost = evaluate(perm, cnt, objective, tables, route)
        if _capped(cost, route, cap) < _capped(costs[idx], route_costs[idx], cap) - 1e-12:
            stats["polish_gains"] += 1
            perms[idx], counts[idx], route_costs[idx], costs[idx] = perm, cnt, route, cost


def warm_chromosome(
    problem: Problem, routes: Sequence[Sequence[int]]
) -> tuple[np.ndarray, np.ndarray]:
    """A warm start as a two-part chromosome. One route per machine, task indices in
    driving order, none twice; a task in no route is added at the end of the shortest
    route, and a route short of ``min_tasks_per_machine`` takes the last task of the
    longest one (so the remaining routes of a plan with a machine gone can be given as
    they are, that machine's route left out); pinned tasks are moved to the front of
    their machine's route."""
    m, n = problem.num_machines, problem.num_tasks
    if len(routes) != m:
        raise ValueError(f"the warm start has {len(routes)} routes for {m} machines")
    lists = [[int(j) for j in route] for route in routes]
    seen: set[int] = set()
    for route in lists:
        for j in route:
            if not 0 <= j < n:
                raise ValueError(f"the warm start names task {j}; there are {n} tasks")
            if j in seen:
                raise ValueError(f"the warm start has task {j} twice")
            seen.add(j)
    for j in range(n):
        if j not in seen:
            min(lists, key=len).append(j)
    for route in lists:
        while len(route) < problem.min_tasks_per_machine:
            route.append(max(lists, key=len).pop())
    perm = np.array([j for route in lists for j in route], dtype=np.int64)
    counts = np.array([len(route) for route in lists], dtype=np.int64)
    pins = np.ascontiguousarray(problem.pinned_machine, dtype=np.int64)
    repair_pins(perm, counts, pins, problem.min_tasks_per_machine)
    return perm, counts


def _orphans(
    problem: Problem, warm: tuple[np.ndarray, np.ndarray], routes: Sequence[Sequence[int]] | None
) -> np.ndarray:
    """The tasks of no route of the warm start ``routes`` (:func:`warm_chromosome` put them
    at the end of the shortest route), as many as can be taken out again: not pinned, and
    not below a route's minimum size."""
    given = {int(j) for route in routes or () for j in route}
    perm, counts = warm
    out: list[int] = []
    begin = 0
    for size in counts.tolist():
        route = perm[begin : begin + size].tolist()
        begin += size
        free = [j for j in route if j not in given and problem.pinned_machine[j] < 0]
        out += free[: max(size - problem.min_tasks_per_machine, 0)]
    return np.array(sorted(out), dtype=np.int64)


def _initial_population(  # type: ignore[no-untyped-def]
    state, perms, counts, min_count, pins, tables, annealing, stop, pre_plan
):
    """Every individual by :func:`_initial_individual`, annealed when ``pre_plan``. One
    call per individual, so that a stop flag is seen during a long pre-planning; once it
    is set the rest are random orders (cheap), never empty."""
    for p in range(perms.shape[0]):
        _initial_individual(
            state,
            perms[p],
            counts[p],
            min_count,
            pins,
            tables,
            pre_plan and not stop.interrupted(),
            annealing.t_start,
            annealing.t_end,
            annealing.alpha,
            annealing.chain,
        )


@njit(cache=True, nogil=True)
def _initial_individual(  # type: ignore[no-untyped-def]
    state, perm, counts, min_count, pins, tables, pre_plan, t_start, t_end, alpha, chain
):
    """§4.6 (1)-(2) for one individual: a random task order, annealed when ``pre_plan``
    (IGHOA's SA path pre-planning), with a random split of the tasks over the machines,
    repaired for its pinned tasks."""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    n = perm.shape[0]
    m = counts.shape[0]
    for k in range(n):
        perm[k] = k
    shuffle(state, perm)
    if pre_plan:
        anneal(state, perm, dist, start_dist, end_dist, t_start, t_end, alpha, chain)
    random_counts(state, n, m, min_count, counts)
    repair_pins(perm, counts, pins, min_count)


_warmed = False


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel on a tiny problem, once."""
    global _warmed
    if _warmed:
        return
    from planner.kernels import drop_stale_kernels
    from planner.problem import Machine, Task

    drop_stale_kernels()  # before any kernel of this process is loaded from the cache

    machines = [Machine(f"w{i}", 2.0, 10.0, 5.0, 0.01, 1.0, 2.0) for i in range(2)]
    tasks = [Task(f"t{j}", float(j), float(j % 2), 10.0, 4.0, 2.5) for j in range(5)]
    tiny = Problem.build(machines, tasks, (0.0, 0.0))
    _warmed = True
    for algorithm, params in (
        ("ighoa", ighoa.IGHOAParams(population=4)),
        ("hybrid", hybrid.HybridParams(population=4, ils_steps=2, ils_on_sums=True)),
        ("ga", ga.GAParams(population=4)),
    ):
        solve(
            tiny,
            Objective.DISTANCE,
            algorithm,
            stop_after(2),
            seed=0,
            params=params,
            annealing=AnnealingParams(t_start=2.0, t_end=1.0),
        )
    # hybrid from scratch under the min-max objectives: the sweep, and the ILS on its
    # routes (the first plan of a farm; `agrifleet bench mtsp --objective minmax`).
    for objective in (Objective.MINMAX, Objective.MAKESPAN):
        solve(
            tiny,
            objective,
            "hybrid",
            stop_after(2),
            seed=0,
            params=hybrid.HybridParams(population=4, ils_steps=2),
        )
    # A warm start (a re-plan) with a task of no route: hybrid's repair and variants.
    solve(
        tiny,
        Objective.MAKESPAN,
        "hybrid",
        stop_after(2),
        seed=0,
        params=hybrid.HybridParams(population=4, ils_steps=2),
        initial_routes=[[0, 1], [2, 3]],
    )
