"""One simulated tractor on a plain MAVLink socket instead of Zenoh, as ArduPilot SITL is.

Whoever connects (a ground station, MAVProxy, the agrifleet bridge) talks raw MAVLink 2
frames with the same :class:`~sim_vehicles.tractor.SimTractor` and the same loop as the
Zenoh runner (:func:`sim_vehicles.runner.serve_vehicles`). URLs (pymavlink's forms):

* ``tcpin:HOST:PORT`` -- listen, one client at a time; a client that leaves makes room for
  the next (SITL's ``tcp:5760`` style);
* ``udpin:HOST:PORT`` -- listen; replies go to whoever sent last, so the peer speaks first;
* ``udpout:HOST:PORT`` -- send to that address.

There is no liveliness token here: on a MAVLink link, presence is the heartbeat.
"""

from __future__ import annotations

import json
import logging
import select
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

from dispatcher.config.scenario import Scenario
from dispatcher.link import mavlink as mc
from dispatcher.link.signals import stop_on_signals
from sim_vehicles.runner import (
    EXIT_OK,
    check_rates,
    serve_vehicles,
)
from sim_vehicles.tractor import RoverParams, SimTractor

logger = logging.getLogger(__name__)

SERVER_SCHEMES = ("tcpin:", "udpin:", "udpout:")


@dataclass
class _PortLink:
    """The simulated vehicle and the MAVLink socket it speaks on."""

    tractor: SimTractor
    codec: mc.Codec
    port: mc.MavlinkConnection
    sent: int = 0

    def send(self, messages: Sequence[mc.MAVLinkMessage]) -> None:
        for msg in messages:
            self.port.write(self.codec.encode(msg))
            self.sent += 1

    def receive(self, timeout_s: float) -> list[tuple[int, mc.MAVLinkMessage]]:
        fd = self.port.fileno()
        if fd is None:
            time.sleep(timeout_s)
        elif timeout_s > 0.0:
            select.select([fd], [], [], timeout_s)
        return [(0, msg) for msg in self.port.receive()]


def check_port_url(url: str) -> None:
    """Raise ValueError unless ``url`` is one a simulated vehicle can serve on."""
    if not url.startswith(SERVER_SCHEMES):
        raise ValueError(
            f"a simulated vehicle serves on tcpin:, udpin: or udpout:HOST:PORT, not {url!r}"
        )
    mc.check_mavlink_url(url)


def run_mavlink(
    scenario: Scenario,
    vehicle_id: str,
    url: str,
    speedup: float = 1.0,
    telemetry_hz: float = 10.0,
    stop: threading.Event | None = None,
    fail_after_s: float | None = None,
    params: RoverParams | None = None,
    stats_path: str | None = None,
    key: bytes | None = None,
) -> int:
    """Simulate ``vehicle_id`` of ``scenario`` on the MAVLink socket ``url`` until ``stop``
    is set or SIGINT/SIGTERM; returns the exit code (0).

    ``fail_after_s``: the simulated second the vehicle breaks down at (it falls silent).
    ``stats_path``, if given, receives ``{vehicle_id: frames sent}`` as JSON at exit.
    ``key``: the vehicle's MAVLink signing key, as an autopilot with signing set up has it
    (signs what it sends, takes only what is signed with it).
    Raises :class:`~dispatcher.config.errors.ConfigError` for an unknown vehicle, ValueError for a
    bad URL or rate, :class:`~dispatcher.link.mavlink.LinkDown` if the socket cannot be
    opened (address in use ...).
    """
    vehicle = scenario.vehicle(vehicle_id)
    check_port_url(url)
    check_rates(speedup, telemetry_hz)
    stop = stop if stop is not None else threading.Event()
    tractor = SimTractor(
        vehicle,
        scenario.farm.garage_lonlat,
        params=params,
        fail_after_s=fail_after_s,
        unix_epoch_s=time.time(),
    )
    port = mc.open_mavlink(url, vehicle.system_id, tractor.component_id)
    link = _PortLink(tractor, mc.Codec(vehicle.system_id, tractor.component_id, key=key), port)
    if key is not None:
        port.verify_with(key)
    restore_signals = stop_on_signals(stop, "stopping the simulator")
    logger.info(
        "simulating %s (system %d) on MAVLink %s at %gx",
        vehicle.id,
        vehicle.system_id,
        url,
        speedup,
    )
    try:
        serve_vehicles([link], link.receive, stop, speedup, telemetry_hz)
    finally:
        restore_signals()
        port.close()
    logger.info("simulator stopped after sending %d frames", link.sent)
    if stats_path:
        with open(stats_path, "w") as f:
            json.dump({vehicle.id: link.sent}, f)
    return EXIT_OK
