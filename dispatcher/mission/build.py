"""Turn one machine's ordered field list into an ArduPilot Rover waypoint mission.

Layout (``seq``: what, MAVLink command; role of the item's trace in quotes)::

    0  home at the garage                      NAV_WAYPOINT, frame GLOBAL        "home"
    1  road speed                              DO_CHANGE_SPEED                   "speed"
       per field, in driving order:
         road points from where the machine was (garage or the last field's exit)
                                               NAV_WAYPOINT                      "road"
         entry waypoint = first swath start    NAV_WAYPOINT  (end of the road)   "transit"
         working speed                         DO_CHANGE_SPEED                   "speed"
         implement down                        DO_SET_SERVO (pwm_down) /
                                               DO_SET_RELAY (1)                  "implement_down"
         per swath (then per headland ring edge), in driving order:
           its start (skipped when within 1 cm of the point before)              "swath_start"
           implement lowered again, when raised for the move before it           "implement_lower"
           its end                                                               "swath_end"
           then, for the move to the next swath or ring:
             implement raised, when the field has planned turns and the next
             line does not start where this one ends                             "implement_raise"
             the turn path's points (arcs of the machine's radius)               "turn"
             or, when a straight line would leave the field, the in-field
             points around a notch or a hole                                     "in_field"
         implement up                          DO_SET_SERVO (pwm_up) /
                                               DO_SET_RELAY (0)                  "implement_up"
         road speed                            DO_CHANGE_SPEED                   "speed"
       road points from the last exit back to the garage  NAV_WAYPOINT           "road"
    n  back at the garage                      NAV_WAYPOINT                      "return"

``implement_down`` and ``implement_up`` are the field's first lowering and last raising:
the dispatcher (``dispatcher.daemon.state``) and the review read them as the field's start and
finish. The raisings and lowerings around each turn have their own roles
(``implement_raise``, ``implement_lower``) so they never finish a field. Without planned
turns (a machine whose turning radius is 0, the paper's hop between swath ends) the
implement stays down from the first swath to the last, as before. Turns are driven at
working speed. Road points carry the id of the field they lead to (``None`` on the way
home) and no swath index. No waypoint repeats the place of the one before it
(:data:`SAME_POINT_M`): a road, turn or link point there is left out, or gives way to the
swath's or the field's waypoint.

Why these choices (ArduPilot sources, libraries/AP_Mission/AP_Mission.cpp and
libraries/GCS_MAVLink/MissionItemProtocol_Waypoints.cpp):

* Slot 0 is home. ArduPilot never runs it (AUTO starts at index 1) and, when the mission
  is read back, answers slot 0 with its own AHRS home as a ``NAV_WAYPOINT`` in
  ``MAV_FRAME_GLOBAL`` (absolute altitude); Mission Planner and ``.waypoints`` files
  (QGC WPL 110) keep it in slot 0 the same way. So item 0 is the garage in
  ``MAV_FRAME_GLOBAL`` with z = 0 (the altitude is not known here and not used).
* Every other waypoint is ``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``, z = 0: a rover drives
  on the ground; ArduPilot stores it as "relative to home".
* DO commands carry no position: ``MAV_FRAME_MISSION`` ("not a coordinate frame",
  what QGroundControl writes), x = y = z = 0. ArduPilot ignores their frame.
* ``DO_CHANGE_SPEED``: param1 = 1 (ground speed), param2 = m/s, param3 = -1 (throttle
  unchanged). Rover uses only param2.
* ``DO_SET_SERVO``: param1 = output channel, 1-based (SERVOn, up to 32 outputs);
  param2 = PWM. ``DO_SET_RELAY``: param1 = relay instance, 0-based (RELAY1 is 0);
  param2 = 1 on, 0 off.
* DO commands run when the vehicle leaves the preceding waypoint, so the implement goes
  down as the machine sets off along a swath (from its start waypoint) and comes up as it
  leaves the swath's end for the turn.
* Turn points lie on arcs every 15° and at most 2 m apart (``planner.turns``): with
  ``WP_RADIUS`` of 1-2 m Rover passes each of them on a smooth curve. They are stored to
  1e-7°, about 1 cm.

Every float parameter is stored already rounded to float32, the width it has on the
wire, so a mission survives MAVLink and file round trips unchanged.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Literal, Protocol, get_args

from pyproj import Geod

from dispatcher.config.errors import DispatcherError
from dispatcher.config.scenario import Implement
from dispatcher.link import mavlink as mc
from dispatcher.link.mission_item import MissionItem

logger = logging.getLogger(__name__)

Role = Literal[
    "home",
    "transit",
    "speed",
    "implement_down",
    "implement_up",
    "swath_start",
    "swath_end",
    "in_field",
    "implement_raise",
    "turn",
    "implement_lower",
    "road",
    "return",
]
ROLES: frozenset[str] = frozenset(get_args(Role))
IMPLEMENT_LOWERED: frozenset[str] = frozenset({"implement_down", "implement_lower"})
"""Roles of the items that lower the implement: a field's first lowering, and again after a
turn."""
IMPLEMENT_RAISED: frozenset[str] = frozenset({"implement_up", "implement_raise"})
"""Roles of the items that raise it: a field's last raising, and for a turn."""


class _HasRole(Protocol):
    @property
    def role(self) -> str: ...


def implement_down_after(steps: Sequence[_HasRole]) -> bool:
    """Whether the implement is down after these mission items (their traces, or planned
    items): the last of them that lowers or raises it says; down from a lowering to the
    next raising, in a swath or in a field without planned turns."""
    for step in reversed(steps):
        if step.role in IMPLEMENT_LOWERED:
            return True
        if step.role in IMPLEMENT_RAISED:
            return False
    return False


def implement_set_before(steps: Sequence[_HasRole], seq: int) -> int | None:
    """The index of the item that set the implement (lowered or raised it) in force when
    the vehicle drives to item ``seq``: the last such before it (item 0 aside); None if
    none did."""
    for k in range(min(seq, len(steps)) - 1, 0, -1):
        role = steps[k].role
        if role in IMPLEMENT_LOWERED or role in IMPLEMENT_RAISED:
            return k
    return None


SAME_POINT_M = 0.1
"""Two waypoints this close (metres) are one place: the second is not sent (a tenth of
ArduPilot Rover's default WP_RADIUS of 2 m; a waypoint's lat/lon is stored to ~1 cm). Of a
via point (road, turn, link) and a swath's start or end at one place, the swath's stays."""

ZERO_LENGTH_M = 0.01
"""A swath shorter than this (metres) is a mistake of the caller's."""

VIA_ROLES = frozenset({"road", "turn", "in_field"})
"""Waypoints that only lead the way: one that falls on the place of the next or the last
waypoint gives way to it (:meth:`_Builder.waypoint`)."""

SERVO_CHANNELS = range(1, 33)  # ArduPilot SERVO1..SERVO32 (NUM_SERVO_CHANNELS = 32)
RELAY_NUMBERS = range(0, 16)  # ArduPilot relay instances, 0-based (RELAY1 = 0)
PWM_RANGE = range(800, 2201)

_GEOD = Geod(ellps="WGS84")


class MissionError(DispatcherError, ValueError):
    """A mission cannot be built from the given spec; the message names machine and field."""

    def __init__(self, machine_id: str, field_id: str | None, problem: str) -> None:
        where = f"machine {machine_id!r}"
        if field_id is not None:
            where += f", field {field_id!r}"
        super().__init__(f"{where}: {problem}")
        self.machine_id = machine_id
        self.field_id = field_id
        self.problem = problem


_Fail = Callable[[str], MissionError]  # builds the error for one problem description


@dataclass(frozen=True)
class LatLon:
    """A WGS84 position in degrees."""

    lat: float
    lon: float


@dataclass(frozen=True)
class FieldVisit:
    """One field in driving order, already in WGS84."""

    field_id: str
    swaths: tuple[tuple[LatLon, LatLon], ...]  # driving order; each (start, end) as driven
    # For the move from swath k to k + 1: points to drive through so as not to leave the
    # field (around a notch or a hole); empty or shorter than the swaths when none are needed.
    links: tuple[tuple[LatLon, ...], ...] = ()
    # For the move from swath k to k + 1: the planned turn's points (implement up), strictly
    # between the two; empty for a hop. Given at all (even all empty): the machine's turns
    # are planned, and the implement is raised for every move between lines.
    turns: tuple[tuple[LatLon, ...], ...] = ()
    # Road points from where the machine was (garage or the last field's exit) to the entry.
    approach: tuple[LatLon, ...] = ()

    @property
    def has_turns(self) -> bool:
        """Whether turns are planned (the implement is raised between swaths)."""
        return len(self.turns) > 0


@dataclass(frozen=True)
class MissionSpec:
    """Everything needed to build one machine's mission; checked at construction."""

    machine_id: str
    home: LatLon  # the garage
    road_speed_kmh: float
    work_speed_kmh: float
    implement: Implement
    visits: tuple[FieldVisit, ...]
    # Road points from the last field's exit back to the garage.
    return_path: tuple[LatLon, ...] = ()

    def __post_init__(self) -> None:
        _check_spec(self)


@dataclass(frozen=True)
class Trace:
    """Why an item is in the mission: which field and swath it serves, in which role."""

    field_id: str | None
    swath_index: int | None
    role: Role

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"unknown trace role {self.role!r}; one of {sorted(ROLES)}")


@dataclass(frozen=True)
class Mission:
    """A machine's mission: items in upload order and, for each, its :class:`Trace`."""

    machine_id: str
    items: tuple[MissionItem, ...]
    traces: tuple[Trace, ...]

    def __post_init__(self) -> None:
        if len(self.items) != len(self.traces):
            raise ValueError(
                f"mission for {self.machine_id!r}: {len(self.items)} items "
                f"but {len(self.traces)} traces"
            )
        for index, item in enumerate(self.items):
            if item.seq != index:
                raise ValueError(
                    f"mission for {self.machine_id!r}: item {index} has seq {item.seq}"
                )

    def __len__(self) -> int:
        return len(self.items)

    def item_for_seq(self, seq: int) -> tuple[MissionItem, Trace]:
        """The item the vehicle reports as ``seq`` (MISSION_CURRENT etc.) and its trace."""
        if not 0 <= seq < len(self.items):
            raise IndexError(
                f"mission for {self.machine_id!r} has no item {seq} "
                f"(it has 0..{len(self.items) - 1})"
            )
        return self.items[seq], self.traces[seq]

    def speed_before(self, seq: int) -> float | None:
        """The ground speed (m/s) in force when the vehicle drives to item ``seq``: that of
        the last DO_CHANGE_SPEED before it; None if there is none."""
        for item in reversed(self.items[1:seq]):
            if item.command == mc.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0:
                return float(item.param2)
        return None

    def to_mavlink(
        self, target_system: int, target_component: int = mc.MAV_COMP_ID_AUTOPILOT1
    ) -> list[mc.MissionItemIntMessage]:
        """MISSION_ITEM_INT messages for the upload, in seq order, addressed to the vehicle."""
        return [item.message(target_system, target_component) for item in self.items]


def build_mission(spec: MissionSpec) -> Mission:
    """The waypoint mission that drives ``spec``'s fields in order (layout: module doc)."""
    builder = _Builder()
    road_speed = spec.road_speed_kmh / 3.6
    work_speed = spec.work_speed_kmh / 3.6

    builder.waypoint(spec.home, Trace(None, None, "home"), frame=mc.MAV_FRAME_GLOBAL)
    builder.change_speed(road_speed, Trace(None, None, "speed"))
    for visit in spec.visits:
        fid = visit.field_id
        last = len(visit.swaths) - 1
        entry = visit.swaths[0][0]
        for point in visit.approach:
            builder.waypoint(point, Trace(fid, None, "road"))
        builder.waypoint(entry, Trace(fid, 0, "transit"))
        builder.change_speed(work_speed, Trace(fid, None, "speed"))
        builder.implement(spec.implement, True, Trace(fid, 0, "implement_down"))
        lifts = visit.has_turns
        previous = entry
        for index, (start, end) in enumerate(visit.swaths):
            moved = index > 0 and _distance_m(previous, start) > SAME_POINT_M
            if moved and lifts:
                builder.implement(spec.implement, False, Trace(fid, index - 1, "implement_raise"))
            turns = visit.turns[index - 1] if 0 < index <= len(visit.turns) else ()
            links = visit.links[index - 1] if 0 < index <= len(visit.links) else ()
            for via in turns:
                builder.waypoint(via, Trace(fid, index, "turn"))
            for via in links:
                builder.waypoint(via, Trace(fid, index, "in_field"))
            if turns or links or _distance_m(previous, start) > SAME_POINT_M:
                # at the place of the via point before it, it takes that one's place
                builder.waypoint(start, Trace(fid, index, "swath_start"))
            if moved and lifts:
                builder.implement(spec.implement, True, Trace(fid, index, "implement_lower"))
            builder.waypoint(end, Trace(fid, index, "swath_end"))
            previous = end
        builder.implement(spec.implement, False, Trace(fid, last, "implement_up"))
        builder.change_speed(road_speed, Trace(fid, None, "speed"))
    for point in spec.return_path:
        builder.waypoint(point, Trace(None, None, "road"))
    builder.waypoint(spec.home, Trace(None, None, "return"))

    mission = Mission(spec.machine_id, tuple(builder.items), tuple(builder.traces))
    logger.debug(
        "mission for %s: %d items over %d fields", spec.machine_id, len(mission), len(spec.visits)
    )
    return mission


class _Builder:
    """Appends items with contiguous sequence numbers."""

    def __init__(self) -> None:
        self.items: list[MissionItem] = []
        self.traces: list[Trace] = []

    def _add(
        self,
        trace: Trace,
        *,
        command: int,
        frame: int = mc.MAV_FRAME_MISSION,
        params: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
        x: int = 0,
        y: int = 0,
    ) -> None:
        p1, p2, p3, p4 = (mc.wire_float(p) for p in params)
        self.items.append(
            MissionItem(
                seq=len(self.items),
                frame=frame,
                command=command,
                current=0,
                autocontinue=1,
                param1=p1,
                param2=p2,
                param3=p3,
                param4=p4,
                x=x,
                y=y,
                z=0.0,
            )
        )
        self.traces.append(trace)

    def waypoint(
        self, point: LatLon, trace: Trace, frame: int = mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    ) -> None:
        """A NAV_WAYPOINT, unless it is at the place of the last waypoint
        (:data:`SAME_POINT_M`): then a via point is not added, and a via point just before
        it (no other item between) is replaced by it."""
        navs = (
            k
            for k in reversed(range(len(self.items)))
            if self.items[k].command == mc.MAV_CMD_NAV_WAYPOINT
        )
        last = next(navs, None)
        if last is not None:
            item = self.items[last]
            if _distance_m(LatLon(item.x / 1e7, item.y / 1e7), point) <= SAME_POINT_M:
                if trace.role in VIA_ROLES:
                    return
                if last == len(self.items) - 1 and self.traces[-1].role in VIA_ROLES:
                    self.items.pop()
                    self.traces.pop()
        self._add(
            trace,
            command=mc.MAV_CMD_NAV_WAYPOINT,
            frame=frame,
            x=round(point.lat * 1e7),
            y=round(point.lon * 1e7),
        )

    def change_speed(self, speed_ms: float, trace: Trace) -> None:
        self._add(
            trace,
            command=mc.MAV_CMD_DO_CHANGE_SPEED,
            params=(float(mc.SPEED_TYPE_GROUNDSPEED), speed_ms, -1.0, 0.0),
        )

    def implement(self, implement: Implement, down: bool, trace: Trace) -> None:
        if implement.kind == "servo":
            pwm = implement.pwm_down if down else implement.pwm_up
            self._add(
                trace,
                command=mc.MAV_CMD_DO_SET_SERVO,
                params=(float(implement.channel), float(pwm), 0.0, 0.0),
            )
        else:
            self._add(
                trace,
                command=mc.MAV_CMD_DO_SET_RELAY,
                params=(float(implement.channel), 1.0 if down else 0.0, 0.0, 0.0),
            )


def _distance_m(a: LatLon, b: LatLon) -> float:
    """Geodesic distance on the WGS84 ellipsoid, metres."""
    _, _, distance = _GEOD.inv(a.lon, a.lat, b.lon, b.lat)
    return float(distance)


def _check_spec(spec: MissionSpec) -> None:
    machine = spec.machine_id
    if not isinstance(machine, str) or not machine.strip():
        raise MissionError(str(machine), None, "machine id must be a non-empty string")

    def fail(field_id: str | None, problem: str) -> MissionError:
        return MissionError(machine, field_id, problem)

    _check_point(spec.home, "garage (home)", partial(fail, None))
    for name in ("road_speed_kmh", "work_speed_kmh"):
        value = getattr(spec, name)
        if not _is_number(value) or not math.isfinite(value) or value <= 0:
            raise fail(None, f"{name} must be a positive number of km/h, got {value!r}")
    _check_implement(spec.implement, partial(fail, None))

    for k, point in enumerate(spec.return_path):
        _check_point(point, f"road point {k} back to the garage", partial(fail, None))
    seen: set[str] = set()
    for number, visit in enumerate(spec.visits):
        fid = visit.field_id
        if not isinstance(fid, str) or not fid.strip():
            raise fail(None, f"visit {number} has no field id")
        if fid in seen:
            raise fail(fid, "field is visited twice; give each visit its own field id")
        seen.add(fid)
        if len(visit.swaths) == 0:
            raise fail(fid, "field has no swaths to drive")
        field_fail = partial(fail, fid)
        for name, moves in (("turn", visit.turns), ("in-field link", visit.links)):
            if len(moves) > len(visit.swaths) - 1:
                raise fail(
                    fid,
                    f"{len(moves)} {name} paths for {len(visit.swaths) - 1} moves between swaths",
                )
            for k, via in enumerate(moves):
                for point in via:
                    _check_point(point, f"{name} point after swath {k}", field_fail)
        for k, point in enumerate(visit.approach):
            _check_point(point, f"road point {k} before the field", field_fail)
        for index, swath in enumerate(visit.swaths):
            if len(swath) != 2:
                raise fail(fid, f"swath {index} must be a (start, end) pair")
            start, end = swath
            _check_point(start, f"swath {index} start", field_fail)
            _check_point(end, f"swath {index} end", field_fail)
            if _distance_m(start, end) <= ZERO_LENGTH_M:
                raise fail(fid, f"swath {index} has zero length (start and end coincide)")


def _check_point(point: LatLon, what: str, fail: _Fail) -> None:
    if not isinstance(point, LatLon):
        raise fail(f"{what} must be a LatLon, got {point!r}")
    lat, lon = point.lat, point.lon
    if not _is_number(lat) or not math.isfinite(lat) or not -90.0 <= lat <= 90.0:
        raise fail(f"{what} latitude {lat!r} is outside -90..90 degrees")
    if not _is_number(lon) or not math.isfinite(lon) or not -180.0 <= lon <= 180.0:
        raise fail(f"{what} longitude {lon!r} is outside -180..180 degrees")


def _check_implement(implement: Implement, fail: _Fail) -> None:
    kind = implement.kind
    if kind not in ("servo", "relay"):
        raise fail(f"implement kind must be 'servo' or 'relay', got {kind!r}")
    channel = implement.channel
    allowed = SERVO_CHANNELS if kind == "servo" else RELAY_NUMBERS
    what = "servo channel" if kind == "servo" else "relay number"
    if not _is_int(channel) or channel not in allowed:
        raise fail(f"{what} must be {allowed.start}..{allowed.stop - 1}, got {channel!r}")
    if kind == "servo":
        for name in ("pwm_down", "pwm_up"):
            pwm = getattr(implement, name)
            if not _is_int(pwm) or pwm not in PWM_RANGE:
                raise fail(
                    f"implement {name} must be {PWM_RANGE.start}..{PWM_RANGE.stop - 1} µs, "
                    f"got {pwm!r}"
                )


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)
