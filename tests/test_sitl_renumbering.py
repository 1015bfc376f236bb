"""What renumbering a driving vehicle's mission relies on (dispatcher/link/numbering.py),
checked against the real autopilot: ArduPilot Rover SITL, spoken to directly with the
dispatcher's own mission upload and commands (no daemon, no bridge).

A rover drives a mission north: eleven waypoints 20 m apart, then three 150 m apart (the
first two of those 100 m east). While it drives to item 12 it is sent home and the items
from 12 on, numbered 1, 2, 3 (ArduPilot cuts its mission at the new count, 4: the index it
drives to is 8 past it, as ``choose_base`` asks). Then:

- sent on to item 1 (set current) as soon as the upload is acknowledged, it drives the new
  mission to its end, where the old one ended;
- not sent on, it drives item 12 from memory and stops there, its mission complete: what
  the daemon's ``_after_renumbering`` starts again after;
- renumbered so that the index it drives to is *inside* the new mission (home and the items
  from 3 on: 13 items), it drives at once to what is now at that index, the old item 14,
  and leaves out items 12 and 13: why ``choose_base`` never does that.

And what the daemon reads a wait at a window's end by: a rover whose mission is complete,
given a longer one (the same items and more after), still says complete at the same item,
with the longer mission's total (daemon/state.py, ``_progress_of_current``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.messages import waypoint
from helpers.sitl import ARDUROVER, HOME, PARAMS, Sitl, needs_ardurover

from dispatcher.daemon.plausibility import metres
from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import (
    CommandSequence,
    MissionUpload,
    Outcome,
    gcs_heartbeat,
    set_current_command,
    start_mission_commands,
)
from dispatcher.link.numbering import MARGIN

pytestmark = needs_ardurover
SPEEDUP = 20.0
NORTH_M = [20.0 * k for k in range(12)] + [370.0, 520.0, 670.0]  # item k's metres from home
EAST_M = [0.0] * 12 + [100.0, 100.0, 0.0]
DRIVING_TO = 12  # the item it drives to when it is renumbered
TIMEOUT_S = 120.0  # wall seconds for any one step
COMPLETE = mc.MISSION_STATE_COMPLETE


def north(k: int) -> tuple[float, float]:
    """The (lat, lon) of the mission's item k (0: home)."""
    east = EAST_M[k] / (111_195.0 * math.cos(math.radians(HOME[0])))
    return HOME[0] + NORTH_M[k] / 111_195.0, HOME[1] + east


def item(seq: int, k: int) -> mc.MAVLinkMessage:
    """The mission's item k as item ``seq`` (home in the absolute frame, as ArduPilot has it)."""
    lat, lon = north(k)
    frame = mc.MAV_FRAME_GLOBAL if seq == 0 else mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    return waypoint(seq, round(lat * 1e7), round(lon * 1e7), frame=frame)


class Rover:
    """The SITL rover over SERIAL0, as a ground station: a HEARTBEAT every second, the
    latest MISSION_CURRENT and position kept."""

    def __init__(self, sitl: Sitl) -> None:
        from pymavlink import mavutil

        self.link = mavutil.mavlink_connection(sitl.url, source_system=255, source_component=190)
        self.current: mc.MAVLinkMessage | None = None
        self.reached: list[int] = []  # MISSION_ITEM_REACHED seqs, in order
        self.lat = self.lon = math.nan
        self._beat = 0.0

    def pump(self, exchange: CommandSequence | MissionUpload | None = None) -> None:
        """Read what came (a little while), answer for ``exchange``, keep the heartbeat."""
        now = time.monotonic()
        if now - self._beat >= 1.0:
            self._beat = now
            self.link.mav.send(gcs_heartbeat())
        msg = self.link.recv_match(blocking=True, timeout=0.05)
        replies = [] if exchange is None else exchange.on_tick(now)
        if msg is not None:
            kind = msg.get_type()
            if kind == "MISSION_CURRENT":
                self.current = msg
            elif kind == "MISSION_ITEM_REACHED":
                self.reached.append(int(msg.seq))
            elif kind == "GLOBAL_POSITION_INT":
                self.lat, self.lon = msg.lat / 1e7, msg.lon / 1e7
            if exchange is not None:
                replies += exchange.on_message(msg, now)
        for reply in replies:
            self.link.mav.send(reply)

    def run(self, exchange: CommandSequence | MissionUpload) -> None:
        """Start ``exchange`` and answer for it until it is over; it must succeed."""
        for msg in exchange.start(time.monotonic()):
            self.link.mav.send(msg)
        deadline = time.monotonic() + TIMEOUT_S
        while exchange.outcome is Outcome.RUNNING and time.monotonic() < deadline:
            self.pump(exchange)
        assert exchange.outcome is Outcome.DONE, (exchange.outcome, exchange.reason)

    def pump_for(self, seconds: float) -> None:
        """Keep reading and beating for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.pump()

    def wait(self, what: str, condition) -> None:  # type: ignore[no-untyped-def]
        deadline = time.monotonic() + TIMEOUT_S
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}: {self.current}"
            self.pump()

    def metres_to(self, k: int) -> float:
        return metres((self.lat, self.lon), north(k))

    def state(self) -> tuple[int, int, int]:
        """MISSION_CURRENT's seq, total and mission_state."""
        c = self.current
        return (-1, -1, -1) if c is None else (c.seq, c.total, c.mission_state)


@pytest.fixture
def rover(tmp_path: Path) -> Iterator[Rover]:
    assert ARDUROVER is not None
    sitl = Sitl(ARDUROVER, tmp_path / "sitl", speedup=SPEEDUP, params=dict(PARAMS))
    sitl.start(wipe=True)
    r = Rover(sitl)
    try:
        mission = [item(k, k) for k in range(len(NORTH_M))]
        r.run(MissionUpload(mission, 1))
        r.run(CommandSequence(start_mission_commands(1), 1, refusal_window_s=TIMEOUT_S))
        r.wait(f"driving to item {DRIVING_TO}", lambda: r.state()[0] == DRIVING_TO)
        yield r
    finally:
        r.link.close()
        sitl.stop()


def renumbered(first: int) -> list[mc.MAVLinkMessage]:
    """Home, then the mission's items from ``first`` on, numbered 1, 2, ..."""
    rest = range(first, len(NORTH_M))
    return [item(0, 0)] + [item(seq, k) for seq, k in enumerate(rest, start=1)]


def test_renumbered_under_way_and_sent_on_it_drives_the_new_numbers(rover: Rover) -> None:
    mission = renumbered(DRIVING_TO)
    last = len(mission) - 1
    assert DRIVING_TO - len(mission) >= MARGIN
    rover.run(MissionUpload(mission, 1))
    rover.run(CommandSequence([set_current_command(1)], 1))
    rover.wait(
        "the new mission complete",
        lambda: rover.state() == (last, last, mc.MISSION_STATE_COMPLETE),
    )
    assert rover.metres_to(len(NORTH_M) - 1) < 10.0, rover.metres_to(len(NORTH_M) - 1)


def test_renumbered_under_way_and_not_sent_on_it_stops_at_its_item(rover: Rover) -> None:
    rover.run(MissionUpload(renumbered(DRIVING_TO), 1))
    # From memory to item DRIVING_TO, then its mission is complete: it stands there.
    rover.wait("its mission complete", lambda: rover.state()[2] == mc.MISSION_STATE_COMPLETE)
    rover.wait("stopped", lambda: rover.metres_to(DRIVING_TO) < 10.0)
    rover.pump_for(3.0)  # a minute of its own: it does not go on
    assert rover.metres_to(DRIVING_TO) < 10.0, rover.metres_to(DRIVING_TO)
    assert rover.state()[2] == mc.MISSION_STATE_COMPLETE, rover.state()


def test_renumbered_around_the_index_it_drives_to_it_leaves_items_out(rover: Rover) -> None:
    mission = renumbered(3)  # 13 items: index 12 is now the old item 14
    assert len(mission) > DRIVING_TO
    rover.run(MissionUpload(mission, 1))
    rover.reached.clear()
    closest = [math.inf, math.inf]  # to the old items 12 and 13 from now on

    def complete() -> bool:
        closest[:] = [min(closest[0], rover.metres_to(12)), min(closest[1], rover.metres_to(13))]
        return rover.state()[2] == mc.MISSION_STATE_COMPLETE

    rover.wait("the mission complete", complete)
    # Straight on to the old item 14 (index 12 now), the old items 12 and 13 left out.
    assert rover.metres_to(len(NORTH_M) - 1) < 10.0, rover.metres_to(len(NORTH_M) - 1)
    assert rover.reached == [DRIVING_TO], rover.reached
    assert min(closest) > 30.0, closest


def test_complete_and_given_a_longer_mission_it_says_so_at_the_same_item(rover: Rover) -> None:
    last = len(NORTH_M) - 1
    rover.wait("its mission complete", lambda: rover.state() == (last, last, COMPLETE))
    lat, lon = north(last)
    more = [
        waypoint(last + j, round((lat + 150.0 * j / 111_195.0) * 1e7), round(lon * 1e7))
        for j in (1, 2, 3)
    ]
    longer = [item(k, k) for k in range(len(NORTH_M))] + more
    rover.run(MissionUpload(longer, 1))
    total = len(longer) - 1
    rover.wait("the longer mission's total", lambda: rover.state()[1] == total)
    rover.pump_for(2.0)  # it stays where it is, complete
    assert rover.state() == (last, total, COMPLETE), rover.state()
    assert rover.metres_to(last) < 10.0, rover.metres_to(last)
