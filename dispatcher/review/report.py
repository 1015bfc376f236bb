"""What a run actually did, read back from its MCAP log and set against its plan.

:func:`review_log` reads one log (finished or cut short by a crash) and gives a
:class:`Review`: per vehicle the fields finished in order, the distance driven, the time
worked, driven and stood still, fuel by the paper's formula (5) on what was driven, the
mission upload and link figures, each beside the plan's value; per field who worked it
and when. :func:`review_table` prints it for people, :func:`review_json` for tools, and
``dispatcher.review.plot.plot_review`` draws it. How every number is computed is in
``docs/review.md``.

Clocks: a vehicle's times come from its own clock (``time_boot_ms`` of
GLOBAL_POSITION_INT and SYSTEM_TIME, simulated seconds for the simulator). Clocks of
different vehicles are not comparable (each counts from its own boot), so every time in a
review is measured from the moment that vehicle set off; the dispatcher starts all
missions together, so these per-vehicle clocks line up as one fleet timeline.
"""

from __future__ import annotations

import bisect
import dataclasses
import itertools
import json
import logging
import math
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
from pyproj import Geod

from dispatcher.daemon import events as ev
from dispatcher.daemon.state import JITTER_M, STILL_SPEED_MS, FleetState, RunClock, SetOff
from dispatcher.link import mavlink as mc
from dispatcher.mission.document import (
    PlanDocument,
    PlanDocumentError,
    PlannedField,
    PlannedItem,
    PlannedMachine,
)
from dispatcher.recording.mcap_file import (
    EVENTS_TOPIC,
    LogContents,
    LogRecord,
    RecordingError,
    read_log,
)
from dispatcher.review.track import TrackQuality, track_quality
from planner import formulas
from planner.geo import LocalFrame

__all__ = [
    "Activity",
    "FieldReview",
    "RecordingError",
    "Review",
    "VehicleReview",
    "Waypoint",
    "review_contents",
    "review_json",
    "review_log",
    "review_table",
]

logger = logging.getLogger(__name__)

WAYPOINT_MATCH_M: Final = 2.0
"""A position this close to a waypoint just reached is taken as the vehicle at it."""
HELD_IN_WORK_S: Final = 60.0
"""Standing still this long in a field's work window is a hold, not work; a shorter pause
(a turn, a hitch) is work."""
HEARTBEAT_GAP_S: Final = 5.0
"""Wall seconds without a heartbeat that count as link lost (the daemon's default)."""
RECORDING_GAP_S: Final = 1.0
"""Receive-time seconds between two positions (and five times their usual spacing) that
make a gap in the recording, as while the dispatcher was down: the vehicle's path across
it is its mission's, from the item it was heading to before to the one after."""
SLOWER_WARNING: Final = 0.10
"""Warn when a vehicle took this share longer than planned (or drove this much more)."""

MOVE_ROLES: Final = frozenset({"in_field", "turn"})
"""Waypoints of a move from one swath to the next (part of the turn, not a new leg)."""

_GEOD: Final = Geod(ellps="WGS84")
_VEHICLE_TOPIC: Final = re.compile(r"^agrifleet/([^/]+)/vehicle/([^/]+)/mavlink/(from|to)(/json)?$")
_FIX_TOPIC: Final = re.compile(r"^/vehicle/([^/]+)/fix$")
_CODEC: Final = mc.Codec(255, 190)  # only decodes (raw frames without a JSON twin)


# --- the result --------------------------------------------------------------------------


@dataclass(frozen=True)
class Waypoint:
    """A navigation item of a planned mission (home, road, transit, swath ends, in-field
    and turn points, return)."""

    seq: int
    field_id: str | None
    role: str
    lat: float
    lon: float


@dataclass(frozen=True)
class Activity:
    """What a vehicle did from ``start_s`` to ``end_s`` (seconds since it set off):
    ``work`` (implement down in ``field_id``), ``transit`` (moving, implement up) or
    ``stopped`` (standing, implement up)."""

    kind: str
    start_s: float
    end_s: float
    field_id: str | None = None


@dataclass(frozen=True)
class VehicleReview:
    """One vehicle: what it did and, beside it, what the plan said (``planned_*``).

    Times are seconds/hours since the vehicle set off; ``start_clock_s`` and
    ``end_clock_s`` are the vehicle's own clock at its start and end."""

    id: str
    phase: str  # done, running, lost, failed, not started ... (status doc, else derived)
    fields_planned: tuple[str, ...]
    fields_done: tuple[str, ...]  # in the order finished
    items_reached: int  # highest mission item reached (0: not started)
    items_total: int
    mission_complete: bool  # the last item (back at the garage) was reached
    start_clock_s: float | None
    end_clock_s: float | None
    distance_m: float
    work_m: float
    transit_m: float
    time_h: float
    working_h: float
    transit_h: float
    stopped_h: float
    turns: int
    turning_h: float  # of working_h, in turns (fuel at the road rate, formula 5)
    fuel_l: float | None  # None: the plan gives no fuel rates
    planned_distance_m: float  # the planned waypoint path, garage to garage
    planned_road_m: float  # plan.json's distance_m: road between fields only
    planned_time_h: float  # plan.json's time_h: formula (6)
    mission_time_h: float | None  # the mission's legs at its set speeds (None: unknown)
    planned_fuel_l: float
    planned_turns: int
    upload_attempts: int
    upload_retries: int
    upload_source: str  # "status", "frames" or "none": where the upload figures come from
    lost_s: float  # wall seconds the dispatcher counted the vehicle lost (status)
    heartbeat_gaps_s: float  # wall seconds in heartbeat gaps over HEARTBEAT_GAP_S
    error: str
    last_report_h: float | None  # the last thing heard, hours since it set off
    activities: tuple[Activity, ...]
    track: tuple[tuple[float, float, float], ...]  # (seconds since set off, lat, lon)
    planned_route: tuple[Waypoint, ...]
    reboots: tuple[float, ...] = ()  # seconds since set off when the autopilot rebooted
    autopilot_problems: tuple[str, ...] = ()  # its STATUSTEXT at WARNING or worse, once each
    quality: TrackQuality | None = None  # cross-track error, implement down outside, loops
    # Lost and re-planned around: reviewed against the last mission it was given.
    left_out: bool = False
    frames_refused: int = 0  # frames on its key not signed with its key, or replayed (status)
    foreign_commands: int = 0  # frames on its command key the dispatcher did not send

    @property
    def started(self) -> bool:
        return self.start_clock_s is not None


@dataclass(frozen=True)
class FieldReview:
    """One field of the plan: who was to work it, whether and when it was worked
    (seconds since that vehicle set off), and when the plan expected it."""

    id: str
    name: str
    area_m2: float
    polygon: tuple[tuple[float, float], ...]  # (lon, lat)
    holes: tuple[tuple[tuple[float, float], ...], ...]  # what inside it is not worked
    vehicle: str | None
    done: bool
    started_s: float | None
    finished_s: float | None
    started_by: str | None  # the vehicle that began it (another when handed over)
    started_clock_s: float | None  # on started_by's own clock
    finished_clock_s: float | None  # on the holder's (vehicle's) own clock
    planned_started_s: float | None
    planned_finished_s: float | None
    # The field's segments (swaths and headland ring edges, numbered as first laid out)
    # and, from the dispatcher's recorded events, those worked more than once or not at all.
    segments: int = 0
    worked_twice: tuple[int, ...] = ()
    never_worked: tuple[int, ...] = ()
    # Laid out anew by a re-plan for a machine of another width or turning radius: (who
    # began it, the segments of the old layout worked), each worked again in the new one.
    relaid: tuple[tuple[str, int], ...] = ()


@dataclass(frozen=True)
class Loss:
    """A vehicle the dispatcher gave up on: when (seconds into the log), why, and where it
    was last heard of (lat, lon; None when it never said)."""

    vehicle: str
    at_s: float
    why: str
    lat: float | None
    lon: float | None


@dataclass(frozen=True)
class Alarm:
    """Something the dispatcher did not trust (events.ALARMS): progress its track did not
    bear out, a command on a vehicle's key it did not send; when (seconds into the log)."""

    vehicle: str
    at_s: float
    kind: str
    text: str
    field: str | None = None  # progress doubted: the field it claimed


@dataclass(frozen=True)
class Replan:
    """The rest of the work planned again: when (seconds into the log), why, the new plan,
    and the fields that changed hands, as (field, from vehicle, to vehicle)."""

    at_s: float
    plan_id: str
    reason: str
    taken_over: tuple[tuple[str, str, str], ...]


@dataclass(frozen=True)
class Review:
    """A run read back from its log."""

    source: str
    farm_id: str
    plan_id: str | None
    plan_ids: tuple[str, ...]  # every plan id in the log, in order
    complete: bool  # False: the log was cut short (crash, kill, full disk) or damaged
    problem: str | None
    log_start_ns: int | None
    log_end_ns: int | None  # the last record read
    garage: tuple[float, float] | None  # (lat, lon)
    vehicles: tuple[VehicleReview, ...]
    fields: tuple[FieldReview, ...]
    planned_makespan_h: float | None
    warnings: tuple[str, ...]
    replans: tuple[Replan, ...] = ()
    losses: tuple[Loss, ...] = ()
    alarms: tuple[Alarm, ...] = ()

    @property
    def makespan_h(self) -> float:
        """Hours from setting off until the last vehicle was back (so far, if not all are);
        a vehicle a re-plan left out does not set it (its clock ran on while it stood where
        it failed: the makespan was credited to a stalled tractor; an outside review)."""
        longest = self.makespan_vehicle
        return longest.time_h if longest is not None else 0.0

    @property
    def makespan_vehicle(self) -> VehicleReview | None:
        """The vehicle that sets :attr:`makespan_h` (of those left out only if all are)."""
        kept = [v for v in self.vehicles if not v.left_out] or list(self.vehicles)
        return max(kept, key=lambda v: v.time_h, default=None)

    @property
    def makespan_final(self) -> bool:
        """Every vehicle with work planned finished its mission (vehicles lost and
        re-planned around aside)."""
        return all(v.mission_complete for v in self.vehicles if v.fields_planned and not v.left_out)

    @property
    def fields_done(self) -> int:
        return sum(f.done for f in self.fields)

    def vehicle(self, vehicle_id: str) -> VehicleReview:
        for v in self.vehicles:
            if v.id == vehicle_id:
                return v
        raise KeyError(vehicle_id)

    def field(self, field_id: str) -> FieldReview:
        for f in self.fields:
            if f.id == field_id:
                return f
        raise KeyError(field_id)


# --- the plan as recorded ----------------------------------------------------------------


@dataclass(frozen=True)
class _Plan:
    plan_id: str | None
    farm_id: str
    log_ns: int
    machines: tuple[PlannedMachine, ...]
    fields: Mapping[str, PlannedField]
    garage: tuple[float, float] | None
    makespan_h: float | None
    document: PlanDocument | None = None


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _parse_plan(doc: Any, log_ns: int) -> _Plan | None:
    """The plan document recorded at ``log_ns``; None if it cannot be read as one."""
    try:
        document = PlanDocument.from_json(doc)
    except PlanDocumentError as exc:
        logger.warning("a plan document in the log cannot be read: %s", exc)
        return None
    lat, lon = document.garage
    return _Plan(
        plan_id=document.plan_id or None,
        farm_id=document.farm_id,
        log_ns=log_ns,
        machines=document.machines,
        fields=document.fields,
        garage=(lat, lon) if math.isfinite(lat) and math.isfinite(lon) else None,
        makespan_h=document.makespan_h if document.machines else None,
        document=document,
    )


def _num(value: object) -> float | None:
    """``value`` as a float if it is a finite number, else None."""
    if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    return None


def _number(value: object) -> float:
    """``value`` as a float if it is a finite number, else 0."""
    number = _num(value)
    return 0.0 if number is None else number


# --- what the log holds, sorted per vehicle ----------------------------------------------


@dataclass
class _Traffic:
    """One vehicle's decoded frames and fixes, in file order, as (log ns, message)."""

    from_vehicle: list[tuple[int, dict[str, Any]]]
    to_vehicle: list[tuple[int, dict[str, Any]]]
    fixes: list[tuple[int, dict[str, Any]]]


def _decode(data: bytes) -> dict[str, Any] | None:
    try:
        doc = json.loads(data)
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


def _decode_record(rec: LogRecord) -> dict[str, Any] | None:
    """A message of any encoding (a fix is protobuf in newer logs, JSON in older ones)."""
    try:
        doc = rec.decode_json()
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


def _sort_traffic(log: LogContents) -> tuple[dict[str, _Traffic], list[tuple[int, Any]], list]:
    """Per vehicle its traffic; the plan documents and status documents (log ns, doc)."""
    json_seen: set[tuple[str, str]] = set()
    raw: dict[tuple[str, str], list[tuple[int, bytes]]] = {}
    traffic: dict[str, _Traffic] = {}
    plans: list[tuple[int, Any]] = []
    statuses: list[tuple[int, Any]] = []

    def of(vid: str) -> _Traffic:
        return traffic.setdefault(vid, _Traffic([], [], []))

    # The run's events, a stored copy among them where no log before held it.
    kept_events = {id(rec) for rec in _event_records(log)}

    for rec in log.records:
        topic = rec.topic
        match = _VEHICLE_TOPIC.match(topic)
        if match:
            _farm, vid, direction, is_json = match.groups()
            if not is_json:
                raw.setdefault((vid, direction), []).append((rec.log_time_ns, rec.data))
                continue
            json_seen.add((vid, direction))
            doc = _decode(rec.data)
            if doc is not None and isinstance(doc.get("mavpackettype"), str):
                t = of(vid)
                (t.from_vehicle if direction == "from" else t.to_vehicle).append(
                    (rec.log_time_ns, doc)
                )
            continue
        fix = _FIX_TOPIC.match(topic)
        if fix:
            doc = _decode_record(rec)
            if doc is not None:
                of(fix.group(1)).fixes.append((rec.log_time_ns, doc))
        elif topic == EVENTS_TOPIC:
            # Items the dispatcher caught up with after a restart (reached while it was
            # down): reports of the vehicle's, as its MISSION_CURRENT showed them. And the
            # items a crash's log lost (its last half second), from their stored copies in
            # the next log (a run killed as it ended was reviewed as unfinished).
            doc = _decode(rec.data)
            if (
                doc is not None
                and doc.get("kind") == ev.ItemReached.kind
                and isinstance(doc.get("vehicle"), str)
                and (
                    id(rec) in kept_events
                    if doc.get(ev.STORED)  # a copy, after a restart, of one seen before?
                    else doc.get("caught_up")
                )
            ):
                of(doc["vehicle"]).from_vehicle.append(
                    (
                        rec.log_time_ns,
                        {
                            "mavpackettype": "MISSION_ITEM_REACHED",
                            "seq": doc.get("seq"),
                            "caught_up": bool(doc.get("caught_up")),
                        },
                    )
                )
        elif topic.startswith("agrifleet/") and topic.endswith("/dispatcher/plan"):
            plans.append((rec.log_time_ns, _decode(rec.data)))
        elif topic.startswith("agrifleet/") and topic.endswith("/dispatcher/status"):
            statuses.append((rec.log_time_ns, _decode(rec.data)))
    # Raw frames whose JSON twin was not recorded: decode them here.
    for (vid, direction), frames in raw.items():
        if (vid, direction) in json_seen:
            continue
        t = of(vid)
        target = t.from_vehicle if direction == "from" else t.to_vehicle
        for log_ns, data in frames:
            msg = _CODEC.decode_one(data)
            if msg is not None:
                target.append((log_ns, mc.as_dict(msg)))
    return traffic, plans, statuses


# --- one vehicle -------------------------------------------------------------------------


@dataclass
class _Point:
    t: float  # vehicle clock, s
    order: int  # file position, to keep the order among equal times
    lat: float
    lon: float
    speed: float | None  # reported ground speed, m/s
    waypoint: bool = False
    log_ns: int | None = None  # when it was received (positions the vehicle reported)
    filled: bool = False  # a waypoint put into a gap of the recording (_across_gaps)


def _metres(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Geodesic distance between two (lat, lon)."""
    return float(_GEOD.inv(a[1], a[0], b[1], b[0])[2])


def _leg_lengths(lats: Sequence[float], lons: Sequence[float]) -> np.ndarray:
    if len(lats) < 2:
        return np.zeros(0)
    lat = np.asarray(lats, dtype=np.float64)
    lon = np.asarray(lons, dtype=np.float64)
    return np.asarray(_GEOD.inv(lon[:-1], lat[:-1], lon[1:], lat[1:])[2], dtype=np.float64)


@dataclass
class _Events:
    """What a vehicle's frames say, before any of it is set against time windows."""

    points: list[_Point]
    reached: list[tuple[int, float | None, int]]  # (seq, clock s, file position)
    heartbeats_ns: list[int]
    last_clock_s: float | None
    reboots: list[float]  # run clock (s) where the vehicle's clock started again
    texts: list[tuple[float | None, int, str]]  # STATUSTEXT: (run clock s, severity, text)
    # What the vehicle said of the item it drives to: (receive ns, file position, the item
    # it was heading to before the report, the item it heads to after it).
    heading_to: list[tuple[int, int, int, int]]
    caught_up: set[int]  # items the dispatcher caught up with after a restart (no position)
    # Items reached again after the vehicle was sent back (a start at the leg's start: the
    # dispatcher's Dispatcher._start_at): (seq, clock s). The DO items after each (and a DO
    # item itself: ArduPilot reports some, DO_CHANGE_SPEED, as reached) ran again then.
    again: list[tuple[int, float]] = field(default_factory=list)
    # When it drove back there with the implement up, after a reboot: from the reboot (its
    # outputs at their boot values) to its first item reached again (run clock s).
    up_spans: list[tuple[float, float]] = field(default_factory=list)


def _read_events(
    frames: Sequence[tuple[int, dict[str, Any]]],
    items: Sequence[PlannedItem],
    sent_to_item: Sequence[int] = (),
) -> _Events:
    """Positions, items reached with their time, heartbeats, from the vehicle's frames;
    ``sent_to_item``: when (receive ns, in order) the dispatcher told it the item to drive
    to (DO_SET_MISSION_CURRENT), after which its MISSION_CURRENT at or before the highest
    item reached says it was sent back.

    A navigation item's MISSION_ITEM_REACHED takes the time of the position that follows
    it when that position is at the waypoint (the simulator sends one right away), else
    the last time heard when it was reported (not when the next frame came: after a gap in
    the recording that is the clock after it); other items take the last time heard. The
    first reports after a gap in the recording come before any time is heard: those take
    the time carried on over the gap (``heard_at``). A report of the item reported last is
    a repeat, and left out.

    Frames are taken in the order they were received. The vehicle's clock
    (``time_boot_ms``) restarts from zero when its autopilot reboots: that is one reboot
    event, and the run's clock carries on from where it was, plus the receive-time gap
    scaled by how fast the vehicle's clock ran against the receive clock before.
    """
    points: list[_Point] = []
    reached: list[tuple[int, float | None, int]] = []
    heartbeats: list[int] = []
    texts: list[tuple[float | None, int, str]] = []
    reboots: list[float] = []
    clock = RunClock()  # the daemon's rule: the same run times live and in review
    # A nav item reached: (seq, file position, the clock when it was reported).
    pending: tuple[int, int, float | None] | None = None
    heading_to: list[tuple[int, int, int, int]] = []
    caught_up: set[int] = set()
    clock_ns: int | None = None  # when the vehicle's clock was last heard (receive ns)
    gap_ns = _recording_gap_ns(
        [ns for ns, m in frames if m.get("mavpackettype") == "GLOBAL_POSITION_INT"]
    )
    # From which entries of ``reached`` and ``again`` the times are heard_at's carried on
    # past a gap, to be bounded by the next clock.
    guessed_from: tuple[int, int] | None = None
    last_reached: int | None = None  # the item of the last MISSION_ITEM_REACHED
    highest, highest_ns, highest_t = 0, 0, -math.inf  # the highest item reached, and when
    # The item the vehicle was sent back to (its MISSION_CURRENT at or before the highest
    # reached), until it is past the highest again.
    sent_back: int | None = None
    again: list[tuple[int, float]] = []
    up_spans: list[tuple[float, float]] = []
    back_since: float | None = None  # found sent back then, not yet there again
    # Whether the vehicle holds the mission reviewed, as far as its MISSION_CURRENT.total
    # tells: the items it reports of another (before a re-plan gave it a new mission whole)
    # say nothing of where it heads in this one.
    this_mission = True

    def settle(at_waypoint: float | None = None) -> None:
        """The pending nav item reached: at ``at_waypoint`` (a position there), else when
        it was reported."""
        nonlocal pending
        if pending is not None:
            t = at_waypoint if at_waypoint is not None else pending[2]
            reached.append((pending[0], clock.now if t is None else t, pending[1]))
            pending = None

    def run_clock(raw: float, log_ns: int) -> float:
        """The vehicle's clock made continuous across reboots."""
        nonlocal clock_ns, pending, guessed_from
        before = clock.now
        t, rebooted = clock.update(raw, log_ns / 1e9)
        if rebooted and before is not None:
            reboots.append(before)
        clock_ns = log_ns
        now = clock.now if clock.now is not None else t
        # What heard_at carried on past a gap happened before this clock, not after.
        if guessed_from is not None:
            for i in range(guessed_from[0], len(reached)):
                seq, when, where = reached[i]
                reached[i] = (seq, None if when is None else min(when, now), where)
            for i in range(guessed_from[1], len(again)):
                again[i] = (again[i][0], min(again[i][1], now))
            guessed_from = None
        if pending is not None and pending[2] is not None and pending[2] > now:
            pending = (pending[0], pending[1], now)
        return t

    def heard_at(log_ns: int) -> float | None:
        """The vehicle's clock when a frame without one (an item reached, a text) came: the
        last time heard; or, the first thing after a gap in the recording (no clock heard for
        as long as _recording_gap_ns: the dispatcher was down, and what it heard first is
        fresh), that time carried on over the gap at the clock's rate; the items reached so
        timed are bounded by the next time heard (a text, or a drive back begun, is not).
        (Before, an item reached reported first after a restart took the time from before
        the kill, and review drew the track back there and forth again.)"""
        if clock.now is None or clock_ns is None or log_ns - clock_ns < gap_ns:
            return clock.now
        return clock.now + (log_ns - clock_ns) / 1e9 * clock.rate

    for order, (log_ns, msg) in enumerate(frames):
        kind = msg.get("mavpackettype")
        if kind == "GLOBAL_POSITION_INT":
            t_ms, lat_i, lon_i = (_num(msg.get(k)) for k in ("time_boot_ms", "lat", "lon"))
            if t_ms is None or lat_i is None or lon_i is None:
                continue
            t, lat, lon = run_clock(t_ms / 1000.0, log_ns), lat_i / 1e7, lon_i / 1e7
            valid = mc.has_fix(lat, lon)
            if pending is not None:
                item = items[pending[0]]
                at_waypoint = (
                    valid and _metres((lat, lon), (item.lat, item.lon)) <= WAYPOINT_MATCH_M
                )
                settle(t if at_waypoint else None)
            if valid:
                vx, vy = _num(msg.get("vx")), _num(msg.get("vy"))
                speed = math.hypot(vx, vy) / 100.0 if vx is not None and vy is not None else None
                points.append(_Point(t, order, lat, lon, speed, log_ns=log_ns))
        elif kind == "SYSTEM_TIME":
            t_ms = _num(msg.get("time_boot_ms"))
            if t_ms is not None and t_ms > 0:
                run_clock(t_ms / 1000.0, log_ns)
        elif kind == "MISSION_ITEM_REACHED":
            seq = msg.get("plan_seq", msg.get("seq"))  # in the plan's numbers (link/numbering.py)
            if not isinstance(seq, int) or seq == last_reached:
                # The item reached last, reported again (a repeated frame): nothing new.
                # Taken as a second reach, the first would settle at the position before
                # its waypoint, and the track would go to the waypoint and back.
                continue
            last_reached = seq
            settle()
            now = heard_at(log_ns)
            if now != clock.now and guessed_from is None:  # bounded by the next clock
                guessed_from = (len(reached), len(again))
            back = sent_back is not None and isinstance(seq, int) and sent_back <= seq <= highest
            if back and 0 < seq < len(items) and now is not None:
                again.append((seq, now))
                if back_since is not None:
                    up_spans.append((back_since, now))
                    back_since = None
            if isinstance(seq, int) and seq > highest:
                highest, highest_ns, sent_back = seq, log_ns, None
                highest_t = now if now is not None else highest_t
            if msg.get("caught_up"):
                # Caught up after a restart: reached at some time before now (not where
                # the vehicle is now), heading to the next item since.
                if 0 <= seq < len(items):
                    heading_to.append((log_ns, order, seq + 1, seq + 1))
                    caught_up.add(seq)
                reached.append((seq, now, order))
                continue
            if 0 <= seq < len(items) and this_mission:
                heading_to.append((log_ns, order, seq, seq + 1))
            if 0 <= seq < len(items) and items[seq].is_nav:
                pending = (seq, order, now)
            else:
                reached.append((seq, now, order))
        elif kind == "MISSION_CURRENT":
            seq = msg.get("plan_seq", msg.get("seq"))
            total = msg.get("plan_total", msg.get("total"))
            if isinstance(total, int) and total not in (0, 0xFFFF):
                # ours, or a window of ours (dispatcher/mission/window.py)
                this_mission = total <= len(items) - 1
            if isinstance(seq, int) and 0 < seq < len(items) and this_mission:
                heading_to.append((log_ns, order, seq, seq))
                told = bisect.bisect_right(sent_to_item, log_ns) > bisect.bisect_right(
                    sent_to_item, highest_ns
                )
                if (
                    seq <= highest
                    and told
                    and msg.get("mission_state") != mc.MISSION_STATE_COMPLETE
                ):
                    if sent_back is None:
                        # Up since a reboot after it reached the highest (its outputs at
                        # their boot values; our start keeps it up where it goes back).
                        back_since = reboots[-1] if reboots and reboots[-1] >= highest_t else None
                    sent_back = seq if sent_back is None else min(sent_back, seq)
                    last_reached = None  # (reaching the item it reached last is news now)
        elif kind == "HEARTBEAT":
            heartbeats.append(log_ns)
        elif kind == "STATUSTEXT":
            text = _statustext(msg.get("text"))
            severity = msg.get("severity")
            if text and isinstance(severity, int):
                texts.append((heard_at(log_ns), severity, text))
    settle()
    if back_since is not None and clock.now is not None:
        up_spans.append((back_since, clock.now))  # the log ends on the drive back
    return _Events(
        points,
        reached,
        heartbeats,
        clock.now,
        reboots,
        texts,
        heading_to,
        caught_up,
        again,
        up_spans,
    )


def _recording_gap_ns(positions_ns: Sequence[int]) -> float:
    """How far apart in receive time (ns) two positions received at ``positions_ns`` (in
    order) are a gap in the recording: RECORDING_GAP_S, and five times their median
    spacing."""
    spacing = float(np.median(np.diff(positions_ns))) if len(positions_ns) > 2 else 0.0
    return max(RECORDING_GAP_S * 1e9, 5.0 * spacing)


def _across_gaps(
    track: list[_Point],
    heading_to: Sequence[tuple[int, int, int, int]],
    items: Sequence[PlannedItem],
    planned_s: Sequence[float] | None = None,
) -> tuple[list[_Point], dict[int, float]]:
    """``track`` with the mission's waypoints put into each gap of the recording.

    Across a gap (positions RECORDING_GAP_S, and five times their median spacing, or more
    apart in receive time, as while the dispatcher was down) the vehicle drove its mission:
    from the item it was heading to before the gap (the last MISSION_CURRENT or item reached
    received in its first half) to the one it was heading to after (the first received in
    its second half). A straight line would cut every turn in between. Also returned: when
    each of those waypoints was passed: at the mission's pace from the gap's start
    (``planned_s``, each item's planned time), the rest of the gap stood where the next
    position was (a dispatcher down: its ground-station failsafe held the tractor), or the
    gap's time spread over them when it drove faster or its pace is not known (before, a
    review counted the hours a tractor stood held while the dispatcher was down as work)."""
    passed: dict[int, float] = {}
    if not heading_to:
        return track, passed
    reports = sorted(heading_to)
    received_at = [r[0] for r in reports]
    gap_ns = _recording_gap_ns([p.log_ns for p in track if p.log_ns is not None])
    out: list[_Point] = []
    a: _Point | None = None  # the last position the vehicle reported
    for b in track:
        if b.log_ns is None:  # a waypoint merged in
            out.append(b)
            continue
        if a is not None and a.log_ns is not None and b.log_ns - a.log_ns >= gap_ns and b.t > a.t:
            middle = bisect.bisect_left(received_at, (a.log_ns + b.log_ns) // 2)
            if 0 < middle < len(reports):
                before, after = reports[middle - 1][3], reports[middle][2]
                for seq, point in _mission_between(a, b, before, after, items, planned_s):
                    out.append(point)
                    if seq is not None:
                        passed[seq] = point.t
        out.append(b)
        a = b
    return out, passed


def _mission_between(
    a: _Point,
    b: _Point,
    before: int,
    after: int,
    items: Sequence[PlannedItem],
    planned_s: Sequence[float] | None = None,
) -> list[tuple[int | None, _Point]]:
    """The mission's waypoints from item ``before`` up to (not with) ``after``, passed
    between positions ``a`` and ``b``: at the mission's pace from ``a`` when ``planned_s``
    (each item's planned time) says it fits in the gap, else at times spread between.
    At that pace, when ``b`` finds it standing, then (item None) its arrival there at the
    pace of the leg into ``after``: the rest of the gap it stood there (held on the leg,
    not at its last waypoint: a straight line on to ``b`` counted those hours as driving)."""
    between = [s for s in range(max(before, 1), min(after, len(items))) if items[s].is_nav]
    pace = planned_s if planned_s is not None and len(planned_s) == len(items) else None
    origin = pace[max(before - 1, 0)] if pace is not None else 0.0
    # the legs to each waypoint, and on from the last to ``b``, fit in the gap
    fits = pace is not None and 0.0 < pace[min(after, len(items) - 1)] - origin <= b.t - a.t
    out: list[tuple[int | None, _Point]] = []
    for n, s in enumerate(between, 1):
        item = items[s]
        if mc.has_fix(item.lat, item.lon):
            if fits and pace is not None:
                t = a.t + pace[s] - origin
            else:
                t = a.t + (b.t - a.t) * n / (len(between) + 1)
            out.append((s, _Point(t, a.order, item.lat, item.lon, None, True, filled=True)))
    # ``after`` and the waypoint before it, when both are (not the whole mission scanned)
    legs = list(
        itertools.islice(
            (
                k
                for k in range(after, 0, -1)
                if items[k].is_nav and mc.has_fix(items[k].lat, items[k].lon)
            ),
            2,
        )
    )
    standing = b.speed is not None and b.speed < STILL_SPEED_MS  # (driving: it drove on)
    if fits and standing and pace is not None and len(legs) >= 2 and legs[0] == after:
        into, frm = items[after], items[legs[1]]
        leg_m = _metres((frm.lat, frm.lon), (into.lat, into.lon))
        leg_s = pace[after] - pace[legs[1]]
        last = out[-1][1] if out else a
        if leg_m > 0.0 and leg_s > 0.0:
            arrive = (
                last.t + min(_metres((last.lat, last.lon), (b.lat, b.lon)) / leg_m, 1.0) * leg_s
            )
            if last.t < arrive < b.t:
                out.append((None, _Point(arrive, a.order, b.lat, b.lon, None, filled=True)))
    return out


def _statustext(value: object) -> str:
    """A STATUSTEXT's text as recorded (a string, or a list of byte values)."""
    if isinstance(value, list):
        try:
            value = bytes(v for v in value if isinstance(v, int)).decode("utf-8", "replace")
        except ValueError:
            return ""
    return str(value).split("\x00", 1)[0].strip() if isinstance(value, str) else ""


def _fix_points(fixes: Sequence[tuple[int, dict[str, Any]]]) -> list[_Point]:
    """Positions from the LocationFix topic (when no GLOBAL_POSITION_INT was decoded)."""
    out = []
    for order, (_ns, fix) in enumerate(fixes):
        lat, lon = _num(fix.get("latitude")), _num(fix.get("longitude"))
        sim = next(
            (kv.get("value") for kv in fix.get("metadata") or [] if kv.get("key") == "sim_time_s"),
            None,
        )
        try:
            t = float(sim) if sim is not None else math.nan
        except (TypeError, ValueError):
            continue
        if lat is not None and lon is not None and math.isfinite(t) and mc.has_fix(lat, lon):
            out.append(_Point(t, order, lat, lon, None))
    return out


def _item_times(
    items: Sequence[PlannedItem],
    reached: Iterable[tuple[int, float | None, int]],
    passed: Mapping[int, float] | None = None,
    again: Iterable[tuple[int, float]] = (),
) -> tuple[dict[int, float], set[int], int, dict[int, int]]:
    """When each item was done (vehicle clock): an item reported reached and every item
    it skipped over (at the time it was ``passed`` in a gap of the recording, else that of
    the item reported). A DO item runs as the navigation item before it completes, so it
    takes that item's time; when the vehicle was sent back and reached an item ``again``,
    the DO items from there to the next navigation item ran again then (the implement
    lowered where a swath starts, after a drive back there with it up) and take that time.
    Also: the items reported themselves, the highest reached and each reported item's
    file position."""
    passed = passed or {}
    times: dict[int, float] = {}
    reported: set[int] = set()
    order_of: dict[int, int] = {}
    last = 0
    last_nav = 0  # item 0 (home) is never run
    for seq, t, order in reached:
        if t is None or not 0 < seq < len(items) or seq <= last:
            continue
        for s in range(last + 1, seq + 1):
            if items[s].is_nav:
                times[s] = min(passed.get(s, t), t) if s != seq else t
                last_nav = s
            elif s == seq or last_nav not in times:
                times[s] = t
            else:
                times[s] = times[last_nav]
        reported.add(seq)
        order_of[seq] = order
        last = seq
    for seq, t in again:
        for s in range(seq + items[seq].is_nav, len(items)):
            if items[s].is_nav:
                break
            if s in times and times[s] < t:
                times[s] = t
    return times, reported, last, order_of


def _start_time(points: Sequence[_Point], road_speed_ms: float) -> float | None:
    """When the vehicle set off (:class:`SetOff`, the daemon's rule), with the speed
    reported at each time (a waypoint merged in has none: a position at its time has)."""
    set_off = SetOff(road_speed_ms if road_speed_ms > 0 else None)
    for k, p in enumerate(points):
        speed = None
        j = k
        while j < len(points) and points[j].t == p.t and speed is None:
            q = points[j]
            speed = q.speed if q.speed is not None and q.speed >= STILL_SPEED_MS else None
            j += 1
        at = set_off.update(p.t, p.lat, p.lon, speed)
        if at is not None:
            return at
    return None


def _union(intervals: Iterable[tuple[float, float]]) -> list[tuple[float, float]]:
    out: list[tuple[float, float]] = []
    for a, b in sorted(i for i in intervals if i[1] > i[0]):
        if out and a <= out[-1][1]:
            out[-1] = (out[-1][0], max(out[-1][1], b))
        else:
            out.append((a, b))
    return out


def _inside(t: float, union: Sequence[tuple[float, float]]) -> bool:
    k = bisect.bisect_right(union, (t, math.inf)) - 1
    return k >= 0 and union[k][0] <= t <= union[k][1]


def _merge_activities(parts: list[Activity]) -> tuple[Activity, ...]:
    out: list[Activity] = []
    for p in sorted(parts, key=lambda a: (a.start_s, a.end_s)):
        if p.end_s - p.start_s <= 1e-9:
            continue
        last = out[-1] if out else None
        if (
            last is not None
            and last.kind == p.kind
            and last.field_id == p.field_id
            and p.start_s - last.end_s <= 1e-6
        ):
            out[-1] = Activity(last.kind, last.start_s, max(last.end_s, p.end_s), last.field_id)
        else:
            out.append(p)
    return tuple(out)


@dataclass(frozen=True)
class _FieldTimes:
    started: float | None  # on the clock of started_by (None: the vehicle's own)
    finished: float | None  # the vehicle's clock
    started_by: str | None = None


def _turn_seqs(items: Sequence[PlannedItem]) -> set[int]:
    """Items that end a move from one swath to the next in the same field (a turn)."""
    return set(_turns(items))


def _turns(items: Sequence[PlannedItem]) -> dict[int, int]:
    """Each turn (a move from one swath to the next in the same field): the item that ends
    it, and the swath end it began at."""
    out = {}
    prev: PlannedItem | None = None
    for item in items:
        if not item.is_nav or item.role in MOVE_ROLES:
            continue
        if (
            item.role == "swath_start"
            and prev is not None
            and prev.role == "swath_end"
            and prev.field_id == item.field_id
        ):
            out[item.seq] = prev.seq
        prev = item
    return out


def _upload_from_frames(to_vehicle: Sequence[tuple[int, dict[str, Any]]]) -> tuple[int, int]:
    """(attempts, resends) of mission uploads: a MISSION_COUNT starts an attempt, unless
    it counts more items than the one before (the next window of the same mission,
    dispatcher/mission/window.py); an upload message identical to the one sent before it
    is a resend."""
    attempts = retries = 0
    previous: tuple[Any, ...] | None = None
    last_count = -1
    for _ns, msg in to_vehicle:
        kind = msg.get("mavpackettype")
        if kind == "MISSION_COUNT":
            key: tuple[Any, ...] = (kind, msg.get("count"))
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            key = (kind, msg.get("seq"))
        else:
            continue
        if key == previous:
            retries += 1
        elif kind == "MISSION_COUNT":
            count = msg.get("count")
            count = count if isinstance(count, int) else 0
            if count <= last_count or last_count < 0:
                attempts += 1
            last_count = count
        previous = key
    return attempts, retries


def _heartbeat_gaps(
    beats: Sequence[int], end_ns: int | None, finished: bool
) -> tuple[float, float]:
    """(wall seconds in gaps over HEARTBEAT_GAP_S between heartbeats, of which at the end)."""
    gaps = 0.0
    for a, b in zip(beats, beats[1:], strict=False):
        gap = (b - a) / 1e9
        if gap > HEARTBEAT_GAP_S:
            gaps += gap
    trailing = 0.0
    if beats and end_ns is not None and not finished:
        tail = (end_ns - beats[-1]) / 1e9
        if tail > HEARTBEAT_GAP_S:
            trailing = tail
    return gaps + trailing, trailing


@dataclass
class _VehicleResult:
    review: VehicleReview
    field_times: dict[str, _FieldTimes]
    start_clock: float | None
    planned_s: list[float] | None  # planned seconds from setting off to each item
    warnings: list[str]
    items: tuple[PlannedItem, ...] = ()  # the mission it was reviewed against


def _review_vehicle(
    vid: str,
    machine: PlannedMachine,
    traffic: _Traffic,
    status: Mapping[str, Any] | None,
    since_ns: int,
    end_ns: int | None,
    fields: Mapping[str, Sequence[Sequence[Sequence[float]]]],
    replanned_ns: int | None = None,
    left_out: bool = False,
) -> _VehicleResult:
    """One vehicle's traffic set against ``machine``, its last mission. With
    ``replanned_ns``, that mission went on through a re-plan made then, whose figures for the
    machine count from where it was: the plan's time, fuel and turns are then what it had
    done by the re-plan plus what the re-plan planned for the rest. ``left_out``: a re-plan
    left it out (lost) and gave the rest of its mission to the others, so its plan counts up
    to the item it reached (the rest is in theirs)."""
    items = machine.items
    warnings: list[str] = []
    frames_from = [(ns, m) for ns, m in traffic.from_vehicle if ns >= since_ns]
    frames_to = [(ns, m) for ns, m in traffic.to_vehicle if ns >= since_ns]
    upload_start = next(
        (ns for ns, m in frames_to if m.get("mavpackettype") == "MISSION_COUNT"),
        since_ns,
    )
    # From the upload on, plus where the vehicle stood when it began (its last position).
    standing = [
        (ns, m)
        for ns, m in traffic.from_vehicle
        if ns < upload_start and m.get("mavpackettype") == "GLOBAL_POSITION_INT"
    ]
    after = [(ns, m) for ns, m in frames_from if ns >= upload_start]
    sent_to_item = [
        ns
        for ns, m in frames_to
        if m.get("mavpackettype") == "COMMAND_LONG"
        and m.get("command") == mc.MAV_CMD_DO_SET_MISSION_CURRENT
    ]
    events = _read_events(standing[-1:] + after, items, sent_to_item)
    points = events.points or _fix_points([(n, f) for n, f in traffic.fixes if n >= upload_start])
    if events.reboots:
        warnings.append(
            f"{vid}: the autopilot rebooted {len(events.reboots)} time(s) "
            f"(its clock started again); the run's times carry on across"
        )
    # Positions in time order; across a gap in the recording, the mission's waypoints the
    # vehicle passed meanwhile (and when, spread over the gap).
    track, passed = _across_gaps(
        sorted(points, key=lambda p: (p.t, p.order)),
        events.heading_to,
        items,
        machine.planned_times(),
    )
    times, reported, last, order_of = _item_times(items, events.reached, passed, events.again)
    n = len(items)
    complete = n > 1 and last == n - 1
    road_ms = machine.param("road_speed_kmh") / 3.6
    if road_ms <= 0:  # an older plan without the machine's speeds: the mission's first
        road_ms = next(
            (i.param2 for i in items if i.command == mc.MAV_CMD_DO_CHANGE_SPEED and i.param2 > 0),
            0.0,
        )

    # The exact waypoints the vehicle reported merged in.
    for seq in reported - events.caught_up:
        item = items[seq]
        if item.is_nav and mc.has_fix(item.lat, item.lon):
            track.append(_Point(times[seq], order_of[seq], item.lat, item.lon, None, True))
    track.sort(key=lambda p: (p.t, p.order))

    start = _start_time(track, road_ms)
    if start is None and times:
        start = min(times.values())
    last_clock = max(
        [t for t in (events.last_clock_s,) if t is not None] + [p.t for p in track], default=None
    )
    end: float | None
    if start is None:
        end = None
    elif complete:
        end = times[n - 1]
    else:
        end = max(start, last_clock if last_clock is not None else start)

    # Work windows, per field, from implement down to implement up (or the end so far).
    field_times: dict[str, _FieldTimes] = {}
    down: dict[str, float] = {}
    fields_done: list[tuple[float, int, str]] = []
    for seq in range(1, last + 1):
        item = items[seq]
        if item.field_id is None or seq not in times:
            continue
        if item.role == "implement_down" and item.field_id not in down:
            down[item.field_id] = times[seq]
            field_times[item.field_id] = _FieldTimes(times[seq], None)
        elif item.role == "implement_up" and item.field_id in down:
            field_times[item.field_id] = _FieldTimes(down[item.field_id], times[seq])
            fields_done.append((times[seq], seq, item.field_id))
    fields_done.sort()

    activities: list[Activity] = []
    distance = work_m = transit_m = 0.0
    working_s = transit_s = stopped_s = 0.0
    kept: list[_Point] = []
    if start is not None and end is not None:
        windows = {
            fid: (
                start if ft.started is None else max(ft.started, start),
                end if ft.finished is None else min(ft.finished, end),
            )
            for fid, ft in field_times.items()
        }
        work_union = _union(windows.values())
        for fid, (a, b) in windows.items():
            if b > a:
                activities.append(Activity("work", a - start, b - start, fid))
                working_s += b - a
        # The window: the last position before setting off, then everything to the end.
        earlier = [p for p in track if p.t <= start]
        inside = [p for p in track if start < p.t <= end]
        window = earlier[-1:] + inside
        # Distance: positions kept once they are JITTER_M from the last kept one.
        kept = _without_jitter(window)
        legs = _leg_lengths([p.lat for p in kept], [p.lon for p in kept])
        for (pa, pb), d in zip(zip(kept, kept[1:], strict=False), legs, strict=False):
            if _inside((max(pa.t, start) + pb.t) / 2, work_union):
                work_m += float(d)
            else:
                transit_m += float(d)
        # Moving or standing, between successive positions, outside the work windows.
        pace = _Pace(kept, legs)
        edges = [(max(p.t, start), p) for p in window]
        # (from, to, moving) between successive positions, then from the last to the end.
        spans = [
            (ta, tb, pace.moving(pa, pb))
            for (ta, pa), (tb, pb) in zip(edges, edges[1:], strict=False)
        ]
        tail_from = edges[-1][0] if edges else start
        if tail_from < end:
            tail = edges[-1][1] if edges else None
            spans.append(
                (tail_from, end, tail is not None and (tail.speed or 0.0) >= STILL_SPEED_MS)
            )
        for ta, tb, moving in spans:
            _outside_work(ta, tb, moving, start, work_union, activities)
        # Runs of standing still in a field's work window: held, not working.
        working_s -= sum(
            _held_in_work(a, b, start, work_union, activities) for a, b in _still_runs(spans)
        )
        for act in activities:
            if act.kind == "transit":
                transit_s += act.end_s - act.start_s
            elif act.kind == "stopped":
                stopped_s += act.end_s - act.start_s
        distance = work_m + transit_m

    turn_from = _turns(items)
    turn_seqs = set(turn_from)
    turns = sum(1 for s in turn_seqs if s <= last)
    working_h, transit_h = working_s / 3600.0, transit_s / 3600.0
    # (5): the turns at the road rate for as long as they took (in the work windows, which
    # would otherwise charge them at the work rate as well: a review), or t_T each.
    turning_h = (
        sum(
            max(times[s] - times[e], 0.0)
            for s, e in turn_from.items()
            if s <= last and s in times and e in times
        )
        / 3600.0
    )
    if turning_h > 0.0:
        fuel = _fuel(machine, transit_h + turning_h, 0, max(working_h - turning_h, 0.0))
    else:
        fuel = _fuel(machine, transit_h, turns, working_h)
    if fuel is None and machine.fields:
        warnings.append(
            f"{vid}: the plan gives no fuel rates for it (an older plan.json?): fuel not computed"
        )
    planned_s = machine.planned_times()
    plan_h, plan_fuel = machine.time_h, machine.fuel_l
    plan_turns = float(len(turn_seqs))  # counted as the driven ones are
    if replanned_ns is not None and start is not None:
        done = _done_by(track, replanned_ns, start, activities, times, turn_seqs)
        if done is not None:
            done_h, done_work_h, done_turns = done
            plan_h += done_h
            plan_fuel += _fuel(machine, done_h - done_work_h, done_turns, done_work_h) or 0.0

    nav = [it for it in items if it.is_nav and mc.has_fix(it.lat, it.lon)]
    plan_road_m = machine.distance_m
    mission_h = planned_s[-1] / 3600.0 if planned_s else None
    if left_out and not complete:
        # Its plan up to where it got: the mission's time to that item, and the planner's
        # time, fuel and road in that proportion (the planner's figures are per machine,
        # not per item); the turns it reached.
        if planned_s and planned_s[-1] > 0:
            share = planned_s[last] / planned_s[-1]
        else:
            share = last / max(n - 1, 1)
        plan_h, plan_fuel, plan_road_m = share * plan_h, share * plan_fuel, share * plan_road_m
        plan_turns = float(sum(1 for s in turn_seqs if s <= last))
        mission_h = planned_s[last] / 3600.0 if planned_s else None
        nav = [it for it in nav if it.seq <= last]  # the route drawn too
    planned_distance = float(_leg_lengths([i.lat for i in nav], [i.lon for i in nav]).sum())

    # Upload and link figures: the status document when there is one, else the frames.
    attempts_f, retries_f = _upload_from_frames(frames_to)
    st = status or {}
    if isinstance(st.get("upload_attempts"), int) and st["upload_attempts"] > 0:
        attempts, retries, source = (
            st["upload_attempts"],
            int(_number(st.get("upload_retries"))),
            "status",
        )
    elif attempts_f:
        attempts, retries, source = attempts_f, retries_f, "frames"
    else:
        attempts, retries, source = 0, 0, "none"
    gaps, trailing = _heartbeat_gaps(events.heartbeats_ns, end_ns, complete)
    lost = _number(st.get("lost_s"))
    phase = str(st.get("phase") or "")
    if complete:
        phase = "done"
    elif not phase:
        phase = "running" if start is not None else "not started"
    error = str(st.get("error") or "")

    last_report_h = None
    if start is not None and last_clock is not None:
        last_report_h = max(last_clock - start, 0.0) / 3600.0
    if not frames_from and not traffic.fixes:
        warnings.append(f"{vid}: no message from this vehicle in the log")
    elif start is None and machine.fields:
        warnings.append(f"{vid}: never set off (phase {phase})")
    elif not complete and machine.fields:
        where = f"{last_report_h:.2f} h after setting off" if last_report_h is not None else ""
        warnings.append(
            f"{vid}: mission not finished (item {last} of {n - 1}, phase {phase}); "
            f"last report {where}".rstrip()
        )
    if error:
        warnings.append(f"{vid}: {error}")
    if retries:
        warnings.append(f"{vid}: mission upload needed {retries} resend(s), {attempts} attempt(s)")
    if lost > 0:
        warnings.append(f"{vid}: the dispatcher counted it lost for {lost:.1f} s (wall)")
    if trailing > 0:
        warnings.append(f"{vid}: no heartbeat for the last {trailing:.1f} s of the log (wall)")
    elif gaps > 0:
        warnings.append(f"{vid}: {gaps:.1f} s (wall) in heartbeat gaps over {HEARTBEAT_GAP_S:g} s")
    if complete and plan_h > 0:
        actual_h = (end - start) / 3600.0 if end is not None and start is not None else 0.0
        if actual_h > plan_h * (1 + SLOWER_WARNING):
            warnings.append(
                f"{vid}: took {actual_h:.2f} h, {100 * (actual_h / plan_h - 1):.0f} % "
                f"more than the planned {plan_h:.2f} h"
            )
        if planned_distance > 0 and distance > planned_distance * (1 + SLOWER_WARNING):
            warnings.append(
                f"{vid}: drove {distance / 1000:.2f} km, more than the planned "
                f"{planned_distance / 1000:.2f} km"
            )
    status_done = st.get("fields_done")
    computed = [f for _, _, f in fields_done]
    if complete and isinstance(status_done, list) and status_done and status_done != computed:
        warnings.append(
            f"{vid}: the dispatcher's status lists fields {' '.join(map(str, status_done))}, "
            f"the frames show {' '.join(computed) or 'none'}"
        )

    problems: list[str] = []
    for _t, severity, text in events.texts:
        if severity <= mc.MAV_SEVERITY_WARNING and text not in problems:
            problems.append(text)
    if problems:
        warnings.append(f"{vid}: the autopilot said: {'; '.join(problems[:5])}")
    # Driving quality from the reported positions, and across a gap in the recording from
    # the mission's waypoints put there (the best known of where it drove).
    quality = track_quality(
        items,
        times,
        [(p.t, p.lat, p.lon) for p in track if not p.waypoint or p.filled],
        fields,
        events.up_spans,
    )
    if quality is not None and quality.outside_down_s > 0:
        warnings.append(
            f"{vid}: implement down outside the field for {quality.outside_down_s:.1f} s"
        )
    if quality is not None and quality.loops:
        warnings.append(f"{vid}: {quality.loops} of {quality.turns} turns driven with a loop")

    rel = (lambda t: t - start) if start is not None else (lambda t: t)
    review = VehicleReview(
        id=vid,
        phase=phase,
        # Its mission's fields: with those it had worked when a re-plan added to it.
        fields_planned=tuple(dict.fromkeys(i.field_id for i in items if i.field_id)),
        fields_done=tuple(computed),
        items_reached=last,
        items_total=n,
        mission_complete=complete,
        start_clock_s=start,
        end_clock_s=end,
        distance_m=distance,
        work_m=work_m,
        transit_m=transit_m,
        time_h=(end - start) / 3600.0 if start is not None and end is not None else 0.0,
        working_h=working_h,
        transit_h=transit_h,
        stopped_h=stopped_s / 3600.0,
        turns=turns,
        turning_h=turning_h,
        fuel_l=fuel,
        planned_distance_m=planned_distance,
        planned_road_m=plan_road_m,
        planned_time_h=plan_h,
        mission_time_h=mission_h,
        planned_fuel_l=plan_fuel,
        planned_turns=round(plan_turns),
        upload_attempts=attempts,
        upload_retries=retries,
        upload_source=source,
        lost_s=lost,
        heartbeat_gaps_s=gaps,
        error=error,
        last_report_h=last_report_h,
        activities=_merge_activities(activities),
        track=tuple((rel(p.t), p.lat, p.lon) for p in kept),
        planned_route=tuple(Waypoint(i.seq, i.field_id, i.role, i.lat, i.lon) for i in nav),
        reboots=tuple(rel(t) for t in events.reboots),
        autopilot_problems=tuple(problems),
        quality=quality,
        frames_refused=int(_number(st.get("frames_refused"))),
        foreign_commands=int(_number(st.get("foreign_commands"))),
    )
    return _VehicleResult(review, field_times, start, planned_s, warnings, items)


class _Pace:
    """Whether a vehicle moved between two positions: a reported ground speed of at
    least STILL_SPEED_MS at either end, or JITTER_M or more between them; without any
    reported speed, the average speed along the jitter-free track there."""

    def __init__(self, kept: Sequence[_Point], legs: np.ndarray) -> None:
        self._times = [p.t for p in kept]
        self._speeds = [
            float(d) / (b.t - a.t) if b.t > a.t else math.inf
            for (a, b), d in zip(zip(kept, kept[1:], strict=False), legs, strict=False)
        ]

    def moving(self, a: _Point, b: _Point) -> bool:
        speeds = [p.speed for p in (a, b) if p.speed is not None]
        if speeds and max(speeds) >= STILL_SPEED_MS:
            return True
        if _metres((a.lat, a.lon), (b.lat, b.lon)) >= JITTER_M:
            return True
        if speeds or not self._speeds:
            return False
        k = bisect.bisect_right(self._times, (a.t + b.t) / 2) - 1
        return self._speeds[min(max(k, 0), len(self._speeds) - 1)] >= STILL_SPEED_MS


def _outside_work(
    ta: float,
    tb: float,
    moving: bool,
    start: float,
    work_union: Sequence[tuple[float, float]],
    out: list[Activity],
) -> None:
    """The parts of [ta, tb] outside the work windows, as transit or stopped."""
    kind = "transit" if moving else "stopped"
    cursor = ta
    for u, v in work_union:
        if cursor >= tb:
            return
        if v <= cursor:
            continue
        if u >= tb:
            break
        if u > cursor:
            out.append(Activity(kind, cursor - start, u - start))
        cursor = max(cursor, v)
    if cursor < tb:
        out.append(Activity(kind, cursor - start, tb - start))


def _still_runs(spans: Sequence[tuple[float, float, bool]]) -> list[tuple[float, float]]:
    """The runs of successive ``spans`` (from, to, moving) standing still, as (from, to)."""
    runs: list[tuple[float, float]] = []
    for ta, tb, moving in spans:
        if moving:
            continue
        if runs and runs[-1][1] == ta:
            runs[-1] = (runs[-1][0], tb)
        else:
            runs.append((ta, tb))
    return runs


def _held_in_work(
    ta: float,
    tb: float,
    start: float,
    work_union: Sequence[tuple[float, float]],
    out: list[Activity],
) -> float:
    """Standing still from ``ta`` to ``tb`` for :data:`HELD_IN_WORK_S` or more: its parts
    inside the work windows, as stopped (held in the field: by the operator, or while the
    dispatcher restarted), and their seconds; 0 for a shorter pause (a turn, a hitch).
    They were counted as work, and charged the work's fuel (review)."""
    if tb - ta < HELD_IN_WORK_S:
        return 0.0
    held = 0.0
    for u, v in work_union:
        a, b = max(ta, u), min(tb, v)
        if b > a:
            out.append(Activity("stopped", a - start, b - start))
            held += b - a
    return held


def _without_jitter(points: Sequence[_Point]) -> list[_Point]:
    """Positions kept when at least JITTER_M from the last kept one (waypoints always)."""
    if not points:
        return []
    lats = np.array([p.lat for p in points])
    lons = np.array([p.lon for p in points])
    frame = LocalFrame.around(float(lons[0]), float(lats[0]))
    xs, ys = frame.to_local(lons, lats)
    kept = [points[0]]
    kx, ky = float(xs[0]), float(ys[0])
    for k in range(1, len(points)):
        d = math.hypot(float(xs[k]) - kx, float(ys[k]) - ky)
        if d >= JITTER_M or (points[k].waypoint and d > 0.01):
            kept.append(points[k])
            kx, ky = float(xs[k]), float(ys[k])
    return kept


# --- the whole log -----------------------------------------------------------------------


def review_log(source: str | os.PathLike[str] | IO[bytes]) -> Review:
    """Review one agrifleet MCAP log (a path or a binary stream).

    A log cut short is read up to where it ends (``complete`` False, and a warning that
    says where). Raises :class:`~dispatcher.recording.mcap_file.RecordingError` (a ``ValueError``)
    for a file that is not an MCAP file or not an agrifleet log.
    """
    log = read_log(source)
    return review_contents(log)


def review_contents(log: LogContents) -> Review:
    """Review a log already read with :func:`dispatcher.recording.mcap_file.read_log`."""
    warnings: list[str] = []
    start_ns = _int_or_none(log.metadata.get("start_time_ns"))
    if start_ns is None and log.records:
        start_ns = min(r.log_time_ns for r in log.records)
    end_ns = max((r.log_time_ns for r in log.records), default=None)
    if not log.complete:
        warnings.append(_ends_early(log.problem, start_ns, end_ns))

    traffic, plan_docs, status_docs = _sort_traffic(log)
    plans = [p for p in (_parse_plan(doc, ns) for ns, doc in plan_docs) if p is not None]
    if len(plans) < len(plan_docs):
        warnings.append(f"{len(plan_docs) - len(plans)} plan document(s) could not be read")
    plan_ids: list[str] = []
    for p in plans:
        if p.plan_id is not None and p.plan_id not in plan_ids:
            plan_ids.append(p.plan_id)
    # The last plan, from where it was first recorded: a dispatcher restarted on its stored
    # run records the same plan again at the start of its new log.
    first = len(plans) - 1
    while first > 0 and plans[first - 1].plan_id == plans[first].plan_id:
        first -= 1
    plan = plans[first] if plans else None
    # The plan the run began with: back over the re-plans of the run (plan_replaced
    # events) and over repeats. Its vehicles' traffic and events count from there; each
    # vehicle is set against the last plan (a driving vehicle's last mission starts with
    # its old one).
    replans = _replans(log)
    replan_ids = {pid for _, pid, _, _ in replans}
    base = first
    while base > 0 and (
        plans[base].plan_id in replan_ids or plans[base - 1].plan_id == plans[base].plan_id
    ):
        base -= 1
    since_ns = plans[base].log_ns if plans and base > 0 else 0
    replan_reviews = (
        _replan_reviews(plans[base], [r for r in replans if r[0] >= plans[base].log_ns], start_ns)
        if plans
        else []
    )
    for rp in replan_reviews:
        moved = "; ".join(
            f"{to} takes {', '.join(f for f, _, t in rp.taken_over if t == to)}"
            for to in dict.fromkeys(t for _, _, t in rp.taken_over)
        )
        warnings.append(
            f"re-planned {rp.at_s:.0f} s into the log: {rp.reason}; plan {rp.plan_id}"
            + (f"; {moved}" if moved else "")
        )
    later = [pid for pid in plan_ids if pid not in replan_ids]
    if len(later) > 1 and plan is not None:
        warnings.append(
            f"the log holds {len(later)} plans ({', '.join(later)}); "
            f"this review follows the last one, {plan.plan_id}"
        )
    farm_id = log.metadata.get("farm_id", "")
    plan_id = plan.plan_id if plan is not None else log.metadata.get("plan_id")
    if plan is None:
        warnings.append("no plan in the log: nothing to set the vehicles against")
        return Review(
            source=log.source,
            farm_id=farm_id,
            plan_id=plan_id,
            plan_ids=tuple(plan_ids),
            complete=log.complete,
            problem=log.problem,
            log_start_ns=start_ns,
            log_end_ns=end_ns,
            garage=None,
            vehicles=(),
            fields=(),
            planned_makespan_h=None,
            warnings=tuple(warnings),
        )

    # The dispatcher's own account, replayed with its FleetState.apply: review and the
    # live status agree on when each field was started and finished, and on which
    # vehicles a re-plan sent out again with a fresh mission.
    replayed, fresh = _replay_events(log, plans[base])
    status = _last_status(status_docs, plan.plan_id)
    vehicles: list[VehicleReview] = []
    results: dict[str, _VehicleResult] = {}

    def reviewed_from(vid: str) -> int:
        """From when the vehicle's traffic is set against its last mission (a re-plan sent
        it out again with that mission: what it did before is added by ``with_before``)."""
        return fresh.get(vid, since_ns)

    def with_before(vid: str, later: _VehicleResult) -> _VehicleResult:
        """``later``, the row of a vehicle a re-plan sent out again with a fresh mission,
        with what it did before against the mission it had then (and a warning saying so);
        ``later`` as it is for any other."""
        given_ns = fresh.get(vid, since_ns)
        if given_ns <= since_ns:
            return later
        joined, before = _with_work_before(
            vid, later, traffic.get(vid, _Traffic([], [], [])), since_ns, given_ns, plans[base:],
            rings,
        )  # fmt: skip
        warnings.append(_fresh_mission(vid, given_ns, start_ns, before))
        if before == "joined":
            # the fields it worked before are its row's again: said as the status lists them
            said = status.get(vid, {}) if status else {}
            if said.get("fields_done") == list(joined.review.fields_done):
                mismatch = f"{vid}: the dispatcher's status lists fields"
                joined.warnings = [w for w in joined.warnings if not w.startswith(mismatch)]
        return joined

    rings = {fid: f.rings for fid, f in plan.fields.items()}
    for machine in plan.machines:
        t = traffic.get(machine.id, _Traffic([], [], []))
        vstatus = status.get(machine.id) if status else None
        # Its mission went on through the last re-plan (not sent out again by it): the
        # re-plan's figures count from where it was then.
        given, planned = _mission_given(plans[base:], plan, machine.id)
        went_on = given is not plans[base] and fresh.get(machine.id, 0) < given.log_ns
        result = _review_vehicle(
            machine.id,
            planned,
            t,
            vstatus if isinstance(vstatus, dict) else None,
            reviewed_from(machine.id),
            end_ns,
            rings,
            given.log_ns if went_on else None,
        )
        result = with_before(machine.id, result)
        results[machine.id] = result
        vehicles.append(result.review)
        warnings += result.warnings
    left_out = {m.id for p in plans[base:] for m in p.machines} - {m.id for m in plan.machines}
    for vid in sorted(left_out):
        # Reviewed against the last mission it was given, up to where it was lost; from the
        # plan that gave it that mission, and, when it went on through a later re-plan, that
        # re-plan's figures for the rest plus what it had done by then (as those in the plan).
        had = next(p for p in reversed(plans[base:]) if any(m.id == vid for m in p.machines))
        given, planned = _mission_given(plans[base:], had, vid)
        went_on = given is not plans[base] and fresh.get(vid, 0) < given.log_ns
        vstatus = status.get(vid) if status else None
        result = _review_vehicle(
            vid,
            planned,
            traffic.get(vid, _Traffic([], [], [])),
            vstatus if isinstance(vstatus, dict) else None,
            reviewed_from(vid),
            end_ns,
            rings,
            given.log_ns if went_on else None,
            left_out=True,
        )
        result = with_before(vid, result)
        result.review = dataclasses.replace(result.review, left_out=True)
        results[vid] = result
        vehicles.append(result.review)
        warnings += result.warnings
        warnings.append(
            f"{vid}: lost; the rest of its work was re-planned over the others "
            f"(its plan counts to item {result.review.items_reached}, where it got)"
        )
    losses = _losses(log, traffic, since_ns, start_ns)
    alarms = _alarms(log, since_ns, start_ns)
    if alarms:
        warnings.append(f"{len(alarms)} alarm(s): see 'alarms'")
    for vr in vehicles:
        if vr.frames_refused or vr.foreign_commands:
            warnings.append(
                f"{vr.id}: {vr.frames_refused} frame(s) from it refused (not signed with its "
                f"key), {vr.foreign_commands} on its command key not sent by the dispatcher"
            )
    strangers = sorted(set(traffic) - {m.id for m in plan.machines} - left_out)
    if strangers:
        warnings.append(f"traffic from vehicles not in the plan, left out: {', '.join(strangers)}")

    if replayed is not None:
        for fid, f in replayed.fields.items():
            if f.vehicle in results:
                results[f.vehicle].field_times[fid] = _FieldTimes(
                    f.started_s, f.finished_s, f.started_by
                )
    fields = _field_reviews(plan, results, replayed)
    not_done = [f"{f.id} ({f.vehicle or 'nobody'})" for f in fields if not f.done]
    if not_done:
        warnings.append(f"fields not done: {', '.join(not_done)}")
    for fr in fields:
        if fr.worked_twice:
            warnings.append(
                f"field {fr.id}: segment(s) {', '.join(map(str, fr.worked_twice))} "
                f"of {fr.segments} worked more than once"
            )
        for began, worked in fr.relaid:
            warnings.append(
                f"field {fr.id}: laid out anew by a re-plan (another working width or turning "
                f"radius): the {worked} segment(s) worked of it before ({began}'s) worked again"
            )
        if fr.done and fr.never_worked:
            warnings.append(
                f"field {fr.id}: done, but segment(s) {', '.join(map(str, fr.never_worked))} "
                f"of {fr.segments} never worked"
            )
    return Review(
        source=log.source,
        farm_id=farm_id or plan.farm_id,
        plan_id=plan_id,
        plan_ids=tuple(plan_ids),
        complete=log.complete,
        problem=log.problem,
        log_start_ns=start_ns,
        log_end_ns=end_ns,
        garage=plan.garage,
        vehicles=tuple(vehicles),
        fields=tuple(fields),
        # After a re-plan, each vehicle's planned hours from when it set off.
        planned_makespan_h=plan.makespan_h
        if plan is plans[base]
        else max((v.planned_time_h for v in vehicles if not v.left_out), default=None),
        warnings=tuple(warnings),
        replans=tuple(replan_reviews),
        losses=tuple(losses),
        alarms=tuple(alarms),
    )


def _fresh_mission(vid: str, given_ns: int, start_ns: int | None, before: str) -> str:
    """What a vehicle's row is when a re-plan gave it a fresh mission; ``before``: what
    :func:`_with_work_before` made of its traffic before ("joined", "nothing", "clock")."""
    if before == "joined":
        return (
            f"{vid}: given a fresh mission by a re-plan {_ago(given_ns, start_ns)}; its row is "
            "what it did before, against the mission it had then (planned to where it got), "
            "and its traffic from there against the new one"
        )
    if before == "nothing":  # (it was told its clock went back: an outside review)
        return (
            f"{vid}: given a fresh mission by a re-plan {_ago(given_ns, start_ns)}, before it "
            "had set off; its row is its traffic from there against that mission"
        )
    return (
        f"{vid}: given a fresh mission by a re-plan {_ago(given_ns, start_ns)}; its row is "
        f"its traffic from there against that mission: what it did before (its clock went "
        "back meanwhile) is not in its row's hours, distance and fuel, nor the totals'"
    )


def _with_work_before(
    vid: str,
    later: _VehicleResult,
    traffic: _Traffic,
    since_ns: int,
    given_ns: int,
    plans: Sequence[_Plan],
    fields: Mapping[str, Sequence[Sequence[Sequence[float]]]],
) -> tuple[_VehicleResult, str]:
    """``later`` (a vehicle's row from ``given_ns``, when a re-plan gave it a fresh mission)
    with its traffic before, reviewed against the mission it had then, up to where it got
    (the rest of that mission went to the re-plan), joined into one row on its clock. A
    tractor stopped, its work re-planned, back and sent out again: its first 13.6 h were
    in neither its row nor the totals (an outside review). ``later`` as it is when it did
    nothing before, or its clock went back meanwhile (a reboot: no one timeline); with
    which of the three ("joined", "nothing", "clock")."""
    before = [p for p in plans if p.log_ns < given_ns]
    had = next((p for p in reversed(before) if any(m.id == vid for m in p.machines)), None)
    if had is None:
        return later, "nothing"
    _, planned = _mission_given(before, had, vid)
    cut = _Traffic(
        [x for x in traffic.from_vehicle if x[0] < given_ns],
        [x for x in traffic.to_vehicle if x[0] < given_ns],
        [x for x in traffic.fixes if x[0] < given_ns],
    )
    earlier = _review_vehicle(vid, planned, cut, None, since_ns, given_ns, fields, left_out=True)
    first, last = earlier.review, later.review
    if first.start_clock_s is None or first.end_clock_s is None:
        return later, "nothing"
    if last.start_clock_s is not None and last.start_clock_s < first.end_clock_s:
        return later, "clock"
    return _joined(earlier, later), "joined"


def _joined(earlier: _VehicleResult, later: _VehicleResult) -> _VehicleResult:
    """One row of two parts of a vehicle's day on one clock: ``earlier`` then ``later``
    (:func:`_with_work_before`); between them it stood."""
    a, b = earlier.review, later.review
    assert a.start_clock_s is not None and a.end_clock_s is not None
    start = a.start_clock_s
    if b.start_clock_s is None:  # not set off again (yet): the earlier part and the wait
        shift, gap = 0.0, 0.0
    else:
        shift = b.start_clock_s - start
        gap = max(b.start_clock_s - a.end_clock_s, 0.0)
    end = b.end_clock_s if b.end_clock_s is not None else a.end_clock_s

    def moved(acts: Sequence[Activity]) -> tuple[Activity, ...]:
        return tuple(
            dataclasses.replace(x, start_s=x.start_s + shift, end_s=x.end_s + shift) for x in acts
        )

    waited = (
        (Activity("stopped", a.end_clock_s - start, a.end_clock_s - start + gap),) if gap else ()
    )
    fuel = None if a.fuel_l is None or b.fuel_l is None else a.fuel_l + b.fuel_l
    review = dataclasses.replace(
        b,
        fields_planned=tuple(dict.fromkeys(a.fields_done + b.fields_planned)),
        fields_done=a.fields_done + b.fields_done,
        start_clock_s=start,
        end_clock_s=end,
        distance_m=a.distance_m + b.distance_m,
        work_m=a.work_m + b.work_m,
        transit_m=a.transit_m + b.transit_m,
        time_h=(end - start) / 3600.0,
        working_h=a.working_h + b.working_h,
        transit_h=a.transit_h + b.transit_h,
        stopped_h=a.stopped_h + b.stopped_h + gap / 3600.0,
        turns=a.turns + b.turns,
        turning_h=a.turning_h + b.turning_h,
        fuel_l=fuel,
        planned_distance_m=a.planned_distance_m + b.planned_distance_m,
        planned_road_m=a.planned_road_m + b.planned_road_m,
        planned_time_h=a.planned_time_h + b.planned_time_h,
        mission_time_h=(
            None
            if a.mission_time_h is None or b.mission_time_h is None
            else a.mission_time_h + b.mission_time_h
        ),
        planned_fuel_l=a.planned_fuel_l + b.planned_fuel_l,
        planned_turns=a.planned_turns + b.planned_turns,
        upload_attempts=a.upload_attempts + b.upload_attempts,
        upload_retries=a.upload_retries + b.upload_retries,
        heartbeat_gaps_s=a.heartbeat_gaps_s + b.heartbeat_gaps_s,
        last_report_h=(
            a.last_report_h if b.last_report_h is None else b.last_report_h + shift / 3600.0
        ),
        activities=a.activities + waited + moved(b.activities),
        track=a.track + tuple((t + shift, lat, lon) for t, lat, lon in b.track),
        planned_route=a.planned_route + b.planned_route,
        reboots=a.reboots + tuple(t + shift for t in b.reboots),
        autopilot_problems=tuple(dict.fromkeys(a.autopilot_problems + b.autopilot_problems)),
    )
    return dataclasses.replace(
        later,
        review=review,
        field_times={**earlier.field_times, **later.field_times},
        start_clock=start,
        planned_s=(None if later.planned_s is None else [t + shift for t in later.planned_s]),
    )


def _event_records(log: LogContents) -> list[LogRecord]:
    """The run's fleet events in time order. A dispatcher resumed on its stored run copies
    the events it resumed from into its new log (marked ``events.STORED``, at their own
    times); the earlier log may lack the last of them (a crash loses its last half
    second): a copy counts where the earlier logs do not hold the same event within
    :data:`SAME_EVENT_NS` of its time."""
    originals: dict[str, list[int]] = {}
    copies: list[tuple[LogRecord, str]] = []
    out: list[LogRecord] = []
    for rec in log.records:
        if rec.topic != EVENTS_TOPIC:
            continue
        doc = _decode(rec.data)
        if not isinstance(doc, dict):
            continue
        stored = doc.pop(ev.STORED, None) is True
        key = json.dumps(doc, sort_keys=True)
        if stored:
            copies.append((rec, key))
        else:
            originals.setdefault(key, []).append(rec.log_time_ns)
            out.append(rec)
    for rec, key in copies:
        if not any(abs(t - rec.log_time_ns) <= SAME_EVENT_NS for t in originals.get(key, ())):
            out.append(rec)
    return sorted(out, key=lambda r: r.log_time_ns)


SAME_EVENT_NS = 10_000_000
"""A stored copy's time (the store's float seconds) and its original's (the log's ns) differ
by rounding only."""


def _replans(log: LogContents) -> list[tuple[int, str, str, Any]]:
    """The run's re-plans: (log ns, new plan id, reason, plan document) of its
    plan_replaced events."""
    out = []
    for rec in _event_records(log):
        doc = rec.decode_json()
        if isinstance(doc, dict) and doc.get("kind") == ev.PlanReplaced.kind:
            out.append(
                (
                    rec.log_time_ns,
                    str(doc.get("plan_id")),
                    str(doc.get("reason")),
                    doc.get("document"),
                )
            )
    return out


def _replan_reviews(
    base: _Plan, replans: Sequence[tuple[int, str, str, Any]], start_ns: int | None
) -> list[Replan]:
    """Each re-plan with the fields that changed hands in it (a field is held by the
    vehicle whose route lists it; the first plan's routes to begin with)."""
    owner = {fid: m.id for m in base.machines for fid in m.fields}
    out = []
    for ns, pid, reason, doc in replans:
        moved = []
        try:
            machines = PlanDocument.from_json(doc).machines if doc is not None else ()
        except PlanDocumentError as exc:
            logger.warning("the document of re-plan %s cannot be read: %s", pid, exc)
            machines = ()
        for m in machines:
            for fid in m.fields:
                before = owner.get(fid)
                if before is not None and before != m.id:
                    moved.append((fid, before, m.id))
                owner[fid] = m.id
        at_s = (ns - start_ns) / 1e9 if start_ns is not None else 0.0
        out.append(Replan(at_s, pid, reason, tuple(moved)))
    return out


def _losses(
    log: LogContents, traffic: Mapping[str, _Traffic], since_ns: int, start_ns: int | None
) -> list[Loss]:
    """Vehicles the dispatcher gave up on (lost or stalled), each where it was last heard
    of before then."""
    out = []
    for rec in _event_records(log):
        if rec.log_time_ns < since_ns:
            continue
        doc = rec.decode_json()
        if not isinstance(doc, dict) or not isinstance(doc.get("vehicle"), str):
            continue
        if doc.get("kind") == ev.VehicleLost.kind:
            why = str(doc.get("why", ""))
        elif doc.get("kind") == ev.VehicleStalled.kind:
            why = f"stalled for {_num(doc.get('seconds')) or 0.0:.0f} s"
        else:
            continue
        vid = doc["vehicle"]
        lat, lon = _last_position(traffic.get(vid), rec.log_time_ns)
        at_s = (rec.log_time_ns - start_ns) / 1e9 if start_ns is not None else 0.0
        out.append(Loss(vid, at_s, why, lat, lon))
    return out


def _alarms(log: LogContents, since_ns: int, start_ns: int | None) -> list[Alarm]:
    """The dispatcher's alarms, as its recorded events tell them."""
    kinds = {cls.kind for cls in ev.ALARMS}
    out = []
    for rec in _event_records(log):
        doc = rec.decode_json()
        if rec.log_time_ns < since_ns or not isinstance(doc, dict) or doc.get("kind") not in kinds:
            continue
        try:
            event = ev.from_dict(doc)
        except (TypeError, ValueError):
            continue
        at_s = (rec.log_time_ns - start_ns) / 1e9 if start_ns is not None else 0.0
        text = event.text() if isinstance(event, ev.ALARMS) else event.kind
        out.append(Alarm(event.vehicle, at_s, event.kind, text, getattr(event, "field", None)))
    return out


def _last_position(traffic: _Traffic | None, ns: int) -> tuple[float | None, float | None]:
    """Where a vehicle said it was last at or before log time ``ns``."""
    if traffic is None:
        return None, None
    for t, m in reversed(traffic.from_vehicle):
        if t <= ns and m.get("mavpackettype") == "GLOBAL_POSITION_INT":
            lat, lon = _num(m.get("lat")), _num(m.get("lon"))
            if lat is not None and lon is not None and mc.has_fix(lat / 1e7, lon / 1e7):
                return lat / 1e7, lon / 1e7
    for t, fix in reversed(traffic.fixes):
        if t <= ns:
            lat, lon = _num(fix.get("latitude")), _num(fix.get("longitude"))
            if lat is not None and lon is not None and mc.has_fix(lat, lon):
                return lat, lon
    return None, None


def _ago(ns: int, start_ns: int | None) -> str:
    return f"{(ns - start_ns) / 1e9:.0f} s into the log" if start_ns is not None else "later"


def _fuel(machine: PlannedMachine, road_h: float, turns: int, work_h: float) -> float | None:
    """Formula (5) on what was driven: road hours and turns at the road rate, work hours at
    the work rate; None if the plan gives no rates (an older plan.json)."""
    if not all(k in machine.params for k in ("road_fuel_lh", "work_fuel_lh", "turn_time_h")):
        return None
    turn_h = turns * machine.param("turn_time_h")
    return formulas.fuel_l(
        road_h, turn_h, work_h, machine.param("road_fuel_lh"), machine.param("work_fuel_lh")
    )


def _mission_given(plans: Sequence[_Plan], plan: _Plan, vid: str) -> tuple[_Plan, PlannedMachine]:
    """The plan that gave vehicle ``vid`` its mission in ``plan``, and its entry there: the
    first of ``plans`` (the run's, in order, ending with ``plan``) whose entry for it has
    the same items. A re-plan that left its mission as it was (nothing new for it) has no
    figures of it of its own: 0 h, where its mission takes what the plan that gave it said."""
    items = next(m.items for m in plan.machines if m.id == vid)
    return next(
        (p, m) for p in plans for m in p.machines if m.id == vid and (p is plan or m.items == items)
    )


def _done_by(
    track: Sequence[_Point],
    log_ns: int,
    start: float,
    activities: Sequence[Activity],
    times: Mapping[int, float],
    turn_seqs: Iterable[int],
) -> tuple[float, float, int] | None:
    """What a vehicle had done when the log was at ``log_ns`` (by its last position
    received by then): hours since it set off, of them working, and turns; None if it had
    not set off."""
    heard = [p.t for p in track if p.log_ns is not None and p.log_ns <= log_ns]
    if not heard or heard[-1] <= start:
        return None
    at = heard[-1] - start
    work_s = sum(max(min(a.end_s, at) - a.start_s, 0.0) for a in activities if a.kind == "work")
    turns = sum(1 for s in turn_seqs if s in times and times[s] - start <= at)
    return at / 3600.0, work_s / 3600.0, turns


def _replay_events(log: LogContents, plan: _Plan) -> tuple[FleetState | None, dict[str, int]]:
    """The fleet state the recorded events of ``plan`` lead to (None: no events recorded,
    a log from before they were), and when a re-plan last gave each vehicle a fresh
    mission (one that does not go on from the mission it had: sent out again from item 1,
    as the state's own rule for a re-plan decides), by vehicle."""
    if plan.document is None:
        return None, {}
    state = FleetState(plan.document)
    seen = False
    fresh: dict[str, int] = {}
    for rec in _event_records(log):
        if rec.log_time_ns < plan.log_ns:
            continue
        try:
            event = ev.from_dict(rec.decode_json())
            replaced = isinstance(event, ev.PlanReplaced)
            before = {vid: v.items for vid, v in state.vehicles.items()} if replaced else {}
            state.apply(event, rec.log_time_ns / 1e9)
        except (ValueError, KeyError) as exc:
            logger.warning("a recorded event cannot be replayed: %s", exc)
            continue
        seen = True
        if replaced:
            for vid, v in state.vehicles.items():
                if v.items != before[vid] and not v.switch and v.reached == 0:
                    fresh[vid] = rec.log_time_ns
    return (state if seen else None), fresh


def _field_reviews(
    plan: _Plan, results: Mapping[str, _VehicleResult], replayed: FleetState | None
) -> list[FieldReview]:
    """Each field: who worked it (the vehicle that finished it, or holds it now, as the
    recorded events tell; else the plan's), when, against the plan; its segments."""
    owner: dict[str, str] = {}
    for m in plan.machines:
        for item in m.items:
            if item.field_id is not None:
                owner.setdefault(item.field_id, m.id)
        for fid in m.fields:
            owner.setdefault(fid, m.id)
    if replayed is not None:
        owner.update({fid: f.vehicle for fid, f in replayed.fields.items()})
    planned: dict[str, tuple[float, float | None]] = {}
    for vid, result in results.items():
        pt = result.planned_s
        if pt is None:
            continue
        for item in result.items:
            if item.field_id is None or owner.get(item.field_id) != vid:
                continue
            if item.role == "implement_down":
                planned[item.field_id] = (pt[item.seq], None)
            elif item.role == "implement_up" and item.field_id in planned:
                planned[item.field_id] = (planned[item.field_id][0], pt[item.seq])
    ids = list(plan.fields) + [f for f in owner if f not in plan.fields]
    out = []
    for fid in ids:
        info = plan.fields.get(fid)
        holder = owner.get(fid)
        held = results.get(holder) if holder is not None else None
        state = replayed.fields.get(fid) if replayed is not None else None
        times = held.field_times.get(fid) if held is not None else None
        start = held.start_clock if held is not None else None
        started = times.started if times is not None else None
        # A field handed over after a loss started on the first vehicle's clock: measured
        # from that vehicle's set-off (the fleet's common timeline).
        started_by = (times.started_by if times is not None else None) or holder
        begun = results.get(started_by) if started_by not in (None, holder) else held
        begun_start = begun.start_clock if begun is not None else None
        finished = times.finished if times is not None else None
        p_start, p_end = planned.get(fid, (None, None))
        out.append(
            FieldReview(
                id=fid,
                name=info.name if info is not None else fid,
                area_m2=info.area_m2 if info is not None else 0.0,
                polygon=info.polygon if info is not None else (),
                holes=info.holes if info is not None else (),
                vehicle=holder,
                done=finished is not None,
                started_s=_minus(started, begun_start),
                finished_s=_minus(finished, start),
                started_by=started_by if started is not None else None,
                started_clock_s=started,
                finished_clock_s=finished,
                planned_started_s=p_start,
                planned_finished_s=p_end,
                segments=state.segments if state is not None else 0,
                worked_twice=tuple(state.worked_twice) if state is not None else (),
                never_worked=tuple(state.never_worked) if state is not None else (),
                relaid=tuple(state.relaid) if state is not None else (),
            )
        )
    return out


def _begun_by(f: FieldReview) -> str:
    """ " (begun by t2)" for a field another vehicle began, else ""."""
    return f" (begun by {f.started_by})" if f.started_by not in (None, f.vehicle) else ""


def _minus(a: float | None, b: float | None) -> float | None:
    return a - b if a is not None and b is not None else None


def _last_status(docs: Sequence[tuple[int, Any]], plan_id: str | None) -> dict[str, Any] | None:
    """The vehicles of the last status document of ``plan_id`` (or without a plan id)."""
    for _ns, doc in reversed(docs):
        if not isinstance(doc, dict) or not isinstance(doc.get("vehicles"), dict):
            continue
        if plan_id is None or doc.get("plan_id") in (None, plan_id):
            return dict(doc["vehicles"])
    return None


def _int_or_none(value: object) -> int | None:
    try:
        return int(str(value))
    except ValueError:
        return None


def _iso(ns: int | None) -> str:
    if ns is None:
        return "?"
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def _ends_early(problem: str | None, start_ns: int | None, end_ns: int | None) -> str:
    reason = f": {problem}" if problem else ""
    if end_ns is None:
        return f"the log ends early{reason}. It ends before its first message"
    where = f"at {_iso(end_ns)}"
    if start_ns is not None:
        where += f", {(end_ns - start_ns) / 1e9:.1f} s after the log started"
    return f"the log ends early{reason}. The last record read is {where}; anything later is lost"


# --- output --------------------------------------------------------------------------------


def review_json(review: Review) -> dict[str, Any]:
    """The review as a JSON-ready dict (tracks left out; activities kept)."""

    def r(value: float | None, digits: int) -> float | None:
        return None if value is None else round(value, digits)

    vehicles = []
    for v in review.vehicles:
        vehicles.append(
            {
                "id": v.id,
                "phase": v.phase,
                "fields_planned": list(v.fields_planned),
                "fields_done": list(v.fields_done),
                "items_reached": v.items_reached,
                "items_total": v.items_total,
                "mission_complete": v.mission_complete,
                "left_out": v.left_out,
                "distance_m": r(v.distance_m, 1),
                "planned_distance_m": r(v.planned_distance_m, 1),
                "work_m": r(v.work_m, 1),
                "transit_m": r(v.transit_m, 1),
                "planned_road_m": r(v.planned_road_m, 1),
                "time_h": r(v.time_h, 4),
                "planned_time_h": r(v.planned_time_h, 4),
                "mission_time_h": r(v.mission_time_h, 4),
                "working_h": r(v.working_h, 4),
                "transit_h": r(v.transit_h, 4),
                "stopped_h": r(v.stopped_h, 4),
                "turns": v.turns,
                "planned_turns": v.planned_turns,
                "fuel_l": r(v.fuel_l, 2),
                "planned_fuel_l": r(v.planned_fuel_l, 2),
                "upload_attempts": v.upload_attempts,
                "upload_retries": v.upload_retries,
                "upload_source": v.upload_source,
                "lost_s": r(v.lost_s, 1),
                "frames_refused": v.frames_refused,
                "foreign_commands": v.foreign_commands,
                "heartbeat_gaps_s": r(v.heartbeat_gaps_s, 1),
                "start_clock_s": r(v.start_clock_s, 3),
                "end_clock_s": r(v.end_clock_s, 3),
                "last_report_h": r(v.last_report_h, 4),
                "error": v.error,
                "reboots_s": [round(t, 1) for t in v.reboots],
                "autopilot_problems": list(v.autopilot_problems),
                "track_quality": None
                if v.quality is None
                else {
                    "samples": v.quality.samples,
                    "cross_track_median_m": r(v.quality.cross_track_median_m, 3),
                    "cross_track_p95_m": r(v.quality.cross_track_p95_m, 3),
                    "cross_track_max_m": r(v.quality.cross_track_max_m, 3),
                    "swath_samples": v.quality.swath_samples,
                    "swath_cross_track_median_m": r(v.quality.swath_median_m, 3),
                    "swath_cross_track_p95_m": r(v.quality.swath_p95_m, 3),
                    "outside_field_implement_down_s": round(v.quality.outside_down_s, 1),
                    "turns": v.quality.turns,
                    "loops": v.quality.loops,
                },
                "activities": [
                    {
                        "kind": a.kind,
                        "field": a.field_id,
                        "start_s": round(a.start_s, 1),
                        "end_s": round(a.end_s, 1),
                    }
                    for a in v.activities
                ],
            }
        )
    fields = {
        f.id: {
            "done": f.done,
            "vehicle": f.vehicle,
            "started": r(f.started_s, 1),
            "finished": r(f.finished_s, 1),
            "started_by": f.started_by,
            "started_clock_s": r(f.started_clock_s, 1),
            "finished_clock_s": r(f.finished_clock_s, 1),
            "planned_started": r(f.planned_started_s, 1),
            "planned_finished": r(f.planned_finished_s, 1),
            "name": f.name,
            "area_m2": f.area_m2,
            "segments": f.segments,
            "worked_twice": list(f.worked_twice),
            "never_worked": list(f.never_worked),
            "relaid": [list(r) for r in f.relaid],
        }
        for f in review.fields
    }
    return {
        "source": review.source,
        "farm_id": review.farm_id,
        "plan_id": review.plan_id,
        "plan_ids": list(review.plan_ids),
        "complete": review.complete,
        "problem": review.problem,
        "log_start": _iso(review.log_start_ns) if review.log_start_ns is not None else None,
        "log_end": _iso(review.log_end_ns) if review.log_end_ns is not None else None,
        "makespan_h": round(review.makespan_h, 4),
        "makespan_final": review.makespan_final,
        "planned_makespan_h": r(review.planned_makespan_h, 4),
        "totals": {
            "fields_done": review.fields_done,
            "fields": len(review.fields),
            "distance_m": round(sum(v.distance_m for v in review.vehicles), 1),
            "planned_distance_m": round(sum(v.planned_distance_m for v in review.vehicles), 1),
            "time_h": round(sum(v.time_h for v in review.vehicles), 4),
            "planned_time_h": round(sum(v.planned_time_h for v in review.vehicles), 4),
            "fuel_l": round(sum(v.fuel_l or 0.0 for v in review.vehicles), 2),
            "planned_fuel_l": round(sum(v.planned_fuel_l for v in review.vehicles), 2),
        },
        "vehicles": vehicles,
        "fields": fields,
        "replans": [
            {
                "at_s": round(rp.at_s, 1),
                "plan_id": rp.plan_id,
                "reason": rp.reason,
                "taken_over": [{"field": f, "from": a, "to": b} for f, a, b in rp.taken_over],
            }
            for rp in review.replans
        ],
        "losses": [
            {
                "vehicle": x.vehicle,
                "at_s": round(x.at_s, 1),
                "why": x.why,
                "lat": x.lat,
                "lon": x.lon,
            }
            for x in review.losses
        ],
        "alarms": [
            {"vehicle": a.vehicle, "at_s": round(a.at_s, 1), "kind": a.kind, "text": a.text}
            for a in review.alarms
        ],
        "warnings": list(review.warnings),
    }


_HEADER: Final = (
    ("", "vehicle"),
    ("fields", "done"),
    ("dist km", "plan"),
    ("", "act"),
    ("time h", "plan"),
    ("", "msn"),
    ("", "act"),
    ("fuel L", "plan"),
    ("", "act"),
    ("work h", "act"),
    ("road h", "act"),
    ("turns", "plan/act"),
    ("upload", "try/re"),
    ("lost s", "wall"),
    ("", "state"),
)


def _columns(rows: Sequence[Sequence[str]]) -> list[str]:
    """Rows as fixed-width text: first column left-aligned, the others right-aligned."""
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    out = []
    for r in rows:
        cells = [
            c.ljust(w) if k in (0, len(r) - 1) else c.rjust(w)
            for k, (c, w) in enumerate(zip(r, widths, strict=True))
        ]
        out.append(" ".join(cells).rstrip())
    return out


def _vehicle_row(v: VehicleReview) -> list[str]:
    return [
        v.id,
        f"{len(v.fields_done)}/{len(v.fields_planned)}",
        f"{v.planned_distance_m / 1000:.2f}",
        f"{v.distance_m / 1000:.2f}",
        f"{v.planned_time_h:.2f}",
        "-" if v.mission_time_h is None else f"{v.mission_time_h:.2f}",
        f"{v.time_h:.2f}",
        f"{v.planned_fuel_l:.1f}",
        "-" if v.fuel_l is None else f"{v.fuel_l:.1f}",
        f"{v.working_h:.2f}",
        f"{v.transit_h:.2f}",
        f"{v.planned_turns}/{v.turns}",
        f"{v.upload_attempts}/{v.upload_retries}",
        f"{max(v.lost_s, v.heartbeat_gaps_s):.1f}",
        v.phase,
    ]


def _total_row(review: Review) -> list[str]:
    vs = review.vehicles
    return [
        "total",
        f"{review.fields_done}/{len(review.fields)}",
        f"{sum(v.planned_distance_m for v in vs) / 1000:.2f}",
        f"{sum(v.distance_m for v in vs) / 1000:.2f}",
        f"{sum(v.planned_time_h for v in vs):.2f}",
        _sum_or_dash([v.mission_time_h for v in vs], 2),
        f"{sum(v.time_h for v in vs):.2f}",
        f"{sum(v.planned_fuel_l for v in vs):.1f}",
        _sum_or_dash([v.fuel_l for v in vs], 1),
        f"{sum(v.working_h for v in vs):.2f}",
        f"{sum(v.transit_h for v in vs):.2f}",
        f"{sum(v.planned_turns for v in vs)}/{sum(v.turns for v in vs)}",
        f"{sum(v.upload_attempts for v in vs)}/{sum(v.upload_retries for v in vs)}",
        f"{sum(max(v.lost_s, v.heartbeat_gaps_s) for v in vs):.1f}",
        "",
    ]


def _sum_or_dash(values: Sequence[float | None], digits: int) -> str:
    known = [v for v in values if v is not None]
    return f"{sum(known):.{digits}f}" if known else "-"


def review_table(review: Review) -> str:
    """The review as a fixed-width table: per vehicle planned vs actual, totals, the
    makespan, the fields in the order worked, and a line per warning."""
    name = Path(review.source).name if review.source else "<stream>"
    span = ""
    if review.log_start_ns is not None and review.log_end_ns is not None:
        span = f", {(review.log_end_ns - review.log_start_ns) / 1e9:.0f} s of it recorded"
    state = "complete" if review.complete else "CUT SHORT"
    lines = [
        f"review of {name}: farm {review.farm_id or '?'}, plan {review.plan_id or '?'}",
        f"log started {_iso(review.log_start_ns)}{span}; log {state}",
    ]
    if not review.complete:
        lines.append(f"!! {_ends_early(review.problem, review.log_start_ns, review.log_end_ns)}")
    lines.append("")
    if not review.vehicles:
        lines.append("no vehicles to review")
    else:
        rows = [list(h) for h in zip(*_HEADER, strict=True)]
        rows += [_vehicle_row(v) for v in review.vehicles]
        rows.append(_total_row(review))
        table = _columns(rows)
        lines += table[:2] + ["-" * len(table[1])] + table[2:-1] + ["-" * len(table[1])]
        lines.append(table[-1])
        lines += [
            "time h: plan = the planner's formula (6); msn = the uploaded mission's waypoints at",
            "the planned speeds; act = the vehicle's clock, setting off to back at the garage",
            "(or to its last report). road h: moving with the implement up.",
            "",
        ]
        longest = review.makespan_vehicle
        assert longest is not None  # (there are vehicles)
        planned = (
            f"{review.planned_makespan_h:.2f} h planned"
            if review.planned_makespan_h is not None
            else "no planned makespan"
        )
        if review.makespan_final:
            lines.append(f"makespan: {review.makespan_h:.2f} h ({longest.id}), {planned}")
        else:
            lines.append(
                f"makespan: at least {review.makespan_h:.2f} h ({longest.id}, not every vehicle "
                f"finished), {planned}"
            )
        lines += ["", "fields in the order worked (hours after the vehicle set off):"]
        digits = 1 if review.makespan_h >= 2.0 else 2
        for v in review.vehicles:
            worked = []
            for fid in v.fields_done:
                f = review.field(fid)
                worked.append(
                    f"{fid} {_hours(f.started_s, digits)}-{_hours(f.finished_s, digits)}"
                    + _begun_by(f)
                )
            for fid in v.fields_planned:
                f = review.field(fid)
                if not f.done and f.started_s is not None:
                    worked.append(
                        f"{fid} {_hours(f.started_s, digits)}- (unfinished)" + _begun_by(f)
                    )
            for f in review.fields:
                if f.started_by == v.id and f.vehicle != v.id:
                    worked.append(
                        f"{f.id} {_hours(f.started_s, digits)}- (handed over to {f.vehicle})"
                    )
            missing = [f for f in v.fields_planned if review.field(f).started_s is None]
            line = f"  {v.id:<6} " + (", ".join(worked) or "-")
            if missing:
                line += f"; not started: {' '.join(missing)}"
            lines.append(line)
        lines += ["", "driving (implement down: cross-track error to the working line):"]
        for v in review.vehicles:
            lines.append(f"  {v.id:<6} {_quality_line(v)}")
    lines.append("")
    if review.alarms:
        lines.append("alarms (what the dispatcher did not trust; nothing of it counted):")
        lines += [f"  !! {a.at_s:7.1f} s  {a.text}" for a in review.alarms]
        doubted = sorted({f"{a.field} ({a.vehicle})" for a in review.alarms if a.field})
        if doubted:
            lines.append(f"  fields whose progress was not plausible: {', '.join(doubted)}")
        lines.append("")
    if review.warnings:
        lines.append("warnings:")
        lines += [f"  ! {w}" for w in review.warnings]
    else:
        lines.append("no warnings")
    return "\n".join(lines)


def _quality_line(v: VehicleReview) -> str:
    q = v.quality
    if q is None or q.cross_track_median_m is None:
        text = "no working stretch driven"
    else:
        swaths = (
            f"swaths {q.swath_median_m:.2f} / {q.swath_p95_m:.2f} m, "
            if q.swath_median_m is not None and q.swath_p95_m is not None
            else ""
        )
        text = (
            f"cross-track median / 95 %: {swaths}all {q.cross_track_median_m:.2f} / "
            f"{q.cross_track_p95_m:.2f} m (max {q.cross_track_max_m:.2f}); "
            f"outside the field {q.outside_down_s:.1f} s; "
            f"turns {q.turns}, with a loop {q.loops}"
        )
    if v.reboots:
        text += f"; rebooted {len(v.reboots)}x"
    return text


def _hours(seconds: float | None, digits: int) -> str:
    return "?" if seconds is None else f"{seconds / 3600:.{digits}f}"
