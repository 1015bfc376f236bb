"""Trust a vehicle's progress only when its own track bears it out.

A vehicle says it reached a mission item with MISSION_ITEM_REACHED (or, when that was lost
on the link, with a MISSION_CURRENT past it). Signing proves who sent the frame, not that
it is true: a faulty or compromised autopilot, or a replayed or forged frame on a vehicle
whose key leaked, could claim a whole field. So a claim counts only once the positions the
vehicle reported (GLOBAL_POSITION_INT) have passed, in mission order, every item up to the
one claimed.

Between two fixes a and b the track passes the items p+1 … k (in mission order, from the
last one passed) when the path a → p+1 → … → k → b is no longer than what the vehicle can
have driven between them: the larger of :data:`PATH_SLACK` · |ab| (a curve between two
fixes close in time) and :data:`SPEED_SLACK` × its top speed × the time between the fixes
on its own clock (a gap in the reports: a radio that went quiet, a process descheduled, a
simulator that moved on in one step), plus 2 · :data:`REACH_M` for the corners it may cut;
and as far as the last such item k after which b lies on the route (within :data:`REACH_M`
of the line from k to the next item).
The top speed is the fastest DO_CHANGE_SPEED of the mission on board, else
:data:`FALLBACK_SPEED_MS`. So a vehicle that was out of hearing and comes back further on
its route is believed as far as it could have driven meanwhile and to where it is now, while
a claim that jumps over swaths its track never went near is not. (Swaths closer together
than :data:`REACH_M` cannot be told apart by position: after a long gap, a vehicle that lies
about its progress could have a few of them counted that it will drive next.)

A claim not borne out within :data:`WAIT_REPORTS` further reports (and :data:`WAIT_S`) is
an alarm (:class:`~dispatcher.daemon.events.ProgressDoubted`), and none of it counts as
done: the field stays to be worked. Items without a position (DO_CHANGE_SPEED,
DO_SET_SERVO ...) pass with the item before them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from dispatcher.daemon import events as ev
from dispatcher.link import mavlink as mc
from dispatcher.mission.document import PlannedItem

REACH_M = 25.0
"""How close a reported track must come to an item: ArduPilot Rover's WP_RADIUS (2 m by
default), GPS error and the overshoot of a turn, with a wide margin."""
PATH_SLACK = 1.2
"""How much longer than the straight line between two fixes the path between them may be."""
SPEED_SLACK = 1.5
"""How much faster than its mission's top speed a vehicle may seem to go between two fixes
(the autopilot's speed overshoot, and clocks read at slightly different moments)."""
FALLBACK_SPEED_MS = 70.0 / 3.6
"""Top speed of a mission that sets none: the upper bound of a road speed
(dispatcher.config.scenario, ``road_speed_kmh``)."""
WAIT_REPORTS = 10
"""Position reports a claim may wait for the track to get there (the claim can arrive
before the fix that shows the vehicle at the item)."""
WAIT_S = 2.0
"""And wall seconds, at the least."""


@dataclass
class Claim:
    seq: int
    clock_s: float | None  # the vehicle's clock when it was made; None: not heard yet
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
        self.prev_clock_s: float | None = None  # the vehicle's own time at ``prev``
        self.top_speed_ms = FALLBACK_SPEED_MS
        self.claims: list[Claim] = []

    def follow(self, mission: Sequence[PlannedItem], reached: int) -> None:
        """The mission on board and the last item taken as reached (by a claim borne out,
        or caught up after a restart): the track is checked from there."""
        if mission is not self.mission:
            self.mission = mission
            self.passed = reached
            self.closest.clear()
            self.claims.clear()
            self.top_speed_ms = top_speed_ms(mission)
        self.passed = max(self.passed, reached)

    def claim(
        self, vid: str, seq: int, clock_s: float | None, caught_up: bool, source: str, now: float
    ) -> list[ev.Event]:
        """The vehicle says it reached ``seq``: the event now if its track bears it out,
        else later (:meth:`observe`), or an alarm. ``clock_s`` None: the vehicle's clock
        is not heard yet (a dispatcher just restarted); the event then takes the clock of
        the position that bears it out (before, it took 0 s, or the clock from before the
        restart)."""
        if seq <= self.passed:
            when = clock_s if clock_s is not None else self.prev_clock_s
            if when is None:
                # Nothing heard since the restart: passed is what was reached before it.
                return []
            return [ev.ItemReached(vid, seq, when, caught_up=caught_up)]
        if not any(c.seq == seq for c in self.claims):
            self.claims.append(Claim(seq, clock_s, caught_up, source, now))
        return []

    def observe(
        self, vid: str, lat: float, lon: float, now: float, clock_s: float | None = None
    ) -> list[ev.Event]:
        """A position report (``clock_s``: the vehicle's own time of it, when known):
        advance along the mission as far as the track has passed; the claims it bears
        out, and alarms for those that waited too long."""
        here = (lat, lon)
        prev, self.prev = self.prev or here, here
        dt = 0.0
        if clock_s is not None:
            if self.prev_clock_s is not None:
                dt = max(clock_s - self.prev_clock_s, 0.0)
            self.prev_clock_s = clock_s
        if self.mission is not None:
            self._advance(prev, here, dt)
        out: list[ev.Event] = []
        waiting = []
        for c in self.claims:
            c.reports += 1
            when = c.clock_s if c.clock_s is not None else clock_s
            if c.seq <= self.passed and when is not None:
                out.append(ev.ItemReached(vid, c.seq, when, caught_up=c.caught_up))
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

    def _advance(self, a: tuple[float, float], b: tuple[float, float], dt: float) -> None:
        """Pass the items the track from fix ``a`` to fix ``b``, ``dt`` of the vehicle's
        seconds later, can have visited in mission order, as far as the last one after
        which ``b`` lies on the route (the module's rule)."""
        assert self.mission is not None
        mission = self.mission
        budget = max(PATH_SLACK * metres(a, b), SPEED_SLACK * self.top_speed_ms * dt) + 2 * REACH_M
        path = 0.0  # a -> the items so far
        at = a
        k = self.passed + 1
        while k < len(mission):
            item = mission[k]
            if not _positioned(item):
                k += 1
                continue
            here = (item.lat, item.lon)
            self.closest[k] = min(self.closest.get(k, math.inf), _to_segment(here, a, b))
            path += metres(at, here)
            # Never shorter for a later item (triangle inequality): the first that does
            # not fit ends the walk.
            if path + metres(here, b) > budget:
                break
            if _to_segment(b, here, self._next_position(k)) <= REACH_M:
                self.passed = k  # b lies on the route after k
            at = here
            k += 1
        # Items without a position right after the last passed one pass with it.
        while self.passed + 1 < len(mission) and not _positioned(mission[self.passed + 1]):
            self.passed += 1

    def _next_position(self, k: int) -> tuple[float, float]:
        """Where the route goes after item ``k``: the next item with a position (``k``'s
        own at the end)."""
        assert self.mission is not None
        for item in self.mission[k + 1 :]:
            if _positioned(item):
                return item.lat, item.lon
        return self.mission[k].lat, self.mission[k].lon


def _positioned(item: PlannedItem) -> bool:
    return item.x != 0 or item.y != 0


def leg_start(mission: Sequence[PlannedItem], seq: int) -> int | None:
    """The item the leg to item ``seq`` starts at: the last item with a position before
    it; None if there is none."""
    return next(
        (k for k in range(min(seq, len(mission)) - 1, -1, -1) if _positioned(mission[k])), None
    )


def leg_end(mission: Sequence[PlannedItem], seq: int) -> int | None:
    """The item the leg to item ``seq`` ends at: the first item with a position at or
    after it (``seq`` itself for a waypoint; after a DO item, the waypoint it leads to);
    None if there is none."""
    return next((k for k in range(max(seq, 0), len(mission)) if _positioned(mission[k])), None)


def off_leg_m(
    mission: Sequence[PlannedItem], seq: int, position: tuple[float, float]
) -> float | None:
    """Metres from ``position`` (lat, lon) to the leg the mission drives on its way to item
    ``seq``: from :func:`leg_start` to :func:`leg_end` (to the end alone at the mission's
    start); None when the mission has no position after."""
    end = leg_end(mission, seq)
    if end is None:
        return None
    start = leg_start(mission, seq)
    before, after = mission[end if start is None else start], mission[end]
    return _to_segment(position, (before.lat, before.lon), (after.lat, after.lon))


def top_speed_ms(mission: Sequence[PlannedItem]) -> float:
    """The fastest ground speed the mission sets (DO_CHANGE_SPEED), else the fallback."""
    speeds = [
        item.param2
        for item in mission
        if item.command == mc.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0
    ]
    return max(speeds, default=FALLBACK_SPEED_MS)


def metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Distance between two (lat, lon) close to each other (equirectangular, metres)."""
    k = math.cos(math.radians((a[0] + b[0]) / 2))
    return 111_195.0 * math.hypot(b[0] - a[0], (b[1] - a[1]) * k)


def _to_segment(p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    """Metres from the point p to the segment a-b, all (lat, lon) (equirectangular about p)."""
    k = math.cos(math.radians(p[0]))
    ax, ay = (a[1] - p[1]) * k * 111_195.0, (a[0] - p[0]) * 111_195.0
    bx, by = (b[1] - p[1]) * k * 111_195.0, (b[0] - p[0]) * 111_195.0
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, -(ax * dx + ay * dy) / length2))
    return math.hypot(ax + t * dx, ay + t * dy)
