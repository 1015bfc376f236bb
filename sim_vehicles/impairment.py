"""A radio that loses, duplicates and delays frames: fault injection for a simulated link.

:class:`Impairment` says how bad the link is; a :class:`DelayLine` applies it to the frames
going one way: each frame is lost with probability ``loss``, else sent, and sent a second
time with probability ``duplicate``; each copy arrives after a delay drawn uniformly from
0 to ``delay_s``, so frames also overtake each other, as on a real radio with retries. The
random numbers come from a seeded generator: a run is repeatable.
"""

from __future__ import annotations

import argparse
import heapq
import itertools
import random
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class Impairment:
    loss: float = 0.0  # probability a frame never arrives
    duplicate: float = 0.0  # probability a frame arrives twice
    delay_s: float = 0.0  # each copy arrives after U(0, delay_s) seconds

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate"):
            value = getattr(self, name)
            if not 0.0 <= value < 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1), got {value}")
        if not 0.0 <= self.delay_s <= 10.0:
            raise ValueError(f"delay must be 0 to 10 s, got {self.delay_s} s")

    @property
    def active(self) -> bool:
        return self.loss > 0.0 or self.duplicate > 0.0 or self.delay_s > 0.0

    def __str__(self) -> str:
        return (
            f"loss {100 * self.loss:g} %, duplicates {100 * self.duplicate:g} %, "
            f"delay up to {1000 * self.delay_s:g} ms"
        )


class DelayLine(Generic[T]):
    """Frames one way through an impaired link; :meth:`due` gives those that arrived."""

    def __init__(self, impairment: Impairment, seed: int) -> None:
        self.impairment = impairment
        self.rng = random.Random(seed)
        self._pending: list[tuple[float, int, T]] = []
        self._order = itertools.count()
        self.lost = self.duplicated = 0

    def push(self, item: T, now: float) -> None:
        imp = self.impairment
        if self.rng.random() < imp.loss:
            self.lost += 1
            return
        copies = 1
        if self.rng.random() < imp.duplicate:
            copies = 2
            self.duplicated += 1
        for _ in range(copies):
            due = now + self.rng.uniform(0.0, imp.delay_s) if imp.delay_s > 0 else now
            heapq.heappush(self._pending, (due, next(self._order), item))

    def due(self, now: float) -> list[T]:
        out = []
        while self._pending and self._pending[0][0] <= now:
            out.append(heapq.heappop(self._pending)[2])
        return out

    def __len__(self) -> int:
        return len(self._pending)


def add_impairment_arguments(parser: argparse.ArgumentParser) -> None:
    """``--loss``, ``--duplicate``, ``--delay`` and ``--radio-seed`` on a simulator's command."""
    g = parser.add_argument_group("fault injection: an impaired radio (every vehicle, both ways)")
    g.add_argument("--loss", type=float, default=0.0, metavar="P", help="share of frames lost")
    g.add_argument(
        "--duplicate", type=float, default=0.0, metavar="P", help="share of frames sent twice"
    )
    g.add_argument(
        "--delay", type=float, default=0.0, metavar="MS", help="frames arrive 0 to MS ms late"
    )
    g.add_argument("--radio-seed", type=int, default=1, metavar="N", help="random seed")


def impairment_of(args: argparse.Namespace) -> Impairment:
    """The impairment the command line asks for (ValueError names the bad one)."""
    return Impairment(loss=args.loss, duplicate=args.duplicate, delay_s=args.delay / 1000.0)
