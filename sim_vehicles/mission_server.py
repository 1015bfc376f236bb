"""The vehicle side of the MAVLink mission protocol, as ArduPilot implements it, without I/O.

:class:`MissionServer` is fed the ground station's messages (``on_message``) and the link
clock (``on_tick``) and answers with the messages the vehicle sends back. It holds the
stored mission (MAV_MISSION_TYPE_MISSION only) as :class:`StoredItem` rows.

What it copies from ArduPilot (``libraries/GCS_MAVLink/MissionItemProtocol.cpp`` and
``MissionItemProtocol.h``, ``MissionItemProtocol_Waypoints.cpp``, ``GCS_Common.cpp``
``handle_mission_*``, ``libraries/AP_Mission/AP_Mission.cpp``):

* Upload. MISSION_COUNT truncates the stored mission to ``count`` at once and the vehicle
  then pulls item ``0 .. count-1`` one by one; each item *replaces or appends in place*
  (a failed upload leaves a mix of old and new items, as on ArduPilot). After the last
  item: MISSION_ACK(ACCEPTED) and STATUSTEXT "Flight plan received". ``count`` 0 is
  acknowledged at once (it clears the mission). ``count`` above the capacity: NO_SPACE.
* MISSION_COUNT while an upload is under way: from the same system/component it restarts
  the upload, from anyone else it is DENIED.
* An item with the wrong ``seq``: MISSION_ACK(INVALID_SEQUENCE) and the transfer goes on
  (the expected item is asked for again by the 1 s re-request). An item from another
  system than the uploader: DENIED. An item when no upload runs: ERROR. A bad item
  (latitude/longitude out of range): its error code, and the upload ends.
* Timers (``MissionItemProtocol::update``): no item for more than 1 s re-sends the
  request for the expected item; no item for more than 8 s (``upload_timeout_ms``) ends
  the upload with MISSION_ACK(OPERATION_CANCELLED) and "Mission upload timeout".
* ArduPilot asks for items with the legacy MISSION_REQUEST (``queued_request_send``
  calls ``mavlink_msg_mission_request_send``; the change to MISSION_REQUEST_INT, ArduPilot
  PR #15067, was closed unmerged). ``request_message`` picks that or the MAVLink spec's
  MISSION_REQUEST_INT.
* Legacy MISSION_ITEM (float lat/lon) is accepted and converted as
  ``AP_Mission::convert_MISSION_ITEM_to_MISSION_ITEM_INT`` does.
* Download. MISSION_REQUEST_LIST answers MISSION_COUNT (home included); MISSION_REQUEST_INT
  answers MISSION_ITEM_INT, MISSION_REQUEST answers MISSION_ITEM. Item 0 is always the
  vehicle's own home (``AP_Mission::read_cmd_from_storage``), whatever was uploaded there.
  A seq past the end answers MISSION_COUNT then MISSION_ACK(ERROR). Requests while an
  upload runs are DENIED. The ground station's final MISSION_ACK needs no answer.
* MISSION_CLEAR_ALL: ACCEPTED, or ERROR during an upload or while the mission runs
  (``AP_Mission::clear`` refuses then).
* Other mission types (fence, rally): MISSION_ACK(UNSUPPORTED) with that type, except
  MISSION_REQUEST(_INT), which ArduPilot ignores for a type it has no protocol for.
  (A real Rover also stores fences and rally points; this simulator does not.)

What it does not copy: ArduPilot re-encodes stored items on download (frames may come back
as the non-``_INT`` variants, unused parameters as 0); here they come back as uploaded.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from dispatcher.link import mavlink as mc
from dispatcher.link.mission_item import MissionItem
from dispatcher.link.mission_protocol import VEHICLE_RE_REQUEST_S

logger = logging.getLogger(__name__)

RequestMessage = Literal["MISSION_REQUEST", "MISSION_REQUEST_INT"]

UPLOAD_TIMEOUT_S = 8.0
"""No item for this long ends an upload (ArduPilot ``upload_timeout_ms = 8000``)."""

RE_REQUEST_S = VEHICLE_RE_REQUEST_S
"""No item for this long re-sends the request (what the dispatcher expects of ArduPilot)."""

MAX_ITEMS = 32766
"""Capacity, home included (ArduPilot's MIS_TOTAL range; real boards hold fewer)."""

_GUIDED_WAYPOINT = 2  # MISSION_ITEM(_INT).current = 2: a guided-mode target, not the mission
_CHANGE_ALTITUDE = 3  # current = 3: change altitude only
_XY_NOT_LATLON = frozenset({mc.MAV_CMD_DO_DIGICAM_CONTROL, mc.MAV_CMD_DO_DIGICAM_CONFIGURE})
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


@dataclass(frozen=True)
class StoredItem(MissionItem):
    """One stored mission item: the uploaded MISSION_ITEM_INT fields (x, y = lat, lon in
    degrees * 1e7), with what the vehicle needs to run and serve it."""

    @property
    def is_nav(self) -> bool:
        """A navigation command (``AP_Mission::is_nav_cmd``: ids up to MAV_CMD_NAV_LAST)."""
        return self.command <= mc.MAV_CMD_NAV_LAST or self.command in (
            mc.MAV_CMD_NAV_SET_YAW_SPEED,
            mc.MAV_CMD_NAV_SCRIPT_TIME,
            mc.MAV_CMD_NAV_ATTITUDE_TIME,
        )

    def to_item_int(self, target_system: int, target_component: int) -> mc.MAVLinkMessage:
        """This item as MISSION_ITEM_INT addressed to the ground station."""
        return self.message(target_system, target_component)

    def to_item(self, target_system: int, target_component: int) -> mc.MAVLinkMessage:
        """This item as legacy MISSION_ITEM (float lat/lon)."""
        scale = 1.0 if self.command in _XY_NOT_LATLON else 1e-7
        return mc.message(
            "MISSION_ITEM",
            target_system=target_system,
            target_component=target_component,
            seq=self.seq,
            frame=mc.float_frame(self.frame),
            command=self.command,
            current=self.current,
            autocontinue=self.autocontinue,
            param1=self.param1,
            param2=self.param2,
            param3=self.param3,
            param4=self.param4,
            x=self.x * scale,
            y=self.y * scale,
            z=self.z,
            mission_type=mc.MAV_MISSION_TYPE_MISSION,
        )


HomeFn = Callable[[], StoredItem]


@dataclass
class _Upload:
    """An upload under way (ArduPilot's ``receiving`` state)."""

    dest_system: int
    dest_component: int
    next_seq: int  # ArduPilot request_i
    last_seq: int  # ArduPilot request_last
    last_receive_s: float
    last_request_s: float


class MissionServer:
    """Stores one vehicle's mission and serves the MAVLink mission protocol like ArduPilot.

    ``home`` gives item 0 as the vehicle reports it; ``is_running`` tells whether the
    mission runs (MISSION_CLEAR_ALL is refused then). ``changes`` counts every change of
    the stored items, so the vehicle can notice a mission changed under it.
    """

    def __init__(
        self,
        home: HomeFn,
        *,
        is_running: Callable[[], bool] = lambda: False,
        request_message: RequestMessage = "MISSION_REQUEST",
        max_items: int = MAX_ITEMS,
    ) -> None:
        if request_message not in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            raise ValueError(
                f"request_message must be MISSION_REQUEST or MISSION_REQUEST_INT, "
                f"not {request_message!r}"
            )
        if not 1 <= max_items <= 65535:
            raise ValueError(f"max_items must be 1..65535, got {max_items}")
        self._home = home
        self._is_running = is_running
        self.request_message: RequestMessage = request_message
        self.max_items = max_items
        self._items: list[StoredItem] = []
        self._upload: _Upload | None = None
        self.changes = 0

    # --- reading ---------------------------------------------------------------------------
    @property
    def items(self) -> tuple[StoredItem, ...]:
        """The stored items, seq 0 .. count-1 (item 0 as uploaded, not the home)."""
        return tuple(self._items)

    @property
    def count(self) -> int:
        """Stored items, home included (ArduPilot ``num_commands``)."""
        return len(self._items)

    @property
    def receiving(self) -> bool:
        """An upload is under way."""
        return self._upload is not None

    def item(self, seq: int) -> StoredItem | None:
        """Stored item ``seq`` (1 ..), or None past the end; 0 is the home."""
        if seq == 0:
            return self._home()
        return self._items[seq] if 0 < seq < len(self._items) else None

    # --- protocol --------------------------------------------------------------------------
    def on_message(self, msg: mc.MAVLinkMessage, now_s: float) -> list[mc.MAVLinkMessage]:
        """The replies to one message from the ground station (others are ignored)."""
        kind = msg.get_type()
        if kind == "MISSION_COUNT":
            return self._on_count(msg, now_s)
        if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            return self._on_item(msg, now_s)
        if kind == "MISSION_REQUEST_LIST":
            return self._on_request_list(msg)
        if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            return self._on_request(msg)
        if kind == "MISSION_CLEAR_ALL":
            return self._on_clear_all(msg)
        return []  # MISSION_ACK from the ground station ends a download: nothing to say

    def on_tick(self, now_s: float) -> list[mc.MAVLinkMessage]:
        """Re-requests and the upload timeout (``MissionItemProtocol::update``)."""
        up = self._upload
        if up is None:
            return []
        if now_s - up.last_receive_s > UPLOAD_TIMEOUT_S:
            self._upload = None
            logger.warning("mission upload timed out waiting for item %d", up.next_seq)
            return [
                _text(mc.MAV_SEVERITY_WARNING, "Mission upload timeout"),
                _ack(up.dest_system, up.dest_component, mc.MAV_MISSION_OPERATION_CANCELLED),
            ]
        if now_s - up.last_request_s > RE_REQUEST_S:
            up.last_request_s = now_s
            logger.debug("re-requesting mission item %d", up.next_seq)
            return [self._request(up)]
        return []

    # --- handlers --------------------------------------------------------------------------
    def _on_count(self, msg: mc.MAVLinkMessage, now_s: float) -> list[mc.MAVLinkMessage]:
        sender = _sender(msg)
        if msg.mission_type != mc.MAV_MISSION_TYPE_MISSION:
            return [_ack(*sender, mc.MAV_MISSION_UNSUPPORTED, msg.mission_type)]
        if self._upload is not None:
            if sender != (self._upload.dest_system, self._upload.dest_component):
                return [_ack(*sender, mc.MAV_MISSION_DENIED)]
            logger.info("mission upload restarted by system %d", sender[0])
            self._upload = None
        count = int(msg.count)
        if count > self.max_items:
            return [
                _ack(*sender, mc.MAV_MISSION_NO_SPACE),
                _text(mc.MAV_SEVERITY_WARNING, f"Only {self.max_items} items are supported"),
            ]
        self._truncate(count)
        if count == 0:
            return self._complete(sender)
        self._upload = _Upload(sender[0], sender[1], 0, count - 1, now_s, now_s)
        return [self._request(self._upload)]

    def _on_item(self, msg: mc.MAVLinkMessage, now_s: float) -> list[mc.MAVLinkMessage]:
        sender = _sender(msg)
        if msg.get_type() == "MISSION_ITEM":
            converted = _from_float_item(msg)
            if isinstance(converted, int):
                return [_ack(*sender, converted, msg.mission_type)]
            item = converted
        else:
            item = _from_int_item(msg)
        if msg.mission_type == mc.MAV_MISSION_TYPE_MISSION and msg.current == _GUIDED_WAYPOINT:
            # A guided-mode target; this simulator has no guided navigation.
            return [_ack(*sender, mc.MAV_MISSION_ERROR)]
        if msg.mission_type == mc.MAV_MISSION_TYPE_MISSION and msg.current == _CHANGE_ALTITUDE:
            return [_ack(*sender, mc.MAV_MISSION_ACCEPTED)]  # altitude means nothing to a rover
        if msg.mission_type != mc.MAV_MISSION_TYPE_MISSION:
            return [_ack(*sender, mc.MAV_MISSION_UNSUPPORTED, msg.mission_type)]
        up = self._upload
        if up is None:
            return [_ack(*sender, mc.MAV_MISSION_ERROR)]
        if item.seq != up.next_seq:
            return [_ack(*sender, mc.MAV_MISSION_INVALID_SEQUENCE)]
        if sender != (up.dest_system, up.dest_component):
            return [_ack(*sender, mc.MAV_MISSION_DENIED)]
        result = _check_item(item)
        if result == mc.MAV_MISSION_ACCEPTED:
            result = self._store(item)
        if result != mc.MAV_MISSION_ACCEPTED:
            self._upload = None
            logger.warning(
                "mission upload refused item %d (MAV_MISSION_RESULT %d)", item.seq, result
            )
            return [_ack(*sender, result)]
        up.last_receive_s = now_s
        up.next_seq += 1
        if up.next_seq > up.last_seq:
            return self._complete(sender)
        up.last_request_s = now_s
        return [self._request(up)]

    def _on_request_list(self, msg: mc.MAVLinkMessage) -> list[mc.MAVLinkMessage]:
        sender = _sender(msg)
        if msg.mission_type != mc.MAV_MISSION_TYPE_MISSION:
            return [_ack(*sender, mc.MAV_MISSION_UNSUPPORTED, msg.mission_type)]
        if self._upload is not None:
            return [_ack(*sender, mc.MAV_MISSION_DENIED)]
        return [self._count_message(sender)]

    def _on_request(self, msg: mc.MAVLinkMessage) -> list[mc.MAVLinkMessage]:
        sender = _sender(msg)
        if msg.mission_type != mc.MAV_MISSION_TYPE_MISSION:
            return []  # ArduPilot: no protocol for that type, no answer
        if self._upload is not None:
            return [_ack(*sender, mc.MAV_MISSION_DENIED)]
        seq = int(msg.seq)
        item = self.item(seq)
        if item is None:
            # "try to educate the GCS on the actual size of the mission"
            return [self._count_message(sender), _ack(*sender, mc.MAV_MISSION_ERROR)]
        if msg.get_type() == "MISSION_REQUEST":
            return [item.to_item(*sender)]
        return [item.to_item_int(*sender)]

    def _on_clear_all(self, msg: mc.MAVLinkMessage) -> list[mc.MAVLinkMessage]:
        sender = _sender(msg)
        if msg.mission_type != mc.MAV_MISSION_TYPE_MISSION:
            return [_ack(*sender, mc.MAV_MISSION_UNSUPPORTED, msg.mission_type)]
        if self._upload is not None or self._is_running():
            return [_ack(*sender, mc.MAV_MISSION_ERROR)]
        self._truncate(0)
        return [_ack(*sender, mc.MAV_MISSION_ACCEPTED)]

    # --- helpers ---------------------------------------------------------------------------
    def _complete(self, sender: tuple[int, int]) -> list[mc.MAVLinkMessage]:
        self._upload = None
        logger.info("mission of %d items received from system %d", self.count, sender[0])
        return [
            _text(mc.MAV_SEVERITY_INFO, "Flight plan received"),
            _ack(*sender, mc.MAV_MISSION_ACCEPTED),
        ]

    def _request(self, up: _Upload) -> mc.MAVLinkMessage:
        return mc.message(
            self.request_message,
            target_system=up.dest_system,
            target_component=up.dest_component,
            seq=up.next_seq,
            mission_type=mc.MAV_MISSION_TYPE_MISSION,
        )

    def _count_message(self, sender: tuple[int, int]) -> mc.MAVLinkMessage:
        return mc.message(
            "MISSION_COUNT",
            target_system=sender[0],
            target_component=sender[1],
            count=self.count,
            mission_type=mc.MAV_MISSION_TYPE_MISSION,
        )

    def _truncate(self, count: int) -> None:
        if len(self._items) > count:
            del self._items[count:]
            self.changes += 1

    def _store(self, item: StoredItem) -> int:
        if item.seq < len(self._items):
            self._items[item.seq] = item
        elif item.seq == len(self._items):
            self._items.append(item)
        else:
            return int(mc.MAV_MISSION_ERROR)
        self.changes += 1
        return int(mc.MAV_MISSION_ACCEPTED)


def _sender(msg: mc.MAVLinkMessage) -> tuple[int, int]:
    return int(msg.get_srcSystem()), int(msg.get_srcComponent())


def _ack(
    target_system: int,
    target_component: int,
    result: int,
    mission_type: int = mc.MAV_MISSION_TYPE_MISSION,
) -> mc.MAVLinkMessage:
    return mc.message(
        "MISSION_ACK",
        target_system=target_system,
        target_component=target_component,
        type=result,
        mission_type=mission_type,
    )


def _text(severity: int, text: str) -> mc.MAVLinkMessage:
    """A STATUSTEXT as ArduPilot words it (at most 50 characters)."""
    return mc.message("STATUSTEXT", severity=severity, text=text.encode()[:50], id=0, chunk_seq=0)


def _from_int_item(msg: mc.MAVLinkMessage) -> StoredItem:
    return StoredItem(
        seq=int(msg.seq),
        frame=int(msg.frame),
        command=int(msg.command),
        current=int(msg.current),
        autocontinue=int(msg.autocontinue),
        param1=float(msg.param1),
        param2=float(msg.param2),
        param3=float(msg.param3),
        param4=float(msg.param4),
        x=int(msg.x),
        y=int(msg.y),
        z=float(msg.z),
    )


def _from_float_item(msg: mc.MAVLinkMessage) -> StoredItem | int:
    """MISSION_ITEM as MISSION_ITEM_INT, or the MAV_MISSION_RESULT why it cannot be."""
    x, y = float(msg.x), float(msg.y)
    if msg.command in _XY_NOT_LATLON:
        # ArduPilot casts to int32 (undefined for NaN, infinity and beyond its range): such
        # a value is refused here, as a bad parameter, so that the stored item fits its frame.
        if not _INT32_MIN <= x <= _INT32_MAX:
            return int(mc.MAV_MISSION_INVALID_PARAM5_X)
        if not _INT32_MIN <= y <= _INT32_MAX:
            return int(mc.MAV_MISSION_INVALID_PARAM6_Y)
        ix, iy = int(x), int(y)
    else:
        if not -90.0 <= x <= 90.0:
            return int(mc.MAV_MISSION_INVALID_PARAM5_X)
        if not -180.0 <= y <= 180.0:
            return int(mc.MAV_MISSION_INVALID_PARAM6_Y)
        ix, iy = round(x * 1e7), round(y * 1e7)
    return StoredItem(
        seq=int(msg.seq),
        frame=int(msg.frame),
        command=int(msg.command),
        current=int(msg.current),
        autocontinue=int(msg.autocontinue),
        param1=float(msg.param1),
        param2=float(msg.param2),
        param3=float(msg.param3),
        param4=float(msg.param4),
        x=ix,
        y=iy,
        z=float(msg.z),
    )


def _check_item(item: StoredItem) -> int:
    """ArduPilot's location checks on a navigation item (``mavlink_int_to_mission_cmd``)."""
    if item.is_nav and item.command not in _XY_NOT_LATLON:
        if abs(item.x) > 900_000_000:
            return int(mc.MAV_MISSION_INVALID_PARAM5_X)
        if abs(item.y) > 1_800_000_000:
            return int(mc.MAV_MISSION_INVALID_PARAM6_Y)
    return int(mc.MAV_MISSION_ACCEPTED)
