"""The wire contract between the dispatcher, vehicles, bridges and tools (see README).

Each Zenoh sample on a ``mavlink`` key carries exactly one MAVLink 2 frame as raw bytes.

    agrifleet/<farm>/vehicle/<vehicle>/mavlink/to     dispatcher -> vehicle
    agrifleet/<farm>/vehicle/<vehicle>/mavlink/from   vehicle -> dispatcher
    agrifleet/<farm>/vehicle/<vehicle>/alive          liveliness token held by the vehicle
    agrifleet/<farm>/dispatcher/plan                  current plan JSON (with its plan id);
                                                      also a queryable: the current plan
    agrifleet/<farm>/dispatcher/status                queryable: JSON status of everything

The dispatcher is MAVLink system 255; vehicles use their scenario ``system_id``. Only the
dispatcher publishes on ``…/mavlink/to``: it listens there for samples from anyone else and
raises an alarm (docs/security.md); with ``--tls`` an access-control list enforces it.
Embedded default: peer mode, the dispatcher listening on tcp/127.0.0.1:7447, everyone
else connecting to it, multicast scouting off.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import logging
import re
import socket
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from dispatcher.config.errors import ConfigError

if TYPE_CHECKING:
    from dispatcher.link.access import TlsIdentity

DISPATCHER_SYSTEM_ID = 255
DISPATCHER_COMPONENT_ID = 190  # MAV_COMP_ID_MISSIONPLANNER
DEFAULT_PORT = 7447
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
DEFAULT_TLS_ENDPOINT = f"tls/127.0.0.1:{DEFAULT_PORT}"
LOOPBACK_PEER_ENDPOINT = "tcp/127.0.0.1:0"
ALONE_WARN_S = 15.0
"""Seconds after which a session told where to connect, and connected to nothing, says so:
Zenoh in peer mode keeps trying without a word (a TLS folder of another farm, an address
its certificate does not name, nothing listening there)."""

log = logging.getLogger(__name__)
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
    ``--listen``, ``--connect``, ``--config``, ``--cfg KEY:VALUE`` and ``--tls DIR``
    (mutual TLS as ``tls``, the identity; the access-control list ``acl`` is applied by
    whoever the others connect to: :mod:`dispatcher.link.access`)."""

    mode: str = "peer"
    listen: Sequence[str] = ()
    connect: Sequence[str] = ()
    config_file: str | None = None
    extra: Sequence[str] = field(default_factory=tuple)  # "key/path:json5 value"
    tls: TlsIdentity | None = None
    acl: dict[str, Any] | None = None
    insecure_listen: bool = False  # --insecure-listen: plain TCP beyond loopback allowed

    def as_identity(self, name: str) -> ZenohOptions:
        """The same options for another identity of the same TLS folder (a simulator
        process runs each of its vehicles in a session of its own)."""
        if self.tls is None:
            return self
        return replace(self, tls=replace(self.tls, name=name))

    def open(self) -> zenoh.Session:
        """A Zenoh session of these options; a :class:`ConfigError` naming the endpoints
        when Zenoh cannot open one (a port in use, a certificate it cannot read)."""
        conf = self.config()
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            where = ", ".join([*self.listen, *self.connect]) or "the configured endpoints"
            raise ConfigError(
                f"Zenoh cannot open a session on {where}: {_zenoh_reason(exc)}"
            ) from None
        if self.connect:
            timer = threading.Timer(ALONE_WARN_S, self._say_if_alone, (session,))
            timer.daemon = True
            timer.start()
        return session

    def _say_if_alone(self, session: zenoh.Session) -> None:
        """A warning if ``session`` reaches no peer nor router (:data:`ALONE_WARN_S`)."""
        try:
            if list(session.info.peers_zid()) or list(session.info.routers_zid()):
                return
        except Exception:  # noqa: BLE001 (closed meanwhile: nothing to say)
            return
        hint = (
            f"is the --tls folder {self.tls.folder} the farm's, and does the listener's "
            "certificate name that address (agrifleet certs --host)?"
            if self.tls is not None
            else "is the dispatcher (or router) listening there?"
        )
        log.warning(
            "connected to nothing at %s after %g s (Zenoh keeps trying): %s",
            ", ".join(self.connect),
            ALONE_WARN_S,
            hint,
        )

    def check_listen_free(self) -> None:
        """A :class:`ConfigError` naming a ``--listen`` endpoint whose port another
        process listens on (a dispatcher or router already running): said before anything
        is planned or stored, where Zenoh says it only when the session opens."""
        for endpoint in self.listen:
            proto, host, port = endpoint_parts(endpoint)
            if not port.isdigit() or int(port) == 0:
                continue
            kind = socket.SOCK_DGRAM if proto in ("udp", "quic") else socket.SOCK_STREAM
            try:
                infos = socket.getaddrinfo(host, int(port), type=kind)
            except OSError:
                continue  # Zenoh says what is wrong with the address
            for family, socktype, protocol, _, sockaddr in infos[:1]:
                with socket.socket(family, socktype, protocol) as probe:
                    probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    try:
                        probe.bind(sockaddr)
                    except OSError as exc:
                        raise ConfigError(
                            f"--listen {endpoint}: {exc.strerror or exc} (another dispatcher "
                            "or router on this port? stop it, or listen on another)"
                        ) from None

    def config(self) -> zenoh.Config:
        if self.config_file:
            try:
                conf = zenoh.Config.from_file(self.config_file)
            except zenoh.ZError as exc:
                raise ConfigError(
                    f"--zenoh-config {self.config_file}: {_zenoh_reason(exc)}"
                ) from None
        else:
            conf = zenoh.Config()
        if self.mode not in ("peer", "client", "router"):
            raise ConfigError(f"zenoh mode must be peer, client or router, not {self.mode!r}")
        conf.insert_json5("mode", json.dumps(self.mode))
        # Loopback and configured endpoints only: never look for peers by multicast, and
        # never listen beyond where asked. A peer's default is every interface (port 0):
        # here, loopback only without TLS (the processes of one machine still reach each
        # other directly) and nowhere with TLS (everything goes through the listener that
        # applies the access-control list).
        conf.insert_json5("scouting/multicast/enabled", "false")
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        elif not self.config_file:
            implicit = [LOOPBACK_PEER_ENDPOINT] if self.mode == "peer" and not self.tls else []
            conf.insert_json5("listen/endpoints", json.dumps(implicit))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        if self.tls is not None:
            plain = [e for e in (*self.listen, *self.connect) if not e.startswith("tls/")]
            if plain:
                raise ConfigError(
                    f"with TLS every endpoint is tls/HOST:PORT; {', '.join(plain)} would let "
                    "anyone in without a certificate"
                )
            for key, value in self.tls.check().settings():
                conf.insert_json5(key, value)
        if self.acl is not None:
            conf.insert_json5("access_control", json.dumps(self.acl))
        for item in self.extra:
            key, sep, value = item.partition(":")
            if not sep:
                raise ConfigError(f"--cfg wants KEY:VALUE, got {item!r}")
            try:
                conf.insert_json5(key, value)
            except zenoh.ZError as exc:
                raise ConfigError(f"--cfg {item}: {_zenoh_reason(exc)}") from None
        self._check_listening(conf)
        return conf

    def listens(self) -> list[str]:
        """The endpoints a session of these options listens on, whoever set them
        (``--listen``, ``--cfg``, the ``--zenoh-config`` file, Zenoh's default)."""
        return self._listen_endpoints(self.config())

    def _listen_endpoints(self, conf: zenoh.Config) -> list[str]:
        value = json.loads(conf.get_json("listen/endpoints"))
        endpoints = value.get(self.mode, []) if isinstance(value, dict) else value
        return [e for e in endpoints if isinstance(e, str)]

    def _check_listening(self, conf: zenoh.Config) -> None:
        """The endpoints the session will listen on, whoever set them (``--cfg``, the
        ``--zenoh-config`` file, or Zenoh's own default of every interface when the file
        sets none): plain TCP beyond loopback only with ``insecure_listen`` (``--cfg
        'listen/endpoints:["tcp/0.0.0.0:7447"]'`` got round ``--listen``'s check)."""
        if self.insecure_listen:
            return
        value = json.loads(conf.get_json("listen/endpoints"))
        endpoints = self._listen_endpoints(conf)
        exposed = [e for e in endpoints if not e.startswith("tls/") and not is_loopback(e)]
        if exposed:
            source = (
                "--cfg"
                if any(item.startswith("listen") for item in self.extra)
                else f"--zenoh-config {self.config_file}"
                if self.config_file
                else "the listen endpoints"
            )
            default = " (Zenoh's default for each mode)" if isinstance(value, dict) else ""
            raise ConfigError(
                f"{source} listens on {exposed[0]} without TLS{default}: anyone who reaches it "
                "could command the tractors. Listen on loopback or tls/ endpoints "
                "(docs/security.md), or add --insecure-listen for a closed test bench"
            )


def _zenoh_reason(exc: zenoh.ZError) -> str:
    """A Zenoh error's message on one line, without its source-file locations."""
    text = " ".join(str(exc).split())
    if expected := re.search(r"= (expected [^\"\\]*)", text):  # a JSON5 value
        return f"not JSON5 ({expected.group(1).strip()})"
    return re.sub(r"\s*(at )?\S+\.rs:\d+(:\d+)?\.?", "", text).strip() or "no reason given"


def dispatcher_options(listen: Sequence[str] = (DEFAULT_ENDPOINT,), **kw: object) -> ZenohOptions:
    return ZenohOptions(listen=tuple(listen), **kw)  # type: ignore[arg-type]


def client_options(connect: Sequence[str] = (DEFAULT_ENDPOINT,), **kw: object) -> ZenohOptions:
    return ZenohOptions(connect=tuple(connect), **kw)  # type: ignore[arg-type]


# --- command-line flags of every command that opens a Zenoh session -----------------


def zenoh_options(
    args: argparse.Namespace, default_listen: bool, identity: str | None = None
) -> ZenohOptions:
    """The Zenoh options of a command from its ``add_zenoh_arguments`` flags; without
    ``--listen``/``--connect`` the dispatcher listens on, and everyone else connects to,
    ``DEFAULT_ENDPOINT`` (``DEFAULT_TLS_ENDPOINT`` with ``--tls``). With ``--tls DIR`` the
    process is ``identity`` of the farm's TLS folder (:mod:`dispatcher.link.access`)."""
    tls = None
    listen = tuple(args.listen or ())
    for flag, endpoints in (("--listen", listen), ("--connect", tuple(args.connect or ()))):
        for endpoint in endpoints:
            check_endpoint(endpoint, flag)
    exposed = [e for e in listen if not e.startswith("tls/") and not is_loopback(e)]
    if exposed and not getattr(args, "insecure_listen", False):
        raise ConfigError(
            f"--listen {exposed[0]} without TLS: anyone who reaches it could command the "
            "tractors. Give --tls DIR (`agrifleet certs`, docs/security.md) and a tls/ "
            "endpoint, listen on loopback only, or add --insecure-listen for a closed test bench"
        )
    if getattr(args, "tls", None):
        from dispatcher.link.access import DISPATCHER, TlsIdentity

        tls = TlsIdentity(Path(args.tls), identity or DISPATCHER)
    connect = tuple(args.connect or ())
    if not listen and not connect and args.mode != "router" and not args.zenoh_config:
        default = DEFAULT_TLS_ENDPOINT if tls else DEFAULT_ENDPOINT
        if default_listen:
            listen = (default,)
        else:
            connect = (default,)
    return ZenohOptions(
        mode=args.mode,
        listen=listen,
        connect=connect,
        config_file=args.zenoh_config,
        extra=tuple(args.cfg or ()),
        tls=tls,
        insecure_listen=bool(getattr(args, "insecure_listen", False)),
    )


ZENOH_MODES = ("peer", "client", "router")


def add_zenoh_arguments(
    p: argparse.ArgumentParser,
    mode: str = "peer",
    title: str = "zenoh",
    modes: Sequence[str] = ZENOH_MODES,
) -> None:
    """The Zenoh options of a command that runs in one of ``modes`` (default ``mode``);
    with one mode there is no ``--mode`` to choose (a router is a router)."""
    g = p.add_argument_group(title)
    if len(modes) > 1:
        g.add_argument(
            "--mode",
            choices=list(modes),
            default=mode,
            help=f"Zenoh session mode (default {mode}; client to go through a router)",
        )
    else:
        p.set_defaults(mode=mode)
    g.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"listen on this endpoint, e.g. {DEFAULT_ENDPOINT}, or tls/HOST:PORT with --tls "
        "(repeatable)",
    )
    g.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"connect to this endpoint (repeatable); default {DEFAULT_ENDPOINT} "
        f"({DEFAULT_TLS_ENDPOINT} with --tls) when neither --listen nor --connect",
    )
    g.add_argument("--zenoh-config", metavar="FILE", help="a zenoh JSON5 config file")
    g.add_argument(
        "--cfg",
        action="append",
        metavar="KEY:VALUE",
        help="zenoh config override, KEY a config path, VALUE JSON5 (repeatable)",
    )
    g.add_argument(
        "--tls",
        metavar="DIR",
        help="the farm's certificates (`agrifleet certs`): mutual TLS, and the access-control "
        "list where the others connect (docs/security.md)",
    )
    g.add_argument(
        "--insecure-listen",
        action="store_true",
        help="allow listening beyond loopback without TLS (a closed test bench only)",
    )


ENDPOINT_PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws")
"""The Zenoh link protocols an endpoint may name (``proto/host:port``)."""


def check_endpoint(endpoint: str, flag: str) -> None:
    """:class:`ConfigError` naming ``flag`` unless ``endpoint`` is ``proto/host:port`` with a
    protocol of :data:`ENDPOINT_PROTOCOLS` and a port of 1-65535 (0 for ``--listen``: any
    free one). Said before anything is planned or stored: Zenoh refuses a bad one only when
    the session opens, with a traceback."""
    proto, host, port = endpoint_parts(endpoint)
    lowest = 0 if flag == "--listen" else 1
    if (
        "/" not in endpoint
        or proto not in ENDPOINT_PROTOCOLS
        or ":" not in endpoint.partition("/")[2]
        or not host
        or not port.isdigit()
        or not lowest <= int(port) <= 65535
    ):
        raise ConfigError(
            f"{flag} {endpoint!r}: an endpoint is PROTOCOL/HOST:PORT, the protocol one of "
            f"{', '.join(ENDPOINT_PROTOCOLS)}, the port {lowest} to 65535 "
            f"(e.g. {DEFAULT_ENDPOINT})"
        )


def endpoint_parts(endpoint: str) -> tuple[str, str, str]:
    """``proto/host:port`` as (proto, host without an IPv6 address's brackets, port), each
    as written ("" where missing)."""
    proto, _, address = endpoint.partition("/")
    host, _, port = address.rpartition(":")
    return proto, host.strip("[]"), port


def is_loopback(endpoint: str) -> bool:
    """Whether ``proto/host:port`` is reachable from this machine only."""
    address = endpoint_parts(endpoint)[1]
    if address == "localhost":
        return True
    try:
        return ipaddress.ip_address(address).is_loopback
    except ValueError:
        return False
