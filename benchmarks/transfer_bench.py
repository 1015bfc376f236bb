"""Mission uploads on a simulated clock, many seeds, so that the tail shows.

Our client (``dispatcher.link.mission_protocol.MissionUpload``) against our ArduPilot-style
server (``sim_vehicles.mission_server.MissionServer``), every message through a MAVLink 2
frame, each way through a radio that loses, duplicates and delays (``sim_vehicles.
impairment``), or to a vehicle that now and then stops answering for a while (a loaded
gateway or autopilot: what reaches it waits). No processes, no sockets: the protocol alone,
repeatable by seed. ``python benchmarks/transfer_bench.py [--seeds N]`` prints the table;
``python benchmarks/run.py transfers`` also appends it to RESULTS.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from dataclasses import dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from dispatcher.link import mavlink as mc  # noqa: E402
from dispatcher.link import wire as contract  # noqa: E402
from dispatcher.link.mission_protocol import MissionUpload, Outcome  # noqa: E402
from sim_vehicles.impairment import DelayLine, Impairment  # noqa: E402
from sim_vehicles.mission_server import MissionServer, StoredItem  # noqa: E402

VEHICLE = 21
ITEMS = 200
LIMIT_S = 600.0


@dataclass(frozen=True)
class Link:
    name: str
    radio: Impairment
    step_s: float = 0.01  # the clock's step: a frame takes at least one
    stall_rate: float = 0.0  # the vehicle stops answering this often (per second) ...
    stall_s: tuple[float, float] = (0.0, 0.0)  # ... for U(a, b) seconds
    latency_s: float = 0.0  # every frame takes this long one way, on top of the radio's delay
    seeds: int = 200


LINKS = (
    Link("clean, 2 ms steps", Impairment(), step_s=0.002),
    Link(
        "clean, the vehicle stops 60-150 ms ~10 times a second",
        Impairment(),
        step_s=0.002,
        stall_rate=10.0,
        stall_s=(0.06, 0.15),
    ),
    Link(
        "clean, the vehicle stops 1-3 s every ~2 s",
        Impairment(),
        stall_rate=0.5,
        stall_s=(1.0, 3.0),
        seeds=40,
    ),
    Link("5 % loss each way", Impairment(loss=0.05)),
    Link("1 s round trip, 5 % loss each way", Impairment(loss=0.05), latency_s=0.5, seeds=40),
    Link("20 % loss each way", Impairment(loss=0.2)),
    Link("20 % loss, up to 20 ms delay", Impairment(loss=0.2, delay_s=0.02)),
    Link("10 % loss, up to 50 ms delay (reorders)", Impairment(loss=0.1, delay_s=0.05)),
    Link(
        "30 % loss, 10 % duplicates, up to 200 ms delay",
        Impairment(loss=0.3, duplicate=0.1, delay_s=0.2),
        seeds=40,
    ),
)


HOME = StoredItem(
    seq=0, frame=mc.MAV_FRAME_GLOBAL, command=mc.MAV_CMD_NAV_WAYPOINT, current=0, autocontinue=1,
    param1=0.0, param2=0.0, param3=0.0, param4=0.0, x=440000000, y=873000000, z=0.0,
)  # fmt: skip


def _items(n: int) -> list[mc.MAVLinkMessage]:
    """Waypoints 0 .. n-1, a metre or so apart."""
    frame = mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    return [
        replace(HOME, seq=k, frame=frame, x=HOME.x + 10 * k, y=HOME.y + 7 * k).message(VEHICLE)
        for k in range(n)
    ]


@dataclass
class Run:
    took_s: float
    done: bool
    resends: int
    twice: int  # items the vehicle received more than once


def upload(link: Link, seed: int, items: int = ITEMS) -> Run:
    """One upload of ``items`` items over ``link``."""
    import random

    gcs_tx = mc.Codec(contract.DISPATCHER_SYSTEM_ID, contract.DISPATCHER_COMPONENT_ID)
    gcs_rx = mc.Codec(contract.DISPATCHER_SYSTEM_ID, contract.DISPATCHER_COMPONENT_ID)
    v_tx = mc.Codec(VEHICLE, mc.MAV_COMP_ID_AUTOPILOT1)
    v_rx = mc.Codec(VEHICLE, mc.MAV_COMP_ID_AUTOPILOT1)
    server = MissionServer(lambda: HOME)
    client = MissionUpload(_items(items), VEHICLE)
    up: DelayLine[bytes] = DelayLine(link.radio, seed)
    down: DelayLine[bytes] = DelayLine(link.radio, seed + 100_000)
    stalls = random.Random(seed + 200_000)
    stalled_until = 0.0
    seen: set[int] = set()
    twice = 0
    now = 0.0
    late = link.latency_s
    for msg in client.start(now):
        up.push(gcs_tx.encode(msg), now + late)
    while client.outcome is Outcome.RUNNING and now < LIMIT_S:
        now += link.step_s
        if now >= stalled_until and stalls.random() < link.stall_rate * link.step_s:
            stalled_until = now + stalls.uniform(*link.stall_s)
        if now >= stalled_until:
            for frame in up.due(now):
                msg = v_rx.decode_one(frame)
                if msg is None:
                    continue
                if msg.get_type() == "MISSION_ITEM_INT":
                    twice += msg.seq in seen
                    seen.add(msg.seq)
                for reply in server.on_message(msg, now):
                    down.push(v_tx.encode(reply), now + late)
            for reply in server.on_tick(now):
                down.push(v_tx.encode(reply), now + late)
        out = []
        for frame in down.due(now):
            msg = gcs_rx.decode_one(frame)
            if msg is not None:
                out += client.on_message(msg, now)
        out += client.on_tick(now)
        for msg in out:
            up.push(gcs_tx.encode(msg), now + late)
    done = client.outcome is Outcome.DONE and server.count == items
    return Run(now, done, client.stats.retries, twice)


def bench_transfers(seeds: int | None = None) -> str:
    lines = [
        f"### Mission uploads on a simulated clock ({ITEMS} items; our client against our "
        "ArduPilot-style server through `sim_vehicles.impairment`; `benchmarks/transfer_bench.py`)",
        "",
        "| link | seeds | median s | mean s | p90 s | max s | resends (mean) "
        "| items received twice (mean) | failed |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for link in LINKS:
        n = seeds or link.seeds
        runs = [upload(link, seed) for seed in range(1, n + 1)]
        took = sorted(r.took_s for r in runs)
        lines.append(
            f"| {link.name} | {n} | {statistics.median(took):.2f} | {statistics.mean(took):.2f} "
            f"| {took[int(0.9 * (n - 1))]:.2f} | {took[-1]:.2f} "
            f"| {statistics.mean(r.resends for r in runs):.1f} "
            f"| {statistics.mean(r.twice for r in runs):.1f} | {sum(not r.done for r in runs)} |"
        )
        print(lines[-1], file=sys.stderr, flush=True)
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=None, help="per link (default: 200, 40)")
    args = parser.parse_args()
    print(bench_transfers(args.seeds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
