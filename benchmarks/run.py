"""`make bench`: speed and quality goals, measured side by side in one run.

Sections (all by default, or name them): ``solver`` — IGHOA (ours), IGHOA as the paper
has it, and the classic GA on a few of the paper's cells at equal time, as ratios to the
paper's figures and to the best-known solutions; ``upload`` — time from "plan ready" to
"every mission acknowledged" for 6 vehicles with ~300 items each on loopback;
``transfers`` — one upload of 200 items on a simulated clock through lossy, late and
reordering radios and to a vehicle that stalls, 40-200 seeds a radio (the tail);
``telemetry`` — 100 simulated vehicles sending telemetry at 10 Hz for 60 s into one
dispatcher: share of messages in the MCAP, dispatcher CPU; ``store`` — what a commit of
the dispatcher's SQLite store costs with synchronous FULL and NORMAL; ``soak`` — 30
tractors on 200 fields for 10 minutes with random kills and stalls and 20 % loss,
re-planned; ``replan`` — the same fleet and farm for 4 minutes on clean radios: how
fast a loss becomes new missions on board; ``sitl`` — a 4-field farm driven by ArduPilot
Rover in SITL through the bridge: planned vs driven, cross-track error, implement down
outside a field, turns without a loop.

The report is printed and appended to benchmarks/RESULTS.md with date, machine and command.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))


def machine_line() -> str:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(__import__("os").sched_getaffinity(0))
    return f"{platform.node()} · {cpu} · {cores} cores · Python {platform.python_version()}"


def bench_solver(seconds: float, seeds: int) -> str:
    from planner.ighoa import IGHOAParams
    from planner.paper import BKS_MINSUM, MTSP_CELLS
    from planner.solve import solve, stop_after
    from planner.tsplib import read_instance

    picks = [("eil51", 3), ("eil76", 5), ("kroA100", 5), ("kroA150", 3), ("kroA200", 4)]
    variants = {
        "IGHOA + our local search": (
            "ighoa",
            IGHOAParams(local_search="extended", memetic=2, shift_counts=True),
        ),
        "IGHOA (the paper's)": ("ighoa", IGHOAParams()),
        "GA": ("ga", None),
    }
    lines = [
        f"### Solver: min-sum mTSP, {seeds} seeds, {seconds:g} s (or 2000 generations) each",
        "",
        "| instance | m | "
        + " | ".join(f"{v} mean" for v in variants)
        + " | paper IGHOA | with ours / paper | with ours / the paper's | BKS |",
        "|---|---|" + "---|" * (len(variants) + 4),
    ]
    for name, m in picks:
        cell = next(c for c in MTSP_CELLS if c.instance == name and c.salesmen == m)
        problem = read_instance(HERE / "tsplib" / f"{name}.tsp").to_problem(m)
        means = {}
        for label, (alg, params) in variants.items():
            costs = [
                solve(
                    problem, "distance", alg, stop_after(2000, seconds), seed=s, params=params
                ).cost
                for s in range(1, seeds + 1)
            ]
            means[label] = statistics.fmean(costs)
        ours, paper_only = means["IGHOA + our local search"], means["IGHOA (the paper's)"]
        bks = BKS_MINSUM.get((name, m))
        lines.append(
            f"| {name} | {m} | "
            + " | ".join(f"{v:.2f}" for v in means.values())
            + f" | {cell.ighoa:.2f} | {ours / cell.ighoa:.3f} | {ours / paper_only:.3f} "
            f"| {f'{bks:.2f}' if bks else '–'} |"
        )
    return "\n".join(lines) + "\n"


def bench_upload() -> str:
    from benchmarks.dispatcher_bench import bench_upload as run

    return run()


def bench_transfers() -> str:
    from benchmarks.transfer_bench import bench_transfers as run

    return run()


def bench_telemetry() -> str:
    from benchmarks.dispatcher_bench import bench_telemetry as run

    return run()


def bench_store() -> str:
    from benchmarks.store_bench import bench_store as run

    return run()


def bench_soak() -> str:
    from benchmarks.soak_bench import bench_soak as run

    return run(seed=int(os.environ.get("AGRIFLEET_SOAK_SEED", "1")))


def bench_replan() -> str:
    from benchmarks.soak_bench import bench_soak as run

    return run(minutes=4.0, loss=0.0, fit=0.5, gap_s=(15.0, 25.0))


def bench_sitl() -> str:
    from benchmarks.sitl_bench import bench_sitl as run

    return run()


SECTIONS = {
    "solver": bench_solver,
    "upload": bench_upload,
    "transfers": bench_transfers,
    "telemetry": bench_telemetry,
    "store": bench_store,
    "sitl": bench_sitl,
    "soak": bench_soak,
    "replan": bench_replan,
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("sections", nargs="*", help=f"any of {', '.join(SECTIONS)} (default: all)")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--no-save", action="store_true")
    args = parser.parse_args()
    unknown = set(args.sections) - set(SECTIONS)
    if unknown:
        parser.error(f"unknown section(s) {', '.join(sorted(unknown))}")
    args.sections = args.sections or list(SECTIONS)
    from planner.solve import warm_up

    warm_up()
    stamp = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE.parent
    ).stdout.strip()
    report = [
        f"## {stamp} · commit {commit}",
        "",
        f"Machine: {machine_line()}",
        f"Command: `python benchmarks/run.py {' '.join(sys.argv[1:])}`",
        "",
    ]
    for name in args.sections:
        fn = SECTIONS[name]
        if name == "solver":
            report.append(fn(args.seconds, args.seeds))
        else:
            report.append(fn())
        print(report[-1], flush=True)
    text = "\n".join(report) + "\n"
    if not args.no_save:
        results = HERE / "RESULTS.md"
        if not results.exists():
            results.write_text("# Benchmark results\n\nNewest last. `make bench` appends.\n\n")
        before = results.read_text()
        with results.open("a") as f:
            # A heading begins a paragraph of its own, whatever the file ended with.
            f.write(
                ("" if before.endswith("\n\n") else "\n" if before.endswith("\n") else "\n\n")
                + text
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
