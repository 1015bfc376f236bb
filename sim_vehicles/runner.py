"""Zenoh I/O around :class:`~sim_vehicles.tractor.SimTractor`: one process, any number of
simulated tractors, each on the wire contract of :mod:`dispatcher.link.wire`.

Per vehicle: a subscriber on ``vehicle_to`` (frames go to a FIFO queue, never dropped),
a publisher on ``vehicle_from`` (one MAVLink 2 frame per sample) and a liveliness token
on ``vehicle_alive`` held while the process runs. A vehicle broken down by fault
injection keeps its token (its radio lives, its autopilot is silent): the ground
station sees heartbeats stop. A stalled vehicle (fault injection: ``stall_after``, or
SIGUSR1 to the process, which stalls every vehicle it simulates) keeps everything but its
progress: armed, in AUTO, reporting, standing still.

Clocks: vehicles move in simulated time, ``speedup`` simulated seconds per wall second;
heartbeats (1 Hz), positions (``telemetry_hz``) and the mission protocol's timeouts run in
wall time, as a ground station on the other end of the link does.

:func:`serve_vehicles` is that loop without the transport; :mod:`sim_vehicles.mavlink_port`
runs it on a plain MAVLink socket instead of Zenoh.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import queue
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Protocol, TypeAlias

import zenoh

from dispatcher.config.errors import ConfigError
from dispatcher.config.scenario import Scenario
from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.link.signals import stop_on_signals
from sim_vehicles.impairment import DelayLine, Impairment
from sim_vehicles.tractor import RoverParams, SimTractor

logger = logging.getLogger(__name__)

EXIT_OK = 0

HEARTBEAT_PERIOD_S = 1.0
MAX_WAIT_S = 0.05
"""Longest wait for a frame before vehicles are moved on (wall seconds)."""

Receive: TypeAlias = Callable[[float], list[tuple[int, mc.MAVLinkMessage]]]
"""Waits up to the given wall seconds for messages to the vehicles; returns them in order,
each with the index of the vehicle it is for."""


class SimLink(Protocol):
    """One simulated vehicle on some transport: its tractor and where its messages go."""

    tractor: SimTractor

    def send(self, messages: Sequence[mc.MAVLinkMessage]) -> None: ...


@dataclass
class _Link:
    """One simulated vehicle and its Zenoh entities."""

    vid: str
    tractor: SimTractor
    codec: mc.Codec  # encodes what the vehicle sends (main thread only)
    inbound: mc.Codec  # decodes what it receives (main thread only)
    publisher: zenoh.Publisher
    subscriber: zenoh.Subscriber[None]
    token: zenoh.LivelinessToken
    sent: int = 0  # frames published
    refused: int = 0  # frames received not signed with its key (or replayed)
    outbound: DelayLine[bytes] | None = None  # an impaired radio, vehicle to ground
    inbound_line: DelayLine[bytes] | None = None  # and ground to vehicle

    def send(self, messages: Sequence[mc.MAVLinkMessage]) -> None:
        now = time.monotonic()
        for msg in messages:
            frame = self.codec.encode(msg)
            if self.outbound is not None:
                self.outbound.push(frame, now)
            else:
                self.publisher.put(frame)
                self.sent += 1

    def flush(self, now: float) -> None:
        """Frames of the impaired radio whose time has come."""
        if self.outbound is not None:
            for frame in self.outbound.due(now):
                self.publisher.put(frame)
                self.sent += 1


def run(
    scenario: Scenario,
    vehicle_ids: list[str],
    options: wire.ZenohOptions,
    speedup: float = 1.0,
    telemetry_hz: float = 10.0,
    stop: threading.Event | None = None,
    fail_after: dict[str, float] | None = None,
    params: RoverParams | None = None,
    stats_path: str | None = None,
    impairment: Impairment | None = None,
    seed: int = 1,
    stall_after: dict[str, float] | None = None,
    stall: threading.Event | None = None,
    keys: Mapping[str, bytes] | None = None,
    deaf_until: dict[str, float] | None = None,
) -> int:
    """Simulate ``vehicle_ids`` of ``scenario`` until ``stop`` is set or SIGINT/SIGTERM.

    ``fail_after`` maps a vehicle id to the simulated second it breaks down at,
    ``stall_after`` to the simulated second it stalls at (stands still, keeps reporting),
    ``deaf_until`` to the simulated second until which it hears nothing (a dead uplink).
    Setting ``stall`` (or SIGUSR1 to the process) stalls every vehicle at once.
    ``impairment`` makes every vehicle's radio lose, duplicate and delay frames both ways
    (random numbers seeded with ``seed`` and the vehicle's place).
    ``keys`` (vehicle id -> MAVLink signing key) signs what each vehicle sends and makes it
    take only commands signed with its key (others are dropped, counted, logged).
    ``stats_path``, if given, receives a JSON object of frames sent per vehicle at exit.
    Returns the exit code (0). Raises :class:`ConfigError` for an unknown vehicle id.
    """
    if not vehicle_ids:
        raise ConfigError(f"{scenario.source}: no vehicle to simulate")
    vehicles = [scenario.vehicle(vid) for vid in vehicle_ids]
    fail_after = dict(fail_after or {})
    stall_after = dict(stall_after or {})
    deaf_until = dict(deaf_until or {})
    for name, faults in (
        ("fail_after", fail_after),
        ("stall_after", stall_after),
        ("deaf_until", deaf_until),
    ):
        for vid in faults:
            if vid not in vehicle_ids:
                raise ConfigError(f"{name} names {vid!r}, which is not simulated here")
    check_rates(speedup, telemetry_hz)
    stop = stop if stop is not None else threading.Event()
    stall = stall if stall is not None else threading.Event()
    restore_signals = stop_on_signals(stop, "stopping the simulator")
    restore_stall_signal = stall_on_signal(stall)
    inbox: queue.Queue[tuple[int, bytes]] = queue.Queue()
    farm = scenario.farm_id

    def key_of(vid: str) -> bytes | None:
        if keys is None:
            return None
        if vid not in keys:
            raise ConfigError(f"no signing key for {vid!r}")
        return keys[vid]

    links: list[_Link] = []
    boot_unix_s = time.time()
    try:
        with contextlib.ExitStack() as sessions:
            shared = None if options.tls else sessions.enter_context(options.open())
            try:
                for index, vehicle in enumerate(vehicles):
                    # With TLS each vehicle is its own identity: a session (and certificate) each.
                    session = shared or sessions.enter_context(
                        options.as_identity(vehicle.id).open()
                    )
                    tractor = SimTractor(
                        vehicle,
                        scenario.farm.garage_lonlat,
                        params=params,
                        fail_after_s=fail_after.get(vehicle.id),
                        stall_after_s=stall_after.get(vehicle.id),
                        deaf_until_s=deaf_until.get(vehicle.id),
                        unix_epoch_s=boot_unix_s,
                    )
                    links.append(
                        _Link(
                            vid=vehicle.id,
                            tractor=tractor,
                            codec=mc.Codec(
                                vehicle.system_id, tractor.component_id, key=key_of(vehicle.id)
                            ),
                            inbound=mc.Codec(
                                vehicle.system_id, tractor.component_id, key=key_of(vehicle.id)
                            ),
                            publisher=session.declare_publisher(
                                wire.vehicle_from(farm, vehicle.id),
                                congestion_control=zenoh.CongestionControl.BLOCK,
                            ),
                            subscriber=session.declare_subscriber(
                                wire.vehicle_to(farm, vehicle.id), _enqueue(inbox, index)
                            ),
                            token=session.liveliness().declare_token(
                                wire.vehicle_alive(farm, vehicle.id)
                            ),
                        )
                    )
                    if impairment is not None and impairment.active:
                        links[-1].outbound = DelayLine(impairment, seed * 1000 + 2 * index)
                        links[-1].inbound_line = DelayLine(impairment, seed * 1000 + 2 * index + 1)
                        logger.info("%s: an impaired radio: %s", vehicle.id, impairment)
                    logger.info(
                        "simulating %s (system %d) at home %s",
                        vehicle.id,
                        vehicle.system_id,
                        scenario.farm.garage_lonlat,
                    )
                logger.info("%d vehicle(s) on farm %r at %gx", len(links), farm, speedup)
                serve_vehicles(
                    links, _zenoh_receiver(links, inbox), stop, speedup, telemetry_hz, stall
                )
            finally:
                for link in links:
                    link.token.undeclare()
                    link.subscriber.undeclare()
                    link.publisher.undeclare()
    finally:
        restore_stall_signal()
        restore_signals()
    sent = {link.vid: link.sent for link in links}
    logger.info("simulator stopped after sending %d frames", sum(sent.values()))
    if stats_path:
        with open(stats_path, "w") as f:
            json.dump(sent, f)
    return EXIT_OK


def stall_on_signal(stall: threading.Event) -> Callable[[], None]:
    """Make SIGUSR1 set ``stall``; returns a function that puts the previous handler back.
    Off the main thread (where Python allows no handlers) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def on_signal(signum: int, frame: FrameType | None) -> None:
        logger.info("signal %d: stalling every vehicle (fault injection)", signum)
        stall.set()

    previous = signal.signal(signal.SIGUSR1, on_signal)

    def restore() -> None:
        signal.signal(signal.SIGUSR1, previous)

    return restore


def check_rates(speedup: float, telemetry_hz: float) -> None:
    """Raise ValueError unless both clocks run forwards."""
    if not 0.0 < speedup < math.inf:
        raise ValueError(f"speedup must be finite and > 0, got {speedup}")
    if not 0.0 < telemetry_hz < math.inf:
        raise ValueError(f"telemetry_hz must be finite and > 0, got {telemetry_hz}")


def serve_vehicles(
    links: Sequence[SimLink],
    receive: Receive,
    stop: threading.Event,
    speedup: float,
    telemetry_hz: float,
    stall: threading.Event | None = None,
) -> None:
    """Run the vehicles until ``stop``: move them on in simulated time, answer what
    ``receive`` brings, send heartbeats (1 Hz) and positions (``telemetry_hz``) in wall time.
    Once ``stall`` is set every vehicle stalls (fault injection)."""
    telemetry_period_s = 1.0 / telemetry_hz
    last = time.monotonic()
    next_heartbeat = last
    next_telemetry = last
    while not stop.is_set():
        wait = min(next_heartbeat, next_telemetry) - time.monotonic()
        inbound = receive(min(max(wait, 0.0), MAX_WAIT_S))
        now = time.monotonic()
        sim_dt = (now - last) * speedup
        last = now
        for link in links:
            link.send(link.tractor.advance(sim_dt))
        if stall is not None and stall.is_set():
            for link in links:
                link.tractor.stall()
        for index, msg in inbound:
            link = links[index]
            link.send(link.tractor.handle(msg, link.tractor.sim_time, link_now=now))
        for link in links:
            link.send(link.tractor.on_link_tick(now))
        if now >= next_heartbeat:
            next_heartbeat = _next_time(next_heartbeat, HEARTBEAT_PERIOD_S, now)
            for link in links:
                link.send(link.tractor.heartbeat(link.tractor.sim_time))
        if now >= next_telemetry:
            next_telemetry = _next_time(next_telemetry, telemetry_period_s, now)
            for link in links:
                link.send(link.tractor.telemetry(link.tractor.sim_time))


def _zenoh_receiver(links: list[_Link], inbox: queue.Queue[tuple[int, bytes]]) -> Receive:
    """Frames queued by the Zenoh subscribers, decoded (a sample that is no frame is dropped)."""

    impaired = any(link.inbound_line is not None for link in links)

    def receive(timeout_s: float) -> list[tuple[int, mc.MAVLinkMessage]]:
        frames: list[tuple[int, bytes]] = []
        try:
            frames.append(inbox.get(timeout=min(timeout_s, 0.01) if impaired else timeout_s))
            while True:
                frames.append(inbox.get_nowait())
        except queue.Empty:
            pass
        if impaired:  # through the impaired radios: some lost, some twice, late
            now = time.monotonic()
            for link in links:
                link.flush(now)
            for index, frame in frames:
                line = links[index].inbound_line
                assert line is not None
                line.push(frame, now)
            frames = [(k, f) for k, link in enumerate(links) for f in link.inbound_line.due(now)]  # type: ignore[union-attr]
        inbound: list[tuple[int, mc.MAVLinkMessage]] = []
        for index, frame in frames:
            link = links[index]
            msg = link.inbound.decode_one(frame)
            if msg is None:
                refused = link.inbound.signing_stats.dropped if link.inbound.signed else 0
                if refused > link.refused:
                    link.refused = refused
                    if refused == 1 or refused % 100 == 0:
                        logger.warning(
                            "%s: dropped %d frame(s) not signed with its key", link.vid, refused
                        )
                else:
                    logger.debug("%s: dropped a sample that is not a MAVLink frame", link.vid)
                continue
            inbound.append((index, msg))
        return inbound

    return receive


def _next_time(scheduled: float, period: float, now: float) -> float:
    """The next tick of a regular clock, without bursts to catch up after a stall."""
    following = scheduled + period
    return following if following > now else now + period


def _enqueue(inbox: queue.Queue[tuple[int, bytes]], index: int) -> Callable[[zenoh.Sample], None]:
    def on_sample(sample: zenoh.Sample) -> None:
        inbox.put((index, sample.payload.to_bytes()))

    return on_sample
