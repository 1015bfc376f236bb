"""The one adapter around pymavlink: MAVLink 2 frames in and out as raw bytes.

Everything else in agrifleet talks MAVLink through this module, so pymavlink is imported
here only. Frames travel as bytes (over Zenoh, later), so :class:`Codec` packs a message
into one MAVLink 2 frame and parses frames back out of any byte string, skipping garbage.

Messages are pymavlink's ``ardupilotmega`` dialect objects (a superset of ``common``),
the dialect ArduPilot Rover speaks.
"""

from __future__ import annotations

import logging
import struct
from typing import Any, TypeAlias

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

logger = logging.getLogger(__name__)

MAVLinkMessage: TypeAlias = mavlink2.MAVLink_message
MissionItemIntMessage: TypeAlias = mavlink2.MAVLink_mission_item_int_message

# Commands a mission uses (MAV_CMD).
MAV_CMD_NAV_WAYPOINT: int = mavlink2.MAV_CMD_NAV_WAYPOINT
MAV_CMD_DO_CHANGE_SPEED: int = mavlink2.MAV_CMD_DO_CHANGE_SPEED
MAV_CMD_DO_SET_SERVO: int = mavlink2.MAV_CMD_DO_SET_SERVO
MAV_CMD_DO_SET_RELAY: int = mavlink2.MAV_CMD_DO_SET_RELAY

# Coordinate frames (MAV_FRAME).
MAV_FRAME_GLOBAL: int = mavlink2.MAV_FRAME_GLOBAL
MAV_FRAME_MISSION: int = mavlink2.MAV_FRAME_MISSION
MAV_FRAME_GLOBAL_RELATIVE_ALT: int = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT
MAV_FRAME_GLOBAL_INT: int = mavlink2.MAV_FRAME_GLOBAL_INT
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: int = mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
MAV_FRAME_GLOBAL_TERRAIN_ALT: int = mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT
MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: int = mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT

MAV_MISSION_TYPE_MISSION: int = mavlink2.MAV_MISSION_TYPE_MISSION
SPEED_TYPE_GROUNDSPEED: int = mavlink2.SPEED_TYPE_GROUNDSPEED
MAV_AUTOPILOT_ARDUPILOTMEGA: int = mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
MAV_TYPE_GROUND_ROVER: int = mavlink2.MAV_TYPE_GROUND_ROVER
MAV_COMP_ID_AUTOPILOT1: int = mavlink2.MAV_COMP_ID_AUTOPILOT1

_FLOAT_FRAME_OF_INT_FRAME: dict[int, int] = {
    MAV_FRAME_GLOBAL_INT: MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: MAV_FRAME_GLOBAL_TERRAIN_ALT,
}

_FLOAT32 = struct.Struct("<f")


def __getattr__(name: str) -> Any:
    """Any other MAVLink constant of the dialect (``MAV_MISSION_ACCEPTED``, ``MAV_RESULT_*``,
    ``MAV_STATE_*`` ...), so that callers need not import pymavlink."""
    if name.isupper() and hasattr(mavlink2, name):
        return getattr(mavlink2, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def constant_name(prefix: str, value: int) -> str:
    """The name of a constant of the dialect, e.g. ("MAV_MISSION_", 4) -> "MAV_MISSION_NO_SPACE"."""
    for name in dir(mavlink2):
        if name.startswith(prefix) and getattr(mavlink2, name) == value:
            return name
    return f"{prefix}{value}"


def message(name: str, **fields: Any) -> MAVLinkMessage:
    """A message by its MAVLink name, e.g. ``message("HEARTBEAT", type=..., ...)``."""
    cls = getattr(mavlink2, f"MAVLink_{name.lower()}_message", None)
    if cls is None:
        raise ValueError(f"unknown MAVLink message {name!r}")
    return cls(**fields)


def as_dict(msg: MAVLinkMessage) -> dict[str, Any]:
    """A JSON-ready view of a message: its name and fields (bytes as lists)."""
    out: dict[str, Any] = {"mavpackettype": msg.get_type()}
    for name in msg.get_fieldnames():
        value = getattr(msg, name)
        if isinstance(value, bytes | bytearray):
            value = list(value)
        elif isinstance(value, float) and value != value:  # NaN is not JSON
            value = None
        out[name] = value
    return out


def float_frame(frame: int) -> int:
    """The MISSION_ITEM (float lat/lon) frame for a MISSION_ITEM_INT frame.

    Waypoint files hold lat/lon in degrees, so they carry the non-``_INT`` frames
    (``GLOBAL_RELATIVE_ALT`` = 3, not ``GLOBAL_RELATIVE_ALT_INT`` = 6); other frames pass.
    """
    return _FLOAT_FRAME_OF_INT_FRAME.get(frame, frame)


def wire_float(value: float) -> float:
    """``value`` rounded to the float32 that a MAVLink ``float`` field carries."""
    result: float = _FLOAT32.unpack(_FLOAT32.pack(value))[0]
    return result


def mission_item_int(
    *,
    target_system: int,
    target_component: int,
    seq: int,
    frame: int,
    command: int,
    current: int,
    autocontinue: int,
    param1: float,
    param2: float,
    param3: float,
    param4: float,
    x: int,
    y: int,
    z: float,
    mission_type: int = MAV_MISSION_TYPE_MISSION,
) -> MissionItemIntMessage:
    """A MISSION_ITEM_INT message (x, y = lat, lon in degrees * 1e7)."""
    return mavlink2.MAVLink_mission_item_int_message(
        target_system,
        target_component,
        seq,
        frame,
        command,
        current,
        autocontinue,
        param1,
        param2,
        param3,
        param4,
        x,
        y,
        z,
        mission_type,
    )


class Codec:
    """Packs messages into MAVLink 2 frames from one system/component, and parses frames.

    ``encode`` stamps each frame with the next sequence number (0..255, wrapping).
    ``decode`` treats successive calls as one byte stream: garbage is skipped (a frame
    must pass its CRC to count), and a frame cut off at the end of one call is completed
    by the bytes of the next. Unsigned frames only are produced; signed ones are parsed
    but their signature is not checked.
    """

    def __init__(self, system_id: int, component_id: int) -> None:
        if not 1 <= system_id <= 255:
            raise ValueError(f"MAVLink system id must be 1..255, got {system_id}")
        if not 0 <= component_id <= 255:
            raise ValueError(f"MAVLink component id must be 0..255, got {component_id}")
        self.system_id = system_id
        self.component_id = component_id
        self._mav = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._pending = bytearray()

    @property
    def next_seq(self) -> int:
        """The sequence number the next encoded frame will carry."""
        seq: int = self._mav.seq
        return seq

    def encode(self, msg: MAVLinkMessage) -> bytes:
        """One MAVLink 2 frame carrying ``msg``; advances the sequence number."""
        frame = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        return frame

    def decode(self, data: bytes) -> list[MAVLinkMessage]:
        """Every message whose frame completes in the stream so far, in order."""
        buf = self._pending + data
        messages: list[MAVLinkMessage] = []
        tail_start: int | None = None  # first candidate frame still missing bytes
        i = 0
        while True:
            start = _next_marker(buf, i)
            if start < 0:
                break
            frame_len = _frame_length(buf, start)
            if frame_len is None or len(buf) - start < frame_len:
                # Either the start of a frame whose rest is still to come, or garbage;
                # keep looking, a complete frame later on settles which.
                if tail_start is None:
                    tail_start = start
                i = start + 1
                continue
            msg = self._decode_frame(buf[start : start + frame_len])
            if msg is None:
                i = start + 1
                continue
            messages.append(msg)
            tail_start = None
            i = start + frame_len
        self._pending = buf[tail_start:] if tail_start is not None else bytearray()
        return messages

    def decode_one(self, frame: bytes) -> MAVLinkMessage | None:
        """The message of one whole frame (one Zenoh sample), or None if it is not a
        valid frame; keeps no state between calls."""
        return self._decode_frame(bytearray(frame))

    def reset(self) -> None:
        """Drop any partial frame kept from earlier ``decode`` calls."""
        self._pending = bytearray()

    def _decode_frame(self, frame: bytearray) -> MAVLinkMessage | None:
        try:
            msg: MAVLinkMessage = self._mav.decode(frame)
        except (mavlink2.MAVError, struct.error, ValueError, IndexError) as exc:
            logger.debug("skipping bad MAVLink frame: %s", exc)
            return None
        if isinstance(msg, mavlink2.MAVLink_unknown):
            # Unknown ids are returned without a CRC check: cannot tell them from garbage.
            logger.debug("skipping frame with unknown message id %s", msg.get_msgId())
            return None
        return msg


def _next_marker(buf: bytearray, start: int) -> int:
    """Index of the next MAVLink start-of-frame byte at or after ``start``, or -1."""
    v2 = buf.find(mavlink2.PROTOCOL_MARKER_V2, start)
    v1 = buf.find(mavlink2.PROTOCOL_MARKER_V1, start)
    if v2 < 0:
        return v1
    if v1 < 0:
        return v2
    return min(v1, v2)


def _frame_length(buf: bytearray, start: int) -> int | None:
    """Total length of the frame starting at ``start``, or None if the header is cut."""
    if len(buf) - start < 3:
        return None
    payload_len = buf[start + 1]
    if buf[start] == mavlink2.PROTOCOL_MARKER_V1:
        return mavlink2.HEADER_LEN_V1 + payload_len + 2
    signed = buf[start + 2] & mavlink2.MAVLINK_IFLAG_SIGNED
    signature = mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN if signed else 0
    return mavlink2.HEADER_LEN_V2 + payload_len + 2 + signature
