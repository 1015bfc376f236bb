"""One explicit random state for all compiled kernels: xorshift64 in a uint64 array.

numba keeps its own hidden generator apart from numpy's; passing this state into every
kernel instead makes a run depend only on its seed, compiled or not (only xor and
shifts, so pure Python under NUMBA_DISABLE_JIT=1 gives the same stream without overflow).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_MASK53 = 2.0**-53


def make_state(seed: int) -> np.ndarray:
    """A fresh state from any integer seed (splitmix-style scrambled, never zero)."""
    z = (int(seed) * 0x9E3779B97F4A7C15 + 0x632BE59BD9B4E019) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z ^= z >> 31
    return np.array([z or 0x2545F4914F6CDD1D], dtype=np.uint64)


@njit(cache=True, nogil=True)
def next_u64(state: np.ndarray) -> np.uint64:
    x = state[0]
    x ^= x << np.uint64(13)
    x ^= x >> np.uint64(7)
    x ^= x << np.uint64(17)
    state[0] = x
    return x


@njit(cache=True, nogil=True)
def uniform(state: np.ndarray) -> float:
    """A float in [0, 1)."""
    return float(next_u64(state) >> np.uint64(11)) * _MASK53


@njit(cache=True, nogil=True)
def randint(state: np.ndarray, n: int) -> int:
    """An int in [0, n)."""
    return int(uniform(state) * n)


@njit(cache=True, nogil=True)
def shuffle(state: np.ndarray, arr: np.ndarray) -> None:
    """Fisher-Yates, in place."""
    for i in range(arr.shape[0] - 1, 0, -1):
        j = randint(state, i + 1)
        tmp = arr[i]
        arr[i] = arr[j]
        arr[j] = tmp
