"""Chromosomes and small problems for the planner's operator tests (hypothesis)."""

import numpy as np
from hypothesis import settings
from hypothesis import strategies as st

from planner.population import random_counts
from planner.problem import Machine, Problem, Task
from planner.rng import make_state

SETTINGS = settings(max_examples=80, deadline=None, derandomize=True)


def NO_PINS(n):  # noqa: N802
    return np.full(n, -1, dtype=np.int64)


@st.composite
def chromosomes(draw, min_count=1):
    n = draw(st.integers(2, 30))
    m = draw(st.integers(1, min(n, 6)))
    seed = draw(st.integers(0, 2**31))
    state = make_state(seed)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(n).astype(np.int64)
    counts = np.empty(m, dtype=np.int64)
    random_counts(state, n, m, min_count, counts)
    return state, perm, counts


def assert_valid(perm, counts, n, m, min_count=1):
    assert sorted(perm.tolist()) == list(range(n))
    assert counts.shape == (m,)
    assert counts.sum() == n
    assert counts.min() >= min_count


def problem_for(n, m, seed, min_count=1, rng=None):
    """n random tasks in a 3 km square, m machines at the origin (draws from ``rng`` when
    given, so that a caller can go on drawing from it)."""
    rng = np.random.default_rng(seed) if rng is None else rng
    machines = [
        Machine(f"m{i}", 3.0 + i, 5000.0 + 500 * i, 10.0 + i, 0.003, 2.5, 5.0) for i in range(m)
    ]
    tasks = [
        Task(f"t{j}", float(x), float(y), 10000.0, 100.0, 80.0)
        for j, (x, y) in enumerate(rng.uniform(0, 3000, size=(n, 2)))
    ]
    return Problem.build(machines, tasks, (0.0, 0.0), min_tasks_per_machine=min_count)


def least_over_insertions(perm, counts, task, figure):
    """The least of ``figure(perm, counts)`` over every place of every route where
    ``task``, taken out of the chromosome, could go back (brute force)."""
    rows = [[int(j) for j in perm[b:e] if j != task] for b, e in _bounds(counts)]
    best = np.inf
    for r, row in enumerate(rows):
        for p in range(len(row) + 1):
            trial = [list(x) for x in rows]
            trial[r].insert(p, task)
            flat = np.array([j for x in trial for j in x], dtype=np.int64)
            best = min(best, figure(flat, np.array([len(x) for x in trial], dtype=np.int64)))
    return best


def _bounds(counts):
    ends = np.cumsum(counts)
    return zip(ends - counts, ends, strict=True)
