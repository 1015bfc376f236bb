"""`agrifleet router`: a Zenoh router for deployments beyond one gateway.

zenohd is not installable from the package registries here, so this is a Zenoh session in
router mode, which routes between the clients and peers connected to it (and other
routers it connects to). Dispatchers, vehicles and bridges then run in client mode with
``--mode client --connect tls/<router>:7447 --tls DIR``; with ``--tls DIR`` the router is
the farm's ``router`` identity and applies the access-control list ``agrifleet certs``
wrote there (docs/security.md).
"""

from __future__ import annotations

import logging
import threading

from dispatcher.link.signals import stop_on_signals
from dispatcher.link.wire import ZenohOptions

log = logging.getLogger(__name__)

DEFAULT_ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"
"""Without TLS a router listens on loopback only (``--insecure-listen`` to go wider)."""
DEFAULT_TLS_ROUTER_ENDPOINT = "tls/0.0.0.0:7447"


def run_router(options: ZenohOptions, stop: threading.Event | None = None) -> int:
    """Route until ``stop`` is set or SIGINT/SIGTERM; returns the exit code (0)."""
    if options.mode != "router":
        raise ValueError(f"a router runs in router mode, not {options.mode!r}")
    stop = stop if stop is not None else threading.Event()
    restore_signals = stop_on_signals(stop, "stopping the router")
    try:
        with options.open() as session:
            log.info(
                "zenoh router %s listening on %s, connected to %s",
                session.zid(),
                ", ".join(options.listen) or "-",
                ", ".join(options.connect) or "-",
            )
            stop.wait()
    finally:
        restore_signals()
    log.info("router stopped")
    return 0
