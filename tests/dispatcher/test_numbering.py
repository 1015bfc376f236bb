"""A vehicle's item numbers against the plan's (dispatcher/link/numbering.py)."""

from __future__ import annotations

from helpers.messages import waypoints

from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import CommandSequence, set_current_command
from dispatcher.link.numbering import (
    LEAST_SAVED,
    MARGIN,
    Numbering,
    choose_base,
    command_to_vehicle,
    on_board,
)


def set_current(item: int) -> mc.MAVLinkMessage:
    """The COMMAND_LONG a CommandSequence sends for ``set_current_command(item)``."""
    seq = CommandSequence([set_current_command(item)], 1)
    (msg,) = seq.start(0.0)
    return msg


def test_the_same_numbers_until_renumbered() -> None:
    n = Numbering()
    for seq in (0, 1, 57, 900):
        assert n.to_vehicle(seq) == seq and n.to_plan(seq) == seq
        assert n.report(seq, 900)[:2] == (seq, 900)
    assert choose_base(n, held=300, first=10, driving_to=9) == 1  # saves too little


def test_a_vehicle_far_into_its_mission_is_sent_the_items_from_where_it_is() -> None:
    n = Numbering()
    # It drives to item 475; the new mission is home and items 470 .. 719: 251 items.
    assert choose_base(n, held=720, first=470, driving_to=475) == 470
    # Not when the new mission would reach the index it drives to (less MARGIN).
    assert choose_base(n, held=470 + 475 - MARGIN, first=470, driving_to=475) == 1
    assert choose_base(n, held=470 + 475 - MARGIN - 2, first=470, driving_to=475) == 470
    # A new mission (items before the base needed): from the start again.
    renumbered = n.uploaded(470, 251)
    assert choose_base(renumbered, held=29, first=1, driving_to=0) == 1
    # Nor when it saves fewer than LEAST_SAVED items.
    assert choose_base(n, held=40, first=LEAST_SAVED, driving_to=39 + MARGIN + 10) == 1


def test_on_board_holds_home_and_the_items_from_the_base_numbered_from_one() -> None:
    plan = waypoints(20)
    held = on_board(plan, 12)
    assert [m.seq for m in held] == list(range(9))
    assert held[0] is plan[0]
    assert [m.x for m in held[1:]] == [m.x for m in plan[12:]]
    assert [m.seq for m in plan] == list(range(20))  # copies: the plan's stay as they were
    assert on_board(plan, 1) == plan


def test_reports_of_the_old_numbers_are_told_from_the_new_until_it_drives_the_new() -> None:
    # Driving to item 475 of 721 (base 1); home and items 470 .. 719 acknowledged (251).
    n = Numbering(count=721).uploaded(470, 251)
    assert (n.base, n.count, n.old_base, n.old_count) == (470, 251, 1, 721)
    assert n.to_vehicle(475) == 6 and n.to_plan(6) == 475
    # ArduPilot drives item 475 from memory across the upload: its reports of it, and a
    # late one of the item before, are in the old numbers (past the new count).
    assert n.report(474)[0] == 474
    assert n.report(475, 250)[:2] == (475, 719)  # MISSION_CURRENT: new count, old item
    # A MISSION_CURRENT of the old mission (its count) is read in the old numbers.
    assert n.report(30, 720)[:2] == (30, 720)
    # The new numbers: item 6 is the plan's 475; and once a MISSION_CURRENT of the new
    # mission says so, every report is in them (items past the first count too, after
    # a later top-up).
    seq, total, after = n.report(6, 250)
    assert (seq, total) == (475, 719)
    assert after.old_base == 470
    assert after.report(300)[0] == 769
    # Until then, a report under the new count reads in the new numbers.
    assert n.report(7)[0] == 476


def test_a_later_upload_in_the_same_numbers_keeps_them() -> None:
    n = Numbering(count=721).uploaded(470, 251).report(6, 250)[2]
    later = n.uploaded(470, 400)
    assert (later.base, later.count) == (470, 400)
    assert later.report(300, 399)[:2] == (769, 868)


def test_set_current_goes_out_in_the_vehicle_numbers() -> None:
    n = Numbering(count=721).uploaded(470, 251)
    msg = set_current(475)
    out = command_to_vehicle(msg, n)
    assert out.param1 == 6.0 and msg.param1 == 475.0
    legacy = mc.message("MISSION_SET_CURRENT", target_system=1, target_component=1, seq=500)
    assert command_to_vehicle(legacy, n).seq == 31
    beat = mc.message("MISSION_ACK", target_system=1, target_component=1, type=0)
    assert command_to_vehicle(beat, n) is beat
    assert command_to_vehicle(msg, Numbering()) is msg
