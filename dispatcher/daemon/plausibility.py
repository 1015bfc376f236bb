"""Trust a vehicle's progress only when its own track bears it out.

A vehicle says it reached a mission item with MISSION_ITEM_REACHED (or, when that was lost
on the link, with a MISSION_CURRENT past it). Signing proves who sent the frame, not that
it is true: a faulty or compromised autopilot, or a replayed or forged frame on a vehicle
whose key leaked, could claim a whole field. So a claim counts only once the positions the
vehicle reported (GLOBAL_POSITION_INT) have passed, in mission order, every item up to the
one claimed, each within :data:`REACH_M` of the track between two fixes: the item lies in
the ellipse about the two fixes a and b that a path of 1.2 |ab| + 2 REACH_M can visit, so a
corner cut between two fixes still passes while a point well beyond them does not. A claim
not borne out within :data:`WAIT_REPORTS` further reports (and :data:`WAIT_S`) is an alarm
(:class:`~dispatcher.daemon.events.ProgressDoubted`), and none of it counts as done: the
field stays to be worked.

Items without a position (DO_CHANGE_SPEED, DO_SET_SERVO ...) pass with the item before
them. One positioned item in a row may go unseen (two fixes far apart around a sharp
corner); two may not: a jump over unfinished swaths is never taken as work.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from dispatcher.daemon import events as ev
from dispatcher.mission.document import PlannedItem

REACH_M = 25.0
"""How close a reported track must come to an item: ArduPilot Rover's WP_RADIUS (2 m by
default), GPS error and the overshoot of a turn, with a wide margin."""
PATH_SLACK = 1.2
"""How much longer than the straight line between two fixes the path between them may be."""
WAIT_REPORTS = 10
"""Position reports a claim may wait for the track to get there (the claim can arrive
before the fix that shows the vehicle at the item)."""
WAIT_S = 2.0
"""And wall seconds, at the least."""


@dataclass
class Claim:
    seq: int
    clock_s: float
    caught_up: bool
    source: str
    since: float  # wall time of the claim
    reports: int = 0  # position reports since


class ProgressWitness:
    """What one vehicle's track has passed of the mission on board, and its claims not yet
    borne out."""

    def __init__(self) -> None:
        self.mission: Sequence[PlannedItem] | None = None
        self.passed = 0  # the last item the track passed (all before it too)
        self.closest: dict[int, float] = {}  # item -> closest approach so far, metres
        self.prev: tuple[float, float] | None = None
        self.claims: list[Claim] = []

    def follow(self, mission: Sequence[PlannedItem], reached: int) -> None:
        """The mission on board and the last item taken as reached (by a claim borne out,
        or caught up after a restart): the track is checked from there."""
        if mission is not self.mission:
            self.mission = mission
            self.passed = reached
            self.closest.clear()
            self.claims.clear()
        self.passed = max(self.passed, reached)

    def claim(
        self, vid: str, seq: int, clock_s: float, caught_up: bool, source: str, now: float
    ) -> list[ev.Event]:
        """The vehicle says it reached ``seq``: the event now if its track bears it out,
        else later (:meth:`observe`), or an alarm."""
        if seq <= self.passed:
            return [ev.ItemReached(vid, seq, clock_s, caught_up=caught_up)]
        if not any(c.seq == seq for c in self.claims):
            self.claims.append(Claim(seq, clock_s, caught_up, source, now))
        return []

    def observe(self, vid: str, lat: float, lon: float, now: float) -> list[ev.Event]:
        """A position report: advance along the mission as far as the track has passed;
        the claims it bears out, and alarms for those that waited too long."""
        here = (lat, lon)
        prev, self.prev = self.prev or here, here
        if self.mission is not None:
            self._advance(prev, here)
        out: list[ev.Event] = []
        waiting = []
        for c in self.claims:
            c.reports += 1
            if c.seq <= self.passed:
                out.append(ev.ItemReached(vid, c.seq, c.clock_s, caught_up=c.caught_up))
            elif c.reports >= WAIT_REPORTS and now - c.since >= WAIT_S:
                item = self._first_unpassed()
                out.append(
                    ev.ProgressDoubted(
                        vid,
                        c.seq,
                        item,
                        round(self.closest.get(item, math.inf), 1),
                        c.source,
                        self._field_of(c.seq),
                    )
                )
            else:
                waiting.append(c)
        self.claims = waiting
        return out

    def _field_of(self, seq: int) -> str | None:
        assert self.mission is not None
        return self.mission[seq].field_id if 0 <= seq < len(self.mission) else None

    def _first_unpassed(self) -> int:
        assert self.mission is not None
        k = self.passed + 1
        while k < len(self.mission) and not _positioned(self.mission[k]):
            k += 1
        return min(k, len(self.mission) - 1)

    def _advance(self, a: tuple[float, float], b: tuple[float, float]) -> None:
        """Pass the items the track from fix ``a`` to fix ``b`` came within reach of, in
        order; one positioned item in a row may be passed unseen if the next is seen."""
        assert self.mission is not None
        mission = self.mission
        ab = metres(a, b)
        k = self.passed + 1
        unseen: int | None = None
        while k < len(mission):
            item = mission[k]
            if not _positioned(item):
                k += 1
                continue
            here = (item.lat, item.lon)
            self.closest[k] = min(self.closest.get(k, math.inf), _to_segment(item, a, b))
            if metres(here, a) + metres(here, b) <= PATH_SLACK * ab + 2 * REACH_M:
                self.passed = k
                unseen = None
            elif unseen is None:
                unseen = k  # perhaps cut between fixes: seen if the next one is
            else:
                break
            k += 1
        # Items without a position right after the last passed one pass with it.
        while self.passed + 1 < len(mission) and not _positioned(mission[self.passed + 1]):
            self.passed += 1


def _positioned(item: PlannedItem) -> bool:
    return item.x != 0 or item.y != 0


def metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance between two (lat, lon) close to each other (equirectangular, metres)."""
    k = math.cos(math.radians((a[0] + b[0]) / 2))
    return 111_195.0 * math.hypot(b[0] - a[0], (b[1] - a[1]) * k)


def _to_segment(item: PlannedItem, a: tuple[float, float], b: tuple[float, float]) -> float:
    """Metres from the item to the segment a-b (equirectangular about the item)."""
    k = math.cos(math.radians(item.lat))
    ax, ay = (a[1] - item.lon) * k * 111_195.0, (a[0] - item.lat) * 111_195.0
    bx, by = (b[1] - item.lon) * k * 111_195.0, (b[0] - item.lat) * 111_195.0
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, -(ax * dx + ay * dy) / length2))
    return math.hypot(ax + t * dx, ay + t * dy)
