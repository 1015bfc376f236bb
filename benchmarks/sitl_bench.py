"""`make bench sitl`: a 4-field farm driven by ArduPilot Rover in SITL through the bridge.

Plans ``benchmarks/sitl-farm4.geojson`` with the SITL test machine (tests/data/sitl.toml),
runs ``agrifleet serve`` + ``agrifleet bridge`` + ``ardurover`` on loopback, and reads the
run back from its log: planned vs driven distance and time, the cross-track error on the
swaths (goal: median < 0.3 m, 95th percentile < 1 m), the time with the implement down
outside a field (goal 0) and the turns driven without a loop. Positions are forwarded at
50 Hz (bridge ``--rate``) so the track is sampled densely at the speedup.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "tests"))  # tests/helpers

FARM = HERE / "sitl-farm4.geojson"
SCENARIO = ROOT / "tests" / "data" / "sitl.toml"
SPEEDUP = 10.0


def bench_sitl() -> str:
    from helpers.sitl import Processes, Sitl, find_ardurover, free_port, log_of, wait_for

    from dispatcher.review.report import review_log, review_table

    binary = find_ardurover()
    title = "### ArduPilot Rover SITL: 4 fields, one rover, through the bridge"
    if binary is None:
        return f"{title}\n\nskipped: no ardurover binary (set AGRIFLEET_ARDUROVER)\n"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        procs = Processes(work)
        sitl = Sitl(binary, work / "sitl", speedup=SPEEDUP)
        try:
            port = free_port()
            sitl.start(wipe=True)
            # Its own data directory (the default, the user's state folder, kept the run and
            # the next bench resumed it) and the bridge with the farm and the keys serve has
            # (without them it spoke for another farm, unsigned: "r1: never came alive").
            data = ("--data-dir", str(work / "data"))
            serve = procs.serve(SCENARIO, port, work / "logs", "--fields", str(FARM), *data)
            procs.bridge(
                SCENARIO,
                "r1",
                sitl,
                port,
                "--fields",
                str(FARM),
                "--rate",
                "GLOBAL_POSITION_INT=50",
            )
            wait_for("the run to finish", lambda: serve.poll() is not None, 900.0)
            output = Processes.output(serve)
            if serve.returncode != 0:
                return f"{title}\n\nFAILED (exit {serve.returncode}):\n```\n{output[-2000:]}\n```\n"
            review = review_log(log_of(output))
        finally:
            procs.stop_all()
            sitl.stop()
    (v,) = review.vehicles
    q = v.quality
    assert q is not None
    lines = [
        title,
        "",
        f"Speedup {SPEEDUP:g}; farm `benchmarks/sitl-farm4.geojson`, machine r1 of "
        "`tests/data/sitl.toml`; `agrifleet review` of the run's log.",
        "",
        "| figure | planned | driven |",
        "|---|---|---|",
        f"| fields done | {len(v.fields_planned)} | {len(v.fields_done)} |",
        f"| distance km | {v.planned_distance_m / 1000:.3f} | {v.distance_m / 1000:.3f} |",
        f"| time h (mission legs at set speeds; vehicle clock) | {v.mission_time_h or 0:.4f} "
        f"| {v.time_h:.4f} |",
        f"| time h, planner's formula (6) | {v.planned_time_h:.4f} | |",
        f"| cross-track error on the swaths, median m (goal < 0.3) | | {_m(q.swath_median_m)} |",
        f"| cross-track error on the swaths, 95th percentile m (goal < 1) | | "
        f"{_m(q.swath_p95_m)} |",
        f"| cross-track error, every working line incl. headland, median / 95 % / max m | | "
        f"{_m(q.cross_track_median_m)} / {_m(q.cross_track_p95_m)} / {_m(q.cross_track_max_m)} |",
        f"| implement down outside a field, s (goal 0) | 0 | {q.outside_down_s:.1f} |",
        f"| turns driven / with a loop | {q.turns} | {q.turns - q.loops} / {q.loops} |",
        f"| positions with the implement down (on swaths) | | {q.samples} ({q.swath_samples}) |",
        "",
        "```",
        review_table(review),
        "```",
        "",
    ]
    return "\n".join(lines)


def _m(value: float | None) -> str:
    return "–" if value is None else f"{value:.3f}"


if __name__ == "__main__":
    print(bench_sitl())
