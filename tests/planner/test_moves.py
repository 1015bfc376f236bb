"""planner.moves: each move's evaluated lengths equal the lengths recomputed after it is
applied, the chromosome stays valid, pins and minimum sizes hold; the local search with
every move and the lexicographic second objective never worsens a solution."""

import numpy as np
import pytest
from helpers.chromosomes import (
    NO_PINS,
    SETTINGS,
    assert_valid,
    chromosomes,
    least_over_insertions,
    problem_for,
)
from hypothesis import given
from hypothesis import strategies as st

from planner.cost import CostTables, Objective, evaluate, split_routes
from planner.local_search import allocation_search, nearest_neighbours
from planner.moves import (
    MOVES,
    TWO_OPT_STAR,
    mask,
    prefix,
    route_rows,
    ruin_recreate,
    segment_apply,
    segment_lengths,
    two_opt_star_allowed,
    two_opt_star_apply,
    two_opt_star_lengths,
)
from planner.pins import pins_hold, repair_pins
from planner.rng import make_state


def lengths_of(routes, sizes, tables):
    perm = np.concatenate([routes[r, : sizes[r]] for r in range(sizes.size)]).astype(np.int64)
    out = np.empty(sizes.size)
    evaluate(perm, sizes.copy(), int(Objective.MINMAX), tables, out)
    return out


def scattered_case(perm, counts):
    """The chromosome as route rows with their prefix lengths, on a problem whose machines
    start at different places (so that start and end legs cannot be mixed up)."""
    n, m = perm.size, counts.size
    rng = np.random.default_rng(n * 31 + m)
    problem = problem_for(n, m, n + m).starting_at(
        [tuple(rng.uniform(0, 3000, 2)) for _ in range(m)]
    )
    tables = CostTables.of(problem).kernel_args()
    routes, sizes = route_rows(perm, counts)
    pref = np.zeros((m, n))
    for r in range(m):
        prefix(routes, sizes, r, r, tables[0], tables[1], pref)
    return tables, routes, sizes, pref


@SETTINGS
@given(chromosomes(min_count=0), st.sampled_from(["two_opt_star", "segment_relocate"]), st.data())
def test_a_moves_lengths_equal_the_lengths_after_it_is_applied(case, move, data):
    _, perm, counts = case
    n, m = perm.size, counts.size
    if m < 2:
        return
    tables, routes, sizes, pref = scattered_case(perm, counts)
    dist, start_dist, end_dist = tables[:3]
    pos = np.empty(n, dtype=np.int64)
    route_of = np.empty(n, dtype=np.int64)
    buf = np.empty(n, dtype=np.int64)
    if move == "two_opt_star":
        busy = [r for r in range(m) if sizes[r] > 0]
        if len(busy) < 2:
            return
        a, b = data.draw(st.permutations(busy))[:2]
        pa = data.draw(st.integers(0, int(sizes[a]) - 1))
        pw = data.draw(st.integers(0, int(sizes[b]) - 1))
        variant = data.draw(st.integers(0, 1))
        new_a, new_b = two_opt_star_lengths(
            routes, sizes, pref, a, pa, b, pw, variant, dist, start_dist, end_dist
        )
        two_opt_star_apply(routes, sizes, pos, route_of, a, pa, b, pw, variant, buf)
    else:
        busy = [r for r in range(m) if sizes[r] >= 2]
        if not busy:
            return
        a = data.draw(st.sampled_from(busy))
        b = data.draw(st.sampled_from([r for r in range(m) if r != a]))
        length = data.draw(st.integers(2, min(3, int(sizes[a]))))
        pa = data.draw(st.integers(0, int(sizes[a]) - length))
        p = data.draw(st.integers(0, int(sizes[b])))
        rev = data.draw(st.booleans())
        lengths = lengths_of(routes, sizes, tables)
        new_a, new_b = segment_lengths(
            routes, sizes, pref, lengths, a, pa, length, b, p, rev, dist, start_dist, end_dist
        )
        moved = routes[a, pa : pa + length].tolist()
        segment_apply(routes, sizes, pos, route_of, a, pa, length, b, p, rev, buf)
        assert routes[b, p : p + length].tolist() == (moved[::-1] if rev else moved)
    after = lengths_of(routes, sizes, tables)
    assert after[a] == pytest.approx(new_a, rel=1e-9, abs=1e-6)
    assert after[b] == pytest.approx(new_b, rel=1e-9, abs=1e-6)
    for r in (a, b):
        for k in range(sizes[r]):
            assert pos[routes[r, k]] == k and route_of[routes[r, k]] == r
    flat = sorted(int(t) for r in range(m) for t in routes[r, : sizes[r]])
    assert flat == list(range(n))


def test_two_opt_star_keeps_a_pinned_first_task_and_the_minimum():
    routes = np.array([[0, 1, 2], [3, 4, 5]], dtype=np.int64)
    sizes = np.array([3, 3], dtype=np.int64)
    pins = NO_PINS(6)
    pins[3] = 1  # task 3 stays first in route 1
    assert not two_opt_star_allowed(routes, sizes, pins, 0, 1, 1, 0, 0, 1)  # 3 would move
    assert not two_opt_star_allowed(routes, sizes, pins, 0, 1, 1, 1, 1, 1)  # 3 would move
    assert two_opt_star_allowed(routes, sizes, pins, 0, 1, 1, 1, 0, 1)
    # Route 1 would be left empty: allowed only without a minimum.
    assert not two_opt_star_allowed(routes, sizes, NO_PINS(6), 0, 2, 1, 0, 0, 1)
    assert two_opt_star_allowed(routes, sizes, NO_PINS(6), 0, 2, 1, 0, 0, 0)


def test_moves_are_chosen_by_name():
    assert mask(MOVES) == 15 and mask(("two_opt_star",)) == TWO_OPT_STAR
    with pytest.raises(ValueError, match="unknown move 'cross'"):
        mask(("cross",))


@SETTINGS
@given(
    chromosomes(),
    st.sampled_from(list(Objective)),
    st.booleans(),
    st.integers(1, 15),
    st.sampled_from([0.0, 1.0, 1.05]),
)
def test_allocation_search_with_every_move_never_worsens(case, objective, lexi, moves, over):
    _, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, int(perm[0]) + 5 * n)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    before = evaluate(perm, counts, int(objective), tables, route)
    # A cap (min-max objectives): a figure up to it counts as equal (0: none).
    minmax = objective in (Objective.MAKESPAN, Objective.MINMAX)
    cap = over * route.max() if minmax else 0.0
    before += max(0.0, cap - route.max())
    total_before = problem_total(perm, counts, tables)
    nn = nearest_neighbours(problem.dist, 5)
    allocation_search(
        perm, counts, int(objective), tables, nn, 1, 20, NO_PINS(n), np.inf,
        np.zeros(n, dtype=np.bool_), False, moves, lexi, cap,
    )  # fmt: skip
    assert_valid(perm, counts, n, m)
    after = evaluate(perm, counts, int(objective), tables, route)
    if minmax:
        assert route.max() <= max(cap, before) * (1 + 1e-9)  # never above the cap
    after += max(0.0, cap - route.max())
    assert after <= before + 1e-9 * max(1.0, before)
    if lexi and after >= before - 1e-9 * max(1.0, before):
        # The objective's figure (or the cap) unchanged: the total distance did not grow.
        assert problem_total(perm, counts, tables) <= total_before + 1e-6


def problem_total(perm, counts, tables):
    out = np.empty(counts.size)
    evaluate(perm, counts, int(Objective.MINMAX), tables, out)
    return out.sum()


@SETTINGS
@given(
    chromosomes(min_count=0),
    st.sampled_from(list(Objective)),
    st.integers(1, 8),
    st.booleans(),
    st.integers(0, 1),
)
def test_ruin_recreate_keeps_validity_minimum_and_pins(case, objective, size, focus, min_count):
    state, perm, counts = case
    n, m = perm.size, counts.size
    if min_count and counts.min() < 1:
        return
    problem = problem_for(n, m, n + 7 * m)
    tables = CostTables.of(problem).kernel_args()
    pins = NO_PINS(n)
    pins[int(perm[0])] = 0  # the first task of route 0 (or of a later one) pinned there
    repair_pins(perm, counts, pins, min_count)
    moved = np.empty(size, dtype=np.int64)
    nn = nearest_neighbours(problem.dist, 5)
    done = ruin_recreate(
        state, perm, counts, int(objective), tables, nn, size, focus, min_count, pins, moved
    )
    assert_valid(perm, counts, n, m, min_count)
    assert pins_hold(perm, counts, pins)
    assert 0 <= done <= size and len(set(moved[:done])) == done and np.all(moved[done:] == -1)
    assert pins[moved[:done]].max(initial=-1) < 0  # the pinned task never moves


@SETTINGS
@given(chromosomes(), st.sampled_from(list(Objective)))
def test_ruin_recreate_puts_a_task_back_where_the_objective_is_least(case, objective):
    # One task taken out (the seed) goes back at the best of every place of every route:
    # the objective after it equals the least found by trying each place.
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, 3 * n + m)
    tables = CostTables.of(problem).kernel_args()
    moved = np.empty(1, dtype=np.int64)
    nn = nearest_neighbours(problem.dist, 3)
    before_perm, before_counts = perm.copy(), counts.copy()
    done = ruin_recreate(
        state, perm, counts, int(objective), tables, nn, 1, False, 1, NO_PINS(n), moved
    )
    route = np.empty(m)
    after = evaluate(perm, counts, int(objective), tables, route)
    if done == 0:  # its route was at the minimum: nothing moves
        assert perm.tolist() == before_perm.tolist()
        return
    best = least_over_insertions(
        before_perm,
        before_counts,
        int(moved[0]),
        lambda flat, sizes: evaluate(flat, sizes, int(objective), tables, route),
    )
    assert after == pytest.approx(best, rel=1e-8, abs=1e-9)


@SETTINGS
@given(chromosomes(), st.sampled_from([Objective.MAKESPAN, Objective.MINMAX]))
def test_ruin_recreate_below_a_cap_puts_a_task_where_it_adds_least_distance(case, objective):
    # Far below the cap the figure counts as the cap wherever the task goes: the distance
    # (the tie-breaker) decides, and the task goes where the fleet drives least.
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, 5 * n + m)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    evaluate(perm, counts, int(objective), tables, route)
    cap = 10.0 * route.sum() + 1.0
    moved = np.empty(1, dtype=np.int64)
    nn = nearest_neighbours(problem.dist, 3)
    rows = split_routes(perm, counts)
    done = ruin_recreate(
        state, perm, counts, int(objective), tables, nn, 1, False, 1, NO_PINS(n), moved, cap
    )
    assert_valid(perm, counts, n, m)
    if done == 0:
        return
    t = int(moved[0])
    rows = [[j for j in r if j != t] for r in rows]
    least = np.inf
    for b in range(m):
        for p in range(len(rows[b]) + 1):
            trial = [list(r) for r in rows]
            trial[b].insert(p, t)
            least = min(least, problem_total(*chromosome_of(trial), tables))
    assert problem_total(perm, counts, tables) == pytest.approx(least, rel=1e-9)
    evaluate(perm, counts, int(objective), tables, route)
    assert route.max() <= cap


def chromosome_of(rows):
    perm = np.array([j for r in rows for j in r], dtype=np.int64)
    return perm, np.array([len(r) for r in rows], dtype=np.int64)


def test_ruin_recreate_gives_the_same_answer_for_the_same_seed():
    problem = problem_for(30, 4, 3)
    tables = CostTables.of(problem).kernel_args()
    nn = nearest_neighbours(problem.dist, 6)
    out = []
    for _ in range(2):
        perm = np.random.default_rng(4).permutation(30).astype(np.int64)
        counts = np.array([7, 8, 7, 8], dtype=np.int64)
        ruin_recreate(
            make_state(9), perm, counts, int(Objective.MINMAX), tables, nn, 5, True, 1,
            NO_PINS(30), np.empty(5, dtype=np.int64),
        )  # fmt: skip
        out.append((perm.tolist(), counts.tolist()))
    assert out[0] == out[1]


def test_nearest_neighbours_by_blocks_are_every_row_s_nearest_in_order():
    pts = np.random.default_rng(2).uniform(0, 1000, (300, 2))  # more rows than one block
    dist = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1))
    expected = np.argsort(dist + np.diag(np.full(300, np.inf)), axis=1)[:, :7]
    assert np.array_equal(nearest_neighbours(dist, 7), expected)
    assert nearest_neighbours(dist[:1, :1], 3).shape == (1, 0)
