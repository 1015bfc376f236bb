"""The wire contract between the dispatcher, vehicles, bridges and tools (see README).

Each Zenoh sample on a ``mavlink`` key carries exactly one MAVLink 2 frame as raw bytes.

    agrifleet/<farm>/vehicle/<vehicle>/mavlink/to     dispatcher -> vehicle
    agrifleet/<farm>/vehicle/<vehicle>/mavlink/from   vehicle -> dispatcher
    agrifleet/<farm>/vehicle/<vehicle>/alive          liveliness token held by the vehicle
    agrifleet/<farm>/dispatcher/plan                  current plan JSON (with its plan id)
    agrifleet/<farm>/dispatcher/status                queryable: JSON status of everything

The dispatcher is MAVLink system 255; vehicles use their scenario ``system_id``.
Embedded default: peer mode, the dispatcher listening on tcp/127.0.0.1:7447, everyone
else connecting to it, multicast scouting off.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import dataclass, field

import zenoh

DISPATCHER_SYSTEM_ID = 255
DISPATCHER_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
PREFIX = "agrifleet"


def vehicle_to(farm: str, vehicle: str) -> str:
    return f"{PREFIX}/{farm}/vehicle/{vehicle}/mavlink/to"


def vehicle_from(farm: str, vehicle: str) -> str:
    return f"{PREFIX}/{farm}/vehicle/{vehicle}/mavlink/from"


def vehicle_alive(farm: str, vehicle: str) -> str:
    return f"{PREFIX}/{farm}/vehicle/{vehicle}/alive"


def dispatcher_plan(farm: str) -> str:
    return f"{PREFIX}/{farm}/dispatcher/plan"


def dispatcher_status(farm: str) -> str:
    return f"{PREFIX}/{farm}/dispatcher/status"


def vehicle_of(key: str) -> str | None:
    """The vehicle id in a ``.../vehicle/<id>/...`` key, else None."""
    parts = key.split("/")
    try:
        return parts[parts.index("vehicle") + 1]
    except (ValueError, IndexError):
        return None


@dataclass(frozen=True)
class ZenohOptions:
    """How a process joins the Zenoh network: the command line's ``--mode``,
    ``--listen``, ``--connect``, ``--config`` and ``--cfg KEY:VALUE``."""

    mode: str = "peer"
    listen: Sequence[str] = ()
    connect: Sequence[str] = ()
    config_file: str | None = None
    extra: Sequence[str] = field(default_factory=tuple)  # "key/path:json5 value"

    def config(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh mode must be peer, client or router, not {self.mode!r}")
        conf.insert_json5("mode", json.dumps(self.mode))
        # Loopback and configured endpoints only: never look for peers by multicast.
        conf.insert_json5("scouting/multicast/enabled", "false")
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        for item in self.extra:
            key, sep, value = item.partition(":")
            if not sep:
                raise ValueError(f"--cfg wants KEY:VALUE, got {item!r}")
            conf.insert_json5(key, value)
        return conf


def dispatcher_options(listen: Sequence[str] = (DEFAULT_ENDPOINT,), **kw: object) -> ZenohOptions:
    return ZenohOptions(listen=tuple(listen), **kw)  # type: ignore[arg-type]


def client_options(connect: Sequence[str] = (DEFAULT_ENDPOINT,), **kw: object) -> ZenohOptions:
    return ZenohOptions(connect=tuple(connect), **kw)  # type: ignore[arg-type]


# --- command-line flags of every command that opens a Zenoh session -----------------


def zenoh_options(args: argparse.Namespace, default_listen: bool) -> ZenohOptions:
    """The Zenoh options of a command from its ``add_zenoh_arguments`` flags; without
    ``--listen``/``--connect`` the dispatcher listens on, and everyone else connects to,
    ``DEFAULT_ENDPOINT``."""
    listen = tuple(args.listen or ())
    connect = tuple(args.connect or ())
    if not listen and not connect and args.mode != "router":
        if default_listen:
            listen = (DEFAULT_ENDPOINT,)
        else:
            connect = (DEFAULT_ENDPOINT,)
    return ZenohOptions(
        mode=args.mode,
        listen=listen,
        connect=connect,
        config_file=args.zenoh_config,
        extra=tuple(args.cfg or ()),
    )


def add_zenoh_arguments(p: argparse.ArgumentParser, mode: str = "peer") -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument(
        "--mode",
        choices=["peer", "client", "router"],
        default=mode,
        help=f"Zenoh session mode (default {mode}; client to go through a router)",
    )
    g.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="listen on this endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    g.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="connect to this endpoint, e.g. tcp/192.168.1.10:7447 (repeatable)",
    )
    g.add_argument("--zenoh-config", metavar="FILE", help="a zenoh JSON5 config file")
    g.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="zenoh config override, KEY a config path, VALUE JSON5 (repeatable)",
    )
