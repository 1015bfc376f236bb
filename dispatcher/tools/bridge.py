"""The bridge: one real autopilot on the farm's Zenoh network, as the wire contract has it.

Runs on the tractor's companion computer, between the autopilot's MAVLink link (serial,
TCP or UDP, opened with pymavlink through :mod:`dispatcher.link.mavlink`) and Zenoh:

* every sample on ``vehicle_to(farm, id)`` is written to the autopilot as it is;
* frames from the autopilot (system = the scenario's ``system_id``, component 1) that the
  dispatcher uses go to ``vehicle_from(farm, id)``, one frame per sample, telemetry at a
  bounded rate per message type (:class:`AutopilotFilter`); a MAVLink 1 frame is packed
  again as MAVLink 2 with its system, component and sequence number, a MAVLink 2 frame
  goes as it came (signature included);
* with the vehicle's signing key (dispatcher/link/keys.py), only samples signed with it
  reach the autopilot (the others are dropped and counted: forged, or replayed), and what
  the autopilot sends unsigned is signed on its way to Zenoh (an autopilot with signing set
  up signs itself: its frames go as they are). ArduPilot set up with the same key
  (docs/bridge.md) then takes commands from the dispatcher only, whatever reaches its radio;
* the liveliness token ``vehicle_alive(farm, id)`` is held while the autopilot's HEARTBEAT
  is live: declared on the first one, undeclared after ``heartbeat_timeout_s`` without one,
  declared again when they come back.

So the dispatcher sees what a simulated tractor shows it. A dropped link (TCP closed,
serial port unplugged, or nothing heard for :data:`RELINK_AFTER_SILENCE_S`) is opened
again every ``reconnect_interval_s``; frames from the dispatcher meanwhile are dropped
(the mission protocol retries). The bridge sends its own 1 Hz HEARTBEAT to the autopilot
as an onboard computer (same system id, component 191), so that a UDP autopilot learns
where to send and MAVLink routers see a companion; it never speaks for the dispatcher.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import queue
import select
import socket
import sys
import threading
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import zenoh

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import Scenario, Vehicle, add_fields_argument
from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.link.keys import add_signing_arguments, signing_keys
from dispatcher.link.signals import stop_on_signals

log = logging.getLogger(__name__)

EXIT_OK = 0
EXIT_BAD_INPUT = 2

NEVER_LIMITED = frozenset(
    {
        "HEARTBEAT",
        "MISSION_COUNT",
        "MISSION_ITEM",
        "MISSION_ITEM_INT",
        "MISSION_REQUEST",
        "MISSION_REQUEST_INT",
        "MISSION_ACK",
        "MISSION_ITEM_REACHED",
        "COMMAND_ACK",
        "STATUSTEXT",
    }
)
"""Forwarded every time: the mission and command protocols, progress, presence, texts."""

DEFAULT_RATE_LIMITS: Mapping[str, float] = MappingProxyType(
    {
        "GLOBAL_POSITION_INT": 10.0,
        "MISSION_CURRENT": 4.0,
        "SYSTEM_TIME": 2.0,
        "SYS_STATUS": 2.0,
        "BATTERY_STATUS": 2.0,
    }
)
"""Telemetry forwarded at most this often (Hz, long-run average; bursts of 2 pass)."""

PASS_ON_CHANGE = frozenset({"MISSION_CURRENT"})
"""Rate-limited types whose sample passes anyway when its content changed."""

BURST = 2.0
HEARTBEAT_TIMEOUT_S = 3.0
RECONNECT_INTERVAL_S = 1.0
RELINK_AFTER_SILENCE_S = 10.0
COMPANION_HEARTBEAT_PERIOD_S = 1.0
MAX_WAIT_S = 0.1


@dataclass
class _TokenBucket:
    rate_hz: float
    tokens: float = BURST
    last: float | None = None

    def take(self, now: float) -> bool:
        if self.last is not None:
            self.tokens = min(BURST, self.tokens + (now - self.last) * self.rate_hz)
        self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class AutopilotFilter:
    """Which messages from the autopilot link go to the dispatcher (no I/O).

    Only the autopilot's own (``system_id``, ``component_id``) counts; its messages pass if
    their type is in :data:`NEVER_LIMITED`, or in ``rate_limits`` and within the rate.
    ``counts`` tells what happened: ``forwarded``, ``other_source``, ``other_type``,
    ``rate_limited``.
    """

    def __init__(
        self,
        system_id: int,
        component_id: int = mc.MAV_COMP_ID_AUTOPILOT1,
        rate_limits: Mapping[str, float] = DEFAULT_RATE_LIMITS,
    ) -> None:
        check_rate_limits(rate_limits)
        self.system_id = system_id
        self.component_id = component_id
        self.rate_limits = dict(rate_limits)
        self.counts: Counter[str] = Counter()
        self._buckets = {kind: _TokenBucket(hz) for kind, hz in rate_limits.items()}
        self._last_content: dict[str, tuple[object, ...]] = {}
        self._strangers: set[tuple[int, int]] = set()

    def stranger(self, msg: mc.MAVLinkMessage) -> tuple[int, int] | None:
        """The (system, component) of an autopilot other than ours that ``msg`` shows
        (its HEARTBEAT, not a ground station's or a companion's), the first time; else
        None. An autopilot whose MAV_SYSID is not the fleet file's ``system_id``."""
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        if (
            msg.get_type() != "HEARTBEAT"
            or msg.autopilot == mc.MAV_AUTOPILOT_INVALID
            or self.from_autopilot(msg)
            or source in self._strangers
        ):
            return None
        self._strangers.add(source)
        return source

    def from_autopilot(self, msg: mc.MAVLinkMessage) -> bool:
        return (msg.get_srcSystem(), msg.get_srcComponent()) == (self.system_id, self.component_id)

    def admit(self, msg: mc.MAVLinkMessage, now: float) -> bool:
        """Whether to forward ``msg``, received at ``now`` (monotonic seconds)."""
        kind = msg.get_type()
        if not self.from_autopilot(msg):
            reason = "other_source"
        elif kind in NEVER_LIMITED:
            reason = "forwarded"
        elif kind not in self._buckets:
            reason = "other_type"
        elif self._passes_limit(kind, msg, now):
            reason = "forwarded"
        else:
            reason = "rate_limited"
        self.counts[reason] += 1
        return reason == "forwarded"

    def _passes_limit(self, kind: str, msg: mc.MAVLinkMessage, now: float) -> bool:
        taken = self._buckets[kind].take(now)
        if kind not in PASS_ON_CHANGE:
            return taken
        content = tuple(getattr(msg, name) for name in msg.get_fieldnames())
        if content == self._last_content.get(kind) and not taken:
            return False
        self._last_content[kind] = content
        return True


def check_rate_limits(rate_limits: Mapping[str, float]) -> None:
    """Raise ConfigError unless every entry is a message type outside :data:`NEVER_LIMITED`
    with a rate > 0 Hz."""
    for kind, hz in rate_limits.items():
        if not mc.is_message_name(kind):
            raise ConfigError(f"rate limit for {kind!r}: not a MAVLink message")
        if kind in NEVER_LIMITED:
            raise ConfigError(f"rate limit for {kind}: that message is never rate-limited")
        if not (hz > 0.0 and math.isfinite(hz)):
            raise ConfigError(f"rate limit for {kind}: want a rate > 0 Hz, got {hz}")


class HeartbeatPresence:
    """The autopilot is present from a HEARTBEAT until ``timeout_s`` without one (no I/O)."""

    def __init__(self, timeout_s: float = HEARTBEAT_TIMEOUT_S) -> None:
        if not timeout_s > 0.0:
            raise ConfigError(f"heartbeat timeout must be > 0 s, got {timeout_s}")
        self.timeout_s = timeout_s
        self._last: float | None = None

    def on_heartbeat(self, now: float) -> None:
        self._last = now

    def present(self, now: float) -> bool:
        return self._last is not None and now - self._last <= self.timeout_s


def run_bridge(
    scenario: Scenario,
    vehicle_id: str,
    mavlink_url: str,
    options: wire.ZenohOptions,
    stop: threading.Event | None = None,
    rate_limits: Mapping[str, float] = DEFAULT_RATE_LIMITS,
    heartbeat_timeout_s: float = HEARTBEAT_TIMEOUT_S,
    reconnect_interval_s: float = RECONNECT_INTERVAL_S,
    companion_heartbeat: bool = True,
    key: bytes | None = None,
    setup_signing: bool = False,
) -> int:
    """Bridge the autopilot of ``vehicle_id`` at ``mavlink_url`` to Zenoh until ``stop`` is
    set or SIGINT/SIGTERM; returns the exit code. ``key``: the vehicle's signing key (None:
    frames pass unchecked and unsigned); ``setup_signing``: give the autopilot that key
    (SETUP_SIGNING) each time its link opens.

    Raises ConfigError for an unknown vehicle or a bad rate limit, ValueError for a bad
    URL. A link that cannot be opened is tried again every ``reconnect_interval_s``.
    """
    vehicle = scenario.vehicle(vehicle_id)
    mc.check_mavlink_url(mavlink_url)
    if not reconnect_interval_s > 0.0:
        raise ConfigError(f"reconnect interval must be > 0 s, got {reconnect_interval_s}")
    autopilot_filter = AutopilotFilter(vehicle.system_id, rate_limits=rate_limits)
    presence = HeartbeatPresence(heartbeat_timeout_s)
    stop = stop if stop is not None else threading.Event()
    restore_signals = stop_on_signals(stop, "stopping the bridge")
    log.info(
        "bridging %s (system %d) at %s to farm %r",
        vehicle.id,
        vehicle.system_id,
        mavlink_url,
        scenario.farm_id,
    )
    try:
        with options.open() as session:
            bridge = _Bridge(
                scenario.farm_id,
                vehicle,
                mavlink_url,
                autopilot_filter,
                presence,
                reconnect_interval_s,
                companion_heartbeat,
                key,
                setup_signing,
            )
            code = bridge.run(session, stop)
    finally:
        restore_signals()
    log.info("bridge stopped: %s", bridge.summary())
    return code


class _Bridge:
    """The bridge's state and I/O; :meth:`run` is its loop (one thread for the link)."""

    def __init__(
        self,
        farm: str,
        vehicle: Vehicle,
        url: str,
        autopilot_filter: AutopilotFilter,
        presence: HeartbeatPresence,
        reconnect_interval_s: float,
        companion_heartbeat: bool,
        key: bytes | None = None,
        setup_signing: bool = False,
    ) -> None:
        self.farm = farm
        self.setup_key = key if setup_signing else None
        # With a key: checks what comes from Zenoh, signs what the autopilot leaves unsigned.
        self.checker = mc.Codec(vehicle.system_id, mc.MAV_COMP_ID_ONBOARD_COMPUTER, key=key)
        self.signer = (
            mc.Codec(vehicle.system_id, mc.MAV_COMP_ID_AUTOPILOT1, key=key)
            if key is not None
            else None
        )
        self.vehicle = vehicle
        self.url = url
        self.filter = autopilot_filter
        self.presence = presence
        self.reconnect_interval_s = reconnect_interval_s
        self.companion = (
            mc.Codec(vehicle.system_id, mc.MAV_COMP_ID_ONBOARD_COMPUTER)
            if companion_heartbeat
            else None
        )
        self.link: mc.MavlinkConnection | None = None
        self.token: zenoh.LivelinessToken | None = None
        self.publisher: zenoh.Publisher | None = None
        self.session: zenoh.Session | None = None
        self.inbox: queue.Queue[bytes] = queue.Queue()  # frames from Zenoh, never dropped here
        self._wake_r, self._wake_w = socket.socketpair()  # the Zenoh callback wakes the loop
        self.stats: Counter[str] = Counter()
        # Whether the autopilot signs with the vehicle's key (seen so): from then on what
        # comes unsigned on its link is a stranger's, dropped, not signed on its way (it was:
        # anyone on the link could send the dispatcher reports it took as genuine).
        self.key = key
        self.autopilot_signs = False
        self._link_unsigned = 0  # what the link (checking signatures) refused unsigned
        self._next_attempt = 0.0
        self._last_rx = 0.0
        self._next_companion_beat = 0.0
        self._quiet_failures = False

    def run(self, session: zenoh.Session, stop: threading.Event) -> int:
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self.session = session
        self.publisher = session.declare_publisher(
            wire.vehicle_from(self.farm, self.vehicle.id),
            congestion_control=zenoh.CongestionControl.BLOCK,
        )
        subscriber = session.declare_subscriber(
            wire.vehicle_to(self.farm, self.vehicle.id), self._on_sample
        )
        try:
            while not stop.is_set():
                if not self._step(time.monotonic()):
                    return EXIT_BAD_INPUT
            return EXIT_OK
        finally:
            if self.token is not None:
                self.token.undeclare()
                self.token = None
            subscriber.undeclare()
            self.publisher.undeclare()
            self._close_link()
            self._wake_r.close()
            self._wake_w.close()

    def summary(self) -> str:
        parts = {**self.stats, **{f"from_autopilot_{k}": v for k, v in self.filter.counts.items()}}
        return ", ".join(f"{k}={v}" for k, v in sorted(parts.items())) or "nothing bridged"

    # --- Zenoh callback (another thread): queue and wake the loop ------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.inbox.put(sample.payload.to_bytes())
        with contextlib.suppress(OSError):  # full (the loop is behind anyway) or closing
            self._wake_w.send(b"\0")

    # --- the loop ------------------------------------------------------------------------
    def _step(self, now: float) -> bool:
        """One turn: (re)connect, wait for input, move frames both ways, follow presence."""
        if self.link is None and now >= self._next_attempt and not self._connect(now):
            return False
        self._wait()
        now = time.monotonic()
        self._to_autopilot(now)
        self._from_autopilot(now)
        self._hold_token(self.presence.present(now))
        if self.link is not None:
            self._beat(now)
            if now - self._last_rx > RELINK_AFTER_SILENCE_S:
                self._drop_link(f"nothing heard for {RELINK_AFTER_SILENCE_S:g} s", now)
        return True

    def _wait(self) -> None:
        fds = [self._wake_r.fileno()]
        link_fd = self.link.fileno() if self.link is not None else None
        if link_fd is not None:
            fds.append(link_fd)
        timeout = MAX_WAIT_S if self.link is None or link_fd is not None else 0.01
        select.select(fds, [], [], timeout)
        with contextlib.suppress(BlockingIOError):
            while self._wake_r.recv(4096):
                pass

    def _connect(self, now: float) -> bool:
        """Try to open the link; False if it never can (a missing serial library)."""
        try:
            self.link = mc.open_mavlink(
                self.url, self.vehicle.system_id, mc.MAV_COMP_ID_ONBOARD_COMPUTER
            )
        except mc.LinkDown as exc:
            log.log(logging.DEBUG if self._quiet_failures else logging.WARNING, "%s", exc)
            if not self._quiet_failures:
                log.info("trying again every %g s", self.reconnect_interval_s)
            self._quiet_failures = True
            self._next_attempt = now + self.reconnect_interval_s
            return True
        except ValueError as exc:
            log.error("%s", exc)
            return False
        log.info("autopilot link %s open", self.url)
        if self.autopilot_signs:
            self._verify_link()  # it signs still: take nothing unsigned
        if self.setup_key is not None:
            self._setup_signing(self.setup_key)
        self.stats["links_opened"] += 1
        self._quiet_failures = False
        self._last_rx = now
        self._next_companion_beat = now
        return True

    def _setup_signing(self, key: bytes) -> None:
        """Give the autopilot the vehicle's key (SETUP_SIGNING, on this wired link): it
        signs from now on and, on every link but its first (USB), takes only signed
        frames. ArduPilot refuses it while armed."""
        assert self.link is not None
        setup = mc.setup_signing(self.vehicle.system_id, key, mc.signing_timestamp())
        self.link.write(
            mc.Codec(self.vehicle.system_id, mc.MAV_COMP_ID_ONBOARD_COMPUTER).encode(setup)
        )
        log.warning("%s: signing key sent to the autopilot (SETUP_SIGNING)", self.vehicle.id)

    def _drop_link(self, why: object, now: float) -> None:
        log.warning("autopilot link %s lost (%s); reopening it", self.url, why)
        self._close_link()
        self._next_attempt = now + self.reconnect_interval_s

    def _close_link(self) -> None:
        if self.link is not None:
            self.link.close()
            self.link = None

    def _to_autopilot(self, now: float) -> None:
        while True:
            try:
                frame = self.inbox.get_nowait()
            except queue.Empty:
                return
            if self.checker.signed and self.checker.decode_one(frame) is None:
                self.stats["to_autopilot_refused"] += 1
                refused = self.stats["to_autopilot_refused"]
                if refused == 1 or refused % 100 == 0:
                    log.warning(
                        "%s: dropped %d frame(s) for the autopilot not signed with its key",
                        self.vehicle.id,
                        refused,
                    )
                continue
            if self.link is None:
                self.stats["to_autopilot_dropped_no_link"] += 1
                log.debug("no autopilot link: dropped a %d-byte frame", len(frame))
                continue
            try:
                self.link.write(frame)
            except mc.LinkDown as exc:
                self._drop_link(exc, now)
                continue
            self.stats["to_autopilot"] += 1

    def _from_autopilot(self, now: float) -> None:
        if self.link is None:
            return
        try:
            messages = self.link.receive()
        except mc.LinkDown as exc:
            self._drop_link(exc, now)
            return
        if messages:
            self._last_rx = now
        if self.autopilot_signs:  # the frames the link itself refused unsigned
            refused = self.link.signing_stats.unsigned
            if refused > self._link_unsigned:
                self._unsigned_dropped(refused - self._link_unsigned)
                self._link_unsigned = refused
        assert self.publisher is not None
        for msg in messages:
            if not self._signed_as_it_should(msg):
                continue
            if msg.get_type() == "HEARTBEAT" and self.filter.from_autopilot(msg):
                self.presence.on_heartbeat(now)
            elif (source := self.filter.stranger(msg)) and not self.presence.present(now):
                log.warning(
                    "%s: %s carries the heartbeat of an autopilot as system %d component %d, "
                    "and none of system %d component %d (the fleet file's system_id): its "
                    "messages are not forwarded; give %s system_id = %d in the fleet file, "
                    "or set MAV_SYSID = %d on the autopilot",
                    self.vehicle.id,
                    self.url,
                    *source,
                    self.filter.system_id,
                    self.filter.component_id,
                    self.vehicle.id,
                    source[0],
                    self.filter.system_id,
                )
            if self.filter.admit(msg, now):
                self.publisher.put(mc.mavlink2_frame(msg, self.signer))

    def _signed_as_it_should(self, msg: mc.MAVLinkMessage) -> bool:
        """Whether to take ``msg`` from the autopilot link. Without a key, or until the
        autopilot is seen signing with it, everything (an autopilot that does not sign
        trusts its link, and what comes on it is signed here on its way to Zenoh). Once a
        frame of the autopilot's carries a good signature, the link takes only signed
        frames (pymavlink checks them), and one unsigned is dropped and counted."""
        if self.key is None:
            return True
        raw = bytes(msg.get_msgbuf())
        if mc.frame_signature(raw) is None:
            if not self.autopilot_signs:
                return True
            self._unsigned_dropped(1)
            return False
        # (the signature alone: an autopilot whose signing clock lags is one that signs)
        if not self.autopilot_signs and self.filter.from_autopilot(msg):
            if mc.signature_good(raw, self.key):
                self.autopilot_signs = True
                self._verify_link()
                log.info(
                    "%s: the autopilot signs: its link takes only signed frames now",
                    self.vehicle.id,
                )
            else:
                self._other_key()
        return True

    def _other_key(self) -> None:
        """A frame with the autopilot's ids signed with another key than the vehicle's:
        passed on (the dispatcher refuses it), counted, said at the first and every
        hundredth. Most often the autopilot holds a key replaced since: on a port other
        than its USB one it refuses a SETUP_SIGNING not signed with the key it holds, so
        --setup-signing there changes nothing (it went unsaid: the dispatcher refused every
        frame, and the tractor stood; an outside review)."""
        self.stats["from_autopilot_other_key"] += 1
        count = self.stats["from_autopilot_other_key"]
        if count == 1 or count % 100 == 0:
            log.error(
                "%s: %d frame(s) with the autopilot's ids signed with a key other than %s's "
                "(the dispatcher refuses them). If its key was replaced (agrifleet keys "
                "--replace), give the autopilot the new one on its USB port (SERIAL0; in SITL "
                "TCP 5760) with --setup-signing: on its other ports it takes SETUP_SIGNING "
                "only signed with the key it holds (docs/bridge.md)",
                self.vehicle.id,
                count,
                self.vehicle.id,
            )

    def _verify_link(self) -> None:
        """The autopilot's link takes only frames signed with the key from now on
        (pymavlink checks them); what it refuses is counted from here."""
        assert self.link is not None and self.key is not None
        self.link.verify_with(self.key)
        self._link_unsigned = 0

    def _unsigned_dropped(self, count: int) -> None:
        """``count`` more unsigned frames dropped on the link of an autopilot that signs:
        counted, said at the first and every hundredth."""
        before = self.stats["from_autopilot_unsigned_dropped"]
        self.stats["from_autopilot_unsigned_dropped"] += count
        dropped = self.stats["from_autopilot_unsigned_dropped"]
        if before == 0 or dropped // 100 > before // 100:
            log.warning(
                "%s: dropped %d unsigned frame(s) on the link of an autopilot that signs: "
                "another sender on %s, or the autopilot no longer signs (its key lost in a "
                "reflash or a reset of its parameters: give it the key again, --setup-signing)",
                self.vehicle.id,
                dropped,
                self.url,
            )

    def _hold_token(self, present: bool) -> None:
        if present and self.token is None and self.session is not None:
            self.token = self.session.liveliness().declare_token(
                wire.vehicle_alive(self.farm, self.vehicle.id)
            )
            log.info("%s: autopilot heartbeat live, liveliness token declared", self.vehicle.id)
        elif not present and self.token is not None:
            self.token.undeclare()
            self.token = None
            log.warning(
                "%s: autopilot heartbeat lost, liveliness token undeclared", self.vehicle.id
            )

    def _beat(self, now: float) -> None:
        """The companion computer's own HEARTBEAT to the autopilot."""
        if self.companion is None or self.link is None or now < self._next_companion_beat:
            return
        self._next_companion_beat = now + COMPANION_HEARTBEAT_PERIOD_S
        beat = mc.peer_heartbeat(mc.MAV_TYPE_ONBOARD_CONTROLLER)
        try:
            self.link.write(self.companion.encode(beat))
        except mc.LinkDown as exc:
            self._drop_link(exc, now)


# --- command line ------------------------------------------------------------------------
def add_bridge_arguments(p: argparse.ArgumentParser) -> None:
    """The bridge's own options (the Zenoh ones come from ``add_zenoh_arguments``)."""
    p.add_argument("scenario", type=Path, help="scenario TOML (farm and fleet)")
    add_fields_argument(p)
    p.add_argument("--vehicle", required=True, metavar="ID", help="the machine this autopilot is")
    p.add_argument(
        "--mavlink",
        required=True,
        metavar="URL",
        help="the autopilot: /dev/ttyUSB0,57600 | tcp:HOST:PORT | udpin:HOST:PORT | "
        "udpout:HOST:PORT | tcpin:HOST:PORT",
    )
    p.add_argument(
        "--heartbeat-timeout",
        type=float,
        default=HEARTBEAT_TIMEOUT_S,
        metavar="S",
        help="seconds without an autopilot HEARTBEAT before the liveliness token goes",
    )
    p.add_argument(
        "--rate",
        action="append",
        default=[],
        metavar="TYPE=HZ",
        help="forward telemetry TYPE at most HZ times a second (repeatable; defaults: "
        + ", ".join(f"{k}={v:g}" for k, v in DEFAULT_RATE_LIMITS.items())
        + ")",
    )
    p.add_argument(
        "--no-companion-heartbeat",
        action="store_true",
        help="do not send the bridge's own 1 Hz HEARTBEAT to the autopilot",
    )
    add_signing_arguments(p)
    p.add_argument(
        "--setup-signing",
        action="store_true",
        help="give the autopilot the vehicle's signing key (SETUP_SIGNING) when its link "
        "opens: provisioning over a wired link, disarmed (docs/bridge.md)",
    )


def parse_rates(items: Sequence[str]) -> dict[str, float]:
    """``["GLOBAL_POSITION_INT=5"]`` over the defaults, checked."""
    rates = dict(DEFAULT_RATE_LIMITS)
    for item in items:
        kind, sep, hz = item.partition("=")
        try:
            rates[kind.strip().upper()] = float(hz) if sep else math.nan
        except ValueError:
            rates[kind.strip().upper()] = math.nan
    check_rate_limits(rates)
    return rates


def bridge_command(args: argparse.Namespace, options: wire.ZenohOptions) -> int:
    """``agrifleet bridge``: what :func:`add_bridge_arguments` parsed, to :func:`run_bridge`."""
    from dispatcher.config.scenario import load_scenario

    try:
        scenario = load_scenario(args.scenario, args.fields)
        keys = signing_keys(args, scenario, [scenario.vehicle(args.vehicle).id])
        if args.setup_signing and keys is None:
            raise ValueError("--setup-signing needs the vehicle's key: drop --unsigned")
        rates = parse_rates(args.rate)
        mc.check_mavlink_url(args.mavlink)
        options.config()  # a bad --cfg fails here, with a message
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
    return run_bridge(
        scenario,
        args.vehicle,
        args.mavlink,
        options,
        rate_limits=rates,
        heartbeat_timeout_s=args.heartbeat_timeout,
        companion_heartbeat=not args.no_companion_heartbeat,
        key=keys[args.vehicle] if keys is not None else None,
        setup_signing=args.setup_signing,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m dispatcher.tools.bridge``: the same as ``agrifleet bridge``."""
    from dispatcher.config.errors import DispatcherError

    parser = argparse.ArgumentParser(
        prog="python -m dispatcher.tools.bridge",
        description="Bridge one ArduPilot autopilot (MAVLink) to the farm's Zenoh network; "
        "see docs/bridge.md.",
    )
    add_bridge_arguments(parser)
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    wire.add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return bridge_command(args, wire.zenoh_options(args, False, identity=args.vehicle))
    except DispatcherError as exc:
        log.error("%s", exc)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    from dispatcher.tools.bridge import (
        main as bridge_main,  # log as dispatcher.tools.bridge, not __main__
    )

    sys.exit(bridge_main())
