"""``python -m sim_vehicles SCENARIO --vehicle ID|--all --connect ENDPOINT --speedup X``:
simulated tractors on Zenoh; with ``--mavlink URL`` one tractor on a plain MAVLink socket
instead, as ArduPilot SITL. Parses arguments and calls :func:`sim_vehicles.runner.run` or
:func:`sim_vehicles.mavlink_port.run_mavlink`."""

from __future__ import annotations

import argparse
import ctypes
import logging
import math
import os
import signal
import sys
from collections.abc import Sequence
from pathlib import Path

import zenoh

from dispatcher.config.errors import DispatcherError
from dispatcher.config.scenario import add_fields_argument
from dispatcher.link import wire
from dispatcher.link.keys import add_signing_arguments, signing_keys
from sim_vehicles.impairment import add_impairment_arguments, impairment_of

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>: the signal a process gets when its parent dies
EXIT_BAD_INPUT = 2
EXIT_LINK_DOWN = 4  # the --mavlink socket could not be opened (address in use ...)

DESCRIPTION = (
    "Simulated tractors on Zenoh, as the dispatcher sees real ones through the bridge; with "
    "--mavlink URL one tractor on a plain MAVLink socket instead, as ArduPilot SITL."
)


def build_parser(prog: str = "python -m sim_vehicles") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=DESCRIPTION)
    p.add_argument("scenario", type=Path, help="scenario TOML (farm and fleet)")
    add_fields_argument(p)
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--vehicle", action="append", metavar="ID", help="machine id (repeatable)")
    who.add_argument("--all", action="store_true", help="the whole fleet in one process")
    p.add_argument("--speedup", type=float, default=1.0, help="simulated seconds per second")
    p.add_argument(
        "--telemetry-hz", type=float, default=10.0, help="GLOBAL_POSITION_INT per wall second"
    )
    p.add_argument(
        "--fail-after",
        action="append",
        metavar="ID:SECONDS",
        default=[],
        help="fault injection: machine ID breaks down after SECONDS simulated",
    )
    p.add_argument(
        "--stall-after",
        action="append",
        metavar="ID:SECONDS",
        default=[],
        help="fault injection: machine ID stalls after SECONDS simulated (stands still, keeps "
        "reporting; SIGUSR1 stalls every machine of the process at once)",
    )
    p.add_argument(
        "--deaf-until",
        action="append",
        metavar="ID:SECONDS",
        default=[],
        help="fault injection: machine ID hears nothing until SECONDS simulated (a dead "
        "uplink that comes back; it reports as ever)",
    )
    p.add_argument(
        "--mission-done",
        choices=["stop", "hold"],
        default="stop",
        help="at mission end stay in AUTO stopped (Rover >= 4.1) or switch to HOLD",
    )
    p.add_argument(
        "--request-int",
        action="store_true",
        help="ask for upload items with MISSION_REQUEST_INT, not ArduPilot's MISSION_REQUEST",
    )
    add_impairment_arguments(p)
    p.add_argument(
        "--gcs-failsafe",
        type=float,
        metavar="SECONDS",
        help="ArduPilot's ground-station failsafe (FS_GCS_ENABLE): HOLD when no ground "
        "station HEARTBEAT is heard for SECONDS simulated (default off)",
    )
    p.add_argument(
        "--mavlink",
        metavar="URL",
        help="serve one --vehicle on this MAVLink socket instead of Zenoh: tcpin:HOST:PORT "
        "(listen, as SITL), udpin:HOST:PORT or udpout:HOST:PORT",
    )
    p.add_argument("--stats", metavar="FILE", help="write frames sent per vehicle as JSON at exit")
    p.add_argument(
        "--exit-with-parent",
        type=int,
        metavar="PID",
        help="stop, as on SIGTERM, when process PID, the one that started it, ends, however "
        "it ends (kill -9 too; Linux): the demo's simulators",
    )
    add_signing_arguments(p)
    p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    wire.add_zenoh_arguments(p, title="zenoh (not with --mavlink)")
    return p


def parse_fail_after(items: Sequence[str], flag: str = "--fail-after") -> dict[str, float]:
    """``["t1:600", ...]`` as ``{"t1": 600.0}``; ValueError names ``flag`` and the item."""
    out: dict[str, float] = {}
    for item in items:
        vid, sep, seconds = item.rpartition(":")
        try:
            value = float(seconds)
        except ValueError:
            value = -1.0
        if not sep or not vid or not value >= 0.0:
            raise ValueError(f"{flag} wants ID:SECONDS (seconds >= 0), got {item!r}")
        out[vid] = value
    return out


def check_mavlink_args(args: argparse.Namespace, ids: Sequence[str]) -> None:
    """``--mavlink`` serves exactly one vehicle and takes no Zenoh options."""
    from sim_vehicles.mavlink_port import check_port_url

    if len(ids) != 1:
        raise ValueError("--mavlink serves one vehicle: give exactly one --vehicle ID")
    check_port_url(args.mavlink)
    zenoh_given = [
        opt
        for opt, value in (
            ("--listen", args.listen),
            ("--connect", args.connect),
            ("--zenoh-config", args.zenoh_config),
            ("--cfg", args.cfg),
            ("--tls", args.tls),
        )
        if value
    ]
    if zenoh_given:
        raise ValueError(f"--mavlink replaces Zenoh: drop {', '.join(zenoh_given)}")


def exit_with_parent(parent: int) -> None:
    """SIGTERM to this process when its parent, process ``parent``, ends, kill -9 too
    (Linux's PR_SET_PDEATHSIG; elsewhere nothing): a demo killed so left its simulators
    connected to its port, where the next demo on it heard them (an outside review). Also
    when it ended before this was asked for (the new parent is another process)."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM) != 0:
        logging.getLogger("sim_vehicles").warning(
            "--exit-with-parent: prctl failed (%s)", os.strerror(ctypes.get_errno())
        )
        return
    if os.getppid() != parent:  # it ended before the signal was asked for
        os.kill(os.getpid(), signal.SIGTERM)


def main(argv: Sequence[str] | None = None, prog: str = "python -m sim_vehicles") -> int:
    args = build_parser(prog).parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    if args.exit_with_parent is not None:
        exit_with_parent(args.exit_with_parent)
    from dispatcher.config.scenario import load_scenario
    from dispatcher.link.mavlink import LinkDown
    from sim_vehicles.mavlink_port import run_mavlink
    from sim_vehicles.runner import run
    from sim_vehicles.tractor import RoverParams

    log = logging.getLogger("sim_vehicles")
    try:
        scenario = load_scenario(args.scenario, args.fields)
        ids = (
            [v.id for v in scenario.vehicles]
            if args.all
            else [scenario.vehicle(vid).id for vid in args.vehicle]
        )
        twice = sorted({vid for vid in ids if ids.count(vid) > 1})
        if twice:  # two simulated tractors of one system id, on one set of keys
            raise ValueError(f"--vehicle {', '.join(twice)} given more than once")
        options = wire.zenoh_options(args, False, identity=ids[0])
        options.config()  # a bad --cfg or --mode fails here, with a message
        params = RoverParams(
            mission_done=args.mission_done,
            upload_request="MISSION_REQUEST_INT" if args.request_int else "MISSION_REQUEST",
            gcs_failsafe_s=args.gcs_failsafe,
        )
        impairment = impairment_of(args)
        fail_after = parse_fail_after(args.fail_after)
        stall_after = parse_fail_after(args.stall_after, "--stall-after")
        deaf_until = parse_fail_after(args.deaf_until, "--deaf-until")
        for flag, faults in (
            ("--fail-after", fail_after),
            ("--stall-after", stall_after),
            ("--deaf-until", deaf_until),
        ):
            unknown = sorted(set(faults) - set(ids))
            if unknown:
                raise ValueError(f"{flag} names {', '.join(unknown)}, not simulated here")
        if not 0.0 < args.speedup < math.inf or not 0.0 < args.telemetry_hz < math.inf:
            raise ValueError(
                f"--speedup and --telemetry-hz must be finite and > 0, not "
                f"{args.speedup:g} and {args.telemetry_hz:g}"
            )
        if args.mavlink:
            check_mavlink_args(args, ids)
            for flag, faults in (("--stall-after", stall_after), ("--deaf-until", deaf_until)):
                if faults:
                    raise ValueError(f"{flag} works on Zenoh only, not with --mavlink")
        keys = signing_keys(args, scenario, ids)
    except (DispatcherError, ValueError, zenoh.ZError) as exc:
        log.error("%s", exc)
        return EXIT_BAD_INPUT
    if args.mavlink:
        try:
            return run_mavlink(
                scenario,
                ids[0],
                args.mavlink,
                speedup=args.speedup,
                telemetry_hz=args.telemetry_hz,
                fail_after_s=fail_after.get(ids[0]),
                params=params,
                stats_path=args.stats,
                key=keys[ids[0]] if keys is not None else None,
            )
        except LinkDown as exc:
            log.error("%s", exc)
            return EXIT_LINK_DOWN
    return run(
        scenario,
        ids,
        options,
        speedup=args.speedup,
        telemetry_hz=args.telemetry_hz,
        fail_after=fail_after,
        params=params,
        stats_path=args.stats,
        impairment=impairment,
        seed=args.radio_seed,
        stall_after=stall_after,
        keys=keys,
        deaf_until=deaf_until,
    )


if __name__ == "__main__":
    sys.exit(main())
