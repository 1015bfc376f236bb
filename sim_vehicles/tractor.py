"""A simulated tractor that answers MAVLink like an ArduPilot Rover autopilot, without I/O.

:class:`SimTractor` is driven by its caller: ``handle`` a message from the ground station,
``advance`` simulated time, ask for ``heartbeat`` and ``telemetry``; each returns the
messages the vehicle sends. Driving is exact in simulated time: legs are straight
geodesics (WGS84) driven at the current speed, and one ``advance`` may pass any number of
waypoints without cutting a corner. Right after a navigation item is reached a
GLOBAL_POSITION_INT at that waypoint follows, so recorded tracks are exact there.

ArduPilot behaviour followed (sources are ArduPilot files):

* Mode numbers (``Rover/mode.h``): MANUAL 0, ACRO 1, STEERING 3, HOLD 4, LOITER 5,
  FOLLOW 6, SIMPLE 7, AUTO 10, RTL 11, SMART_RTL 12, GUIDED 15. Simulated: MANUAL, HOLD,
  LOITER, GUIDED (all standing still: no RC, no guided target), AUTO, RTL. Others fail.
* HEARTBEAT (``Rover/GCS_MAVLink_Rover.cpp``): type GROUND_ROVER, autopilot
  ARDUPILOTMEGA, base_mode CUSTOM_MODE_ENABLED plus GUIDED_ENABLED in AUTO/GUIDED/RTL,
  MANUAL_INPUT_ENABLED in MANUAL, SAFETY_ARMED when armed; custom_mode = mode number;
  system_status CRITICAL in a failsafe, else STANDBY in HOLD, ACTIVE otherwise (that is
  Rover's rule, ``vehicle_system_status``, not "armed"; SITL says CRITICAL in HOLD from the
  ground-station failsafe until the ground station is heard again).
* COMMAND_LONG / COMMAND_INT are answered with COMMAND_ACK(command, result, target = the
  sender) (``GCS_Common.cpp`` ``handle_command_long``):
  ARM_DISARM param1 1 arms, 0 disarms (ACCEPTED also when already so; anything else
  UNSUPPORTED); DO_SET_MODE needs MAV_MODE_FLAG_CUSTOM_MODE_ENABLED in param1 (else
  DENIED) and a mode that can be entered (else FAILED); MISSION_START with a non-zero
  param1/param2 is DENIED, else it is "set mode AUTO" (ACCEPTED or FAILED)
  (``Rover/GCS_MAVLink_Rover.cpp``); NAV_RETURN_TO_LAUNCH is "set mode RTL"; DO_CHANGE_SPEED
  is ACCEPTED in AUTO/RTL/GUIDED, FAILED elsewhere, DENIED for climb/descent speed;
  DO_SET_MISSION_CURRENT (param2 = 1 resets a finished mission) and the deprecated
  MISSION_SET_CURRENT message move the current item. Unknown commands: UNSUPPORTED.
* SET_MODE (the message) is acknowledged with COMMAND_ACK whose command is 11, the
  message id, as ArduPilot does (``GCS_MAVLINK::handle_set_mode``).
* AUTO cannot be entered without a mission beyond home ("No Mission. Can't set AUTO.",
  ``Rover/mode_auto.cpp``); it can be entered disarmed (the vehicle then does not move).
  Entering AUTO keeps the speed the mission last set (SITL 4.7.0-dev: a rover its failsafe
  held and put back in AUTO mid-swath drove on at the mission's 2.22 m/s, not WP_SPEED's
  3.33; tests/test_sitl.py), the cruise speed until one is set, and
  resumes the mission where it stopped (MIS_RESTART = 0, ``AP_Mission::start_or_resume``);
  a completed mission starts again from item 1. Leaving AUTO stops the mission. So a new
  mission uploaded to a vehicle stopped half-way resumes at the old index: send
  DO_SET_MISSION_CURRENT(1, 1) first (or set ``mission_restart``). MISSION_START in AUTO
  changes nothing (the mode is already AUTO).
* Mission execution (``AP_Mission::update``, ``advance_current_nav_cmd``): item 0 (home)
  never runs; the DO items after a navigation item run as soon as that item completes
  (so the implement drops as the tractor sets off along the swath); NAV_WAYPOINT param1 is
  a hold time in seconds. DO_CHANGE_SPEED sets the speed from param2 (m/s);
  DO_SET_SERVO/DO_SET_RELAY set the output that lowers/raises the implement.
* MISSION_ITEM_REACHED: ArduPilot sends it from ``ModeAuto::verify_command_callback``, so
  for navigation items *and* for DO items the vehicle verifies (DO_CHANGE_SPEED), but not
  for DO_SET_SERVO/DO_SET_RELAY (``AP_Mission::verify_command`` completes those without the
  callback). ``RoverParams.report_all_items`` (default on) reports every item, for
  progress; off reproduces ArduPilot.
* MISSION_CURRENT (``GCS_MAVLINK::send_mission_current``): seq = the current navigation
  item, total = items without home, mission_state NO_MISSION (< 2 items) / NOT_STARTED
  (stopped) / ACTIVE / COMPLETE, mission_mode 1 in AUTO. Sent on every change and with
  each heartbeat.
* Mission end (``ModeAuto::exit_mission``): "Mission Complete"; with MIS_DONE_BEHAV = 0
  current Rover stays in AUTO and stops (``start_stop``); Rover 4.0 and earlier switched
  to HOLD. ``RoverParams.mission_done`` picks "stop" (current) or "hold".
* Ground-station failsafe (``Rover::gcs_failsafe_check``, ``failsafe_trigger``), when
  ``RoverParams.gcs_failsafe_s`` is set (FS_GCS_ENABLE = 1, FS_GCS_TIMEOUT, FS_ACTION = 2
  Hold): once a ground station's HEARTBEAT has been heard, an armed vehicle that hears
  nothing from its system id for that long switches to HOLD ("GCS Failsafe"); it stays
  there when the ground station is back ("GCS Failsafe Cleared"), which starts it again.
* Messages addressed to another system or component are ignored.
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass
from typing import Literal

from pyproj import Geod

from dispatcher.config.scenario import Vehicle
from dispatcher.link import mavlink as mc
from sim_vehicles.mission_server import MissionServer, RequestMessage, StoredItem

logger = logging.getLogger(__name__)

_GEOD = Geod(ellps="WGS84")
_MSG_ID_SET_MODE = 11  # COMMAND_ACK.command that ArduPilot uses to acknowledge SET_MODE


class Mode(enum.IntEnum):
    """ArduPilot Rover mode numbers (``Rover/mode.h``)."""

    MANUAL = 0
    ACRO = 1
    STEERING = 3
    HOLD = 4
    LOITER = 5
    FOLLOW = 6
    SIMPLE = 7
    AUTO = 10
    RTL = 11
    SMART_RTL = 12
    GUIDED = 15
    INITIALISING = 16


SIMULATED_MODES = frozenset({Mode.MANUAL, Mode.HOLD, Mode.LOITER, Mode.AUTO, Mode.RTL, Mode.GUIDED})
_AUTOPILOT_MODES = frozenset({Mode.AUTO, Mode.GUIDED, Mode.RTL, Mode.SMART_RTL})
_MANUAL_INPUT_MODES = frozenset({Mode.MANUAL, Mode.ACRO, Mode.STEERING, Mode.SIMPLE})
_SPEED_MODES = frozenset({Mode.AUTO, Mode.RTL, Mode.GUIDED})  # set_desired_speed works

# DO items AP_Mission completes itself, without the vehicle's verify callback, hence
# without MISSION_ITEM_REACHED on a real ArduPilot.
_SILENT_DO = frozenset(
    {
        mc.MAV_CMD_DO_SET_SERVO,
        mc.MAV_CMD_DO_SET_RELAY,
        mc.MAV_CMD_DO_REPEAT_SERVO,
        mc.MAV_CMD_DO_REPEAT_RELAY,
    }
)
_DRIVEN_NAV = frozenset(
    {
        mc.MAV_CMD_NAV_WAYPOINT,
        mc.MAV_CMD_NAV_LOITER_UNLIM,
        mc.MAV_CMD_NAV_LOITER_TIME,
        mc.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    }
)

MissionDone = Literal["stop", "hold"]
Outcome = tuple[int, list[mc.MAVLinkMessage]]  # a MAV_RESULT and the events it caused


class MissionState(enum.Enum):
    """``AP_Mission::mission_state``."""

    STOPPED = "stopped"
    RUNNING = "running"
    COMPLETE = "complete"


@dataclass(frozen=True)
class RoverParams:
    """The autopilot's parameters and version behaviours the simulation depends on."""

    initial_mode: int = Mode.HOLD  # INITIAL_MODE (ArduPilot's default is MANUAL)
    mission_done: MissionDone = "stop"  # see module doc: "stop" = Rover >= 4.1
    mission_restart: bool = False  # MIS_RESTART: restart, not resume, on entering AUTO
    upload_request: RequestMessage = "MISSION_REQUEST"  # what ArduPilot asks items with
    report_all_items: bool = True  # MISSION_ITEM_REACHED for DO_SET_SERVO/RELAY as well
    status_texts: bool = True  # STATUSTEXT as ArduPilot words them
    gcs_failsafe_s: float | None = None  # FS_GCS_TIMEOUT with FS_GCS_ENABLE; None: off

    def __post_init__(self) -> None:
        if self.initial_mode not in SIMULATED_MODES or self.initial_mode == Mode.AUTO:
            allowed = sorted(int(m) for m in SIMULATED_MODES - {Mode.AUTO})
            raise ValueError(f"initial_mode must be one of {allowed}, got {self.initial_mode}")
        if self.mission_done not in ("stop", "hold"):
            raise ValueError(f"mission_done must be 'stop' or 'hold', not {self.mission_done!r}")
        if self.gcs_failsafe_s is not None and not self.gcs_failsafe_s > 0.0:
            raise ValueError(f"gcs_failsafe_s must be > 0 seconds, got {self.gcs_failsafe_s}")
        if self.upload_request not in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            raise ValueError(
                "upload_request must be MISSION_REQUEST or MISSION_REQUEST_INT, "
                f"not {self.upload_request!r}"
            )


class SimTractor:
    """One simulated tractor with its ArduPilot Rover autopilot.

    Simulated time starts at 0 (boot) at home, at rest, disarmed, in
    ``params.initial_mode``, with the machine's road speed as default cruise speed.
    ``fail_after_s`` (simulated seconds) injects a breakdown: from then on the vehicle
    stops and sends nothing. ``stall_after_s`` (simulated seconds), or :meth:`stall`,
    injects a stall (stuck in mud): from then on the vehicle stands still, armed and in its
    mode, its mission running but getting nowhere, and keeps reporting and answering as
    before. ``deaf_until_s`` (simulated seconds) injects a dead uplink: until then the
    vehicle hears nothing (no command, no ground-station HEARTBEAT) and reports as ever.
    ``unix_epoch_s`` is the UNIX time at boot for SYSTEM_TIME
    (None: 0, "no GPS time").
    """

    def __init__(
        self,
        vehicle: Vehicle,
        home_lonlat: tuple[float, float],
        *,
        params: RoverParams | None = None,
        fail_after_s: float | None = None,
        stall_after_s: float | None = None,
        deaf_until_s: float | None = None,
        unix_epoch_s: float | None = None,
        component_id: int = mc.MAV_COMP_ID_AUTOPILOT1,
    ) -> None:
        lon, lat = home_lonlat
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise ValueError(f"home (lon, lat) = {home_lonlat} is not a WGS84 position")
        if fail_after_s is not None and not fail_after_s >= 0.0:
            raise ValueError(f"fail_after_s must be >= 0 simulated seconds, got {fail_after_s}")
        if stall_after_s is not None and not stall_after_s >= 0.0:
            raise ValueError(f"stall_after_s must be >= 0 simulated seconds, got {stall_after_s}")
        if deaf_until_s is not None and not deaf_until_s >= 0.0:
            raise ValueError(f"deaf_until_s must be >= 0 simulated seconds, got {deaf_until_s}")
        self.vehicle = vehicle
        self.params = params or RoverParams()
        self.system_id = vehicle.system_id
        self.component_id = component_id
        self.home_lat, self.home_lon = lat, lon
        self.fail_after_s = fail_after_s
        self.stall_after_s = stall_after_s
        self.deaf_until_s = deaf_until_s
        self.unix_epoch_s = unix_epoch_s
        self.cruise_speed_ms = vehicle.machine.road_speed_kmh / 3.6  # WP_SPEED
        self.mission = MissionServer(
            self._home_item,
            is_running=lambda: self._state is MissionState.RUNNING,
            request_message=self.params.upload_request,
        )
        self._t = 0.0
        self._lat, self._lon = lat, lon
        self._heading_deg = 0.0
        self._velocity_ne = (0.0, 0.0)
        self._speed_ms = self.cruise_speed_ms
        self._mode = Mode(self.params.initial_mode)
        self._armed = False
        self._failed = False
        self._stalled = False
        self._state = MissionState.STOPPED
        self._nav_index: int | None = None
        self._nav_memory: StoredItem | None = None  # the item at _nav_index when last read
        self._resume_from: int | None = None
        self._dwell_until: float | None = None
        self._rtl_done = False
        self._seen_changes = 0
        self._last_mission_current: tuple[int, int, int, int] | None = None
        self._gcs_system: int | None = None  # the ground station's system id, once heard
        self._gcs_heard_at: float | None = None  # sim time it was last heard
        self._gcs_failsafe_on = False  # triggered, and the ground station not heard since
        self.servo_pwm: dict[int, int] = {}
        self.relays: dict[int, bool] = {}

    # --- state -----------------------------------------------------------------------------
    @property
    def sim_time(self) -> float:
        """Simulated seconds since boot."""
        return self._t

    @property
    def lat(self) -> float:
        return self._lat

    @property
    def lon(self) -> float:
        return self._lon

    @property
    def mode(self) -> Mode:
        return self._mode

    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def failed(self) -> bool:
        """Broken down (``fail_after_s`` passed): silent and still."""
        return self._failed

    @property
    def stalled(self) -> bool:
        """Stuck (``stall_after_s`` passed or :meth:`stall`): still, but reporting."""
        return self._stalled

    def stall(self) -> None:
        """Stall now: stand still from here on, keep everything else (fault injection)."""
        if not self._stalled:
            self._stalled = True
            self._velocity_ne = (0.0, 0.0)
            logger.warning(
                "system %d stalled at t=%.1f s (fault injection)", self.system_id, self._t
            )

    @property
    def speed_ms(self) -> float:
        """The speed the vehicle drives at when it drives (m/s)."""
        return self._speed_ms

    @property
    def mission_state(self) -> MissionState:
        return self._state

    @property
    def current_seq(self) -> int:
        """The navigation item being driven to (MISSION_CURRENT.seq)."""
        return self._nav_index or 0

    @property
    def implement_down(self) -> bool:
        """Whether the implement output is at its "down" setting."""
        imp = self.vehicle.implement
        if imp.kind == "relay":
            return self.relays.get(imp.channel, False)
        pwm = self.servo_pwm.get(imp.channel)
        return pwm is not None and abs(pwm - imp.pwm_down) < abs(pwm - imp.pwm_up)

    # --- the caller's interface ------------------------------------------------------------
    def handle(
        self, msg: mc.MAVLinkMessage, sim_now: float, link_now: float | None = None
    ) -> list[mc.MAVLinkMessage]:
        """Replies (and events) to one message, after catching up to ``sim_now``.

        ``link_now`` is the clock of the mission protocol's timeouts (the ground station
        runs in wall time; default: ``sim_now``).
        """
        out = self._catch_up(sim_now)
        if self._failed:
            return out
        if self.deaf_until_s is not None and self._t < self.deaf_until_s:
            return out  # a dead uplink (fault injection)
        if msg.get_type() == "HEARTBEAT" and int(msg.type) == mc.MAV_TYPE_GCS:
            self._gcs_system = msg.get_srcSystem()
        if msg.get_srcSystem() == self._gcs_system:  # any message of it (MAV_GCS_SYSID)
            self._gcs_heard_at = self._t
            if self._gcs_failsafe_on:
                self._gcs_failsafe_on = False
                if self.params.status_texts:
                    out.append(_statustext(mc.MAV_SEVERITY_INFO, "GCS Failsafe Cleared"))
        if not self._addressed_to_me(msg):
            return out
        kind = msg.get_type()
        if kind == "MISSION_SET_CURRENT":  # deprecated; answered with MISSION_CURRENT
            result, events = self._set_current(int(msg.seq), reset=False)
            out += events
            if result == mc.MAV_RESULT_ACCEPTED and "MISSION_CURRENT" not in _types(events):
                out.append(self._mission_current())
        elif kind.startswith("MISSION_"):
            out += self.mission.on_message(msg, sim_now if link_now is None else link_now)
            out += self._sync_mission()
            if not self.mission.receiving:
                self._note_mission_current(out)
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            out += self._on_command(msg)
        elif kind == "SET_MODE":
            result, events = self._set_mode_common(int(msg.base_mode), int(msg.custom_mode))
            out.append(_command_ack(_MSG_ID_SET_MODE, result, msg))
            out += events
        return out

    def on_link_tick(self, link_now: float) -> list[mc.MAVLinkMessage]:
        """Mission-protocol re-requests and timeouts, on the link clock."""
        self._check_breakdown()
        if self._failed:
            return []
        return self.mission.on_tick(link_now)

    def advance(self, sim_dt: float) -> list[mc.MAVLinkMessage]:
        """Let ``sim_dt`` simulated seconds pass; the events that happened, in order."""
        if sim_dt < 0.0:
            raise ValueError(f"cannot advance by a negative time ({sim_dt} s)")
        end = self._t + sim_dt
        if self._failed:
            self._t = end
            return []
        limit = end
        if self.fail_after_s is not None and self.fail_after_s < end:
            limit = max(self._t, self.fail_after_s)
        out: list[mc.MAVLinkMessage] = []
        while True:  # the events due before ``limit``, in the order they happen
            due = [
                (at, event)
                for at, event in (
                    (self._gcs_failsafe_at(), self._gcs_failsafe),
                    (self._stall_at(), self._stall_event),
                )
                if at is not None and at <= limit
            ]
            if not due:
                break
            at, event = min(due, key=lambda pair: pair[0])
            out += self._drive_until(max(self._t, at))
            self._t = max(self._t, at)
            out += event()
        out += self._drive_until(limit)
        self._t = end
        self._check_breakdown()
        return out

    def heartbeat(self, sim_now: float) -> list[mc.MAVLinkMessage]:
        """The 1 Hz set: HEARTBEAT, SYSTEM_TIME, MISSION_CURRENT."""
        out = self._catch_up(sim_now)
        if self._failed:
            return out
        out += [self._heartbeat(), self._system_time(), self._mission_current()]
        return out

    def telemetry(self, sim_now: float) -> list[mc.MAVLinkMessage]:
        """The position stream: GLOBAL_POSITION_INT."""
        out = self._catch_up(sim_now)
        if self._failed:
            return out
        out.append(self._position())
        return out

    # --- driving ---------------------------------------------------------------------------
    def _catch_up(self, sim_now: float) -> list[mc.MAVLinkMessage]:
        out = self.advance(sim_now - self._t) if sim_now > self._t else []
        self._check_breakdown()
        return out

    def _check_breakdown(self) -> None:
        if self.fail_after_s is not None and self._t >= self.fail_after_s:
            self._break_down()

    def _stall_at(self) -> float | None:
        """When the injected stall happens (None: none to come)."""
        return None if self._stalled else self.stall_after_s

    def _stall_event(self) -> list[mc.MAVLinkMessage]:
        self.stall()
        return []

    def _drive_until(self, limit: float) -> list[mc.MAVLinkMessage]:
        out: list[mc.MAVLinkMessage] = []
        while True:
            out += self._sync_mission()
            if self._stalled:
                break
            if self._dwell_until is not None:
                if self._dwell_until > limit:
                    break
                self._t = self._dwell_until
                self._dwell_until = None
                out += self._nav_complete()
                continue
            target = self._target()
            if target is None or self._t >= limit:
                break
            t_lat, t_lon = target
            azimuth, _, dist = _GEOD.inv(self._lon, self._lat, t_lon, t_lat)
            speed = self._speed_ms
            if dist > 0.0:
                self._heading_deg = azimuth % 360.0
                rad = math.radians(azimuth)
                self._velocity_ne = (speed * math.cos(rad), speed * math.sin(rad))
            arrive = self._t + dist / speed
            if arrive > limit:
                lon, lat, _ = _GEOD.fwd(self._lon, self._lat, azimuth, speed * (limit - self._t))
                self._lat, self._lon = float(lat), float(lon)
                self._t = limit
                break
            self._t = arrive
            self._lat, self._lon = t_lat, t_lon
            out += self._arrive()
        if self._target() is None or self._dwell_until is not None:
            self._velocity_ne = (0.0, 0.0)
        return out

    def _target(self) -> tuple[float, float] | None:
        """Where the vehicle drives to now (lat, lon), or None when it stands still."""
        if self._failed or self._stalled or not self._armed or self._dwell_until is not None:
            return None
        if self._mode == Mode.RTL and not self._rtl_done:
            return self.home_lat, self.home_lon
        if self._mode != Mode.AUTO or self._state is not MissionState.RUNNING:
            return None
        item = self._nav_item()
        if item is None:
            return None
        if item.command == mc.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self.home_lat, self.home_lon
        if item.x == 0 and item.y == 0:  # Location::sanitize: "here"
            return self._lat, self._lon
        return item.lat, item.lon

    def _arrive(self) -> list[mc.MAVLinkMessage]:
        position = self._position()
        if self._mode == Mode.RTL:
            self._rtl_done = True
            return [position]
        item = self._nav_item()
        assert item is not None and self._nav_index is not None
        hold_s = item.param1 if item.command != mc.MAV_CMD_NAV_RETURN_TO_LAUNCH else 0.0
        if item.command == mc.MAV_CMD_NAV_LOITER_UNLIM:
            hold_s = math.inf
        if hold_s > 0.0:
            self._dwell_until = self._t + hold_s
            return [
                position,
                *self._texts(f"Reached waypoint #{self._nav_index}. Loiter for {hold_s:g} seconds"),
            ]
        return self._nav_complete(position)

    def _nav_complete(self, position: mc.MAVLinkMessage | None = None) -> list[mc.MAVLinkMessage]:
        """The current navigation item is done: report it and move on."""
        seq = self._nav_index
        assert seq is not None
        out = [mc.message("MISSION_ITEM_REACHED", seq=seq)]
        if position is not None:
            out.append(position)
            out += self._texts(f"Reached waypoint #{seq}")
        out += self._advance_from(seq + 1)
        return out

    # --- the mission -----------------------------------------------------------------------
    def _nav_item(self) -> StoredItem | None:
        """The navigation item driven to. ArduPilot keeps it in memory (``_nav_cmd``): an
        upload that ends the mission before it (truncated past it) leaves it driven to,
        and the mission completes there."""
        if self._nav_index is None:
            return None
        if self._nav_index < self.mission.count:
            self._nav_memory = self.mission.item(self._nav_index)
            return self._nav_memory
        memory = self._nav_memory
        return memory if memory is not None and memory.seq == self._nav_index else None

    def _advance_from(self, index: int) -> list[mc.MAVLinkMessage]:
        """Run DO items from ``index`` up to the next navigation item, which becomes the
        target; or complete the mission."""
        out: list[mc.MAVLinkMessage] = []
        self._dwell_until = None
        for seq in range(max(index, 1), self.mission.count):
            item = self.mission.item(seq)
            assert item is not None
            if item.is_nav:
                if item.command in _DRIVEN_NAV:
                    self._nav_index, self._nav_memory = seq, item
                    self._note_mission_current(out)
                    return out
                out += self._texts(f"Skipping invalid cmd #{item.command}")
                continue
            out += self._run_do(item)
        out += self._complete()
        return out

    def _run_do(self, item: StoredItem) -> list[mc.MAVLinkMessage]:
        cmd = item.command
        if cmd == mc.MAV_CMD_DO_CHANGE_SPEED:
            if item.param2 > 0.0:
                self._speed_ms = item.param2
                out = self._texts(f"speed: {item.param2:.1f} m/s")
            else:
                out = []
        elif cmd == mc.MAV_CMD_DO_SET_SERVO:
            self.servo_pwm[int(item.param1)] = int(item.param2)
            out = []
        elif cmd == mc.MAV_CMD_DO_SET_RELAY:
            self.relays[int(item.param1)] = item.param2 != 0.0
            out = []
        else:
            out = []
        logger.debug("system %d ran DO item %d (command %d)", self.system_id, item.seq, cmd)
        if self.params.report_all_items or cmd not in _SILENT_DO:
            out.insert(0, mc.message("MISSION_ITEM_REACHED", seq=item.seq))
        return out

    def _complete(self) -> list[mc.MAVLinkMessage]:
        self._state = MissionState.COMPLETE
        self._dwell_until = None
        logger.info("system %d: mission complete at t=%.1f s", self.system_id, self._t)
        out = self._texts("Mission Complete")
        if self.params.mission_done == "hold":
            _, events = self._set_mode(Mode.HOLD)
            out += events
        self._note_mission_current(out)
        return out

    def _start_or_resume(self) -> list[mc.MAVLinkMessage]:
        """``AP_Mission::start_or_resume`` with MIS_RESTART from the params."""
        if self._resume_from is not None:
            start, self._resume_from = self._resume_from, None
            self._state = MissionState.RUNNING
            return self._advance_from(start)
        resumable = (
            not self.params.mission_restart
            and self._state is MissionState.STOPPED
            and self._nav_index is not None
            and self._nav_index < self.mission.count
        )
        self._state = MissionState.RUNNING
        if not resumable:
            self._nav_index = None
            return self._advance_from(1)
        item = self._nav_item()
        if item is None or not item.is_nav:
            return self._advance_from(self._nav_index or 1)
        return []

    def _sync_mission(self) -> list[mc.MAVLinkMessage]:
        """Follow a mission changed under a running AUTO (ArduPilot restarts the current
        navigation command with its new content, ``ModeAuto::update``)."""
        if self.mission.changes == self._seen_changes:
            return []
        self._seen_changes = self.mission.changes
        if self._mode != Mode.AUTO or self._state is not MissionState.RUNNING:
            return []
        self._dwell_until = None
        item = self._nav_item()
        if item is None:
            return self._complete()
        if not item.is_nav:
            assert self._nav_index is not None
            return self._advance_from(self._nav_index)
        return []

    def _set_current(self, seq: int, reset: bool) -> Outcome:
        """MAV_CMD_DO_SET_MISSION_CURRENT (``handle_command_do_set_mission_current``)."""
        if not 0 <= seq < self.mission.count:
            return mc.MAV_RESULT_DENIED, []
        if self.mission.count <= 1:
            return mc.MAV_RESULT_FAILED, []  # nothing but home
        seq = max(seq, 1)
        if self._mode == Mode.AUTO and (self._state is MissionState.RUNNING or reset):
            self._state = MissionState.RUNNING
            return mc.MAV_RESULT_ACCEPTED, self._advance_from(seq)
        self._resume_from = seq
        self._nav_index, self._nav_memory = seq, self.mission.item(seq)
        if self._state is MissionState.COMPLETE or reset:
            self._state = MissionState.STOPPED
        out: list[mc.MAVLinkMessage] = []
        self._note_mission_current(out)
        return mc.MAV_RESULT_ACCEPTED, out

    # --- commands and modes ----------------------------------------------------------------
    def _on_command(self, msg: mc.MAVLinkMessage) -> list[mc.MAVLinkMessage]:
        cmd = int(msg.command)
        p1, p2 = float(msg.param1), float(msg.param2)
        result, events = self._run_command(cmd, p1, p2)
        logger.debug("system %d: command %d -> result %d", self.system_id, cmd, result)
        return [_command_ack(cmd, result, msg), *events]

    def _run_command(self, cmd: int, p1: float, p2: float) -> Outcome:
        if cmd == mc.MAV_CMD_COMPONENT_ARM_DISARM:
            if p1 == 1.0:
                self._armed = True
            elif p1 == 0.0:
                self._armed = False
                self._velocity_ne = (0.0, 0.0)
            else:
                return mc.MAV_RESULT_UNSUPPORTED, []
            return mc.MAV_RESULT_ACCEPTED, []
        if cmd == mc.MAV_CMD_DO_SET_MODE:
            return self._set_mode_common(int(p1), int(p2))
        if cmd == mc.MAV_CMD_MISSION_START:
            if p1 != 0.0 or p2 != 0.0:
                return mc.MAV_RESULT_DENIED, []  # first/last item not supported
            return self._result_of(self._set_mode(Mode.AUTO))
        if cmd == mc.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._result_of(self._set_mode(Mode.RTL))
        if cmd == mc.MAV_CMD_DO_CHANGE_SPEED:
            if int(p1) in (mc.SPEED_TYPE_CLIMB_SPEED, mc.SPEED_TYPE_DESCENT_SPEED):
                return mc.MAV_RESULT_DENIED, []
            if self._mode not in _SPEED_MODES or not p2 > 0.0:
                return mc.MAV_RESULT_FAILED, []
            self._speed_ms = p2
            return mc.MAV_RESULT_ACCEPTED, []
        if cmd == mc.MAV_CMD_DO_SET_SERVO:
            if not 1 <= int(p1) <= 32:
                return mc.MAV_RESULT_FAILED, []
            self.servo_pwm[int(p1)] = int(p2)
            return mc.MAV_RESULT_ACCEPTED, []
        if cmd == mc.MAV_CMD_DO_SET_RELAY:
            if not 0 <= int(p1) < 16:
                return mc.MAV_RESULT_FAILED, []
            self.relays[int(p1)] = p2 != 0.0
            return mc.MAV_RESULT_ACCEPTED, []
        if cmd == mc.MAV_CMD_DO_SET_MISSION_CURRENT:
            return self._set_current(int(p1), p2 == 1.0)
        return mc.MAV_RESULT_UNSUPPORTED, []

    def _set_mode_common(self, base_mode: int, custom_mode: int) -> Outcome:
        """``GCS_MAVLINK::_set_mode_common``: custom modes only."""
        if not base_mode & mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mc.MAV_RESULT_DENIED, []
        return self._result_of(self._set_mode(custom_mode))

    @staticmethod
    def _result_of(change: tuple[bool, list[mc.MAVLinkMessage]]) -> Outcome:
        ok, events = change
        return (mc.MAV_RESULT_ACCEPTED if ok else mc.MAV_RESULT_FAILED), events

    def _set_mode(self, number: int) -> tuple[bool, list[mc.MAVLinkMessage]]:
        """``Rover::set_mode``: True if the vehicle is now in mode ``number``."""
        if number == self._mode:
            return True, []
        if number not in SIMULATED_MODES:
            logger.warning("system %d: mode %d is not simulated", self.system_id, number)
            return False, self._texts("Flight mode change failed")
        new = Mode(number)
        if new == Mode.AUTO and self.mission.count <= 1:
            return False, [
                *self._texts("No Mission. Can't set AUTO."),
                *self._texts("Flight mode change failed"),
            ]
        if self._mode == Mode.AUTO and self._state is MissionState.RUNNING:
            self._state = MissionState.STOPPED
        self._dwell_until = None
        self._mode = new
        logger.info("system %d: mode %s", self.system_id, new.name)
        out: list[mc.MAVLinkMessage] = []
        if new == Mode.AUTO:
            self._seen_changes = self.mission.changes
            out += self._start_or_resume()
        elif new == Mode.RTL:
            self._speed_ms = self.cruise_speed_ms
            self._rtl_done = False
        self._note_mission_current(out)
        return True, out

    def _gcs_failsafe_at(self) -> float | None:
        """When the ground-station failsafe triggers if nothing is heard before (None:
        off, never heard, not armed, or already holding or returning)."""
        timeout = self.params.gcs_failsafe_s
        if timeout is None or self._gcs_heard_at is None or not self._armed:
            return None
        if self._mode in (Mode.HOLD, Mode.RTL):
            return None
        return self._gcs_heard_at + timeout

    def _gcs_failsafe(self) -> list[mc.MAVLinkMessage]:
        logger.warning("system %d: no ground station heard: failsafe HOLD", self.system_id)
        _, out = self._set_mode(Mode.HOLD)
        self._gcs_failsafe_on = True
        text = [_statustext(mc.MAV_SEVERITY_WARNING, "GCS Failsafe")]
        return (text if self.params.status_texts else []) + out

    def _break_down(self) -> None:
        if not self._failed:
            self._failed = True
            self._velocity_ne = (0.0, 0.0)
            logger.warning(
                "system %d broke down at t=%.1f s (fault injection)",
                self.system_id,
                self.fail_after_s or 0.0,
            )

    def _addressed_to_me(self, msg: mc.MAVLinkMessage) -> bool:
        system = getattr(msg, "target_system", None)
        if system is None:
            return False  # not a request to anyone (HEARTBEAT ...): nothing to answer
        if system not in (0, self.system_id):
            return False
        component = getattr(msg, "target_component", 0)
        return component in (0, self.component_id)

    # --- messages --------------------------------------------------------------------------
    def _home_item(self) -> StoredItem:
        """Item 0 as ArduPilot reports it: its home, NAV_WAYPOINT in MAV_FRAME_GLOBAL."""
        return StoredItem(
            seq=0,
            frame=mc.MAV_FRAME_GLOBAL,
            command=mc.MAV_CMD_NAV_WAYPOINT,
            current=0,
            autocontinue=1,
            param1=0.0,
            param2=0.0,
            param3=0.0,
            param4=0.0,
            x=round(self.home_lat * 1e7),
            y=round(self.home_lon * 1e7),
            z=0.0,
        )

    def _time_boot_ms(self) -> int:
        return round(self._t * 1000.0) & 0xFFFFFFFF

    def _heartbeat(self) -> mc.MAVLinkMessage:
        base = mc.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self._mode in _MANUAL_INPUT_MODES:
            base |= mc.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if self._mode in _AUTOPILOT_MODES:
            base |= mc.MAV_MODE_FLAG_GUIDED_ENABLED
        if self._armed:
            base |= mc.MAV_MODE_FLAG_SAFETY_ARMED
        if self._gcs_failsafe_on:
            status = mc.MAV_STATE_CRITICAL
        elif self._mode == Mode.HOLD:
            status = mc.MAV_STATE_STANDBY
        else:
            status = mc.MAV_STATE_ACTIVE
        return mc.message(
            "HEARTBEAT",
            type=mc.MAV_TYPE_GROUND_ROVER,
            autopilot=mc.MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode=base,
            custom_mode=int(self._mode),
            system_status=status,
            mavlink_version=3,
        )

    def _system_time(self) -> mc.MAVLinkMessage:
        unix_us = 0 if self.unix_epoch_s is None else round((self.unix_epoch_s + self._t) * 1e6)
        return mc.message("SYSTEM_TIME", time_unix_usec=unix_us, time_boot_ms=self._time_boot_ms())

    def _position(self) -> mc.MAVLinkMessage:
        vn, ve = self._velocity_ne
        return mc.message(
            "GLOBAL_POSITION_INT",
            time_boot_ms=self._time_boot_ms(),
            lat=round(self._lat * 1e7),
            lon=round(self._lon * 1e7),
            alt=0,
            relative_alt=0,
            vx=round(vn * 100.0),
            vy=round(ve * 100.0),
            vz=0,
            hdg=round(self._heading_deg * 100.0) % 36000,
        )

    def _mission_current_fields(self) -> tuple[int, int, int, int]:
        count = self.mission.count
        if count < 2:
            state = mc.MISSION_STATE_NO_MISSION
        elif self._state is MissionState.RUNNING:
            state = mc.MISSION_STATE_ACTIVE
        elif self._state is MissionState.COMPLETE:
            state = mc.MISSION_STATE_COMPLETE
        else:
            state = mc.MISSION_STATE_NOT_STARTED
        mission_mode = 1 if self._mode == Mode.AUTO else 0
        return self.current_seq, max(count - 1, 0), state, mission_mode

    def _mission_current(self) -> mc.MAVLinkMessage:
        seq, total, state, mission_mode = self._mission_current_fields()
        self._last_mission_current = (seq, total, state, mission_mode)
        return mc.message(
            "MISSION_CURRENT", seq=seq, total=total, mission_state=state, mission_mode=mission_mode
        )

    def _note_mission_current(self, out: list[mc.MAVLinkMessage]) -> None:
        """Append MISSION_CURRENT to ``out`` if what it says changed."""
        if self._mission_current_fields() != self._last_mission_current:
            out.append(self._mission_current())

    def _texts(self, *texts: str) -> list[mc.MAVLinkMessage]:
        if not self.params.status_texts:
            return []
        return [_statustext(mc.MAV_SEVERITY_INFO, text) for text in texts]


def _command_ack(command: int, result: int, request: mc.MAVLinkMessage) -> mc.MAVLinkMessage:
    return mc.message(
        "COMMAND_ACK",
        command=command,
        result=result,
        progress=0,
        result_param2=0,
        target_system=int(request.get_srcSystem()),
        target_component=int(request.get_srcComponent()),
    )


def _statustext(severity: int, text: str) -> mc.MAVLinkMessage:
    return mc.message("STATUSTEXT", severity=severity, text=text.encode()[:50], id=0, chunk_seq=0)


def _types(messages: list[mc.MAVLinkMessage]) -> list[str]:
    return [m.get_type() for m in messages]
