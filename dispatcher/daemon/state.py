"""The dispatcher's state, kept in one place: every vehicle and every field.

Knowledge changes only through :meth:`FleetState.apply`, one
:mod:`~dispatcher.daemon.events` event at a time (a vehicle seen or lost, an upload
started or failed, a mission started, an item reached, a reboot); the daemon records every
event, and review replays them from the log with the same method. What the vehicles merely
report (mode, armed, position, clock, the autopilot's texts) is kept by
:meth:`FleetState.on_message`, which also turns a report into the events it implies.
Status JSON, progress lines and the end-of-run summary are read from it. Times are the
vehicle's run clock (seconds) where they come from the vehicle and wall seconds
(``time.monotonic``, or log time on replay) for link liveness.
"""

from __future__ import annotations

import enum
import math
import re
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from dispatcher.daemon import events as ev
from dispatcher.daemon.plausibility import ProgressWitness
from dispatcher.daemon.plausibility import metres as _metres
from dispatcher.link import mavlink as mc
from dispatcher.link.mission_protocol import ROVER_MODE_AUTO
from dispatcher.link.numbering import Numbering
from dispatcher.mission.document import PlanDocument, PlannedItem, PlannedMachine


class Phase(enum.StrEnum):
    WAITING = "waiting"  # no liveliness token yet
    ALIVE = "alive"
    UPLOADING = "uploading"
    STARTING = "starting"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"  # upload or start refused or timed out
    LOST = "lost"  # token gone or heartbeats stopped before the end


ACTIVE = (Phase.UPLOADING, Phase.STARTING, Phase.RUNNING)
READY_STATES = frozenset({mc.MAV_STATE_STANDBY, mc.MAV_STATE_ACTIVE})
"""HEARTBEAT.system_status of an autopilot that has finished booting (ArduPilot reports
UNINIT/BOOT with mode 16 INITIALISING before, and refuses a mission then)."""
CLOCK_RESTART_S = 1.0
"""The vehicle's clock going back by more than this, to less than half of where it was, is
a reboot (a clock restarts from zero; a report that comes late over a radio that delays
and reorders frames is only a little behind)."""
PROBLEM_SEVERITY = mc.MAV_SEVERITY_WARNING
"""STATUSTEXT at this severity or worse (PreArm/Arm refusals are CRITICAL) is kept as the
autopilot's word on a problem."""
STALL_MIN_WALL_S = 5.0
"""Wall seconds a vehicle must also get nowhere for before it counts as stalled."""
STALL_MOVE_M = 3.0
"""Moving this far counts as getting somewhere (a stalled vehicle's position jitters)."""
CURRENT_SETTLE_S = 2.0
"""Wall seconds after a start before MISSION_CURRENT counts as news of the started mission."""
TEXT_WINDOW_S = 10.0
"""How far back (wall seconds) an autopilot's problem text explains a refusal."""
FAILSAFE_TEXT = re.compile(r"^(?:(?:GCS|Radio) Failsafe|Failsafe trigger: .*\b(?:GCS|Radio)\b.*)$")
"""An ArduPilot Rover failsafe for want of its ground station (Rover/failsafe.cpp,
``failsafe_trigger``: "%s Failsafe"; "Failsafe trigger: %s" in later 4.7). The name is that
of the check that happened to cross FS_TIMEOUT, not of the cause: our SITL (4.7.0-dev) said
"Radio Failsafe" for a ground-station failsafe (tests/test_sitl.py, docs/bridge.md)."""
FAILSAFE_CLEARED_TEXT = re.compile(r"^\w+ Failsafe Cleared$")
"""ArduPilot's word that every failsafe is over ("%s Failsafe Cleared": for ours, once a
HEARTBEAT of ours reached it again)."""
EKF_FAILSAFE_TEXT = re.compile(r"^EKF failsafe$", re.IGNORECASE)
"""Rover's failsafe for a position it cannot trust (``failsafe_ekf_event``): its HEARTBEAT
says CRITICAL as in the ground station's, but that one is for the operator to look at."""


@dataclass
class RunClock:
    """A vehicle's own clock (``time_boot_ms``) made continuous across reboots: the run's
    clock. When the vehicle's clock goes back by more than CLOCK_RESTART_S the autopilot
    rebooted; the run's clock carries on from where it was, plus the receive-time gap scaled
    by how fast the vehicle's clock ran against the receive clock before (its speedup).
    The daemon (live) and review (from the log) keep a vehicle's time with this one rule
    (but for :attr:`floor`: after a restart of the dispatcher, review, reading one stream
    of the vehicle's frames, counts the time down as the daemon cannot).

    ``floor``: the latest run time stored of the vehicle (its items reached). Its new
    clock, first hearing the vehicle's, does not start below it: a vehicle that rebooted
    before the crash (its run clock ahead of its own by the reboot) or while the
    dispatcher was down would otherwise have its times after the restart behind the stored
    ones (a field finished before it started, a stall unseen until the clock caught up)."""

    now: float | None = None  # the run's clock, latest (s)
    floor: float = 0.0
    _offset: float = 0.0
    _raw_last: float | None = None
    _first: tuple[float, float] | None = None  # (run clock, receive time) when first heard
    _last_wall: float = 0.0

    def update(self, raw_s: float, wall_s: float) -> tuple[float, bool]:
        """The run time of a report at ``raw_s`` on the vehicle's clock, received at
        ``wall_s``; and whether the vehicle rebooted before it."""
        rebooted = False
        if self._raw_last is None and raw_s + self._offset < self.floor:
            self._offset = self.floor - raw_s  # goes on from the time stored
        if (
            self._raw_last is not None
            and raw_s < self._raw_last
            and not (raw_s < self._raw_last - CLOCK_RESTART_S and raw_s < 0.5 * self._raw_last)
        ):
            # A late report: its time, without moving the clock back.
            t = raw_s + self._offset
            if self.now is None or t > self.now:
                self.now = t
            return t, False
        if (
            self._raw_last is not None
            and self.now is not None
            and raw_s < self._raw_last - CLOCK_RESTART_S
        ):
            self._offset = self.now - raw_s + max(wall_s - self._last_wall, 0.0) * self.rate
            rebooted = True
        self._raw_last = raw_s
        t = raw_s + self._offset
        self.now = t if self.now is None else max(self.now, t)
        if self._first is None:
            self._first = (t, wall_s)
        self._last_wall = wall_s
        return t, rebooted

    @property
    def rate_known(self) -> bool:
        """Heard for more than a second: :attr:`rate` is measured, not assumed."""
        return (
            self._first is not None
            and self.now is not None
            and self._last_wall > self._first[1] + 1.0
            and self.now > self._first[0]
        )

    @property
    def rate(self) -> float:
        """How fast the vehicle's clock runs against the receive clock (its speedup; 1 for
        a real vehicle), since it was first heard; 1 until a second has passed."""
        if self.rate_known:
            assert self._first is not None and self.now is not None
            return (self.now - self._first[0]) / (self._last_wall - self._first[1])
        return 1.0


JITTER_M = 0.5
"""Positions closer than this are GPS noise, not driving."""
STILL_SPEED_MS = 0.1
"""Below this ground speed a vehicle stands still."""


@dataclass
class SetOff:
    """When a vehicle set off: its first position JITTER_M or more from where it
    first stood, taken back along that first leg at the speed it reported there (the road
    speed, or the last time it stood, without one). Every time of a run is measured from
    here; the daemon (live, from the first position it hears) and review (from the log)
    keep it with this one rule."""

    road_speed_ms: float | None = None
    at_s: float | None = None  # the vehicle's clock when it set off, once it did
    _origin: tuple[float, float] | None = None
    _still: tuple[float, float, float] | None = None  # (t, lat, lon): the last stood

    @property
    def heard(self) -> bool:
        """A position of the vehicle was given."""
        return self._origin is not None

    def update(self, t: float, lat: float, lon: float, speed_ms: float | None) -> float | None:
        """A position fix at ``t`` on the vehicle's clock; the set-off time once known."""
        if self.at_s is not None:
            return self.at_s
        if self._origin is None:
            self._origin = (lat, lon)
        if _metres(self._origin, (lat, lon)) < JITTER_M:
            self._still = (t, lat, lon)
            return None
        if self._still is None:
            self.at_s = t
            return t
        still_t, still_lat, still_lon = self._still
        speed = speed_ms if speed_ms is not None and speed_ms >= STILL_SPEED_MS else None
        speed = speed if speed is not None else self.road_speed_ms
        if speed is None or speed <= 0:
            self.at_s = still_t
        else:
            self.at_s = max(still_t, t - _metres((still_lat, still_lon), (lat, lon)) / speed)
        return self.at_s


GONE = (Phase.LOST, Phase.FAILED, Phase.WAITING)
"""Phases of a vehicle that gets no work in a re-plan (and is not waited for)."""


@dataclass
class VehicleState:
    id: str
    system_id: int
    items: tuple[PlannedItem, ...]  # the mission as planned (plan document)
    planned_s: list[float]  # simulated seconds from the start to reaching each item
    phase: Phase = Phase.WAITING
    reached: int = 0  # highest item seq reached
    current: int = 0
    sim_time_s: float = 0.0
    finished_s: float | None = None  # simulated time the last item was reached
    finished_at_next_fix: bool = False
    # Its clock at its last few positions: a report of the last item accepted late (once
    # its track bore it out) still finishes at the first position after the report.
    fix_times_s: deque[float] = field(default_factory=lambda: deque(maxlen=16))
    lat: float | None = None
    lon: float | None = None
    # Its clock (sim_time_s) at the last position heard; -inf from a reboot on, until it
    # says where it is again.
    position_s: float = -math.inf
    heading_deg: float | None = None  # course over ground, from GLOBAL_POSITION_INT.hdg
    # When it set off, from the positions heard since its mission's start (not known to a
    # dispatcher resumed after the vehicle's first item: None).
    set_off: SetOff = field(default_factory=SetOff)
    mode: int | None = None
    armed: bool = False
    last_seen: float | None = None  # wall clock of the last message
    lost_at: float | None = None
    phase_before_lost: Phase | None = None  # where to go back to when the link returns
    off_auto_since: float | None = None  # wall clock since a running vehicle left AUTO/armed
    # Out of AUTO or disarmed while its clock ran on (reported since), not a reboot's doing.
    stopped_on_clock: bool = False
    # The operator took it out of AUTO (no failsafe said so): left alone, never armed or
    # started by us, until it is put back in AUTO (then it drives on; after a reboot
    # meanwhile, from where it was).
    operator_hold: bool = False
    lost_s: float = 0.0  # wall seconds without link, over the run
    upload_attempts: int = 0
    upload_retries: int = 0
    frames_refused: int = 0  # frames on its key not signed with its key (or replayed)
    error: str = ""
    fields_done: list[str] = field(default_factory=list)
    system_status: int | None = None  # HEARTBEAT.system_status (MAV_STATE)
    clock: RunClock = field(default_factory=RunClock)  # the vehicle's clock, continuous
    reboots: int = 0
    # Rebooted while driving, or left to the operator when it was to be started: to be
    # armed again and resumed (the latter once the operator puts it back in AUTO).
    needs_restart: bool = False
    held_for_route: bool = False  # told to HOLD until its new route is on board (events)
    # MISSION_CURRENT.total: the last item the vehicle holds (in the plan's numbers)
    mission_total: int | None = None
    mission_state: int | None = None  # MISSION_CURRENT.mission_state (MISSION_STATE_*)
    acked: bool = False  # the vehicle acknowledged our whole mission (it holds the plan's)
    # How many first items of ``items`` the vehicle holds, or is being given (a window of
    # its mission, dispatcher/mission/window.py); 0 until an upload begins.
    onboard: int = 0
    held_before: int = 0  # what it held before its last top-up (it may wait at its end)
    numbering: Numbering = field(default_factory=Numbering)  # its item numbers vs the plan's
    # Its last MISSION_CURRENT was in the numbers of its last upload (not, renumbered under
    # way, of the item it still drove to from memory in the numbers before).
    current_of_last_upload: bool = True
    started_at: float | None = None  # wall time of the last MissionStarted
    progress_s: float | None = None  # its own time it last got somewhere (moved, reached)
    progress_at: tuple[float, float] | None = None  # (lat, lon) there
    progress_wall: float | None = None  # and the wall time then
    stalled: bool = False  # lost for getting nowhere in AUTO (until it moves)
    retired: bool = False  # left out of the plan after a re-plan (it was lost)
    switch: bool = False  # driving; its new mission (same start) is to be uploaded
    # While switching, until the new mission is on board (SwitchUploaded): the mission
    # still on board, and the last of its items reached beyond the part the new one keeps
    # (a vehicle that drove past it).
    old_items: tuple[PlannedItem, ...] | None = None
    old_reached: int = 0
    route_from: int = 1  # the first item of its current route (after a re-plan: the new part)
    active_seen: bool = False  # MISSION_CURRENT said "active" since then
    # It reported reaching an item of the mission being started (one from the start item
    # on) since the start was asked for: driving it, though no "active" came in time.
    start_from: int = 0
    moved_since_start: bool = False
    resuming: bool = False  # the dispatcher restarted: to be asked where it is first
    lost_before_restart: bool = False  # lost when the dispatcher stopped: given less time
    texts: deque[tuple[float, int, str]] = field(default_factory=lambda: deque(maxlen=32))
    critical_at: float | None = None  # wall time of its last HEARTBEAT saying CRITICAL
    witness: ProgressWitness = field(default_factory=ProgressWitness)  # its track vs claims
    alarms: int = 0  # progress doubted, commands on its key the dispatcher did not send
    verify_mission: bool = False  # a foreign command: read its mission back, restore it

    @property
    def ready(self) -> bool:
        """The autopilot has booted: a mission may be uploaded and started."""
        return self.system_status in READY_STATES

    @property
    def where(self) -> tuple[float, float] | None:
        """Where it is (lat, lon), as heard since its autopilot last rebooted; None if not
        heard since (before, where it stood then: a simulator starts again in its garage,
        a tractor may have been towed)."""
        if self.lat is None or self.lon is None or self.position_s == -math.inf:
            return None
        return self.lat, self.lon

    @property
    def driving(self) -> bool:
        """Armed in AUTO: the autopilot is driving a mission."""
        return self.mode == ROVER_MODE_AUTO and self.armed

    @property
    def runs_mission(self) -> bool:
        """Armed in AUTO, its mission running (not stopped): it drives it."""
        return self.driving and not self.mission_stopped

    @property
    def mission_stopped(self) -> bool:
        """Its autopilot says its mission is not running (MISSION_CURRENT.mission_state):
        complete, or not started (an item set current on a mission that had completed), or
        paused. In AUTO and armed it then stands still until it is started again: setting
        the current item alone does not move it (``AP_Mission::set_current_cmd``)."""
        return self.mission_state in (
            mc.MISSION_STATE_COMPLETE,
            mc.MISSION_STATE_NOT_STARTED,
            mc.MISSION_STATE_PAUSED,
        )

    @property
    def go_on_item(self) -> int:
        """Where a stopped mission goes on: after the last item reached, or after the item
        its autopilot says it completed its mission at when that is further (the reports of
        the last items reached may be lost; MISSION_CURRENT is sent every second)."""
        item = self.resume_item
        if self.mission_state == mc.MISSION_STATE_COMPLETE:
            item = max(item, min(self.current + 1, len(self.items) - 1))
        return item

    @property
    def held(self) -> int:
        """How many first items of its mission the vehicle holds (all until an upload says)."""
        return self.onboard or len(self.items)

    @property
    def at_window_end(self) -> bool:
        """It reached the last item of a window of its mission: it stands there until it
        is given more (the daemon tops it up, then starts it again). Also while the next
        window is on its way: at the end of the one it held before (not beyond)."""
        if self.held < len(self.items) and self.reached >= self.held - 1:
            return True
        if (
            self.held_before > 0
            and self.reached == self.held_before - 1
            and self.current < self.held_before
        ):
            # Not once its autopilot says it heads for the first new item (it holds it):
            # one that gets nowhere then is stuck on the way, not waiting.
            return True
        # Its autopilot says its mission is complete at the last item of what it holds:
        # the report of that item was lost, or doubted (a demo at 2367x through a 10 %-loss
        # radio: positions too far apart to witness it), and it was taken for stalled.
        last = self.mission_total  # the last item it holds, as it says
        if self.mission_state == mc.MISSION_STATE_COMPLETE and not self.current_of_last_upload:
            return True  # renumbered under way, stopped at the item it drove to from memory
        if (
            last is None
            or last >= len(self.items) - 1
            or self.mission_state != mc.MISSION_STATE_COMPLETE
        ):
            return False
        # Complete at the end of the window it held before, the next one on board: it says
        # so at that item, with the longer total (ArduPilot; FleetState._progress_of_current).
        end = min(last, self.held_before - 1) if self.held_before else last
        return self.current >= end

    @property
    def resume_item(self) -> int:
        """Where the mission goes on: the item after the last one reached (never item 0)."""
        return min(max(self.reached + 1, 1), len(self.items) - 1)

    def problems(self, since: float) -> list[str]:
        """The autopilot's problem texts (STATUSTEXT, WARNING or worse) since ``since``,
        oldest first, each once."""
        out: list[str] = []
        for t, severity, text in self.texts:
            if t >= since and severity <= PROBLEM_SEVERITY and text not in out:
                out.append(text)
        return out

    def failsafe(self, since: float, held_since: float) -> tuple[float, str, bool] | None:
        """The autopilot's last failsafe for want of its ground station: when, what said
        so, and whether it said the failsafe is over since. Said by its text since ``since``
        (wall), or (the text lost on the radio) by a HEARTBEAT saying CRITICAL since
        ``held_since`` (out of AUTO), as Rover says for exactly its radio, ground-station
        and EKF failsafes, or by the text saying it is over since ``held_since``; over when
        the text says so (when: then) or a later HEARTBEAT is STANDBY or ACTIVE again. None
        after an EKF failsafe."""
        found: tuple[float, str, bool] | None = None
        for t, _, text in self.texts:
            if t < since:
                continue
            if EKF_FAILSAFE_TEXT.match(text):
                return None
            if FAILSAFE_TEXT.match(text):
                found = (t, text, False)
            elif FAILSAFE_CLEARED_TEXT.match(text):
                if found is not None:  # when: its end (each failsafe once, its end with it)
                    found = (t, found[1], True)
                elif t >= held_since:
                    # Its start not heard (our session down meanwhile: a dispatcher frozen
                    # for 20 s heard neither text nor CRITICAL), its end after it left AUTO:
                    # a failsafe held it, and is over.
                    found = (t, text, True)
        if self.critical_at is None or self.critical_at < held_since:
            return found
        over = self.system_status in READY_STATES  # a HEARTBEAT after the critical one
        if found is None:
            return (self.critical_at, "HEARTBEAT system_status CRITICAL", over)
        return (found[0], found[1], found[2] or over)

    @property
    def held_by_failsafe(self) -> str | None:
        """What says a failsafe for want of its ground station holds this vehicle out of
        AUTO (:meth:`failsafe`), or None: to be started again once it hears us, not given up."""
        if self.off_auto_since is None:
            return None
        found = self.failsafe(self.off_auto_since - TEXT_WINDOW_S, self.off_auto_since)
        return None if found is None else found[1]

    def explain(self, reason: str, since: float) -> str:
        """``reason`` with what the autopilot said about it since ``since``."""
        said = self.problems(since)
        return f"{reason} (autopilot: {'; '.join(said)})" if said else reason

    @property
    def share_done(self) -> float:
        total = self.planned_s[-1] if self.planned_s else 0.0
        return 1.0 if total <= 0 else min(self.planned_s[self.reached] / total, 1.0)

    @property
    def eta_s(self) -> float:
        """Simulated seconds of planned work left."""
        return (
            max(self.planned_s[-1] - self.planned_s[self.reached], 0.0) if self.planned_s else 0.0
        )

    @property
    def current_field(self) -> str | None:
        return self.items[min(max(self.current, self.reached), len(self.items) - 1)].field_id


@dataclass
class FieldState:
    id: str
    vehicle: str
    status: str = "pending"  # pending, working, done
    # Times on the clock of the vehicle that reached them: the start on ``started_by``'s
    # (the first vehicle to begin the field: a field handed over after a loss keeps its
    # first start), the finish on ``vehicle``'s.
    started_s: float | None = None
    finished_s: float | None = None
    started_by: str | None = None
    swaths_done: int = 0
    # Segments (swaths and headland ring edges) of the field's layout, and how many times
    # each was worked (its end reached, implement down, by any vehicle): a segment worked
    # twice or never shows here, through any number of re-plans (PlannedItem.segment).
    segments: int = 0
    passes: dict[int, int] = field(default_factory=dict)
    # (working width, turning radius) of the layout the segments number: a re-plan that
    # gives the field to a machine of another width or radius lays it out anew.
    layout: tuple[float, float] | None = None
    # Each time it was laid out anew with some of it worked: who began it, and how many of
    # the old layout's segments had been worked (to be worked again in the new one).
    relaid: list[tuple[str, int]] = field(default_factory=list)

    @property
    def worked_twice(self) -> list[int]:
        return sorted(k for k, n in self.passes.items() if n > 1)

    @property
    def never_worked(self) -> list[int]:
        return [k for k in range(self.segments) if k not in self.passes]


class FleetState:
    def __init__(self, document: PlanDocument) -> None:
        self.plan_id = document.plan_id
        self.vehicles: dict[str, VehicleState] = {}
        self.fields: dict[str, FieldState] = {}
        for m in document.machines:
            road_ms = m.param("road_speed_kmh") / 3.6
            self.vehicles[m.id] = VehicleState(
                id=m.id,
                system_id=m.system_id,
                items=m.items,
                planned_s=m.planned_times() or [],
                set_off=SetOff(road_ms if road_ms > 0 else None),
            )
            for fid in m.fields:
                self.fields[fid] = FieldState(fid, m.id)
        self._count_segments(document)
        self.by_system = {v.system_id: v.id for v in self.vehicles.values()}
        # Alarms, oldest first: (wall time, vehicle, what): progress doubted, foreign commands.
        self.alarms: list[tuple[float, str, str]] = []
        # When the last event but a Resumed happened, on the events' clock: a restart's
        # Resumed is applied on the daemon's clock after events replayed on the store's
        # wall clock, so only this is on the clock of their times.
        self.last_event_at: float | None = None
        # Wall seconds it takes to get missions on board (the first uploads, and the
        # slowest vehicle of any re-plan since): how long a re-plan's kept part must last.
        self.upload_s = 0.0

    # --- knowledge: events ----------------------------------------------------------------
    def apply(self, event: ev.Event, now: float) -> None:
        """Change the state by one event; ``now`` is the wall (or log) time it happened."""
        before = self.last_event_at
        if not isinstance(event, ev.Resumed):  # (one for each vehicle, in a row)
            self.last_event_at = now
        if isinstance(event, ev.PlanReplaced):
            self._replace_plan(PlanDocument.from_json(event.document))
            return
        v = self.vehicles[event.vehicle]
        match event:
            case ev.VehicleSeen():
                self._back(v, now)
                if v.phase is Phase.WAITING:
                    v.phase = Phase.ALIVE
                v.last_seen = now
            case ev.VehicleLost(why=why):
                self._lost(v, why, now)
            case ev.VehicleStalled(seconds=seconds):
                self._lost(v, f"stalled: in AUTO and not getting anywhere for {seconds:.0f} s", now)
                v.stalled = True
            case ev.UploadStarted(items=items):
                v.phase = Phase.UPLOADING
                v.upload_attempts += 1
                v.acked = False
                v.resuming = False
                v.onboard, v.held_before = items or len(v.items), 0
            case ev.MissionNumbered(base=base, count=count):
                if base != v.numbering.base:
                    v.current_of_last_upload = False  # until a MISSION_CURRENT in the new numbers
                v.numbering = v.numbering.uploaded(base, count)
            case ev.WindowExtended(items=items):
                v.held_before, v.onboard = v.held, items
            case ev.UploadAcked():
                if v.switch:  # it may have stood still meanwhile (stalled_for)
                    v.progress_s, v.progress_wall = v.sim_time_s, now
                v.acked = True
                v.switch = False
                v.old_items = None
            case ev.SwitchUploaded():
                v.old_items = None
                # Its MISSION_CURRENT still counts in the old mission until it is sent on
                # (a vehicle past the kept part): news of this one only once it says it is
                # active again, CURRENT_SETTLE_S from now.
                v.started_at, v.active_seen = now, False
            case ev.RouteJoined(item=item):
                v.reached = min(max(item - 1, 0), len(v.items) - 1)
            case ev.HeldForRoute():
                v.held_for_route = True
                v.off_auto_since = None
            case ev.UploadFailed(reason=reason, final=final):
                v.acked = False
                if final:
                    v.phase = Phase.FAILED
                    v.error = reason
            case ev.StartRequested(item=item):
                v.phase = Phase.STARTING
                v.operator_hold = False
                v.resuming = False
                v.start_from, v.moved_since_start = item, False
            case ev.MissionStarted():
                v.phase = Phase.RUNNING
                v.held_for_route = False
                v.resuming = False
                v.error = ""
                # A lossy radio: its ACK for AUTO can come after it drove its last items
                # and reported its mission complete (never "active" again): its reports of
                # items since the start say it is driving this mission.
                v.started_at, v.active_seen = now, v.moved_since_start
                v.progress_s, v.progress_wall = v.sim_time_s, now
            case ev.Resumed():
                self._resumed(v, now, before)
            case ev.StartFailed(reason=reason):
                v.phase = Phase.FAILED
                v.error = reason
            case ev.AnsweringAgain():
                if v.phase is Phase.FAILED:
                    v.phase, v.error = Phase.ALIVE, ""
                    v.upload_attempts = 0
                    v.needs_restart = False  # (rebooted meanwhile): a new mission's start
            case ev.StartRefused(reason=reason):
                v.error = reason
            case ev.LeftAuto(reason=reason, by_operator=by_operator):
                v.error = reason
                v.operator_hold = v.operator_hold or by_operator
            case ev.BackInAuto():
                v.error = ""
                v.operator_hold = False
            case ev.ItemReached(seq=seq, clock_s=clock_s):
                self._item_reached(v, seq, clock_s, now)
            case ev.ProgressDoubted() | ev.ForeignCommand():
                v.alarms += 1
                self.alarms.append((now, v.id, event.text()))
                if isinstance(event, ev.ForeignCommand):
                    v.verify_mission = v.phase is not Phase.FAILED and not v.retired
            case ev.Rebooted():
                v.reboots += 1
                v.system_status = None  # booting: not ready until a heartbeat says so
                v.mission_total = None  # what it holds now is to be heard again
                if v.phase in (Phase.RUNNING, Phase.STARTING) or (
                    v.phase is Phase.LOST and v.phase_before_lost in (Phase.RUNNING, Phase.STARTING)
                ):
                    # To go on from where it was: at once if it was driving, once put back
                    # in AUTO if the operator had stopped it (the daemon tells which).
                    v.needs_restart = True

    def _replace_plan(self, doc: PlanDocument) -> None:
        """The rest of the work planned again (events.PlanReplaced). A vehicle driving its
        mission keeps its progress (its new mission starts with the old one up to where it
        is) and is to receive the new one (``switch``), unless its mission is unchanged;
        one not driving starts the new one from its first item; one not in the plan (lost)
        gets no more work."""
        self.plan_id = doc.plan_id
        planned = {m.id: m for m in doc.machines}
        for v in self.vehicles.values():
            m = planned.get(v.id)
            if m is None:
                # (one not heard since the dispatcher's restart has nothing left to be
                # asked about: it rejoins as any retired vehicle does, when heard)
                v.retired, v.resuming = True, False
                continue
            if m.items == v.items and not v.retired:
                self._own_fields(m)
                continue  # its mission goes on as it is (or stays done): nothing to upload
            common = _common_prefix(v.items, m.items)
            if v.phase is Phase.DONE and not v.retired and common == len(v.items):
                # It finished while the re-plan ran, which sends it on after its mission:
                # the new mission is uploaded and started after what it did (never again
                # from item 1: it would work its fields twice).
                v.items, v.planned_s = m.items, m.planned_times() or []
                v.phase, v.acked, v.upload_attempts = Phase.ALIVE, False, 0
                v.onboard = v.held_before = 0
                v.finished_s = None
                self._own_fields(m)
                continue
            if (
                v.phase is Phase.RUNNING
                and not v.retired
                and not v.switch
                and v.onboard
                and common >= v.onboard
            ):
                # What it holds is unchanged (the new route begins after its window): it
                # drives on, and its next top-up brings the new route.
                v.items = m.items
                v.planned_s = m.planned_times() or []
                self._own_fields(m)
                continue
            # Driving its mission, which the new one begins with: it carries on. When it
            # went past that part meanwhile, the items it reached beyond are the new
            # route's now: it is sent back to the route's first item (the daemon). One left
            # out and back (held where it is) gets a new mission planned from there, whose
            # first items may equal its old one's by chance: not a switch.
            keeps = v.phase is Phase.RUNNING and common > 1 and not v.retired
            if keeps and v.old_items is None:
                v.old_items, v.old_reached = v.items, v.reached
            if keeps and v.reached >= common:
                v.reached = common - 1
            v.route_from = common if keeps else 1
            v.items = m.items
            v.planned_s = m.planned_times() or []
            v.acked = False
            v.retired = False
            if keeps:
                v.switch = True
            else:
                v.switch = False
                v.reached = v.current = 0
                v.onboard = v.held_before = 0  # its upload says how much of it it holds
                v.finished_s = None
                if v.phase in (
                    Phase.DONE,
                    Phase.ALIVE,
                    Phase.UPLOADING,
                    Phase.STARTING,
                    Phase.RUNNING,
                ):
                    v.phase = Phase.ALIVE  # the new mission is uploaded and started
                v.upload_attempts = 0
            self._own_fields(m)
        self._count_segments(doc)

    def _own_fields(self, m: PlannedMachine) -> None:
        for fid in m.fields:
            f = self.fields.setdefault(fid, FieldState(fid, m.id))
            if f.status != "done":
                f.vehicle = m.id

    def _count_segments(self, doc: PlanDocument) -> None:
        """Each field's number of segments, from the plan that lays it out; a field already
        worked keeps the count of the layout it is worked in, unless the plan lays it out
        anew (a machine of another width or turning radius works it: planned whole again,
        its segments numbered anew, what was worked of the old ones forgotten)."""
        ends: dict[str, set[int]] = {}
        layouts: dict[str, tuple[float, float]] = {}
        for m in doc.machines:
            layout = (m.working_width_m, m.param("min_turn_radius_m"))
            for item in m.items:
                if item.role == "swath_end" and item.field_id and item.segment is not None:
                    ends.setdefault(item.field_id, set()).add(item.segment)
                    layouts[item.field_id] = layout
        for fid, segments in ends.items():
            f = self.fields.get(fid)
            if f is None:
                continue
            anew = f.layout is not None and layouts[fid] != f.layout
            if anew:
                if f.passes:  # (begun by started_by; the plan has given it on by now)
                    f.relaid.append((f.started_by or f.vehicle, len(f.passes)))
                f.passes = {}
            if anew or not f.passes:
                f.segments = max(segments) + 1
                f.layout = layouts[fid]

    def _lost(self, v: VehicleState, why: str, now: float) -> None:
        if v.phase in (Phase.DONE, Phase.FAILED, Phase.LOST):
            return
        v.phase_before_lost = v.phase
        v.phase = Phase.LOST
        v.lost_at = now
        v.error = why

    def stalled_for(self, v: VehicleState, limit_s: float, now: float) -> float | None:
        """How long (its own seconds) a vehicle driving its mission has got nowhere, when
        that is longer than ``limit_s`` and than STALL_MIN_WALL_S of wall time (a simulator
        at a high speedup passes a minute between two reports); else None."""
        if v.phase is not Phase.RUNNING or not v.driving or v.progress_s is None:
            return None
        if v.switch or v.at_window_end:
            # Its new mission on its way: an autopilot truncates its mission to the new
            # count at MISSION_COUNT, so one that drove past the new mission's length
            # stands still, its mission complete, until it is sent on (the daemon); its
            # stall clock starts again once the new mission is on board. At the end of its
            # window, it waits for more of its mission (the daemon tops it up).
            return None
        idle = v.sim_time_s - v.progress_s
        if v.progress_wall is None or now - v.progress_wall < STALL_MIN_WALL_S:
            return None
        return idle if idle > limit_s else None

    def _resumed(self, v: VehicleState, now: float, stopped: float | None) -> None:
        """The dispatcher restarted (at ``now``), after its last event before (``stopped``,
        on the clock of the events replayed): what it knew of the link is gone; what was
        reached stays. A vehicle not done, and in the plan, is heard again and asked where it
        is (the daemon). One lost when the dispatcher stopped has its time lost counted up
        to that last event (was: not at all), and one that stays lost (left out) on from
        the restart until heard again. Its clock, new, goes on from the latest time stored
        of it (:attr:`RunClock.floor`)."""
        v.sim_time_s = max(v.sim_time_s, v.clock.floor)
        if v.phase is Phase.DONE:
            return
        v.lost_before_restart = v.phase is Phase.LOST and not v.retired
        if v.lost_at is not None and stopped is not None:
            v.lost_s += max(stopped - v.lost_at, 0.0)
        # One lost and left out by a re-plan stays lost, its reason kept, until heard again
        # (shown as waiting, it had a field and hours of work it no longer has).
        keep_lost = v.phase is Phase.LOST and v.retired
        if not keep_lost:
            v.phase = Phase.WAITING
            v.error = ""
        # One left out of the plan holds no mission of ours to go on with: heard again, it
        # is held and a re-plan may give it work, as without a restart (the daemon).
        v.resuming = not v.retired
        v.upload_attempts = 0
        v.needs_restart = False
        v.last_seen = v.off_auto_since = None
        v.lost_at = now if keep_lost else None
        v.phase_before_lost = None
        v.mode = v.system_status = v.mission_total = v.mission_state = v.critical_at = None
        v.armed = False

    def _back(self, v: VehicleState, now: float) -> None:
        """The link to a lost vehicle works again: resume where it was."""
        if v.phase is not Phase.LOST:
            return
        if v.lost_at is not None:
            v.lost_s += now - v.lost_at
        v.lost_at = None
        v.phase = v.phase_before_lost or Phase.ALIVE
        if v.phase is Phase.WAITING:
            v.phase = Phase.ALIVE
        v.phase_before_lost = None
        v.error = ""
        v.stalled = False
        v.progress_s, v.progress_wall = v.sim_time_s, now

    def _item_reached(self, v: VehicleState, seq: int, clock_s: float, now: float) -> None:
        if not 0 <= seq < len(v.items):
            return
        if v.phase not in (Phase.RUNNING, Phase.STARTING, Phase.LOST) and not v.resuming:
            return
        v.progress_s = max(v.progress_s or 0.0, clock_s)
        v.clock.floor = max(v.clock.floor, clock_s)  # kept: replayed events reset progress_s
        v.progress_wall = now
        if v.phase is Phase.STARTING and seq >= v.start_from:
            v.moved_since_start = True
        old = v.old_items
        if v.switch and old is not None and seq >= v.route_from:
            # Past the kept part, on the mission still on board: its items, not the new.
            # The end of the kept part first (reports lost: it went on from there).
            for s in range(v.reached + 1, v.route_from):
                self._item_done(v, s, clock_s, reported=False)
            v.reached = max(v.reached, v.route_from - 1)
            v.old_reached = max(v.old_reached, v.route_from - 1)
            for s in range(max(v.old_reached + 1, v.route_from), min(seq + 1, len(old))):
                self._item_done(v, s, clock_s, reported=s == seq, item=old[s])
            v.old_reached = max(v.old_reached, seq)
            return
        for s in range(v.reached + 1, seq + 1):  # items skipped in between count as done
            self._item_done(v, s, clock_s, reported=s == seq)
        v.reached = max(v.reached, seq)
        if v.reached == len(v.items) - 1:
            v.phase = Phase.DONE
            v.resuming = False
            # The vehicle reports its position right after the last waypoint: that is when
            # it finished (the report's own time is the position before it).
            after = next((t for t in v.fix_times_s if t > clock_s), None)
            v.finished_s = clock_s if after is None else after
            v.finished_at_next_fix = after is None

    def _item_done(
        self,
        v: VehicleState,
        seq: int,
        clock_s: float,
        reported: bool,
        item: PlannedItem | None = None,
    ) -> None:
        """Item ``seq`` (of ``v.items``, or ``item``) is done; ``reported`` when the
        vehicle said so itself (its time is then exact), not when it is inferred from a
        later item."""
        item = item if item is not None else v.items[seq]
        if item.field_id is None or item.field_id not in self.fields:
            return
        f = self.fields[item.field_id]
        if item.role == "swath_end" and item.segment is not None:
            f.passes[item.segment] = f.passes.get(item.segment, 0) + 1
        if f.vehicle != v.id:  # given to another vehicle by a re-plan
            return
        if item.role == "transit" and f.status == "pending":
            # At the field's entry. ArduPilot does not report DO_SET_SERVO/RELAY as
            # reached, so this is the start unless the implement-down item says better.
            f.status = "working"
            f.started_s, f.started_by = clock_s, v.id
        elif item.role == "implement_down" and f.status != "done":
            f.status = "working"
            # Its time is the start, better than the entry's, unless some of the field was
            # worked before (a re-plan's rest of it: the start stays the first visit's).
            if (reported and not f.passes and not f.relaid) or f.started_s is None:
                f.started_s, f.started_by = clock_s, v.id
        elif item.role == "swath_end":
            f.swaths_done += 1
        elif item.role == "implement_up" and f.status != "done":
            f.status = "done"
            f.finished_s = clock_s
            if f.started_s is None:
                f.started_s, f.started_by = clock_s, v.id
            v.fields_done.append(f.id)

    # --- reports: what the vehicle says, and the events it implies ------------------------
    def on_message(self, vid: str, msg: mc.MAVLinkMessage, now: float) -> list[ev.Event]:
        """Keep what a vehicle reports; return the events it implies (to be applied)."""
        v = self.vehicles[vid]
        out: list[ev.Event] = []
        if v.phase in (Phase.LOST, Phase.WAITING) and not v.stalled:
            out.append(ev.VehicleSeen(vid))
        v.last_seen = now
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            v.mode = int(msg.custom_mode)
            v.armed = bool(msg.base_mode & mc.MAV_MODE_FLAG_SAFETY_ARMED)
            status = int(msg.system_status)
            if v.ready and status in (mc.MAV_STATE_UNINIT, mc.MAV_STATE_BOOT):
                out.append(ev.Rebooted(vid))  # booting again (before its clock tells)
                v.position_s = -math.inf  # where it is is to be heard again
            else:
                v.system_status = status
                if status == mc.MAV_STATE_CRITICAL:
                    v.critical_at = now
            was_off = v.off_auto_since is not None
            if (v.needs_restart and not v.operator_hold) or v.held_for_route:
                v.off_auto_since = None  # expected: the daemon starts it again
            elif v.phase is Phase.RUNNING and not v.driving:
                if v.off_auto_since is None:
                    v.off_auto_since = now  # a failsafe, the operator, a reboot ...
            else:
                v.off_auto_since = None
            if v.driving:
                v.stopped_on_clock = False
                if was_off and v.off_auto_since is None:  # its time out of AUTO: no stall
                    v.progress_s, v.progress_wall = v.sim_time_s, now
        elif kind == "GLOBAL_POSITION_INT":
            if not mc.has_fix(msg.lat / 1e7, msg.lon / 1e7):
                # No position yet (an autopilot without a GPS fix reports 0, 0): its clock
                # still counts, nothing else.
                return out + self._clock(v, msg.time_boot_ms / 1000.0, now)
            v.lat, v.lon = msg.lat / 1e7, msg.lon / 1e7
            course = mc.course_deg(msg)
            if course is not None:  # (north is 0: not "unknown")
                v.heading_deg = course
            out += self._clock(v, msg.time_boot_ms / 1000.0, now)
            v.position_s = v.sim_time_s
            v.fix_times_s.append(v.sim_time_s)
            if v.reached == 0 or v.set_off.heard:  # (resumed past its start: not known)
                v.set_off.update(v.sim_time_s, v.lat, v.lon, math.hypot(msg.vx, msg.vy) / 100.0)
            if v.progress_at is None or _metres(v.progress_at, (v.lat, v.lon)) >= STALL_MOVE_M:
                if v.stalled:
                    out.append(ev.VehicleSeen(vid))  # it moves again
                v.progress_at, v.progress_s = (v.lat, v.lon), v.sim_time_s
                v.progress_wall = now
            if v.phase is Phase.DONE and v.finished_at_next_fix:
                # The vehicle reports its position right after the last waypoint.
                v.finished_s = v.sim_time_s
                v.finished_at_next_fix = False
            self._follow(v)
            out += v.witness.observe(vid, v.lat, v.lon, now, v.sim_time_s)
        elif kind == "SYSTEM_TIME":
            if msg.time_boot_ms > 0:
                out += self._clock(v, msg.time_boot_ms / 1000.0, now)
        elif kind == "MISSION_CURRENT":
            reported_total = getattr(msg, "total", None)
            reported_total = reported_total if isinstance(reported_total, int) else None
            before = v.numbering
            seq, total, v.numbering = before.report(int(msg.seq), reported_total)
            v.current = seq
            v.current_of_last_upload = before.in_last(int(msg.seq), reported_total)
            if total is not None:
                v.mission_total = total
            state = getattr(msg, "mission_state", None)
            if isinstance(state, int) and state != mc.MISSION_STATE_UNKNOWN:
                v.mission_state = state
            out += self._progress_of_current(v, now)
        elif kind == "STATUSTEXT":
            text = mc.statustext(msg)
            v.texts.append((now, int(msg.severity), text))
        elif kind == "MISSION_ITEM_REACHED":
            seq, _, v.numbering = v.numbering.report(int(msg.seq))
            out += self._claim(v, seq, False, "MISSION_ITEM_REACHED", now)
        return out

    def _follow(self, v: VehicleState) -> None:
        """Point the vehicle's witness at the mission on board (the old one while a new one
        is on its way) and the last item taken as reached."""
        if v.switch and v.old_items is not None:
            v.witness.follow(v.old_items, max(v.reached, v.old_reached))
        else:
            v.witness.follow(v.items, v.reached)

    def _claim(
        self, v: VehicleState, seq: int, caught_up: bool, source: str, now: float
    ) -> list[ev.Event]:
        """The vehicle says it reached ``seq``: counted once its track bears it out
        (:mod:`dispatcher.daemon.plausibility`)."""
        self._follow(v)
        clock_s = v.sim_time_s if v.clock.now is not None else None  # None: not heard yet
        return v.witness.claim(v.id, seq, clock_s, caught_up, source, now)

    def _progress_of_current(self, v: VehicleState, now: float) -> list[ev.Event]:
        """What MISSION_CURRENT says of a running mission that MISSION_ITEM_REACHED did not
        (lost on the link): the items before the current one are reached, and the current
        one too once the mission is complete (where it completed). Only once the vehicle
        has said its mission is active, CURRENT_SETTLE_S after the start: a report still on
        its way from before the start (of an earlier mission, complete) says nothing of
        this one. While its next window is on its way, a report of the window it holds
        counts too (both are first items of the same mission): one that reached the end of
        its window, whose MISSION_ITEM_REACHED was lost, is known to wait there, not taken
        for stalled (20 %-loss soak)."""
        windows = (v.held - 1, v.held_before - 1) if v.held_before else (v.held - 1,)
        last = v.mission_total  # the last item of what it holds
        if (
            v.phase is not Phase.RUNNING
            or v.old_items is not None  # the new mission on its way: which one it reports?
            or last is None
            or last not in windows
            or v.started_at is None
            or now - v.started_at < CURRENT_SETTLE_S
        ):
            return []
        if v.mission_state == mc.MISSION_STATE_ACTIVE:
            v.active_seen = True
        # Complete at the last item it holds, past where it was started, CURRENT_SETTLE_S
        # after the start: it drove there, though every report of it on the way was lost
        # (a lossy radio: started at item 24 of 27 behind its AUTO's late ACK, it drove the
        # last three and said "complete", never "active"; the run waited for ever).
        finished = (
            v.mission_state == mc.MISSION_STATE_COMPLETE
            and v.current == last
            and last > v.start_from
        )
        if not v.active_seen and not finished:
            return []
        done = v.current - 1
        if v.mission_state == mc.MISSION_STATE_COMPLETE:
            # Complete at the item it says: the end of what it held, or, renumbered under
            # way, the item it drove to from memory past the new count (link/numbering.py).
            # Not the total: given its next window while it stood there, ArduPilot says
            # complete at the same item with the longer mission's total (Rover 4.7 SITL).
            done = v.current
        if done > v.reached:
            return self._claim(v, done, True, "MISSION_CURRENT", now)
        return []

    def _clock(self, v: VehicleState, clock_s: float, now: float) -> list[ev.Event]:
        """The vehicle's clock; a restart is a reboot, and its time carries on from there."""
        t, rebooted = v.clock.update(clock_s, now)
        v.sim_time_s = max(v.sim_time_s, t)
        if rebooted:
            # Where it is is to be heard again (the position that told of the reboot sets
            # it after this).
            v.position_s = -math.inf
        if not rebooted and v.off_auto_since is not None:
            v.stopped_on_clock = True
        return [ev.Rebooted(v.id)] if rebooted and not v.needs_restart else []

    # --- reading -------------------------------------------------------------------------
    def join_item(self, v: VehicleState, first: int) -> int:
        """Where a vehicle that drove past its kept part goes on in its new mission: after
        the new route's first swaths as far as it worked them meanwhile (from ``first``)."""
        join = first
        for k in range(first, len(v.items)):
            item = v.items[k]
            if item.role != "swath_end" or item.field_id is None or item.segment is None:
                continue
            f = self.fields.get(item.field_id)
            if f is None or not f.passes.get(item.segment):
                break
            join = k + 1
        return min(join, len(v.items) - 1)

    def finished(self, now: float, lost_grace_s: float) -> bool:
        """Nothing more will happen: every vehicle done, failed, or lost for longer than
        ``lost_grace_s`` (a short loss of link is not the end of a vehicle). One out of
        AUTO is waited for, however long that takes: its failsafe's is started again once
        it hears us, the operator's drives on when put back in AUTO."""
        return all(
            v.phase in (Phase.DONE, Phase.FAILED)
            or v.retired
            or (v.phase is Phase.LOST and v.lost_at is not None and now - v.lost_at >= lost_grace_s)
            for v in self.vehicles.values()
        )

    def all_fields_done(self) -> bool:
        return all(f.status == "done" for f in self.fields.values())

    def status_doc(self, now: float | None = None) -> dict[str, Any]:
        """The fleet's status document (docs/link.md). ``now`` (the clock of the events):
        a vehicle lost at that moment has its loss so far in ``lost_s`` (it was counted only
        once it came back: one lost for good, stalled or killed, showed 0)."""

        def lost_s(v: VehicleState) -> float:
            ongoing = now - v.lost_at if now is not None and v.lost_at is not None else 0.0
            return v.lost_s + max(ongoing, 0.0)

        return {
            "plan_id": self.plan_id,
            "vehicles": {
                v.id: {
                    "phase": v.phase.value,
                    "system_id": v.system_id,
                    "mode": v.mode,
                    "armed": v.armed,
                    "reached": v.reached,
                    "items": len(v.items),
                    "items_held": v.held,
                    "current_field": v.current_field,
                    "share_done": round(v.share_done, 4),
                    "eta_s": round(v.eta_s, 1),
                    "set_off_s": v.set_off.at_s,
                    "finished_s": v.finished_s,
                    "sim_time_s": round(v.sim_time_s, 1),
                    "lat": v.lat,
                    "lon": v.lon,
                    "heading_deg": v.heading_deg,
                    "fields_done": v.fields_done,
                    "upload_attempts": v.upload_attempts,
                    "upload_retries": v.upload_retries,
                    "frames_refused": v.frames_refused,
                    "alarms": v.alarms,
                    "lost_s": round(lost_s(v), 3),
                    "stopped_outside_auto": v.off_auto_since is not None,
                    "system_status": v.system_status,
                    "reboots": v.reboots,
                    "autopilot_says": v.problems(-math.inf)[-3:],
                    "error": v.error,
                }
                for v in self.vehicles.values()
            },
            "fields": {
                f.id: {
                    "status": f.status,
                    "vehicle": f.vehicle,
                    "started_s": f.started_s,
                    "started_by": f.started_by,
                    "finished_s": f.finished_s,
                    "swaths_done": f.swaths_done,
                    "segments": f.segments,
                    "worked_twice": f.worked_twice,
                    "relaid": [list(r) for r in f.relaid],
                }
                for f in self.fields.values()
            },
            "alarms": [text for _, _, text in self.alarms[-20:]],
        }


def _common_prefix(old: tuple[PlannedItem, ...], new: tuple[PlannedItem, ...]) -> int:
    """How many first items ``new`` shares with ``old`` (a mission carried on)."""
    same = 0
    for a, b in zip(old, new, strict=False):
        if (a.command, a.x, a.y, a.role) != (b.command, b.x, b.y, b.role):
            break
        same += 1
    return same
