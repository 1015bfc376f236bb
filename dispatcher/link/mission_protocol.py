"""The ground-station side of the MAVLink mission and command protocols, without I/O.

Each machine here is fed the vehicle's messages (``on_message``) and the clock
(``on_tick``) and answers with the messages to send; the daemon does the sending. That
keeps the protocol testable against recorded exchanges and a simulated vehicle alike.

Mission upload (https://mavlink.io/en/services/mission.html): MISSION_COUNT, then the
vehicle pulls each item with MISSION_REQUEST_INT(seq) and ends with MISSION_ACK. Download,
the other way round: MISSION_REQUEST_LIST, the vehicle's MISSION_COUNT, then each item asked
for with MISSION_REQUEST_INT, and our MISSION_ACK. Timeouts follow the protocol: 1.5 s
without an answer resends the last message, at most 5 times.

Only the addressed vehicle's frames count: a frame from another system or component (another
vehicle or ground station on the same radio, a companion computer) takes no step, and one of
the protocol is counted as stray. (A message built in memory, with no sender, is taken.)
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from dispatcher.link import mavlink as mc

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 1.5
"""The protocol's timeout for an answer; shortened to a few round trips once they are
measured (never under MIN_TIMEOUT_S), so a lossy link resends soon."""
MIN_TIMEOUT_S = 0.3
TRANSFER_MIN_TIMEOUT_S = 0.05
"""A mission transfer's timeout is never shorter (the daemon's loop wakes every 50 ms)."""
TRANSFER_MIN_MARGIN_S = 0.04
"""Nor closer to the smoothed round trip than this, however steady the link."""
MAX_RETRIES = 8
"""Resends of one command without an answer before it fails (with 30 % of the frames lost
each way, 0.51^9 ≈ 0.2 % of the commands)."""
TRANSFER_RETRIES = 12
"""The same for one step of a mission upload or download: each item is a round trip of its
own, and with 30 % of the frames lost each way about half of them fail (0.51^13 ≈ 1e-4)."""
TRANSFER_PIPELINE = 8
"""Mission items in flight on a clean link: sent ahead of the vehicle's requests by an upload
(:class:`MissionUpload`), asked for at once by a read-back (:class:`MissionDownload`)."""
LOST_LAST_REQUESTS = 2
"""An upload's ACCEPTED counts when the vehicle asked for one of its last items this many
items or less before the end (its requests for the ones after lost); one before that is
taken for a late answer to an earlier upload."""
TRANSFER_STALL_S = 10.0
"""A transfer also needs this long without progress before it fails (its retries may come
faster than the vehicle's own one-second re-requests; ArduPilot gives up after 8 s)."""
BACKOFF_AFTER = 3
"""An upload's timeouts in a row without progress before each waits twice the one before
(from the first, it slowed every lossy radio by 7-10 %; from the fourth, 0-2.5 % over 160
seeds of the worst radio, and a vehicle stopped 1-3 s got 9 items twice for 49). An item
sent longer ago than the timeout so stretched counts as lost (_lost)."""
LONG_SAMPLES_TAKEN = 3
"""Round trips of a re-request's length in a row, with none shorter between, that are taken
for the link's (see MissionUpload._sample)."""
VEHICLE_RE_REQUEST_S = 1.0
"""A vehicle receiving a mission asks again for the item it expects after this long without
one (ArduPilot's ``MissionItemProtocol::update``: 1 000 ms plus the link's stream slowdown)."""
REFUSAL_BACKOFF_S = 2.0  # pause before asking again after a refused command
START_REFUSAL_WINDOW_S = 60.0  # how long a vehicle may refuse to arm before it is failed

# ArduPilot Rover flight modes (Rover/mode.h).
ROVER_MODE_MANUAL = 0
ROVER_MODE_HOLD = 4
ROVER_MODE_AUTO = 10
ROVER_MODE_RTL = 11


class Outcome(enum.Enum):
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"


@dataclass
class Stats:
    attempts: int = 1  # times the whole exchange was (re)started
    retries: int = 0  # messages resent after a timeout
    stray: int = 0  # frames of the protocol that fit no step (late, duplicated, stale): ignored


@dataclass
class RoundTrip:
    """A link's smoothed round trip and its mean deviation, in seconds (RFC 6298): the
    exchanges over one link share it, so a transfer starts with what the last one
    measured (on a lossy link most items go twice, and Karn's rule leaves one transfer
    few samples of its own)."""

    srtt: float | None = None
    rttvar: float = 0.0

    def sample(self, round_trip: float) -> None:
        sample = max(round_trip, 0.0)
        if self.srtt is None:
            self.srtt, self.rttvar = sample, sample / 2.0
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - sample)
            self.srtt = 0.875 * self.srtt + 0.125 * sample


class _Exchange:
    """What every exchange with one vehicle has: its address, timeouts and outcome."""

    def __init__(
        self,
        target_system: int,
        target_component: int = mc.MAV_COMP_ID_AUTOPILOT1,
        timeout_s: float = REQUEST_TIMEOUT_S,
        max_retries: int = MAX_RETRIES,
        round_trip: RoundTrip | None = None,
    ) -> None:
        self.target_system = target_system
        self.target_component = target_component
        self.timeout_s = timeout_s
        self.max_retries = max_retries
        self.outcome = Outcome.RUNNING
        self.reason = ""
        self.stats = Stats()
        self._base_timeout_s = timeout_s
        self.round_trip = round_trip if round_trip is not None else RoundTrip()
        self._adapt_timeout()
        self._sent_at = 0.0
        self._resent = False  # the last message went out more than once

    def _foreign(self, msg: mc.MAVLinkMessage) -> bool:
        """Whether ``msg`` was sent by another system or component than the one this
        exchange is with (sender 0/0: a message not received in a frame, taken)."""
        system, component = msg.get_srcSystem(), msg.get_srcComponent()
        if system == 0 and component == 0:
            return False
        if system != self.target_system:
            return True
        return self.target_component != 0 and component != self.target_component

    def _fail(self, reason: str) -> list[mc.MAVLinkMessage]:
        self.outcome = Outcome.FAILED
        self.reason = reason
        return []

    def _answered(self, now: float) -> None:
        """An answer to what was last sent: measure the round trip (not of a message sent
        again: the answer may be to either copy, Karn's rule) and adapt the timeout."""
        if self._resent:
            return
        self._sample(now - self._sent_at)

    def _sample(self, round_trip: float) -> None:
        """A round trip measured on a message sent once (Karn's rule): the timeout adapts."""
        self.round_trip.sample(round_trip)
        self._adapt_timeout()

    def _adapt_timeout(self) -> None:
        rt = self.round_trip
        if rt.srtt is not None:
            self.timeout_s = min(self._base_timeout_s, self._timeout_for(rt.srtt, rt.rttvar))

    def _timeout_for(self, srtt: float, rttvar: float) -> float:
        return max(MIN_TIMEOUT_S, 2.0 * srtt + 0.2)


class _Transfer(_Exchange):
    """A mission upload or download: one step at a time, the last message resent at each
    timeout; it fails only after its retries *and* TRANSFER_STALL_S without progress."""

    def __init__(
        self, target_system: int, round_trip: RoundTrip | None = None, **kw: float
    ) -> None:
        kw.setdefault("max_retries", TRANSFER_RETRIES)
        super().__init__(target_system, round_trip=round_trip, **kw)  # type: ignore[arg-type]
        self._progress_at = 0.0
        self._last: mc.MAVLinkMessage | None = None
        self._deadline = 0.0
        self._retries_left = self.max_retries

    def _timeout_for(self, srtt: float, rttvar: float) -> float:
        """A transfer's step is resent sooner than a command: a round trip and four of its
        deviations (RFC 6298's RTO), not under TRANSFER_MIN_TIMEOUT_S. A resent item
        costs a frame the vehicle refuses; a wait too long costs the transfer its time
        (through 20 % loss, an upload of 200 items took 20 s with the command's timeout,
        almost all of it spent waiting)."""
        return max(TRANSFER_MIN_TIMEOUT_S, srtt + max(4.0 * rttvar, TRANSFER_MIN_MARGIN_S))

    def _progress(self, now: float) -> None:
        """A step went through: its retries start again."""
        self._retries_left = self.max_retries
        self._progress_at = now

    def _due(self, now: float) -> bool:
        """A resend is due now."""
        return self.outcome is Outcome.RUNNING and self._last is not None and now >= self._deadline

    def _given_up(self, now: float) -> bool:
        return self._retries_left <= 0 and now - self._progress_at >= TRANSFER_STALL_S

    def _send(
        self, msg: mc.MAVLinkMessage, now: float, again: bool = False
    ) -> list[mc.MAVLinkMessage]:
        """Send ``msg`` (``again``: a resend, one retry spent) and time its answer."""
        if again:
            self._retries_left -= 1
            self.stats.retries += 1
        self._resent = again
        self._last = msg
        self._sent_at = now
        self._deadline = now + self.timeout_s
        return [msg]


class _GoBack(NamedTuple):
    """Items ``first`` to ``end`` - 1 sent again at a timeout (or more than one timeout in a
    row): ``copies`` of them the vehicle may have had, and will refuse."""

    first: int
    end: int
    copies: int


class MissionUpload(_Transfer):
    """Upload ``items`` (MISSION_ITEM_INT messages, seq 0..n-1) to one vehicle.

    The items go out ``pipeline`` at a time ahead of the vehicle's requests, a sliding
    window: ArduPilot takes the item it expects whether it asked for it or not and answers
    MAV_MISSION_INVALID_SEQUENCE to any other (``MissionItemProtocol::handle_mission_item``),
    so a window costs one round trip, not one per item, and a mission of hundreds of items
    goes up in a fraction of the time over a busy link. A request for item k says the
    vehicle holds every item before k, and refused every item of the window sent before
    the one it took last: a request sends those again with the new ones (go-back-N from
    the request). When the vehicle stops asking (an item or its request lost), the
    timeout sends a pipeline of items again from the item it asked for last and halves the
    window; each item taken in order grows it back (one more per window's worth), so a
    radio that reorders frames works near one item per round trip, as the protocol was
    written, and a clean link at the full window. The first INVALID_SEQUENCE after a
    request also resends the requested item, once, without waiting for the timeout (TCP's
    fast retransmit). ``pipeline=1``: one item per request.
    """

    def __init__(
        self,
        items: Sequence[mc.MAVLinkMessage],
        target_system: int,
        pipeline: int = TRANSFER_PIPELINE,
        round_trip: RoundTrip | None = None,
        **kw: float,
    ) -> None:
        super().__init__(target_system, round_trip, **kw)
        self.items = list(items)
        self.last_refusal = ""
        self.pipeline = max(1, int(pipeline))
        self.unconfirmed = False  # done on the vehicle's word that it is no longer receiving
        self._long_samples = 0  # round trips of a re-request's length in a row, not taken
        # The timeout's factor, doubled past BACKOFF_AFTER in a row. Progress does not take
        # it back to 1 (the next timeout does): after a stall the vehicle works through the
        # copies the stall's timeouts sent, and the items sent meanwhile, judged lost after
        # one timeout again, went a third time (tests/test_mission_protocol_pair.py, a
        # one-second stall: 55 retries instead of at most 8).
        self._backoff = 1.0
        self._restart()

    def _restart(self) -> None:
        """Back to the count: nothing asked for yet."""
        self._window = float(self.pipeline)  # items sent ahead of the request
        self._highest = -1  # the item asked for last: the vehicle holds those before it
        self._asked_last = False  # the vehicle has asked for the last item
        self._next = 0  # the first item not yet sent since the last go-back
        self._item_at: dict[int, float] = {}  # when each item was last sent
        self._order: dict[int, int] = {}  # and in which place (items of one tick share a time)
        self._sends = 0
        self._sent_twice: set[int] = set()  # (no round trip is measured on those)
        self._fast_for = -1  # the request whose item was resent on an INVALID_SEQUENCE
        self._refused_at = -1  # the place of the last send when an item was last refused
        self._refused_since_progress = False  # an item refused since the last progress
        self._go_back: _GoBack | None = None  # a timeout's copies, their refusals to come

    @property
    def progress(self) -> float:
        return max(self._highest, 0) / max(len(self.items), 1)

    def start(self, now: float) -> list[mc.MAVLinkMessage]:
        self._progress(now)
        return self._send(self._count(), now)

    def _count(self) -> mc.MAVLinkMessage:
        return mc.message(
            "MISSION_COUNT",
            target_system=self.target_system,
            target_component=self.target_component,
            count=len(self.items),
            mission_type=mc.MAV_MISSION_TYPE_MISSION,
        )

    def on_message(self, msg: mc.MAVLinkMessage, now: float) -> list[mc.MAVLinkMessage]:
        if self.outcome is not Outcome.RUNNING:
            return []
        kind = msg.get_type()
        if getattr(msg, "mission_type", 0) != mc.MAV_MISSION_TYPE_MISSION:
            return []
        if self._foreign(msg):
            self.stats.stray += kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK")
            return []
        # On a lossy link frames come late, twice or from an earlier attempt: what fits no
        # step of this transfer is counted and ignored; only the timeouts end it.
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            return self._on_request(int(msg.seq), now)
        if kind == "MISSION_ACK":
            result = int(msg.type)
            n = len(self.items)
            if (
                result == mc.MAV_MISSION_ACCEPTED
                and n - 1 in self._item_at
                and self._highest >= n - 1 - LOST_LAST_REQUESTS
            ):
                # The vehicle asked for one of the last items and every item went out: its
                # ACCEPTED ends the transfer, also when its requests for the last ones were
                # lost (the items went in the pipeline). Before, such an upload began again
                # from the count, twice in a row in a 20 %-loss soak. Unconfirmed then (the
                # daemon reads the mission back).
                self.unconfirmed = not self._asked_last
                self.outcome = Outcome.DONE
                return []
            if result == mc.MAV_MISSION_ERROR and self._asked_last and n - 1 in self._sent_twice:
                # The last item sent again because no ACK came, and ArduPilot, done
                # receiving, answers an item with MAV_MISSION_ERROR: its ACCEPTED was what
                # was lost. Taken as done, unconfirmed (the daemon reads the mission back).
                self.unconfirmed = True
                self.outcome = Outcome.DONE
                return []
            self.stats.stray += 1
            if result == mc.MAV_MISSION_INVALID_SEQUENCE:
                if self._copy_refused():
                    return []
                # A loss, or what the count of copies did not foresee: it is spent.
                self._go_back = None
                self._refused_since_progress = True
                self._refused_at = self._sends
                return self._fast_retransmit(now)
            if result != mc.MAV_MISSION_ACCEPTED:
                # The vehicle gave up this transfer (or an earlier one): start it again
                # from the count at the next timeout, and say why if it never goes through.
                self.last_refusal = mc.constant_name("MAV_MISSION_", result)
                self._last = self._count()
                self._restart()
            return []
        return []

    def _on_request(self, seq: int, now: float) -> list[mc.MAVLinkMessage]:
        if not 0 <= seq < len(self.items):
            self.stats.stray += 1
            return []
        repeat = seq == self._highest
        out = []
        if seq < self._highest:
            # A late duplicate of an earlier request, or the vehicle started the transfer
            # again (a duplicated MISSION_COUNT): either way what it asks for now. Answered
            # from there: the items of the window not sent within a timeout go (a late
            # duplicate soon after costs an item or two that the vehicle refuses; a
            # restart followed from the last item asked for would never go on).
            self.stats.stray += 1
            self._highest = seq
            self._progress(now)
            self._deadline = now + self.timeout_s
        elif seq > self._highest:  # the vehicle took every item before ``seq``
            before = seq - 1
            if before in self._item_at and (
                before not in self._sent_twice or self.round_trip.srtt is None
            ):
                # Karn's rule, but for the first sample: on a link that reorders, most
                # items go twice, and a transfer without a sample waits the protocol's
                # 1.5 s at every loss (the latest copy's round trip, too short if the
                # answer was to the first, is corrected by the samples that follow).
                self._sample(now - self._item_at[before])
            elif self._highest < 0:
                self._answered(now)  # the MISSION_COUNT's round trip
            if self._go_back is not None and seq > self._go_back.end:
                self._go_back = None  # the copies' refusals came before: they went before
            self._highest = seq
            self._refused_since_progress = False
            self._asked_last = self._asked_last or seq == len(self.items) - 1
            self._progress(now)
            self._window = min(float(self.pipeline), self._window + 1.0 / self._window)
            self._deadline = now + self.timeout_s
        last = min(len(self.items), seq + int(self._window))
        for k in range(seq, last):
            if k >= self._next or self._lost(k, now, seq):
                out.append(self._item(k, now))
        if repeat and not out:
            self.stats.stray += 1  # the last request again (a duplicate): its item is on its way
        return out

    def _copy_refused(self) -> bool:
        """Whether a refusal is of a copy a timeout sent again needlessly. Once the vehicle
        has asked for the end of the items the timeout sent again it held them all, and
        refuses each copy it gets twice: the refusals that come before it asks beyond
        (they went before the items sent since), as many as there were copies, tell of
        no loss. (Taken for losses, they had the items asked for next sent again, their
        originals on the way, whose copies were refused in turn: one timeout that a
        stall outlasted kept a copy going every few items to the end of a clean upload,
        63 resends a tractor at the demo's start.)"""
        go_back = self._go_back
        if go_back is None or self._highest < go_back.end:
            return False
        more = go_back.copies - 1
        self._go_back = go_back._replace(copies=more) if more > 0 else None
        return True

    def _sample(self, round_trip: float) -> None:
        """A request that comes a re-request's time after the item (or the count) it
        answers may be the vehicle's own re-request, its first request lost: not taken as
        a round trip unless the link has shown round trips of that size, or such come
        LONG_SAMPLES_TAKEN in a row (a link that slow is measured after all). (Taken, the
        count's 1.02 s with its first request lost set the timeout to the protocol's 1.5 s
        for the next dozens of items: one upload in ten through 20 % loss took 25 s
        instead of 2.5 s.)"""
        srtt = self.round_trip.srtt
        if round_trip >= 0.9 * VEHICLE_RE_REQUEST_S and (
            srtt is None or srtt < 0.3 * VEHICLE_RE_REQUEST_S
        ):
            # Taken when it comes again with no short one between: the link is that slow
            # (a lost request is seldom followed by another lost one just so).
            self._long_samples += 1
            if self._long_samples < LONG_SAMPLES_TAKEN:
                return
        else:
            self._long_samples = 0
        super()._sample(round_trip)

    def _lost(self, seq: int, now: float, asked: int) -> bool:
        """Whether item ``seq``, the vehicle asking for ``asked``, is to be sent (again):
        never sent; sent long enough ago to be lost; sent before the item the vehicle took
        last (then it came first and was refused, or was lost); or, the item asked for,
        refused items were reported since it went (it may be one: the link reorders)."""
        order = self._order.get(seq)
        if order is None or now - self._item_at[seq] >= self.timeout_s * self._backoff:
            return True
        if order < self._order.get(asked - 1, -1):
            return True
        return seq == asked and self._refused_at > order

    def _fast_retransmit(self, now: float) -> list[mc.MAVLinkMessage]:
        """The vehicle refused an item it did not expect: the one it asked for last may be
        lost. Sent again, once a request, if it went out half a round trip ago or more;
        the window halves, once a request (a loss or a reordering link: fewer ahead)."""
        seq = self._highest
        if seq < 0 or self._fast_for == seq:
            return []
        if now - self._item_at.get(seq, -math.inf) < 0.5 * (self.round_trip.srtt or 0.0):
            return []
        self._fast_for = seq
        self._window = max(1.0, self._window / 2.0)
        self.stats.retries += 1
        return [self._item(seq, now)]

    def _item(self, seq: int, now: float) -> mc.MAVLinkMessage:
        if seq in self._item_at:
            self._sent_twice.add(seq)
        self._item_at[seq] = now
        self._sends += 1
        self._order[seq] = self._sends
        self._next = max(self._next, seq + 1)
        return self.items[seq]

    def on_tick(self, now: float) -> list[mc.MAVLinkMessage]:
        if self.outcome is not Outcome.RUNNING or now < self._deadline:
            return []
        if self._given_up(now):
            if self.last_refusal:
                return self._fail(f"vehicle refused the mission: {self.last_refusal}")
            asked = "MISSION_COUNT" if self._highest < 0 else "MISSION_ITEM_INT"
            return self._fail(f"no answer to {asked} after {self.max_retries} retries")
        if self._highest < 0:
            log.debug("resending MISSION_COUNT to system %d", self.target_system)
            return self._send(self._count(), now, again=True)
        self._retries_left -= 1
        self.stats.retries += 1
        # Past BACKOFF_AFTER timeouts in a row without progress, each waits twice as long as
        # the one before (RFC 6298 5.5), up to the protocol's: a vehicle stopped for seconds
        # is not sent a pipeline every 50 ms, while a loss still costs a short timeout.
        in_row = self.max_retries - self._retries_left
        self._backoff = (
            min(2.0 * self._backoff, REQUEST_TIMEOUT_S / self.timeout_s)
            if in_row > BACKOFF_AFTER
            else 1.0
        )
        self._deadline = now + self.timeout_s * self._backoff
        self._window = max(1.0, self._window / 2.0)
        # Go back to the item asked for last, a whole pipeline of items however small the
        # window: the vehicle may hold several of them, their requests lost. (Two items
        # after the window had halved to one: a vehicle two ahead refused both at every
        # timeout, until its own re-request a second later.)
        self._next = first = self._highest
        last = min(len(self.items), first + max(2, self.pipeline, int(self._window)))
        if not self._refused_since_progress:
            # Nothing refused since the last request: the vehicle is silent, not missing
            # an item (then it refuses those after it). Its refusals of the copies to come
            # tell of no loss; a copy it takes (the item was lost after all) leaves one.
            copies = last - first
            if self._go_back is not None and self._go_back.first == first:
                copies += self._go_back.copies  # timed out again, no progress since
            self._go_back = _GoBack(first, last, copies)
        return [self._item(k, now) for k in range(first, last)]


_MISSION_FRAMES = frozenset(
    {
        "MISSION_COUNT",
        "MISSION_ITEM_INT",
        "MISSION_ITEM",
        "MISSION_REQUEST_INT",
        "MISSION_REQUEST",
        "MISSION_ACK",
    }
)
"""What a vehicle sends in the mission protocol (what else it sends is not stray)."""


class MissionDownload(_Transfer):
    """Read a vehicle's mission back: MISSION_REQUEST_LIST, its MISSION_COUNT, then each
    item from ``first`` on with MISSION_REQUEST_INT(seq) until all are in; MISSION_ACK ends
    it. ``items`` holds the MISSION_ITEM_INT messages (``first`` on) once the outcome is
    DONE. A ``first`` past the count reads none (the count says what is held).

    Up to ``pipeline`` requests are out at once: ArduPilot answers each on its own
    (``handle_mission_request_int``), so the items come in one round trip per window, in
    any order; each that comes in asks for the next one not yet asked for. When none comes
    for a timeout, the missing ones asked for are asked for again (selective repeat)."""

    def __init__(
        self,
        target_system: int,
        first: int = 0,
        pipeline: int = TRANSFER_PIPELINE,
        round_trip: RoundTrip | None = None,
        **kw: float,
    ) -> None:
        super().__init__(target_system, round_trip, **kw)
        self.first = first
        self.pipeline = max(1, int(pipeline))
        self.count: int | None = None
        self.items: list[mc.MAVLinkMessage] = []
        self._got: dict[int, mc.MAVLinkMessage] = {}
        self._asked_at: dict[int, float] = {}
        self._asked_twice: set[int] = set()
        self._next = first  # the first item not yet asked for

    def start(self, now: float) -> list[mc.MAVLinkMessage]:
        self._progress(now)
        ask = mc.message(
            "MISSION_REQUEST_LIST",
            target_system=self.target_system,
            target_component=self.target_component,
            mission_type=mc.MAV_MISSION_TYPE_MISSION,
        )
        return self._send(ask, now)

    def on_message(self, msg: mc.MAVLinkMessage, now: float) -> list[mc.MAVLinkMessage]:
        if self.outcome is not Outcome.RUNNING:
            return []
        if getattr(msg, "mission_type", 0) != mc.MAV_MISSION_TYPE_MISSION:
            return []
        kind = msg.get_type()
        if kind not in _MISSION_FRAMES:
            return []  # a HEARTBEAT, a position report: not of this protocol
        if self._foreign(msg):
            self.stats.stray += 1
            return []
        if kind == "MISSION_COUNT" and self.count is None:
            self._answered(now)
            self.count = int(msg.count)
            self._progress(now)
            self._deadline = now + self.timeout_s
            return self._ask(now, self.pipeline)
        if kind == "MISSION_ITEM_INT" and self.count is not None:
            seq = int(msg.seq)
            if seq not in self._asked_at or seq in self._got:
                self.stats.stray += 1  # a late answer to a request sent again
                return []
            if seq not in self._asked_twice:
                self._sample(now - self._asked_at[seq])
            self._got[seq] = msg
            self._progress(now)
            self._deadline = now + self.timeout_s
            return self._ask(now, 1)
        self.stats.stray += 1  # a second count, an ACK (an error: asked again at the timeout)
        return []

    def on_tick(self, now: float) -> list[mc.MAVLinkMessage]:
        if self.outcome is not Outcome.RUNNING or now < self._deadline:
            return []
        if self._given_up(now):
            asked = "MISSION_REQUEST_LIST" if self.count is None else "MISSION_REQUEST_INT"
            return self._fail(f"no answer to {asked} after {self.max_retries} retries")
        if self.count is None:
            return self._send(self._last, now, again=True) if self._last is not None else []
        self._retries_left -= 1
        self.stats.retries += 1
        self._deadline = now + self.timeout_s
        missing = [k for k in sorted(self._asked_at) if k not in self._got][: self.pipeline]
        for k in missing:
            self._asked_twice.add(k)
        return [self._request(k, now) for k in missing]

    def _ask(self, now: float, more: int) -> list[mc.MAVLinkMessage]:
        """Up to ``more`` requests for items not yet asked for; the final ACK when all are
        in."""
        assert self.count is not None
        if len(self._got) >= self.count - self.first:  # only items asked for are taken
            self.outcome = Outcome.DONE
            self.items = [self._got[k] for k in range(self.first, self.count)]
            ack = mc.message(
                "MISSION_ACK",
                target_system=self.target_system,
                target_component=self.target_component,
                type=mc.MAV_MISSION_ACCEPTED,
                mission_type=mc.MAV_MISSION_TYPE_MISSION,
            )
            return [ack]
        out = []
        while more > 0 and self._next < self.count:
            out.append(self._request(self._next, now))
            self._next += 1
            more -= 1
        return out

    def _request(self, seq: int, now: float) -> mc.MAVLinkMessage:
        self._asked_at[seq] = now
        return mc.message(
            "MISSION_REQUEST_INT",
            target_system=self.target_system,
            target_component=self.target_component,
            seq=seq,
            mission_type=mc.MAV_MISSION_TYPE_MISSION,
        )


def mission_differences(
    held: Sequence[mc.MAVLinkMessage],
    ours: Sequence[mc.MAVLinkMessage],
    limit: int = 3,
    first: int = 0,
    count: int | None = None,
) -> list[str]:
    """Where a mission read back from a vehicle is not ours (at most ``limit`` places; empty:
    the same). Item 0, home, is left out: the autopilot sets it itself. Compared: command,
    position, the parameters our items use (param1, param2: hold time, speed, channel and
    setting) as float32 carries them, and the frame of a navigation item (an integer frame
    and its float twin are one). Not what an autopilot stores in its own way: a DO item's
    frame (ArduPilot returns MAV_FRAME_GLOBAL for our MAV_FRAME_MISSION), param3, param4,
    altitude. ``held`` may be the items from ``first`` on of the ``count`` held (a
    :class:`MissionDownload` from ``first``), to be set against ``ours[first:]``."""
    out = []
    count = first + len(held) if count is None else count
    if count != len(ours):
        return [f"{count} items, not {len(ours)}"]
    if first + len(held) != count:
        return [f"items {first + len(held)}..{count - 1} not read"]
    skip = 1 if first == 0 else 0
    for a, b in zip(held[skip:], ours[first + skip :], strict=True):
        same = (
            a.command == b.command
            and (
                b.command > mc.MAV_CMD_NAV_LAST
                or mc.float_frame(a.frame) == mc.float_frame(b.frame)
            )
            and (a.x, a.y) == (b.x, b.y)
            and all(
                abs(getattr(a, p) - getattr(b, p)) <= 1e-4 * max(1.0, abs(getattr(b, p)))
                for p in ("param1", "param2")
            )
        )
        if not same:
            out.append(f"item {b.seq}")
            if len(out) == limit:
                break
    return out


@dataclass(frozen=True)
class Command:
    command: int
    params: tuple[float, ...] = ()
    optional: bool = False  # refused, it is noted (CommandSequence.skipped) and passed over


class CommandSequence(_Exchange):
    """Send COMMAND_LONGs one after another, each confirmed by its COMMAND_ACK; resend
    (``confirmation`` + 1) after a timeout."""

    def __init__(
        self,
        commands: Sequence[Command],
        target_system: int,
        refusal_window_s: float = 0.0,
        **kw: float,
    ) -> None:
        super().__init__(target_system, **kw)  # type: ignore[arg-type]
        self.commands = list(commands)
        self.refusal_window_s = refusal_window_s
        self._refused_since: float | None = None
        self.last_refusal = ""  # the latest refusal, while the command is asked again
        self._index = 0
        self._confirmation = 0
        self._deadline = 0.0
        self.unanswered = False  # failed for want of an answer (not refused)
        self.skipped: list[str] = []  # the refusals of optional commands, passed over

    def start(self, now: float) -> list[mc.MAVLinkMessage]:
        if not self.commands:  # nothing to send: done
            self.outcome = Outcome.DONE
            return []
        return [self._current(now)]

    def on_message(self, msg: mc.MAVLinkMessage, now: float) -> list[mc.MAVLinkMessage]:
        if self.outcome is not Outcome.RUNNING or msg.get_type() != "COMMAND_ACK":
            return []
        if self._foreign(msg) or int(msg.command) != self.commands[self._index].command:
            self.stats.stray += 1  # another's, or a late answer to an earlier command
            return []
        result = int(msg.result)
        if result == mc.MAV_RESULT_IN_PROGRESS:
            self._deadline = now + self.timeout_s
            return []
        name = mc.constant_name("MAV_CMD_", self.commands[self._index].command)
        refusal = f"{name} refused: {mc.constant_name('MAV_RESULT_', result)}"
        if result != mc.MAV_RESULT_ACCEPTED and self.commands[self._index].optional:
            self.skipped.append(refusal)
            result = mc.MAV_RESULT_ACCEPTED  # passed over: on to the next
        elif result in (mc.MAV_RESULT_TEMPORARILY_REJECTED, mc.MAV_RESULT_FAILED):
            # ArduPilot refuses to arm until its pre-arm checks pass (GPS fix, EKF ...):
            # ask again after a pause, for a while. Its STATUSTEXT says why (the daemon
            # keeps those with the vehicle's state).
            self._refused_since = self._refused_since if self._refused_since is not None else now
            self.last_refusal = refusal
            if now - self._refused_since < self.refusal_window_s:
                self._confirmation = 0
                self._deadline = now + REFUSAL_BACKOFF_S
                return []
        if result != mc.MAV_RESULT_ACCEPTED:
            return self._fail(refusal)
        self._index += 1
        self._confirmation = 0
        self._refused_since = None
        self.last_refusal = ""
        if self._index == len(self.commands):
            self.outcome = Outcome.DONE
            return []
        return [self._current(now)]

    def on_tick(self, now: float) -> list[mc.MAVLinkMessage]:
        if self.outcome is not Outcome.RUNNING or now < self._deadline:
            return []
        if self._confirmation >= self.max_retries:
            name = mc.constant_name("MAV_CMD_", self.commands[self._index].command)
            self.unanswered = True
            return self._fail(f"no COMMAND_ACK for {name} after {self.max_retries} retries")
        self._confirmation += 1
        self.stats.retries += 1
        return [self._current(now)]

    def _current(self, now: float) -> mc.MAVLinkMessage:
        cmd = self.commands[self._index]
        params = (list(cmd.params) + [0.0] * 7)[:7]
        self._deadline = now + self.timeout_s
        return mc.message(
            "COMMAND_LONG",
            target_system=self.target_system,
            target_component=self.target_component,
            command=cmd.command,
            confirmation=self._confirmation,
            param1=params[0],
            param2=params[1],
            param3=params[2],
            param4=params[3],
            param5=params[4],
            param6=params[5],
            param7=params[6],
        )


def start_mission_commands(
    first_item: int = 1,
    in_auto: bool = False,
    speed_ms: float | None = None,
    implement: Command | None = None,
) -> list[Command]:
    """How a ground station starts (or resumes) an ArduPilot Rover mission at
    ``first_item``: make it current while disarmed, (given ``implement``) set the implement
    as the mission has it there, arm, then switch to AUTO; then, given ``speed_ms``, set the
    speed the mission's DO_CHANGE_SPEED items set before that item.

    * The current item is set with ``DO_SET_MISSION_CURRENT`` param2 = 0, never 1 (reset):
      a reset sent while armed outside AUTO makes ArduPilot start the first navigation
      command outside AUTO and can leave a sticky internal error ("SCurve ... zero length
      path") that refuses every later ARM until a reboot. With the mission stopped,
      ``AP_Mission::set_current_cmd`` loads the item and AUTO resumes there
      (MIS_RESTART = 0, the default), also on a freshly uploaded mission and after a reboot.
    * A vehicle still in AUTO (a finished mission stays in AUTO with MIS_DONE_BEHAV = 0)
      is put in HOLD first: asking for AUTO while in AUTO changes nothing, so the mission
      would not resume at the new item.
    * Entering AUTO sets the speed to WP_SPEED (``ModeAuto::_enter``, ``wp_nav.init()``),
      and a mission resumed past its DO_CHANGE_SPEED items does not run them again: resumed
      in a field, the implement would work at road speed until the next one. So the speed
      in force at ``first_item`` is set once in AUTO (DO_CHANGE_SPEED param1 = 1 ground
      speed, param2 = m/s, param3 = -1 throttle unchanged).
    * Nor does it run the DO_SET_SERVO or DO_SET_RELAY that lowered the implement, and an
      autopilot that rebooted holds its outputs at their boot values: resumed in a field, the
      machine would drive on with the implement up, in a field without planned turns to the
      field's end, while the field counts as worked. So ``implement``, that item as a
      command (the same param1 output and param2 setting), goes before it sets off. It is
      optional: an autopilot may refuse an output it uses for something else, or a relay
      not set up (in the mission such an item does not stop it); the start goes on, the
      refusal noted.
    """
    commands = []
    if in_auto:
        commands.append(_set_mode(ROVER_MODE_HOLD))
    commands.append(Command(mc.MAV_CMD_DO_SET_MISSION_CURRENT, (float(first_item), 0.0)))
    if implement is not None:
        commands.append(implement)
    commands += [
        Command(mc.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,)),
        _set_mode(ROVER_MODE_AUTO),
    ]
    if speed_ms is not None:
        commands.append(Command(mc.MAV_CMD_DO_CHANGE_SPEED, (1.0, float(speed_ms), -1.0)))
    return commands


GCS_HEARTBEAT_PERIOD_S = 1.0
"""The dispatcher's HEARTBEAT to every vehicle, as a ground station: ArduPilot's GCS
failsafe (FS_GCS_ENABLE, after FS_GCS_TIMEOUT without one) can stay on."""


def gcs_heartbeat() -> mc.MAVLinkMessage:
    """The HEARTBEAT a ground station sends (MAV_TYPE_GCS, no autopilot)."""
    return mc.peer_heartbeat(mc.MAV_TYPE_GCS)


def set_current_command(item: int) -> Command:
    """Drive to ``item`` next (MAV_CMD_DO_SET_MISSION_CURRENT, without resetting)."""
    return Command(mc.MAV_CMD_DO_SET_MISSION_CURRENT, (float(item), 0.0))


def hold_commands() -> list[Command]:
    """Stop where it is: HOLD (armed; a tractor that was lost keeps its state)."""
    return [_set_mode(ROVER_MODE_HOLD)]


def park_commands() -> list[Command]:
    """What the dispatcher sends a vehicle whose mission is complete: HOLD, then disarm, so
    a tractor back in the garage is not left armed in AUTO."""
    return [_set_mode(ROVER_MODE_HOLD), Command(mc.MAV_CMD_COMPONENT_ARM_DISARM, (0.0,))]


def _set_mode(mode: int) -> Command:
    return Command(
        mc.MAV_CMD_DO_SET_MODE, (float(mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(mode))
    )
