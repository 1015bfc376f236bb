"""planner.moves: each move's evaluated lengths equal the lengths recomputed after it is
applied, the chromosome stays valid, pins and minimum sizes hold; the local search with
every move and the lexicographic second objective never worsens a solution."""

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, SETTINGS, assert_valid, chromosomes, problem_for
from hypothesis import given
from hypothesis import strategies as st

from planner.cost import CostTables, Objective, evaluate
from planner.local_search import allocation_search, nearest_neighbours
from planner.moves import (
    MOVES,
    TWO_OPT_STAR,
    mask,
    prefix,
    route_rows,
    segment_apply,
    segment_lengths,
    two_opt_star_allowed,
    two_opt_star_apply,
    two_opt_star_lengths,
)


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
@given(chromosomes(), st.sampled_from(list(Objective)), st.booleans(), st.integers(1, 15))
def test_allocation_search_with_every_move_never_worsens(case, objective, lexi, moves):
    _, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, int(perm[0]) + 5 * n)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    before = evaluate(perm, counts, int(objective), tables, route)
    total_before = problem_total(perm, counts, tables)
    nn = nearest_neighbours(problem.dist, 5)
    allocation_search(
        perm, counts, int(objective), tables, nn, 1, 20, NO_PINS(n), np.inf,
        np.zeros(n, dtype=np.bool_), False, moves, lexi,
    )  # fmt: skip
    assert_valid(perm, counts, n, m)
    after = evaluate(perm, counts, int(objective), tables, route)
    assert after <= before + 1e-9 * max(1.0, before)
    if lexi and after >= before - 1e-9 * max(1.0, before):
        # The objective's figure unchanged: the total distance did not grow.
        assert problem_total(perm, counts, tables) <= total_before + 1e-6


def problem_total(perm, counts, tables):
    out = np.empty(counts.size)
    evaluate(perm, counts, int(Objective.MINMAX), tables, out)
    return out.sum()
