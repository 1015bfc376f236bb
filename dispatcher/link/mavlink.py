"""The one adapter around pymavlink: MAVLink 2 frames in and out as raw bytes.

Everything else in agrifleet talks MAVLink through this module, so pymavlink is imported
here only. Frames travel as bytes (over Zenoh, later), so :class:`Codec` packs a message
into one MAVLink 2 frame and parses frames back out of any byte string, skipping garbage.

Messages are pymavlink's ``ardupilotmega`` dialect objects (a superset of ``common``),
the dialect ArduPilot Rover speaks.

:func:`open_mavlink` opens a MAVLink link (serial, TCP, UDP) with pymavlink's ``mavutil``
for the bridge to a real autopilot and the simulator's MAVLink port: a
:class:`MavlinkConnection` that parses MAVLink 2 and raises :class:`LinkDown` when the link
drops, instead of printing and reconnecting by itself.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import hashlib
import heapq
import hmac
import logging
import math
import socket
import struct
import time
from dataclasses import dataclass
from typing import Any, TypeAlias

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from dispatcher.config.errors import DispatcherError

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
MAV_AUTOPILOT_INVALID: int = mavlink2.MAV_AUTOPILOT_INVALID  # a ground station, a companion
MAV_TYPE_GROUND_ROVER: int = mavlink2.MAV_TYPE_GROUND_ROVER
MAV_COMP_ID_AUTOPILOT1: int = mavlink2.MAV_COMP_ID_AUTOPILOT1
MAV_COMP_ID_ONBOARD_COMPUTER: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER

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


def peer_heartbeat(mav_type: int) -> MAVLinkMessage:
    """The HEARTBEAT of a component that is no autopilot (a ground station, a companion
    computer): its type, no autopilot, active."""
    return message(
        "HEARTBEAT",
        type=mav_type,
        autopilot=mavlink2.MAV_AUTOPILOT_INVALID,
        base_mode=0,
        custom_mode=0,
        system_status=mavlink2.MAV_STATE_ACTIVE,
        mavlink_version=3,
    )


def is_message_name(name: str) -> bool:
    """Whether ``name`` is a message of the dialect, e.g. "GLOBAL_POSITION_INT"."""
    return name.isupper() and hasattr(mavlink2, f"MAVLink_{name.lower()}_message")


def course_deg(msg: MAVLinkMessage) -> float | None:
    """A GLOBAL_POSITION_INT's course over ground in degrees, None when it says it is
    unknown (``hdg`` UINT16_MAX)."""
    return None if msg.hdg == 0xFFFF else msg.hdg / 100.0


def has_fix(lat_deg: float, lon_deg: float) -> bool:
    """Whether a reported position (degrees) is a fix: finite, on the globe, and not the
    0, 0 an autopilot reports in GLOBAL_POSITION_INT before it has one."""
    return (
        math.isfinite(lat_deg)
        and math.isfinite(lon_deg)
        and -90.0 <= lat_deg <= 90.0
        and -180.0 <= lon_deg <= 180.0
        and not (lat_deg == 0.0 and lon_deg == 0.0)
    )


def statustext(msg: MAVLinkMessage) -> str:
    """The text of a STATUSTEXT, without its NUL padding."""
    text = msg.text
    if isinstance(text, bytes | bytearray):
        text = bytes(text).decode("utf-8", "replace")
    return str(text).split("\x00", 1)[0].strip()


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


SIGNING_KEY_BYTES = 32
"""A MAVLink 2 signing secret key is 32 bytes."""

_SIGNING_EPOCH_UNIX_S = 1_420_070_400  # 2015-01-01T00:00:00Z, the signing timestamps' zero


SIGNATURE_LEN = 13  # a MAVLink 2 signature: link id, 6-byte timestamp, 6-byte hash


def signing_timestamp(unix_s: float | None = None) -> int:
    """The MAVLink 2 signing timestamp of ``unix_s`` (default: now): units of 10 us since
    1 January 2015 UTC, as the signing specification counts them."""
    t = time.time() if unix_s is None else unix_s
    return max(0, int((t - _SIGNING_EPOCH_UNIX_S) * 100_000))


class _MAVLink(mavlink2.MAVLink):  # type: ignore[misc]
    """pymavlink's parser with the signature checked before the timestamp is believed.

    pymavlink's ``check_signature`` records a frame's timestamp as its stream's newest
    before it checks the signature: one forged frame with a late timestamp would make every
    genuine frame after it look like a replay. Here a frame counts only once its signature
    is right. Then its timestamp must not have been seen on its stream before (a replay)
    and be newer than the stream's newest less :data:`REORDER_WINDOW` — the specification
    wants it newer than the newest, but a radio or a network that delivers frames out of
    order would then lose every frame overtaken by a later one; the timestamps of that
    window are remembered, so a frame is still taken at most once (the sliding window of
    IPsec's replay protection, RFC 4303). A stream not seen before must be at most a
    minute older than the clock (the specification says than our own timestamp; ours may
    run ahead of the clock after a restart, by the margin the dispatcher keeps, and would
    then refuse every sender met anew)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # Per stream, the timestamps taken within the window: a set to look them up, and
        # the same in a heap to let the oldest go as the window moves on.
        self._recent: dict[tuple[int, int, int], set[int]] = {}
        self._oldest: dict[tuple[int, int, int], list[int]] = {}

    def check_signature(self, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        signing = self.signing
        if not signature_good(msgbuf, signing.secret_key):
            return False
        low, high = struct.unpack("<IH", bytes(msgbuf[-12:-6]))
        stamp = low + (high << 32)
        stream = (msgbuf[-13], src_system, src_component)
        last = signing.stream_timestamps.get(stream)
        recent = self._recent.setdefault(stream, set())
        if last is not None and (stamp <= last - REORDER_WINDOW or stamp in recent):
            return False
        if last is None and stamp + _NEW_STREAM_SLACK < signing_timestamp():
            return False
        newest = stamp if last is None else max(last, stamp)
        recent.add(stamp)
        oldest = self._oldest.setdefault(stream, [])
        heapq.heappush(oldest, stamp)
        while oldest[0] <= newest - REORDER_WINDOW:  # out of the window: refused by age now
            recent.discard(heapq.heappop(oldest))
        signing.stream_timestamps[stream] = newest
        signing.timestamp = max(signing.timestamp, stamp)
        return True


_NEW_STREAM_SLACK = 60 * 100_000  # one minute in signing timestamp units

REORDER_WINDOW = 2 * 100_000
"""How far (10 us units: two seconds) a signed frame may arrive behind the newest of its
stream and still be taken, once (:class:`_MAVLink`)."""


RECENT_FRAMES = 512
SENT_SIGNATURES = 4096
"""The signatures of its own last frames a signing :class:`Codec` keeps (minutes of a
vehicle's commands and heartbeats), to tell one of them sent again (a replay, which the
vehicle refuses) from a frame signed anew with the key."""
"""Signed frames a codec remembers taking, to tell a radio's copy of one from a forgery."""


class _Recent:
    """The last ``size`` frames added, for ``in``."""

    def __init__(self, size: int) -> None:
        self._order: collections.deque[bytes] = collections.deque()
        self._set: set[bytes] = set()
        self._size = size

    def add(self, frame: bytes) -> None:
        if frame in self._set:
            return
        self._order.append(frame)
        self._set.add(frame)
        if len(self._order) > self._size:
            self._set.discard(self._order.popleft())

    def __contains__(self, frame: object) -> bool:
        return frame in self._set


def signature_good(frame: bytes | bytearray, key: bytes) -> bool:
    """Whether a signed MAVLink 2 frame's signature is ``key``'s (the signature alone: not
    whether its timestamp is new)."""
    digest = hashlib.sha256(key + bytes(frame[:-6])).digest()[:6]
    return hmac.compare_digest(digest, bytes(frame[-6:]))


def frame_signature(frame: bytes) -> tuple[int, int] | None:
    """A signed MAVLink 2 frame's (link id, timestamp), or None for any other frame."""
    if len(frame) < 10 + SIGNATURE_LEN or frame[0] != mavlink2.PROTOCOL_MARKER_V2:
        return None
    if not frame[2] & mavlink2.MAVLINK_IFLAG_SIGNED:
        return None
    tail = frame[-SIGNATURE_LEN:]
    return tail[0], int.from_bytes(tail[1:7], "little")


def _set_signing(mav: Any, key: bytes, link_id: int, timestamp: int | None) -> None:
    if len(key) != SIGNING_KEY_BYTES:
        raise ValueError(f"a signing key is {SIGNING_KEY_BYTES} bytes, got {len(key)}")
    if not 0 <= link_id <= 255:
        raise ValueError(f"a signing link id is 0..255, got {link_id}")
    signing = mav.signing
    signing.secret_key = bytes(key)
    signing.link_id = link_id
    signing.sign_outgoing = True
    signing.timestamp = max(signing.timestamp, signing_timestamp(), timestamp or 0)
    signing.allow_unsigned_callback = lambda _mav, _msg_id: False


def _stats(mav: Any) -> SigningStats:
    s = mav.signing
    return SigningStats(
        good=s.goodsig_count, bad=s.badsig_count, unsigned=s.reject_count - s.badsig_count
    )


@dataclass(frozen=True)
class SigningStats:
    """Frames a signing :class:`Codec` took (``good``) and dropped: ``bad`` (a wrong
    signature, or a replay: a timestamp not newer than that stream's last), ``unsigned``,
    and ``duplicate``: copies of frames it took (a radio repeats some), no signing matter
    and not in :attr:`dropped`."""

    good: int = 0
    bad: int = 0
    unsigned: int = 0
    duplicate: int = 0

    @property
    def dropped(self) -> int:
        return self.bad + self.unsigned


class Codec:
    """Packs messages into MAVLink 2 frames from one system/component, and parses frames.

    ``encode`` stamps each frame with the next sequence number (0..255, wrapping).
    ``decode`` treats successive calls as one byte stream: garbage is skipped (a frame
    must pass its CRC to count), and a frame cut off at the end of one call is completed
    by the bytes of the next.

    With a signing ``key`` (:meth:`sign`) every frame is signed (MAVLink 2 message
    signing: link id, a timestamp that never goes back, SHA-256 of key and frame) and
    only frames signed with the same key and a timestamp newer than the last of their
    stream are taken; the others are dropped and counted (:attr:`signing_stats`).
    Without one, frames go out unsigned and signed ones are parsed without checking.
    """

    def __init__(
        self,
        system_id: int,
        component_id: int,
        key: bytes | None = None,
        link_id: int = 0,
        timestamp: int | None = None,
    ) -> None:
        if not 1 <= system_id <= 255:
            raise ValueError(f"MAVLink system id must be 1..255, got {system_id}")
        if not 0 <= component_id <= 255:
            raise ValueError(f"MAVLink component id must be 0..255, got {component_id}")
        self.system_id = system_id
        self.component_id = component_id
        self._mav = _MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self._pending = bytearray()
        self._taken: _Recent = _Recent(RECENT_FRAMES)  # the last signed frames taken
        self._sent: _Recent = _Recent(SENT_SIGNATURES)  # the signatures of the last sent
        self._duplicates = 0
        if key is not None:
            self.sign(key, link_id, timestamp)

    def sign(self, key: bytes, link_id: int = 0, timestamp: int | None = None) -> None:
        """Sign from now on with ``key`` on link ``link_id`` (0..255), the timestamps
        starting at ``timestamp`` or now, whichever is later (never back: give the last one
        used before a restart), and take only frames signed with ``key``."""
        _set_signing(self._mav, key, link_id, timestamp)

    @property
    def signed(self) -> bool:
        return self._mav.signing.secret_key is not None

    def _follow_clock(self) -> None:
        """Signing timestamps follow the clock (pymavlink only adds one per frame): a
        receiver meeting this sender anew takes a stream at most a minute behind its clock."""
        signing = self._mav.signing
        if signing.sign_outgoing:
            signing.timestamp = max(signing.timestamp, signing_timestamp())

    @property
    def timestamp(self) -> int:
        """The signing timestamp the next frame will carry (to keep across a restart)."""
        return int(self._mav.signing.timestamp)

    @property
    def signing_stats(self) -> SigningStats:
        stats = _stats(self._mav)
        return dataclasses.replace(
            stats, bad=stats.bad - self._duplicates, duplicate=self._duplicates
        )

    def sent_before(self, frame: bytes) -> bool:
        """Whether ``frame`` carries the signature of one of this codec's last frames
        (:data:`SENT_SIGNATURES`): one of its frames again (a replay, which a receiver that
        heard the first refuses), not a frame signed anew with the key. (A frame signed
        anew with an older timestamp than this codec's last is no replay: a receiver takes
        it within its reordering window; a leaked key.)"""
        if frame_signature(frame) is None or not self.signed:
            return False
        return bytes(frame[-SIGNATURE_LEN:]) in self._sent

    def _sent_frame(self, frame: bytes) -> bytes:
        if self.signed:
            self._sent.add(bytes(frame[-SIGNATURE_LEN:]))
        return frame

    @property
    def next_seq(self) -> int:
        """The sequence number the next encoded frame will carry."""
        seq: int = self._mav.seq
        return seq

    def encode(self, msg: MAVLinkMessage) -> bytes:
        """One MAVLink 2 frame carrying ``msg``; advances the sequence number."""
        self._follow_clock()
        frame = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        return self._sent_frame(frame)

    def repack(self, msg: MAVLinkMessage) -> bytes:
        """``msg`` as a MAVLink 2 frame from its own system, component and sequence number,
        signed when this codec signs: a frame another sender sent unsigned (an autopilot
        without signing, behind the bridge), passed on signed."""
        self._follow_clock()
        mav = self._mav
        own = (mav.srcSystem, mav.srcComponent, mav.seq)
        mav.srcSystem, mav.srcComponent, mav.seq = (
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            msg.get_seq(),
        )
        try:
            frame: bytes = msg.pack(mav)
        finally:
            mav.srcSystem, mav.srcComponent, mav.seq = own
        return self._sent_frame(frame)

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
        bad_before = self._mav.signing.badsig_count
        try:
            msg: MAVLinkMessage = self._mav.decode(frame)
        except (mavlink2.MAVError, struct.error, ValueError, IndexError) as exc:
            logger.debug("skipping bad MAVLink frame: %s", exc)
            if self._mav.signing.badsig_count > bad_before and bytes(frame) in self._taken:
                self._duplicates += 1  # a copy of a frame taken: the radio's, not a forgery
            return None
        if self.signed:  # taken signed (a codec that signs takes no other)
            self._taken.add(bytes(frame))
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


# --- MAVLink links (pymavlink's mavutil) ---------------------------------------------------

DEFAULT_SERIAL_BAUD = 115200
TCP_CONNECT_TIMEOUT_S = 3.0
_URL_SCHEMES = ("tcp:", "tcpin:", "udp:", "udpin:", "udpout:", "udpbcast:")


class LinkDown(DispatcherError):
    """A MAVLink link could not be opened or has dropped (TCP closed, serial port gone);
    opening it again later may succeed."""


def check_mavlink_url(url: str) -> None:
    """Raise ValueError unless ``url`` is a MAVLink URL :func:`open_mavlink` takes:
    ``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, ``udp:``/``udpin:``/``udpout:``/``udpbcast:HOST:PORT``
    or a serial device ``DEVICE[,BAUD]`` (``/dev/ttyUSB0,57600``, ``COM3``)."""
    scheme = next((s for s in _URL_SCHEMES if url.startswith(s)), None)
    if scheme is not None:
        host, sep, port = url[len(scheme) :].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ValueError(f"MAVLink URL {url!r}: want {scheme}HOST:PORT")
        return
    device, sep, baud = url.partition(",")
    path_like = device.startswith("/") or ":" not in device  # /dev/serial/by-path/...:1.0
    if not device or not path_like or (sep and not baud.isdigit()):
        raise ValueError(
            f"MAVLink URL {url!r}: want tcp:HOST:PORT, tcpin:HOST:PORT, udpin:HOST:PORT, "
            "udpout:HOST:PORT or a serial device DEVICE[,BAUD]"
        )


class MavlinkConnection:
    """One MAVLink link opened with pymavlink's ``mavutil``: a TCP client or server, a UDP
    socket or a serial port.

    Frames are parsed with the MAVLink 2 ``ardupilotmega`` dialect (MAVLink 1 frames are
    parsed too), whatever the process's ``MAVLINK20`` setting. A TCP connection closed by
    the other side and a serial port that fails raise :class:`LinkDown`; a TCP server
    (``tcpin:``) instead waits for the next client. Not thread-safe: one thread reads and
    writes.
    """

    def __init__(self, url: str, port: Any) -> None:
        self.url = url
        self._port = port
        _reset_parser(port)

    def verify_with(self, key: bytes) -> None:
        """Take only frames signed with ``key`` from now on (others are skipped and
        counted: :attr:`signing_stats`); frames written go out as given."""
        _set_signing(self._port.mav, key, 0, None)
        self._port.mav.signing.sign_outgoing = False

    @property
    def signing_stats(self) -> SigningStats:
        return _stats(self._port.mav)

    def fileno(self) -> int | None:
        """The descriptor to wait on for input (it changes as a TCP server accepts a
        client), or None if the link has none (poll instead)."""
        fd: int | None = self._port.fd
        return fd

    def receive(self) -> list[MAVLinkMessage]:
        """Every message that has arrived, without blocking (bad frames are skipped)."""
        messages: list[MAVLinkMessage] = []
        try:
            while (msg := self._port.recv_msg()) is not None:
                kind = msg.get_type()
                if kind == "BAD_DATA" or isinstance(msg, mavlink2.MAVLink_unknown):
                    logger.debug("%s: skipping %s", self.url, kind)
                    continue
                messages.append(msg)
        except OSError as exc:  # socket or serial errors (SerialException is an OSError)
            raise LinkDown(f"MAVLink link {self.url} failed: {exc}") from exc
        return messages

    def write(self, frame: bytes) -> None:
        """Send one frame as it is (a UDP or TCP server with no peer yet drops it)."""
        try:
            self._port.write(frame)
        except OSError as exc:
            raise LinkDown(f"MAVLink link {self.url} failed: {exc}") from exc
        if getattr(self._port, "portdead", False):
            raise LinkDown(f"MAVLink link {self.url}: the serial port is gone")

    def close(self) -> None:
        try:
            self._port.close()
        except OSError as exc:
            logger.debug("closing %s: %s", self.url, exc)


def open_mavlink(
    url: str, source_system: int = 255, source_component: int = 0
) -> MavlinkConnection:
    """Open the MAVLink link ``url`` (see :func:`check_mavlink_url`) with pymavlink's mavutil.

    A TCP client tries once, for at most :data:`TCP_CONNECT_TIMEOUT_S` (no retry loop, no
    reconnect: the caller decides). Raises
    ValueError for a malformed URL and :class:`LinkDown` if the link cannot be opened.
    """
    check_mavlink_url(url)
    classes = _link_classes()
    ids = {"source_system": source_system, "source_component": source_component}
    try:
        if url.startswith("tcp:"):
            port = classes.tcp_client(url[4:], **ids)
        elif url.startswith("tcpin:"):
            port = classes.tcp_server(url[6:], **ids)
        elif url.startswith("udp"):
            port = classes.mavutil.mavlink_connection(url, **ids)
        else:
            device, _, baud = url.partition(",")
            port = classes.serial(device, baud=int(baud or DEFAULT_SERIAL_BAUD), **ids)
    except ImportError as exc:
        raise ValueError(f"{url}: serial links need pyserial (pip install pyserial)") from exc
    except OSError as exc:  # refused, unreachable, no such device, address in use ...
        raise LinkDown(f"cannot open MAVLink link {url}: {exc}") from exc
    return MavlinkConnection(url, port)


def setup_signing(target_system: int, key: bytes, initial_timestamp: int) -> MAVLinkMessage:
    """SETUP_SIGNING: give an autopilot its signing key (an all-zero key and timestamp
    turn signing off)."""
    msg: MAVLinkMessage = mavlink2.MAVLink_setup_signing_message(
        target_system, MAV_COMP_ID_AUTOPILOT1, list(key), initial_timestamp
    )
    return msg


def mavlink2_frame(msg: MAVLinkMessage, signer: Codec | None = None) -> bytes:
    """The frame ``msg`` arrived in, as MAVLink 2: its own bytes if it came as MAVLink 2
    and signed, or unsigned when there is no ``signer``; else packed again as MAVLink 2 with
    the same system, component and sequence number, signed by ``signer`` when given (this
    rewrites ``msg``'s buffer)."""
    raw = bytes(msg.get_msgbuf())
    v2 = raw[:1] == bytes([mavlink2.PROTOCOL_MARKER_V2])
    if v2 and (signer is None or raw[2] & mavlink2.MAVLINK_IFLAG_SIGNED):
        return raw
    return (signer or Codec(msg.get_srcSystem() or 1, msg.get_srcComponent())).repack(msg)


@dataclass(frozen=True)
class _LinkClasses:
    mavutil: Any
    tcp_client: Any
    tcp_server: Any
    serial: Any


@functools.cache
def _link_classes() -> _LinkClasses:
    """mavutil's link classes, adjusted to report a dead link instead of printing and
    reconnecting by themselves; imported on first use (mavutil loads a dialect at import)."""
    from pymavlink import mavutil

    class TcpClient(mavutil.mavtcp):  # type: ignore[misc, name-defined]
        def do_connect(self) -> None:
            """One attempt, bounded by a timeout (mavutil retries and sleeps)."""
            self.port = socket.create_connection(self.destination_addr, TCP_CONNECT_TIMEOUT_S)
            self.port.setblocking(False)
            self.port.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            mavutil.set_close_on_exec(self.port.fileno())

        def handle_disconnect(self) -> None:
            raise LinkDown(f"MAVLink link {self.address}: connection reset")

        def handle_eof(self) -> None:
            raise LinkDown(f"MAVLink link {self.address}: closed by the other side")

    class TcpServer(mavutil.mavtcpin):  # type: ignore[misc, name-defined]
        def recv(self, n: int | None = None) -> bytes:
            data: bytes = super().recv(n)
            client: socket.socket | None = self.port  # type: ignore[has-type]
            if not data and client is not None and _peer_closed(client):
                logger.info("%s: the MAVLink client left; waiting for the next", self.address)
                client.close()
                self.port = None
                self.fd = self.listen.fileno()
                _reset_parser(self)  # drop a frame the last client left half-sent
            return data

    class Serial(mavutil.mavserial):  # type: ignore[misc, name-defined]
        def write(self, buf: bytes) -> int:
            written: int = self.port.write(bytes(buf))  # errors reach the caller
            return written

    return _LinkClasses(mavutil, TcpClient, TcpServer, Serial)


def _reset_parser(port: Any) -> None:
    """Give a mavutil link a fresh MAVLink 2 ardupilotmega parser: mavutil otherwise parses
    with a process-wide dialect chosen from the environment."""
    port.mav = _MAVLink(port, srcSystem=port.source_system, srcComponent=port.source_component)
    port.mav.robust_parsing = True
    port.first_byte = False  # no switching of protocol version on the first byte
    port.WIRE_PROTOCOL_VERSION = "2.0"


def _peer_closed(sock: socket.socket) -> bool:
    """Whether the other end of a connected, non-blocking TCP socket has closed it."""
    try:
        return sock.recv(1, socket.MSG_PEEK) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True
