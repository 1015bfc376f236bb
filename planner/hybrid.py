"""``hybrid``: IGHOA's shape (SA pre-planning → GA over two-part chromosomes → local
optimisation) with what the best mTSP/VRP methods add (docs/ighoa.md, "hybrid").

Beyond ``ighoa`` with its extended local search, each generation:

- polishes with **Or-opt** too (:func:`or_opt`): a segment of 1-3 tasks moved, possibly
  reversed, next to one of its nearest neighbours in the same route, each move evaluated
  in O(1) from the four legs it changes;
- runs an **iterated local search** on the elite (:func:`ils_step`, ``ils_steps`` times):
  a perturbation (ruin and recreate of ``ruin`` tasks around a seed, for the min-max
  objectives on the longest route, :func:`planner.moves.ruin_recreate`; or
  :func:`perturb`: ``perturb`` tasks each moved next to a random one of its nearest
  neighbours, half of them from the longest route) followed by the relocate/exchange
  search between routes with don't-look bits (only the moved tasks and their neighbours
  are looked at first, so a step costs O(moves), not O(n)) and 2-opt; the result is kept
  when it is better than the elite, and walked on from (record-to-record travel) when it is
  within ``accept`` of it.

The local search between routes also tries 2-opt* (:mod:`planner.moves`: the moves, by
name, each evaluated in O(1)) and, with ``lexicographic``, takes moves that shorten the
fleet's total distance without worsening the objective's figure. One individual of the
first population is a giant tour, improved by an iterated local search of its own
(:func:`tour_ils`: local double-bridge kicks, 2-opt and Or-opt with a queue of tasks to
look at), cut by the optimal split (:func:`giant_tour`); under the min-max objectives
another is a sweep (:func:`sweep`: a sector of the tasks around the depot a machine, the
cuts moved until the routes beside each are even, each route ordered by that ILS); the
same ILS orders the elite's longest route again each generation (:func:`route_ils`), and,
under the min-max objectives, one other route in turn (``other_routes``). A warm-started
run (a re-plan) starts instead from the plan being carried out and variants of it
(:func:`warm_population`). Under the sums, a population whose elite has not improved for
``restart`` of the run starts again, the best found so far kept aside
(:func:`planner.solve.solve`).

Under the makespan (the farm) the elite's ILS is the squeeze (:func:`ils_step`): a plan
whose routes all end within minutes of the makespan leaves no move under the makespan
itself, so the ILS minimises the fleet's total hours instead, each hour a route ends after a
target just under the best makespan counted OVERLOAD times (a sum, where a field may move to
the machine that does it faster); a result whose makespan is lower is the new elite, and the
target follows it. In two generations of three the target is above the makespan instead
(strategic oscillation): the walk may end routes past it where the fleet's hours fall, and
is squeezed back under in the others. Each generation the squeeze's walk is first handed
round by cyclic exchanges and paths under the squeeze's figure, with driving counted twice
(:mod:`planner.cyclic_exchange`): where every route ends near the target a field moved in is
one too many, and a cycle or a chain through three or more routes moves the fields that
one-for-one moves cannot. The same jam leaves the total road distance, the second
objective, short of room. With ``distance_share`` > 0 (off by default), in that last share
of the time a makespan up to ``1 + distance_slack`` times the best found by then counts as
equal to it (a cap, :func:`planner.cost.fleet_value`), the ILS's ruin starts on any route,
and the road distance decides below the cap (docs/ighoa.md, "fourth round"); a deadline
(:func:`planner.solve.solve`'s ``finish_within_h``) is such a cap in hours, from the first
plan within it. Under a cap the ILS's walk goes by the road: it takes a result whose
distance is within ``accept`` of the elite's, not one as far over the cap as ``accept`` of
the makespan.

``ighoa`` stays as the paper has it; these only run under ``--algorithm hybrid``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from planner.choices import SLACK_SHARE, check_makespan_slack
from planner.cost import evaluate, squeeze_figure
from planner.ighoa import IGHOAParams
from planner.local_search import allocation_search, optimal_split, past
from planner.moves import SEGMENT, mask, ruin_recreate
from planner.operators import edge, improve_routes, leg
from planner.pins import first_fixed, repair_pins
from planner.population import random_counts
from planner.problem import Problem
from planner.rng import randint

MAX_SEGMENT = 3  # Or-opt moves segments of 1..MAX_SEGMENT tasks
MIN_POPULATION = 50  # the fewest individuals HybridParams.population_tasks leaves


@dataclass(frozen=True)
class HybridParams(IGHOAParams):
    """IGHOA's settings with our local search between routes, plus the iterated local
    search on the elite."""

    shift_counts: bool = True
    local_search: str = "extended"
    memetic: int = 2

    ils_steps: int = 200  # perturb-and-improve attempts on the elite per generation
    perturb: int = 3  # tasks moved by one perturbation
    # The ILS runs for the min-max objectives (minmax, makespan); on the sums it did not
    # pay at 10 s (benchmarks/RESULTS.md), unless this is set.
    ils_on_sums: bool = False
    or_opt: bool = True  # Or-opt in the polish
    # The moves between routes of the local search, by name (planner.moves.MOVES);
    # segment_relocate did not pay on kroA200 min-max (benchmarks/RESULTS.md), so it is
    # selectable but off.
    moves: tuple[str, ...] = ("relocate", "exchange", "two_opt_star")
    # Total distance as the local search's second objective, after the objective's own
    # figure (lexicographic): routes that do not set a min-max figure are shortened too.
    lexicographic: bool = True
    # Under the makespan, the last ``distance_share`` of the time limit (0: never) lets a
    # makespan up to ``1 + distance_slack`` times the best found by then count as equal
    # to it (the road distance decides below that cap), and the ILS's ruin starts on any
    # route. Off by default: 0.2 and 0.003 gave 1.9 % less road for 0.29 % more makespan
    # at 500 x 30 (60 s) and cost the 100 x 10 makespan its lead over OR-Tools
    # (benchmarks/RESULTS.md, 2026-11-25).
    distance_share: float = 0.0
    distance_slack: float = 0.003
    # Record-to-record travel in the ILS: a result within ``accept`` (relative) of the
    # elite is walked on from; 0: every step starts from the elite.
    accept: float = 0.03
    # One individual of the first population is a giant tour (nearest neighbour, then
    # 2-opt and Or-opt with neighbour lists) cut optimally into routes (route first,
    # cluster second): what the GA's random orders take long to find on a large instance.
    giant_tour: bool = True
    # Ruin and recreate as the ILS's perturbation (planner.moves.ruin_recreate): this many
    # tasks around a seed (on the longest route for min-max; at most the seed and its
    # ``neighbours``) taken out and put back where they cost least; 0: the neighbour moves
    # of ``perturb`` instead.
    ruin: int = 11
    # Or-opt over every route in each ILS step too (not only in the polish).
    ils_or_opt: bool = False
    # The giant tour's iterated local search (tour_ils): at most ``tour_kicks`` kicks a task
    # and ``tour_share`` of the time limit; 0 kicks: 2-opt and Or-opt to a local optimum.
    tour_kicks: int = 100
    tour_share: float = 0.5
    # Each generation, the elite's longest route (min-max) or its routes in turn (the sums)
    # get that ILS too (route_ils), for this many kicks a task of the route; 0: never.
    route_kicks: int = 10
    # Under the min-max objectives, one other route in turn too each generation: the
    # routes that do not set the cost got no ILS of their own (pcb3038 m=3 min-max 120 s,
    # seeds 1-3: +3.02 % mean with it, +3.40 % without; benchmarks/RESULTS.md).
    other_routes: bool = True
    # At most this many tasks over the whole population (its size times n; 0: no bound),
    # and never fewer than MIN_POPULATION individuals: a generation's crossovers and
    # evaluations cost O(population x n), and at n = 3038 the 200 of the paper left few
    # generations to the ILS (benchmarks/RESULTS.md, 2026-11-25: 50 individuals were ahead
    # on pcb3038 min-max and min-sum). Up to n = 760 the population stays at 200.
    population_tasks: int = 152_000
    # Under the min-max objectives, one individual of the first population is a sweep
    # (sweep): a sector of the tasks around the depot a machine, the sectors evened out.
    sweep: bool = True
    # Under the sums (not min-max, not a warm start), the population starts again, as the
    # first did, when its elite has not improved for this share of the run (0: never); the
    # best found before is kept aside and returned if nothing beats it. The GA otherwise
    # fills its population with an early elite: kroA150 m=3 min-sum at 10 s, seed 1, stayed
    # at 26 982.02 from the first second where the other seeds reach 26 942.25
    # (benchmarks/RESULTS.md, 2026-11-26).
    restart: float = 0.1
    # Under the makespan, the elite's ILS is the squeeze (ils_step; 0 or (): the ILS of
    # the min-max objective): the fleet's total hours, each hour over a target of
    # ``1 - step`` times the best makespan counted OVERLOAD times, perturbed as that ILS
    # is (ruin, or perturb when ruin is 0). 500 x 30 at 60 s, seeds 1-2: 55.63 and
    # 55.62 h without it, 55.26 and 55.28 h with it (benchmarks/RESULTS.md, 2026-11-26).
    # The steps, one a generation in turn (a number: that step alone; a step 0: that
    # generation the ILS of the min-max objective): a coarse step pushes the longest routes
    # down; a fine one keeps the target at the makespan, and the fields go where they cost
    # the fleet least. 60 s, seeds 1-2: 500 x 30 with 6 passes 320.06 and 320.15 h at
    # 0.002 alone, 319.70 and 319.70 h at 0.0002 alone, but 100 x 10 is better at 0.002
    # (33.134 / 33.113 h against 33.138 / 33.166 h); in turn, no farm measured is worse
    # than at 0.002 alone (benchmarks/RESULTS.md, 2026-11-27). A step below 0 puts the
    # target above the makespan (strategic oscillation): the walk is let past it where the
    # fleet's weighed hours fall, and the steps above 0 then squeeze it back under. Four
    # such generations of six, 60 s, seeds 1-3: six passes 319.37 / 319.25 / 319.31 h
    # without, 319.08 / 319.01 / 319.06 h with (on average: two of four 319.08 h, eight
    # of ten 319.10 h, -0.01 for -0.003 319.11 h, -0.003 for the fine step 319.24 h); 100 x 10
    # 33.126 h on average against 33.119 h; 500 x 30 55.085 / 55.113 h against 55.038 /
    # 55.081 h (benchmarks/RESULTS.md, 2026-11-29).
    squeeze: float | tuple[float, ...] = (0.002, 0.0002, -0.003, -0.003, -0.003, -0.003)
    # The squeeze weighs each machine's hours by what they are worth to the makespan, the
    # duals of the relaxation of assigning fields to machines with the travel no route
    # avoids (planner.relaxation; False: all alike). 60 s, seeds 1-2: 500 x 30 with 6
    # passes 320.34 and 320.25 h alike, 320.06 and 320.15 h weighed; level within the
    # noise on the farms of one pass, 100 x 10 to 500 x 30 (benchmarks/RESULTS.md,
    # 2026-11-26 22:12).
    weigh_hours: bool = True
    # Under the makespan, each generation up to this many rounds of the cyclic exchange
    # (planner.cyclic_exchange) on a copy of the elite, the answer when it drives less: no route
    # past its makespan (or the cap of a deadline or a slack); 0: never. Where every route
    # ends near the makespan, no move between two routes shortens the roads; a cycle of
    # three or more does (500 x 30, 60 s, seeds 1-2: 1 726 and 1 689 road km without,
    # 1 668 and 1 658 with; benchmarks/RESULTS.md, 2026-11-26 19:00).
    cyclic_exchange_rounds: int = 1000
    # Under the makespan, each generation this many rounds of the cyclic exchange by the
    # squeeze's figure (planner.cyclic_exchange with a target) on the squeeze's walk before
    # its ILS steps, no route past the walk's makespan; 0: never. The squeeze's moves
    # between two routes stop where every route is near the target: a field in is a field
    # too many. A cycle through three or more routes hands the fields round to the machines
    # that do them in fewer weighed hours. In the exchange's figure an hour of driving
    # counts ``squeeze_exchange_road`` times more than in the squeeze's: at 0 the exchanges
    # bought hours of work with road the makespan never got back (500 x 30, 60 s, seeds 1-2:
    # level makespan, 2.8 % more road). 500 x 30 with 6 passes at 60 s, seeds 1-2: 320.01 /
    # 319.94 h, 2 090 / 2 083 km without; 319.53 / 319.52 h, 2 057 / 2 080 km with (0.5:
    # 319.67 h, 2: 319.55 / 319.66 h); benchmarks/RESULTS.md, 2026-11-28.
    squeeze_exchange_rounds: int = 1000
    squeeze_exchange_road: float = 1.0
    # In those exchanges, each route's pick is no field with this chance (planner.
    # cyclic_exchange): a cycle through it is a path, a field handed on from route to route
    # towards one with room, the sizes changing where no single move fits. Six passes,
    # 60 s, seeds 1-4: 319.53 / 319.52 / 319.72 / 319.55 h without, 319.40 / 319.30 /
    # 319.22 / 319.49 h at 0.2 (0.1: 319.40 / 319.42 h, 0.4: 319.62 / 319.32 h); 100 x 10
    # seeds 1-5 33.116 h on average without, 33.138 h at 0.2 (benchmarks/RESULTS.md,
    # 2026-11-28 09:20).
    squeeze_exchange_empty: float = 0.2

    def __post_init__(self) -> None:
        super().__post_init__()
        if (
            min(self.ils_steps, self.ruin, self.tour_kicks, self.route_kicks) < 0
            or min(self.population_tasks, self.cyclic_exchange_rounds) < 0
            or self.squeeze_exchange_rounds < 0
            or not self.squeeze_exchange_road >= 0.0  # NaN too
            or self.perturb < 1
        ):
            raise ValueError(
                "ils_steps, ruin, tour_kicks, route_kicks, population_tasks, "
                "cyclic_exchange_rounds, squeeze_exchange_rounds and squeeze_exchange_road "
                "must be >= 0 and perturb >= 1"
            )
        shares = (self.tour_share, self.distance_share, self.restart, self.squeeze_exchange_empty)
        if not all(0.0 <= x <= 1.0 for x in shares):
            raise ValueError(
                "tour_share, distance_share, restart and squeeze_exchange_empty must be "
                "within [0, 1]"
            )
        if not all(-1.0 < x < 1.0 for x in self.squeeze_steps):
            # a step of 1 would leave the squeeze a target of 0 h
            raise ValueError(f"squeeze steps must be within (-1, 1), not {self.squeeze}")
        if self.distance_slack < 0.0:
            raise ValueError(f"distance_slack must be >= 0, not {self.distance_slack}")
        mask(self.moves)

    @classmethod
    def with_makespan_slack(cls, slack: float) -> HybridParams:
        """The defaults, ε-lexicographic under the makespan with ε = ``slack``: in the last
        :data:`~planner.choices.SLACK_SHARE` of the time a makespan up to ``1 + slack``
        times the best found by then counts as equal to it, and the road distance decides
        (0: the makespan, then the road distance). A farm's ``[solver] makespan_slack``;
        ``slack`` within [0, :data:`~planner.choices.MAX_SLACK`]."""
        if check_makespan_slack(slack) == 0.0:  # refuses a slack out of range
            return cls()
        return cls(distance_share=SLACK_SHARE, distance_slack=slack)

    @property
    def squeeze_steps(self) -> tuple[float, ...]:
        """The squeeze's steps as given (a number: that one step; 0 or (): no squeeze)."""
        if isinstance(self.squeeze, tuple):
            return self.squeeze
        return (self.squeeze,) if self.squeeze != 0.0 else ()

    def squeeze_at(self, generation: int) -> float:
        """The squeeze's step in ``generation`` (1, 2, ...): the steps in turn; 0: none."""
        steps = self.squeeze_steps
        return steps[(generation - 1) % len(steps)] if steps else 0.0

    def population_for(self, n: int) -> int:
        """The population for ``n`` tasks: :attr:`population`, fewer for a large instance
        (:attr:`population_tasks`), but not below MIN_POPULATION (nor above it asked)."""
        if self.population_tasks <= 0 or n <= 0:
            return self.population
        fits = self.population_tasks // n
        return max(min(self.population, fits), min(self.population, MIN_POPULATION))

    @property
    def move_mask(self) -> int:
        """:attr:`moves` as the local search's bit mask."""
        return mask(self.moves)


@njit(cache=True, nogil=True)
def or_opt(perm, begin, count, machine, dist, start_dist, end_dist, neighbours, fixed):  # type: ignore[no-untyped-def]
    """Or-opt on the route ``perm[begin:begin+count]`` of ``machine`` until no move pays:
    a segment of 1..MAX_SEGMENT tasks goes, as it is or reversed, between a nearest
    neighbour of one of its ends and that neighbour's predecessor or successor. The first
    ``fixed`` tasks (a pinned task) stay first. Returns the total gain (distance)."""
    if count < 3:
        return 0.0
    route = perm[begin : begin + count]
    where = np.full(dist.shape[0], -1, dtype=np.int64)
    for p in range(count):
        where[route[p]] = p
    buf = np.empty(count, dtype=np.int64)
    total = 0.0
    improved = True
    while improved:
        improved = False
        for length in range(1, MAX_SEGMENT + 1):
            for i in range(fixed, count - length + 1):
                s0 = route[i]
                s1 = route[i + length - 1]
                a = route[i - 1] if i > 0 else -1
                b = route[i + length] if i + length < count else -2
                removal = (
                    leg(a, s0, machine, dist, start_dist, end_dist)
                    + leg(s1, b, machine, dist, start_dist, end_dist)
                    - leg(a, b, machine, dist, start_dist, end_dist)
                )
                if removal <= 1e-10:
                    continue
                best = 1e-10
                best_p = -2
                best_rev = False
                for end in range(2):
                    node = s0 if end == 0 else s1
                    for q in range(neighbours.shape[1]):
                        w = neighbours[node, q]
                        pw = where[w]
                        if pw < 0:
                            continue
                        for p in (pw - 1, pw):
                            # Edge (route[p], route[p+1]) outside the segment and its legs.
                            if not (p <= i - 2 or p >= i + length) or p < fixed - 1:
                                continue
                            if p < -1 or p >= count:
                                continue
                            u = route[p] if p >= 0 else -1
                            v = route[p + 1] if p + 1 < count else -2
                            base = leg(u, v, machine, dist, start_dist, end_dist)
                            fwd = (
                                leg(u, s0, machine, dist, start_dist, end_dist)
                                + leg(s1, v, machine, dist, start_dist, end_dist)
                                - base
                            )
                            rev = (
                                leg(u, s1, machine, dist, start_dist, end_dist)
                                + leg(s0, v, machine, dist, start_dist, end_dist)
                                - base
                            )
                            if removal - fwd > best:
                                best, best_p, best_rev = removal - fwd, p, False
                            if removal - rev > best:
                                best, best_p, best_rev = removal - rev, p, True
                if best_p == -2:
                    continue
                out = 0
                if best_p == -1:
                    for k in range(length):
                        buf[out] = route[i + length - 1 - k] if best_rev else route[i + k]
                        out += 1
                for idx in range(count):
                    if i <= idx < i + length:
                        continue
                    buf[out] = route[idx]
                    out += 1
                    if idx == best_p:
                        for k in range(length):
                            buf[out] = route[i + length - 1 - k] if best_rev else route[i + k]
                            out += 1
                route[:] = buf
                for p in range(count):
                    where[route[p]] = p
                total += best
                improved = True
    return total


@njit(cache=True, nogil=True)
def or_opt_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins):  # type: ignore[no-untyped-def]
    """:func:`or_opt` on every route of a chromosome; returns the total gain."""
    begin = 0
    total = 0.0
    for i in range(counts.shape[0]):
        fixed = first_fixed(perm, begin, counts[i], i, pins)
        total += or_opt(perm, begin, counts[i], i, dist, start_dist, end_dist, neighbours, fixed)
        begin += counts[i]
    return total


@njit(cache=True, nogil=True)
def _route_at(counts, index):  # type: ignore[no-untyped-def]
    """The route that place ``index`` of the task order belongs to."""
    begin = 0
    for r in range(counts.shape[0]):
        if index < begin + counts[r]:
            return r
        begin += counts[r]
    return counts.shape[0] - 1


@njit(cache=True, nogil=True)
def _move_after(perm, counts, src, w):  # type: ignore[no-untyped-def]
    """Move the task at ``perm[src]`` to just after task ``w``, into w's route."""
    n = perm.shape[0]
    task = perm[src]
    counts[_route_at(counts, src)] -= 1
    for k in range(src, n - 1):
        perm[k] = perm[k + 1]
    at = 0
    while perm[at] != w:
        at += 1
    route_w = _route_at(counts, at)
    for k in range(n - 1, at + 1, -1):
        perm[k] = perm[k - 1]
    perm[at + 1] = task
    counts[route_w] += 1


@njit(cache=True, nogil=True)
def perturb(
    state, perm, counts, route_cost, strength, focus_longest, min_count, pins, neighbours, moved
):  # type: ignore[no-untyped-def]
    """Move ``strength`` random tasks each to just after one of its nearest neighbours,
    picked at random (often in another route); with ``focus_longest``, every other task
    is taken from the route of highest ``route_cost``. A route is never left below
    ``min_count`` and a pinned task never moves (nor has one put before it). The tasks
    moved are written to ``moved`` (the rest -1); returns how many."""
    n = perm.shape[0]
    k = neighbours.shape[1]
    done = 0
    moved[:] = -1
    if k == 0:
        return 0
    for step in range(strength):
        src = randint(state, n)
        if focus_longest and step % 2 == 0:
            longest = int(np.argmax(route_cost))
            if counts[longest] > 0:
                begin = 0
                for r in range(longest):
                    begin += counts[r]
                src = begin + randint(state, counts[longest])
        if counts[_route_at(counts, src)] <= min_count or pins[perm[src]] >= 0:
            continue
        task = perm[src]
        w = neighbours[task, randint(state, k)]
        _move_after(perm, counts, src, w)
        moved[done] = task
        done += 1
    return done


@njit(cache=True, nogil=True)
def local_optimum(
    perm,
    counts,
    objective,
    tables,
    neighbours,
    min_count,
    pins,
    deadline,
    dont_look,
    moves,
    lexi,
    cap=0.0,
):  # type: ignore[no-untyped-def]
    """The ``moves`` between routes from the tasks whose don't-look bit is clear, then
    the neighbour-list 2-opt inside the routes, in place. (Or-opt is left to the
    polish: over every route it costs more than an ILS step is worth.)"""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    allocation_search(
        perm, counts, objective, tables, neighbours, min_count, 50, pins, deadline, dont_look,
        True, moves, lexi, cap,
    )  # fmt: skip
    improve_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins)


@njit(cache=True, nogil=True)
def within_accept(cost, elite_cost, cap, accept):  # type: ignore[no-untyped-def]
    """Whether the ILS's walk may be at ``cost`` (record-to-record travel): within
    ``accept`` of the elite's cost, or under a makespan ``cap`` (both costs capped,
    :func:`planner.cost.fleet_value`) within ``accept`` of what the elite's has above the
    cap (its distance term): at most that much more road, never ``accept`` of the
    makespan over the cap whatever the roads."""
    return cost - cap < (elite_cost - cap) * (1.0 + accept) - 1e-12


@njit(cache=True, nogil=True)
def ils_step(  # type: ignore[no-untyped-def]
    state,
    elite_perm,
    elite_counts,
    elite_route,
    elite_cost,
    walk_perm,
    walk_counts,
    walk_route,
    walk_cost,
    objective,
    tables,
    neighbours,
    min_count,
    pins,
    steps,
    strength,
    deadline,
    moves,
    lexi,
    accept,
    ruin,
    with_or_opt,
    focus,
    cap=0.0,
    squeeze=0.0,
):
    """``steps`` perturb-and-improve attempts from the walk's solution (record-to-record
    travel): a result is the walk's next solution when it costs less than ``1 + accept``
    times the elite, and the new elite when it costs less than the elite (both sets of
    arrays are updated in place). With ``accept`` = 0 the walk is the elite. With
    ``focus`` the perturbation starts on the route of highest share (the min-max
    objectives' longest), else anywhere. ``cap`` (min-max objectives; 0: none): every cost,
    the elite's and the walk's given too, takes the min-max figure as at least ``cap``
    (:func:`planner.cost.fleet_value`), so that below it the distance decides; the walk's
    ``accept`` is then a share of what a cost has above the cap (its distance term).

    ``squeeze`` not 0 (the makespan; ``cap`` 0) is the squeeze: the search and the walk go by
    :func:`planner.cost.squeeze_figure` with the target ``1 - squeeze`` times the elite's
    makespan, above it for a step below 0 (the walk loosened, free to end routes past the
    makespan where the weighed hours fall): the fleet's hours weighed by the tables' hour
    weights, each hour over the target counted :data:`~planner.cost.OVERLOAD` times; every
    other ruin seeded on the longest route when ``focus``; a result is the walk's next
    solution when its figure is lower, and the new elite (the target following it) when its
    makespan is. Under the makespan itself a plan whose routes all end near it leaves no
    move (each lengthens some route up to it); under the sum a field goes to a machine that
    does it faster or nearer, and the overloads then even out. The costs given and returned
    stay the objective's.

    Returns the new elite cost and walk cost."""
    perm = walk_perm.copy()
    counts = walk_counts.copy()
    route = walk_route.copy()
    moved = np.empty(max(strength, ruin), dtype=np.int64)
    dont_look = np.empty(perm.shape[0], dtype=np.bool_)
    hour_weights = tables[8]  # CostTables.hour_weights
    target = elite_route.max() * (1.0 - squeeze)
    walk_figure = squeeze_figure(walk_route, target, hour_weights)
    figure = walk_figure
    for step in range(steps):
        if past(deadline):
            break
        cut = -target if squeeze != 0.0 else cap  # fleet_value's cap < 0: the squeeze
        perm[:] = walk_perm
        counts[:] = walk_counts
        if ruin > 0:
            done = ruin_recreate(
                state, perm, counts, objective, tables, neighbours, ruin,
                focus and (squeeze == 0.0 or step % 2 == 1), min_count, pins, moved, cut,
            )  # fmt: skip
        else:
            done = perturb(
                state, perm, counts, walk_route, strength, focus, min_count, pins, neighbours,
                moved,
            )  # fmt: skip
        # Only the moved tasks and their neighbours are looked at first.
        dont_look[:] = True
        for q in range(done):
            dont_look[moved[q]] = False
            for w in neighbours[moved[q]]:
                dont_look[w] = False
        local_optimum(
            perm, counts, objective, tables, neighbours, min_count, pins, deadline, dont_look,
            moves, lexi and squeeze == 0.0, cut,
        )  # fmt: skip
        if with_or_opt:
            or_opt_routes(perm, counts, tables[0], tables[1], tables[2], neighbours, pins)
        cost = evaluate(perm, counts, objective, tables, route)
        if squeeze != 0.0:
            figure = squeeze_figure(route, target, hour_weights)
            walk_on = figure < walk_figure - 1e-12
        else:
            if cap > 0.0:
                cost += max(0.0, cap - route.max())
            walk_on = cost < walk_cost - 1e-12 or within_accept(cost, elite_cost, cap, accept)
        if walk_on:
            walk_perm[:] = perm
            walk_counts[:] = counts
            walk_route[:] = route
            walk_cost = cost
            walk_figure = figure
        if cost < elite_cost - 1e-12:
            elite_perm[:] = perm
            elite_counts[:] = counts
            elite_route[:] = route
            elite_cost = cost
            if squeeze != 0.0:
                target = route.max() * (1.0 - squeeze)
                walk_figure = squeeze_figure(walk_route, target, hour_weights)
    return elite_cost, walk_cost


@njit(cache=True, nogil=True)
def warm_population(  # type: ignore[no-untyped-def]
    state, perms, counts, first, objective, tables, neighbours, size, min_count, pins
):
    """A re-plan's first population: individuals ``first``.. each a variant of individual 0
    (the plan being carried out, repaired), ``size`` tasks around a random seed ruined and
    recreated (:func:`planner.moves.ruin_recreate`): near the plan, and diverse."""
    moved = np.empty(max(size, 1), dtype=np.int64)
    for p in range(first, perms.shape[0]):
        perms[p] = perms[0]
        counts[p] = counts[0]
        ruin_recreate(
            state, perms[p], counts[p], objective, tables, neighbours, size, False, min_count,
            pins, moved,
        )  # fmt: skip


@njit(cache=True, nogil=True)
def giant_tour(  # type: ignore[no-untyped-def]
    state, perm, counts, objective, tables, neighbours, min_count, pins, deadline, kicks, ils_end
):
    """A first individual, route first and cluster second: one tour through every task
    (nearest neighbour from machine 0's start, then 2-opt and Or-opt with the neighbour
    lists until neither pays, then :func:`tour_ils` for ``kicks`` kicks or until
    ``ils_end``) cut by :func:`optimal_split` for the objective; when the pins allow no
    cut, or ``deadline`` passes, a random split repaired for the pins."""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    n = perm.shape[0]
    m = counts.shape[0]
    perm[:] = np.arange(n)
    _nearest_neighbour(perm, 0, start_dist, dist)
    tour_ils(state, perm, 0, dist, start_dist, end_dist, neighbours, kicks, min(deadline, ils_end))
    random_counts(state, n, m, min_count, counts)
    split = counts.copy()
    if optimal_split(perm, split, objective, tables, min_count, pins, deadline) < np.inf:
        counts[:] = split
    repair_pins(perm, counts, pins, min_count)


@njit(cache=True, nogil=True)
def _nearest_neighbour(path, machine, start_dist, dist):  # type: ignore[no-untyped-def]
    """Order the tasks of ``path`` in place by nearest neighbour from ``machine``'s start."""
    n = path.shape[0]
    for k in range(n):
        best = k
        prev = path[k - 1] if k > 0 else -1
        best_d = np.inf
        for q in range(k, n):
            t = path[q]
            d = start_dist[machine, t] if prev < 0 else dist[prev, t]
            if d < best_d or (d == best_d and t < path[best]):  # ties: the lowest task
                best, best_d = q, d
        path[k], path[best] = path[best], path[k]


def sweep_order(problem: Problem) -> np.ndarray | None:
    """The tasks by their angle around the depot, from the widest gap between two of them
    on (the order :func:`sweep` cuts into sectors); ``None`` when the problem has no depot."""
    if problem.depot is None or problem.num_tasks == 0:
        return None
    xy = np.array([(t.x, t.y) for t in problem.tasks], dtype=np.float64)
    angle = np.arctan2(xy[:, 1] - problem.depot[1], xy[:, 0] - problem.depot[0])
    order = np.argsort(angle, kind="stable")
    sorted_angle = angle[order]
    gaps = np.diff(np.append(sorted_angle, sorted_angle[0] + 2.0 * np.pi))
    return np.roll(order, -(int(np.argmax(gaps)) + 1)).astype(np.int64)


@njit(cache=True, nogil=True)
def sweep(  # type: ignore[no-untyped-def]
    state,
    perm,
    counts,
    order,
    objective,
    tables,
    neighbours,
    min_count,
    pins,
    deadline,
    kicks,
    ils_end,
):
    """A first individual, cluster first and route second (the sweep): the tasks in
    ``order`` (by their angle around the depot, :func:`sweep_order`) cut
    into one sector a machine, each sector's route ordered by nearest neighbour, then
    2-opt and Or-opt (:func:`tour_ils` without kicks, :func:`_sector`). The cuts then move
    while that shortens the longer of the two routes beside the cut (or, that equal, their
    sum), by steps halved down to one task; last, each route gets :func:`tour_ils` with
    ``kicks`` kicks a task, until ``ils_end`` (and ``deadline``, the run's end, for all).

    Routes that each serve a wedge from the depot carry no long empty leg through the
    other routes' areas, which a giant tour's split cannot avoid when the depot is far
    from the middle (a corner): under the min-max objectives they are what the search
    must otherwise find move by move."""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    n = perm.shape[0]
    m = counts.shape[0]
    least = max(min_count, 1)
    if n < m * least:
        return
    for k in range(m):
        counts[k] = n // m + (1 if k < n % m else 0)
    begin = 0
    for k in range(m):
        _sector(state, perm, counts, order, begin, k, dist, start_dist, end_dist, neighbours)
        begin += counts[k]
    route_costs = np.empty(m)
    evaluate(perm, counts, objective, tables, route_costs)
    trial = np.empty(m)
    saved = np.empty(n, dtype=np.int64)
    step = max(n // (4 * m), 1) if m > 1 else 0
    while step >= 1 and not past(deadline):
        moved = False
        for cut in range(m - 1):
            for grow in (step, -step):
                if counts[cut] + grow < least or counts[cut + 1] - grow < least:
                    continue
                begin = _route_begin(counts, cut)
                span = counts[cut] + counts[cut + 1]
                saved[:span] = perm[begin : begin + span]
                counts[cut] += grow
                counts[cut + 1] -= grow
                _sector(state, perm, counts, order, begin, cut, dist, start_dist, end_dist,
                        neighbours)  # fmt: skip
                _sector(state, perm, counts, order, begin + counts[cut], cut + 1, dist,
                        start_dist, end_dist, neighbours)  # fmt: skip
                evaluate(perm, counts, objective, tables, trial)
                old_max = max(route_costs[cut], route_costs[cut + 1])
                new_max = max(trial[cut], trial[cut + 1])
                old_sum = route_costs[cut] + route_costs[cut + 1]
                new_sum = trial[cut] + trial[cut + 1]
                if new_max < old_max - 1e-9 * old_max or (
                    new_max <= old_max and new_sum < old_sum - 1e-9 * old_sum
                ):
                    route_costs[:] = trial
                    moved = True
                    break
                counts[cut] -= grow
                counts[cut + 1] += grow
                perm[begin : begin + span] = saved[:span]
        if not moved:
            step //= 2
    begin = 0
    for k in range(m):
        count = counts[k]
        tour_ils(state, perm[begin : begin + count], k, dist, start_dist, end_dist, neighbours,
                 kicks * count, min(deadline, ils_end))  # fmt: skip
        begin += count
    repair_pins(perm, counts, pins, min_count)


@njit(cache=True, nogil=True)
def _route_begin(counts, k):  # type: ignore[no-untyped-def]
    """The place in ``perm`` where route ``k`` begins."""
    begin = 0
    for i in range(k):
        begin += counts[i]
    return begin


@njit(cache=True, nogil=True)
def _sector(state, perm, counts, order, begin, k, dist, start_dist, end_dist, neighbours):  # type: ignore[no-untyped-def]
    """Route ``k`` of the sweep: the tasks of ``order`` from ``begin`` on, as many as
    ``counts[k]``, ordered by nearest neighbour, then 2-opt and Or-opt."""
    path = perm[begin : begin + counts[k]]
    path[:] = order[begin : begin + counts[k]]
    _nearest_neighbour(path, k, start_dist, dist)
    tour_ils(state, path, k, dist, start_dist, end_dist, neighbours, 0, np.inf)


@njit(cache=True, nogil=True)
def tour_ils(state, perm, machine, dist, start_dist, end_dist, neighbours, kicks, deadline):  # type: ignore[no-untyped-def]
    """Iterated local search on one path through the tasks of ``perm`` (``machine``'s
    start, the tasks in order, its end), in place; returns the total gain. ``perm`` may
    hold some of the tasks only (one route: :func:`route_ils`); the neighbours of a task
    that are not on the path are passed over. Each of up to
    ``kicks`` steps (until ``deadline``, a monotonic instant) is a local double-bridge
    (three stretches of a window of at most :data:`KICK_WINDOW` places swapped, A B C D to
    A C B D: what 2-opt and Or-opt cannot undo) and a local search of 2-opt and Or-opt
    (a segment of 1..:data:`SEGMENT` tasks moved, as it is or reversed) with neighbour
    lists and a queue of the tasks to look at (don't-look bits: only the kick's ends and
    the ends of each move are), kept when the path is shorter, else undone; so a step costs
    O(its moves), not O(n)."""
    n = perm.shape[0]
    if n < 8:
        return 0.0
    nodes = np.empty(n + 2, dtype=np.int64)
    nodes[0] = -1
    nodes[n + 1] = -2
    pos = np.full(dist.shape[0], -1, dtype=np.int64)  # -1: not on the path
    for k in range(n):
        nodes[k + 1] = perm[k]
        pos[perm[k]] = k + 1
    kept = nodes.copy()
    args = (machine, dist, start_dist, end_dist)
    queue = np.empty(n, dtype=np.int64)
    queued = np.zeros(dist.shape[0], dtype=np.bool_)
    span = np.array([n + 1, 0], dtype=np.int64)  # places changed since the last kept path
    buf = np.empty(KICK_WINDOW + 1, dtype=np.int64)
    head = np.zeros(2, dtype=np.int64)  # queue's first place, its length
    for k in range(n):
        _push(queue, queued, head, perm[k])
    total = _path_search(nodes, pos, neighbours, queue, queued, head, span, args)
    kept[:] = nodes
    span[0], span[1] = n + 1, 0
    window = min(KICK_WINDOW, n - 1)
    for step in range(kicks):
        if step % CHECK_KICKS == 0 and past(deadline):
            break
        p1 = 1 + randint(state, n - window + 1)
        a = 1 + randint(state, window - 2)
        b = 1 + randint(state, window - 2)
        c = 1 + randint(state, window - 2)
        cuts = np.sort(np.array([a, b, c]))
        if cuts[0] == cuts[1] or cuts[1] == cuts[2]:
            continue
        # A = ..p1+i, B = p1+i+1..p1+j, C = p1+j+1..p1+k, D = p1+k+1..
        i, j, k = p1 + cuts[0] - 1, p1 + cuts[1] - 1, p1 + cuts[2] - 1
        if k > n:
            continue
        delta = (
            _e(nodes[i], nodes[j + 1], args)
            + _e(nodes[k], nodes[i + 1], args)
            + _e(nodes[j], nodes[k + 1], args)
            - _e(nodes[i], nodes[i + 1], args)
            - _e(nodes[j], nodes[j + 1], args)
            - _e(nodes[k], nodes[k + 1], args)
        )
        out = 0
        for q in range(j + 1, k + 1):
            buf[out] = nodes[q]
            out += 1
        for q in range(i + 1, j + 1):
            buf[out] = nodes[q]
            out += 1
        for q in range(out):
            nodes[i + 1 + q] = buf[q]
            pos[buf[q]] = i + 1 + q
        span[0] = min(span[0], i + 1)
        span[1] = max(span[1], k)
        for q in (i, i + 1, j, j + 1, k, k + 1):
            if 1 <= q <= n:
                _push(queue, queued, head, nodes[q])
        gain = _path_search(nodes, pos, neighbours, queue, queued, head, span, args) - delta
        lo, hi = span[0], span[1]
        if gain > 1e-7:
            total += gain
            kept[lo : hi + 1] = nodes[lo : hi + 1]
        else:
            nodes[lo : hi + 1] = kept[lo : hi + 1]
            for q in range(lo, hi + 1):
                pos[nodes[q]] = q
        span[0], span[1] = n + 1, 0
    for q in range(n):
        perm[q] = nodes[q + 1]
    return total


@njit(cache=True, nogil=True)
def route_ils(state, perm, counts, route, tables, neighbours, pins, kicks, deadline):  # type: ignore[no-untyped-def]
    """:func:`tour_ils` on route ``route`` of a chromosome, in place, for ``kicks`` kicks
    (or until ``deadline``); returns the route's distance saved. Only the order of its tasks
    changes, and every objective grows with a route's distance, so the chromosome is never
    worse. A route whose first task is pinned to it (a field in progress, planner/pins.py)
    is left as it is."""
    begin = _route_begin(counts, route)
    end = begin + counts[route]
    if end - begin < 8 or first_fixed(perm, begin, end - begin, route, pins):
        return 0.0
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    return tour_ils(
        state, perm[begin:end], route, dist, start_dist, end_dist, neighbours, kicks, deadline
    )


KICK_WINDOW = 50  # places a double-bridge kick of tour_ils spans at most
CHECK_KICKS = 256  # kicks between two looks at the clock


@njit(cache=True, nogil=True)
def _push(queue, queued, head, t):  # type: ignore[no-untyped-def]
    """Put task t on the circular queue unless it is there."""
    if queued[t]:
        return
    n = queue.shape[0]
    queue[(head[0] + head[1]) % n] = t
    head[1] += 1
    queued[t] = True


@njit(cache=True, nogil=True)
def _reverse_path(nodes, pos, lo, hi):  # type: ignore[no-untyped-def]
    while lo < hi:
        nodes[lo], nodes[hi] = nodes[hi], nodes[lo]
        pos[nodes[lo]] = lo
        pos[nodes[hi]] = hi
        lo += 1
        hi -= 1
    if lo == hi:
        pos[nodes[lo]] = lo


@njit(cache=True, nogil=True)
def _path_search(nodes, pos, neighbours, queue, queued, head, span, args):  # type: ignore[no-untyped-def]
    """2-opt and Or-opt on the path ``nodes`` (start -1, tasks, end -2) from the tasks on
    the queue until it is empty; returns the gain. ``span`` widens to every place changed."""
    dist = args[1]
    n = nodes.shape[0] - 2
    k = neighbours.shape[1]
    total = 0.0
    while head[1] > 0:
        a = queue[head[0]]
        head[0] = (head[0] + 1) % n
        head[1] -= 1
        queued[a] = False
        improved = True
        while improved:
            improved = False
            i = pos[a]
            # 2-opt: a's edge to its successor (step 1) or predecessor (step -1) and the
            # same edge of a neighbour c become a-c and b-d.
            for step in (1, -1):
                b = nodes[i + step]
                d_ab = _e(a, b, args)
                for q in range(k):
                    c = neighbours[a, q]
                    d_ac = dist[a, c]
                    if d_ac >= d_ab:
                        break
                    j = pos[c]
                    if j < 0 or j == i + step:
                        continue
                    d = nodes[j + step]
                    delta = d_ac + _e(b, d, args) - d_ab - _e(c, d, args)
                    if delta < -1e-10:
                        if step == 1:
                            lo, hi = (i + 1, j) if j > i else (j + 1, i)
                        else:
                            lo, hi = (i, j - 1) if j > i else (j, i - 1)
                        _reverse_path(nodes, pos, lo, hi)
                        span[0] = min(span[0], lo)
                        span[1] = max(span[1], hi)
                        for t in (a, b, c, d):
                            if t >= 0:
                                _push(queue, queued, head, t)
                        total -= delta
                        improved = True
                        break
                if improved:
                    break
            if improved:
                continue
            # Or-opt: the segment of 1..SEGMENT tasks from a onwards goes between a
            # neighbour w of its ends and w's predecessor or successor.
            for length in range(1, SEGMENT + 1):
                if i + length - 1 > n:
                    break
                s0, s1 = nodes[i], nodes[i + length - 1]
                before, after = nodes[i - 1], nodes[i + length]
                removal = _e(before, s0, args) + _e(s1, after, args)
                removal -= _e(before, after, args)
                if removal <= 1e-10:
                    continue
                best, best_p, best_rev = 1e-10, -1, False
                for end in range(2):
                    node = s0 if end == 0 else s1
                    for q in range(k):
                        w = neighbours[node, q]
                        if dist[node, w] >= removal:
                            break
                        pw = pos[w]
                        if pw < 0:
                            continue
                        for p in (pw - 1, pw):
                            if i - 1 <= p <= i + length - 1 or p < 0 or p > n:
                                continue
                            u, v = nodes[p], nodes[p + 1]
                            base = _e(u, v, args)
                            fwd = _e(u, s0, args) + _e(s1, v, args) - base
                            rev = _e(u, s1, args) + _e(s0, v, args) - base
                            if removal - fwd > best:
                                best, best_p, best_rev = removal - fwd, p, False
                            if removal - rev > best:
                                best, best_p, best_rev = removal - rev, p, True
                if best_p < 0:
                    continue
                _move_segment(nodes, pos, i, length, best_p, best_rev, span)
                for t in (before, after, s0, s1, nodes[pos[s0] - 1], nodes[pos[s1] + 1]):
                    if t >= 0:
                        _push(queue, queued, head, t)
                for t in (nodes[pos[s0] + 1], nodes[pos[s1] - 1]):
                    if t >= 0:
                        _push(queue, queued, head, t)
                total += best
                improved = True
                break
    return total


@njit(cache=True, nogil=True)
def _move_segment(nodes, pos, i, length, p, rev, span):  # type: ignore[no-untyped-def]
    """Move nodes[i:i+length] between places p and p+1 (outside it), reversed when ``rev``."""
    seg = nodes[i : i + length].copy()
    if rev:
        seg = seg[::-1].copy()
    if p >= i + length:
        for q in range(i + length, p + 1):
            nodes[q - length] = nodes[q]
            pos[nodes[q - length]] = q - length
        at = p - length + 1
        lo, hi = i, p
    else:
        for q in range(i - 1, p, -1):
            nodes[q + length] = nodes[q]
            pos[nodes[q + length]] = q + length
        at = p + 1
        lo, hi = p + 1, i + length - 1
    for q in range(length):
        nodes[at + q] = seg[q]
        pos[seg[q]] = at + q
    span[0] = min(span[0], lo)
    span[1] = max(span[1], hi)


@njit(cache=True, nogil=True)
def _e(u, v, args):  # type: ignore[no-untyped-def]
    """:func:`planner.operators.edge` with ``args`` = (machine, dist, start_dist, end_dist)."""
    return edge(u, v, args[0], args[1], args[2], args[3])
