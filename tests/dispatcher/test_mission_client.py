"""The ground-station side of the mission protocol against recorded ArduPilot-style
exchanges: what a Rover sends, in the order it sends it."""

import pytest
from helpers.messages import command_ack, waypoints

from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import (
    MIN_TIMEOUT_S,
    TRANSFER_MIN_MARGIN_S,
    TRANSFER_RETRIES,
    Command,
    CommandSequence,
    MissionUpload,
    Outcome,
    start_mission_commands,
)

VEHICLE = 7


def items(n):
    return waypoints(n, VEHICLE)


def request(seq):
    return mc.message(
        "MISSION_REQUEST_INT", target_system=255, target_component=190, seq=seq, mission_type=0
    )


def ack(result):
    return mc.message(
        "MISSION_ACK", target_system=255, target_component=190, type=result, mission_type=0
    )


def wire(msg):
    """Through a real MAVLink 2 frame, as the vehicle's message would arrive."""
    codec = mc.Codec(VEHICLE, 1)
    return mc.Codec(255, 190).decode_one(codec.encode(msg))


def test_full_upload():
    """One item per request, as the protocol was written (``pipeline=1``)."""
    up = MissionUpload(items(3), VEHICLE, pipeline=1)
    (count,) = up.start(0.0)
    assert count.get_type() == "MISSION_COUNT" and count.count == 3
    assert count.target_system == VEHICLE
    for k in range(3):
        (item,) = up.on_message(wire(request(k)), 0.1 * k)
        assert item.get_type() == "MISSION_ITEM_INT" and item.seq == k
    assert up.on_message(wire(ack(mc.MAV_MISSION_ACCEPTED)), 0.5) == []
    assert up.outcome is Outcome.DONE and up.stats.retries == 0


def test_vehicle_asks_again_for_an_item_and_flags_an_out_of_sequence_one():
    up = MissionUpload(items(3), VEHICLE, pipeline=1)
    up.start(0.0)
    up.on_message(request(0), 0.0)
    up.on_message(request(1), 0.1)
    # A duplicate of the request, soon after: the item is on its way, not sent twice ...
    assert up.on_message(request(1), 0.15) == []
    # ... but ArduPilot re-requests an item it did not get, a second later: sent again ...
    (again,) = up.on_message(request(1), 1.1)
    assert again.seq == 1
    # ... and answers an item it did not ask for with INVALID_SEQUENCE, going on.
    up.on_message(ack(mc.MAV_MISSION_INVALID_SEQUENCE), 1.2)
    assert up.outcome is Outcome.RUNNING
    up.on_message(request(2), 1.3)
    up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 1.4)
    assert up.outcome is Outcome.DONE


def test_timeout_then_retry_then_success():
    up = MissionUpload(items(2), VEHICLE, pipeline=1)
    up.start(0.0)
    assert up.on_tick(1.0) == []  # not yet 1.5 s
    (resent,) = up.on_tick(1.6)  # no request came: resend the count
    assert resent.get_type() == "MISSION_COUNT"
    up.on_message(request(0), 1.7)
    # Item 0 (or the request for item 1) lost on the way: resend it, and item 1 with it.
    item, following = up.on_tick(3.3)
    assert (item.get_type(), item.seq, following.seq) == ("MISSION_ITEM_INT", 0, 1)
    up.on_message(request(1), 3.4)
    up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 3.5)
    assert up.outcome is Outcome.DONE and up.stats.retries == 2


def test_gives_up_after_its_retries():
    up = MissionUpload(items(2), VEHICLE)
    up.start(0.0)
    now, sent = 0.0, 0
    while up.outcome is Outcome.RUNNING:
        now += 1.6
        sent += len(up.on_tick(now))
    assert sent == TRANSFER_RETRIES and up.outcome is Outcome.FAILED
    assert f"after {TRANSFER_RETRIES} retries" in up.reason


def test_a_refusal_is_asked_again_from_the_count_and_named_when_it_never_goes_through():
    up = MissionUpload(items(2), VEHICLE)
    up.start(0.0)
    assert up.on_message(ack(mc.MAV_MISSION_NO_SPACE), 0.1) == []
    assert up.outcome is Outcome.RUNNING and up.stats.stray == 1
    (again,) = up.on_tick(1.7)
    assert again.get_type() == "MISSION_COUNT"  # the transfer starts over
    now = 1.7
    while up.outcome is Outcome.RUNNING:
        now += 1.6
        up.on_message(ack(mc.MAV_MISSION_NO_SPACE), now)
        up.on_tick(now + 1.6)
    assert "refused the mission: MAV_MISSION_NO_SPACE" in up.reason


def test_stray_frames_are_counted_and_ignored():
    up = MissionUpload(items(3), VEHICLE, pipeline=1)
    up.start(0.0)
    assert up.on_message(request(7), 0.05) == []  # no such item
    up.on_message(request(0), 0.1)
    assert up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 0.15) == []  # early: not all sent
    up.on_message(request(1), 0.2)
    # A late duplicate soon after: item 0 is not sent again (a vehicle that started over
    # and asks for it a timeout later gets it then).
    assert up.on_message(request(0), 0.25) == []
    up.on_message(request(2), 0.3)
    up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 0.35)
    assert up.outcome is Outcome.DONE and up.stats.stray == 3


def test_the_timeout_follows_the_round_trip():
    """A transfer's timeout is the round trip and a margin (RFC 6298's four deviations,
    none on a steady link), not the command's 0.3 s at least: through 20 % loss an upload
    spent nearly all its time waiting for it."""
    up = MissionUpload(items(40), VEHICLE, pipeline=1)
    up.start(0.0)
    for k in range(40):
        up.on_message(request(k), 0.02 * (k + 1))  # 20 ms round trips
    assert up.timeout_s == pytest.approx(0.02 + TRANSFER_MIN_MARGIN_S)
    assert up.timeout_s < MIN_TIMEOUT_S


def test_start_sequence_sets_the_item_disarmed_then_arms_then_sets_auto_with_retries():
    seq = CommandSequence(start_mission_commands(), VEHICLE)
    (current,) = seq.start(0.0)
    # item 1 current, without the reset flag (param2 = 1 can lock ArduPilot's arming)
    assert current.command == mc.MAV_CMD_DO_SET_MISSION_CURRENT
    assert (current.param1, current.param2) == (1, 0)
    (again,) = seq.on_tick(1.6)
    assert again.confirmation == 1  # a resend counts up its confirmation
    accepted = mc.MAV_RESULT_ACCEPTED
    (arm,) = seq.on_message(command_ack(mc.MAV_CMD_DO_SET_MISSION_CURRENT, accepted), 1.7)
    assert arm.command == mc.MAV_CMD_COMPONENT_ARM_DISARM and arm.param1 == 1
    (mode,) = seq.on_message(command_ack(mc.MAV_CMD_COMPONENT_ARM_DISARM, accepted), 1.8)
    assert mode.command == mc.MAV_CMD_DO_SET_MODE and mode.param2 == 10  # Rover AUTO
    seq.on_message(command_ack(mc.MAV_CMD_DO_SET_MODE, accepted), 1.9)
    assert seq.outcome is Outcome.DONE


def test_refused_command_fails():
    seq = CommandSequence([Command(mc.MAV_CMD_MISSION_START)], VEHICLE)
    seq.start(0.0)
    seq.on_message(command_ack(mc.MAV_CMD_MISSION_START, mc.MAV_RESULT_DENIED), 0.1)
    assert seq.outcome is Outcome.FAILED and "refused" in seq.reason


@pytest.mark.parametrize("result", ["MAV_RESULT_FAILED", "MAV_RESULT_DENIED"])
def test_a_refused_optional_command_is_noted_and_passed_over(result):
    """The implement set at a start (an output ArduPilot refuses when given another
    function, a relay not set up): the start goes on, the refusal noted."""
    servo = Command(mc.MAV_CMD_DO_SET_SERVO, (9.0, 1100.0), optional=True)
    seq = CommandSequence(start_mission_commands(5, implement=servo), VEHICLE, refusal_window_s=60)
    seq.start(0.0)
    accepted = mc.MAV_RESULT_ACCEPTED
    (servo_sent,) = seq.on_message(command_ack(mc.MAV_CMD_DO_SET_MISSION_CURRENT, accepted), 0.1)
    assert (servo_sent.command, servo_sent.param1, servo_sent.param2) == (183, 9.0, 1100.0)
    refused = command_ack(mc.MAV_CMD_DO_SET_SERVO, getattr(mc, result))
    (arm,) = seq.on_message(refused, 0.2)
    assert arm.command == mc.MAV_CMD_COMPONENT_ARM_DISARM
    assert seq.skipped == [f"MAV_CMD_DO_SET_SERVO refused: {result}"]
    seq.on_message(command_ack(mc.MAV_CMD_COMPONENT_ARM_DISARM, accepted), 0.3)
    seq.on_message(command_ack(mc.MAV_CMD_DO_SET_MODE, accepted), 0.4)
    assert seq.outcome is Outcome.DONE


def test_a_refused_arm_is_asked_again_within_the_window():
    seq = CommandSequence(start_mission_commands(), VEHICLE, refusal_window_s=60.0)
    seq.start(0.0)
    seq.on_message(command_ack(mc.MAV_CMD_DO_SET_MISSION_CURRENT, mc.MAV_RESULT_ACCEPTED), 0.05)
    refused = command_ack(mc.MAV_CMD_COMPONENT_ARM_DISARM, mc.MAV_RESULT_FAILED)
    assert seq.on_message(refused, 0.1) == []  # pre-arm checks not passed yet
    assert seq.outcome is Outcome.RUNNING
    assert seq.last_refusal == "MAV_CMD_COMPONENT_ARM_DISARM refused: MAV_RESULT_FAILED"
    assert seq.on_tick(1.0) == []  # still pausing
    (again,) = seq.on_tick(2.2)
    assert again.command == mc.MAV_CMD_COMPONENT_ARM_DISARM
    seq.on_message(refused, 30.0)
    seq.on_message(refused, 61.0)  # refused for longer than the window: give up
    assert seq.outcome is Outcome.FAILED and "MAV_RESULT_FAILED" in seq.reason


def seqs(msgs):
    return [m.seq for m in msgs]


def asked_in_turn(up, *times):
    """The vehicle asks for items 0, 1, ... at ``times``."""
    for k, t in enumerate(times):
        up.on_message(request(k), t)


def test_a_pipelined_upload_sends_a_window_ahead_and_each_item_once():
    up = MissionUpload(items(20), VEHICLE, pipeline=8)
    up.start(0.0)
    sent = seqs(up.on_message(request(0), 0.01))
    assert sent == list(range(8))  # the window goes out at the first request
    for k in range(1, 20):  # ArduPilot asks for each next one as it takes an item
        new = seqs(up.on_message(request(k), 0.01 + 0.001 * k))
        assert new == ([k + 7] if k + 7 < 20 else []), k
        sent += new
    assert sorted(sent) == list(range(20))  # each item once
    up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 0.05)
    assert up.outcome is Outcome.DONE and up.stats.retries == 0 and not up.unconfirmed


def test_a_lost_item_goes_again_at_the_first_refusal_then_the_refused_ones_as_asked():
    up = MissionUpload(items(20), VEHICLE, pipeline=8)
    up.start(0.0)
    asked_in_turn(up, 0.1, 0.2, 0.3)  # items 0..9 sent, round trips of 0.1 s
    # Item 2 was lost: the vehicle asked for it (it was sent after item 1: on its way, not
    # sent again) and refuses items 3.. as they come.
    assert seqs(up.on_message(request(2), 0.31)) == []
    assert seqs(up.on_message(ack(mc.MAV_MISSION_INVALID_SEQUENCE), 0.35)) == [2]
    assert seqs(up.on_message(ack(mc.MAV_MISSION_INVALID_SEQUENCE), 0.36)) == []  # once
    # Item 3 went before the resent item 2 and was refused: asked for, it goes again.
    assert 3 in seqs(up.on_message(request(3), 0.45))
    assert up.stats.retries == 1 and up.outcome is Outcome.RUNNING


def test_silence_sends_the_window_again_from_the_item_asked_for_last():
    up = MissionUpload(items(20), VEHICLE, pipeline=8)
    up.start(0.0)
    up.on_message(request(0), 0.1)
    up.on_message(request(1), 0.2)  # then nothing: item 1 or 2, or the requests, lost
    assert up.on_tick(0.2 + up.timeout_s - 0.01) == []
    again = seqs(up.on_tick(0.2 + up.timeout_s))
    # From the one asked for, a whole pipeline however small the window has become: the
    # vehicle may hold several of them, their requests lost.
    assert again == list(range(1, 9))
    assert up.stats.retries == 1


def test_an_accepted_ack_before_the_last_item_is_asked_for_is_stale():
    up = MissionUpload(items(10), VEHICLE, pipeline=8)
    up.start(0.0)
    asked_in_turn(up, 0.1, 0.2, 0.3)  # every item sent, the vehicle holds 0..1
    up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 0.35)  # of an earlier upload
    assert up.outcome is Outcome.RUNNING and up.stats.stray == 1


def test_an_accepted_ack_after_a_lost_request_for_the_last_item_ends_the_upload():
    up = MissionUpload(items(10), VEHICLE, pipeline=8)
    up.start(0.0)
    asked_in_turn(up, *(0.1 * k for k in range(1, 10)))  # requests 0..8; 9's is lost
    up.on_message(ack(mc.MAV_MISSION_ACCEPTED), 1.0)
    assert up.outcome is Outcome.DONE and up.unconfirmed  # the daemon reads it back


def test_a_vehicle_that_starts_over_is_followed_from_where_it_asks():
    # A duplicated MISSION_COUNT came late: ArduPilot starts the transfer again from item 0.
    up = MissionUpload(items(12), VEHICLE, pipeline=4)
    up.start(0.0)
    asked_in_turn(up, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)  # items 0..8 sent
    # Long after: the window from there again (sent a timeout ago), then on as asked.
    assert seqs(up.on_message(request(0), 2.0)) == [0, 1, 2, 3]
    assert seqs(up.on_message(request(1), 2.1)) == [4]
    again = up.on_tick(2.1 + up.timeout_s)  # nothing more came: from item 1, not item 5
    assert seqs(again)[0] == 1 and up.outcome is Outcome.RUNNING


def test_a_lost_final_ack_then_mission_error_to_the_last_item_sent_again_is_done_unconfirmed():
    up = MissionUpload(items(3), VEHICLE, pipeline=8)
    up.start(0.0)
    asked_in_turn(up, 0.1, 0.11, 0.12)  # the ACCEPTED after item 2 is lost
    assert seqs(up.on_tick(0.12 + up.timeout_s)) == [2]
    # ArduPilot, no longer receiving, answers an item with MAV_MISSION_ERROR.
    up.on_message(ack(mc.MAV_MISSION_ERROR), 0.2 + up.timeout_s)
    assert up.outcome is Outcome.DONE and up.unconfirmed


def test_a_pipelined_read_back_asks_for_a_window_takes_items_in_any_order_and_asks_again():
    from dispatcher.link.mission_protocol import MissionDownload

    down = MissionDownload(VEHICLE, first=2, pipeline=4)
    (ask,) = down.start(0.0)
    assert ask.get_type() == "MISSION_REQUEST_LIST"
    count = mc.message(
        "MISSION_COUNT", target_system=255, target_component=190, count=9, mission_type=0
    )
    assert seqs(down.on_message(wire(count), 0.1)) == [2, 3, 4, 5]
    held = items(9)
    assert seqs(down.on_message(wire(held[4]), 0.2)) == [6]  # out of order: taken
    assert down.on_message(wire(held[4]), 0.21) == []  # twice: stray
    for k in (2, 5, 6):
        down.on_message(wire(held[k]), 0.3)
    # Item 3 was lost (7 and 8 asked for meanwhile): asked again at the timeout.
    assert 3 in seqs(down.on_tick(0.3 + down.timeout_s))
    for k in (7, 8):
        down.on_message(wire(held[k]), 0.9)
    (end,) = down.on_message(wire(held[3]), 1.0)
    assert end.get_type() == "MISSION_ACK" and down.outcome is Outcome.DONE
    assert seqs(down.items) == list(range(2, 9)) and down.stats.stray == 1
