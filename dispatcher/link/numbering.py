"""Mission item numbers on board and in the plan: a vehicle holds its mission from an item on.

The daemon counts a vehicle's mission in the plan's numbers (``PlannedItem`` order: home 0,
then every item of the vehicle's day). What a vehicle holds is home, then the plan's items
from ``base`` on: its item k ≥ 1 is the plan's item ``base + k - 1``. At first ``base`` is 1
(the same numbers). Later uploads may move it on (*renumber*): a vehicle far into a long
mission is sent home plus the items from where it is, not the whole prefix again, which
through a lossy radio costs seconds per few hundred items (docs/link.md, "Missions go in
windows").

Renumbering a vehicle that drives its mission is safe only one way round. ArduPilot cuts
its mission to the new count at the MISSION_COUNT (``MissionItemProtocol::handle_mission_count``,
``truncate``), replaces items in place as they come, and when its mission changes under AUTO
it restarts the item it drives to *by index* from storage (Rover ``ModeAuto::update``,
``AP_Mission::restart_current_nav_cmd``); an index past the new count it keeps driving from
memory, and stops there, its mission complete. So a mission is renumbered only when the new
one ends ``MARGIN`` items or more before the index the vehicle drives to (:func:`choose_base`):
no item it may read while the upload goes on is one of the new mission's, and every index
of the old numbering it may report from then on is past the new count. Reports are then
told apart by their number (and MISSION_CURRENT by its ``total``, the count) in
:meth:`Numbering.report`, and the item it drives to is set again in the new numbers as soon
as the upload is acknowledged. The daemon renumbers a vehicle whose mission runs only when
that upload should be on board before it reaches the item it drives to (it would stop
there), or when the whole prefix would stop it longer at the end of the window it holds (a
top-up through a slow radio or on a fast clock), and for its new route after a re-plan (a
stop costs one start; the prefix, seconds); one standing still (in the garage, held, at the
end of its window) any time.
tests/test_sitl_renumbering.py checks these facts against ArduPilot SITL.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass, replace

from dispatcher.link import mavlink as mc

MARGIN = 8
"""A driving vehicle's mission is renumbered only when the new one ends this many items or
more before the index it drives to (reports of a few items ago still on their way stay
readable)."""
LEAST_SAVED = 32
"""Nor for fewer items saved than this: each renumbering costs a set-current command."""


@dataclass(frozen=True)
class Numbering:
    """How a vehicle's item numbers map to the plan's: its item k ≥ 1 is the plan's item
    ``base + k - 1`` in a mission of ``count`` items (home included; 0: not told yet).
    Until the vehicle is known to drive the renumbered mission (:meth:`report`), reports
    of the numbering before (``old_base``, ``old_count``) may still come."""

    base: int = 1
    count: int = 0
    old_base: int = 1
    old_count: int = 0

    def to_vehicle(self, plan_item: int) -> int:
        """The vehicle's number of plan item ``plan_item`` (home stays 0). An item before
        the base is not on board: its number would be 0 or less, and is raised to 1."""
        if plan_item <= 0:
            return 0
        return max(plan_item - self.base + 1, 1)

    def to_plan(self, seq: int, base: int | None = None) -> int:
        """The plan's number of the vehicle's item ``seq`` (in the numbering from ``base``,
        this one's by default)."""
        if seq <= 0:
            return seq
        return seq + (self.base if base is None else base) - 1

    def uploaded(self, base: int, count: int) -> Numbering:
        """The vehicle acknowledged a mission of ``count`` items from plan item ``base``."""
        if base == self.base:
            return replace(self, count=count)
        return Numbering(base, count, self.base, self.count)

    def in_last(self, seq: int, total: int | None = None) -> bool:
        """Whether a report (as :meth:`report` takes it) is in the numbers of the last
        upload, not of the one before: a number past the new count is of the old numbering
        (the item driven from memory across the upload, or a late report); so is a
        MISSION_CURRENT of another count."""
        if self.old_base == self.base:
            return True
        if total is not None and total != 0xFFFF and total != self.count - 1:
            return False
        return seq < self.count

    def report(self, seq: int, total: int | None = None) -> tuple[int, int | None, Numbering]:
        """A report's item (MISSION_ITEM_REACHED ``seq``, or MISSION_CURRENT ``seq`` and
        ``total``, its count less home) in the plan's numbers, and the numbering from now
        on: once a MISSION_CURRENT says the vehicle drives the renumbered mission, the old
        numbering's reports are over (which numbering a report is in: :meth:`in_last`)."""
        base = self.base if self.in_last(seq, total) else self.old_base
        plan_total = None
        if total is not None and total != 0xFFFF:
            counted = self.base if total == self.count - 1 else self.old_base
            plan_total = self.to_plan(total, counted)
        if total is not None and total == self.count - 1 and 0 < seq < self.count:
            after = replace(self, old_base=self.base, old_count=self.count)
        else:
            after = self
        return self.to_plan(seq, base), plan_total, after


def choose_base(numbering: Numbering, held: int, first: int, driving_to: int) -> int:
    """The plan item a vehicle's next upload is to begin at (its item 1): ``first`` (the
    first item it may still need, in the plan's numbers) when that saves LEAST_SAVED
    items or more and the new mission (home and the plan's items ``first`` .. ``held`` - 1)
    ends MARGIN items or more before the index it drives to or stands at now
    (``driving_to``, plan numbers; 0: none); else the base it has. (Standing still, it
    reports that index too: a number under the new count would read as one of the new
    mission's.) A mission that needs items before the base (a new one, given to a vehicle
    standing still) begins at 1 again."""
    first = max(first, 1)
    if first < numbering.base:
        return 1
    if first - numbering.base < LEAST_SAVED:
        return numbering.base
    count = count_on_board(held, first)
    index = numbering.to_vehicle(driving_to) if driving_to > 0 else 0
    if index - count < MARGIN:
        return numbering.base
    return first


def count_on_board(held: int, base: int) -> int:
    """How many items a vehicle holds when it holds the plan's first ``held`` items from
    plan item ``base`` on: home, then items ``base`` .. ``held`` - 1 (all of them from 1)."""
    return held - max(base, 1) + 1


def on_board(items: Sequence[mc.MAVLinkMessage], base: int) -> list[mc.MAVLinkMessage]:
    """A mission's MISSION_ITEM_INT messages (plan numbers, home first) as the vehicle is to
    hold them from plan item ``base`` on: home, then copies of the items from ``base``,
    numbered 1, 2, ..."""
    if base <= 1:
        return list(items)
    out = [items[0]]
    for k, item in enumerate(items[base:], start=1):
        moved = copy.copy(item)
        moved.seq = k
        out.append(moved)
    return out


SET_CURRENT_COMMANDS = frozenset({mc.MAV_CMD_DO_SET_MISSION_CURRENT})
"""Commands whose first parameter is a mission item number."""


def command_to_vehicle(msg: mc.MAVLinkMessage, numbering: Numbering) -> mc.MAVLinkMessage:
    """``msg`` as sent to the vehicle: a command that names a mission item (set current, in
    COMMAND_LONG / COMMAND_INT, or MISSION_SET_CURRENT) with the item in its numbers (a
    copy); any other message as it is."""
    if numbering.base == 1:
        return msg
    kind = msg.get_type()
    if kind in ("COMMAND_LONG", "COMMAND_INT") and msg.command in SET_CURRENT_COMMANDS:
        out = copy.copy(msg)
        out.param1 = float(numbering.to_vehicle(int(msg.param1)))
        return out
    if kind == "MISSION_SET_CURRENT":
        out = copy.copy(msg)
        out.seq = numbering.to_vehicle(int(msg.seq))
        return out
    return msg
