"""Missions sent in windows: how much of its mission a vehicle holds at a time.

A long mission (a day's work over many fields: hundreds to thousands of items) is not sent
whole. A vehicle holds a *window*: the first items of its mission, up to just after the
implement is raised (the end of a field, or the next swath's start after a turn), and is
given more (the window extended, "topped up") while it drives, well
before it reaches the end of what it holds. What it holds is always a prefix of its planned
mission, with the plan's item numbers, so a top-up is an upload that begins with the items
the vehicle already holds: the autopilot keeps driving the item it is on (ArduPilot replaces
or appends items in place), and any half-done upload still leaves a prefix of the plan on
board.

The way home from the last field is a window of its own, so a vehicle at work always
holds up to a place where a route may end (a field's end, or a swath's start).

Why: what goes over the radio at a re-plan is bounded by the window, not by the day (a
re-plan changes the routes *after* each vehicle's window; a driving vehicle's window is not
uploaded again), and an autopilot with little mission storage can still work a big farm.

A driving vehicle re-planned is sent its new route only to the first place a window may
end (:func:`shortest`: the implement next raised, at a turn or at the field's end): that
upload is what a re-plan waits for, and top-ups give the rest while it drives that part.

:func:`window` says how many items to hold; :data:`ROUTE_ENDS` where a route may end (a
window, the part of an old mission a vehicle keeps at a re-plan).
"""

from __future__ import annotations

from collections.abc import Sequence

from dispatcher.mission.build import IMPLEMENT_RAISED
from dispatcher.mission.document import PlannedItem

ROUTE_ENDS = frozenset({"swath_end", "swath_start", "road", "transit", "return"})
"""Roles of the items where a route may end and another begin (not in the middle of a turn
or an in-field detour)."""

FIELD_ENDS = IMPLEMENT_RAISED
"""Roles of the items after which a window may end (at the next item where a route may
end): the implement raised at the end of a field, or for a turn between two swaths."""


def window(items: Sequence[PlannedItem], held: int, size: int) -> int:
    """How many first items of ``items`` (a mission, home first) a vehicle that holds
    ``held`` of them now is to hold: up to the first waypoint where a route may end after
    the implement is raised (:data:`FIELD_ENDS`: a field's end, or a turn), as many such
    stretches as fit in ``size`` more items, at least one; all of them once no field is
    left (the way home), or when ``size`` is 0 (no windows).

    The way home comes in a window of its own: a vehicle at work always holds up to a place
    where a route may end, so a re-plan can send it on from there without changing what it
    holds."""
    held = max(held, 1)
    if size <= 0:
        return len(items)
    boundaries = []
    in_field_end = False
    for k in range(held, len(items)):
        role = items[k].role
        if role in FIELD_ENDS:
            in_field_end = True
        elif in_field_end and items[k].is_nav and role in ROUTE_ENDS:
            in_field_end = False
            boundaries.append(k + 1)
            if k + 1 - held >= size:
                break
    fits = [b for b in boundaries if b - held <= size]
    if fits:
        return fits[-1]
    return boundaries[0] if boundaries else len(items)


def shortest(size: int) -> int:
    """The ``size`` for :func:`window` that holds a new route up to the first place a
    window may end (after the implement is next raised), given the scenario's window
    ``size``; 0 (no windows) stays 0: the whole mission."""
    return min(size, 1)
