"""`agrifleet bench compile` and `agrifleet bench scale`: what the solver costs to start and
to run, apart from the quality of its answers.

``compile``: wall seconds to make the kernels ready with an empty numba cache (a fresh
install) and then with the cache it left (every later run), each in a fresh process.

``scale``: the default solver for a fixed time on TSPLIB instances of growing n, each in a
fresh process: generations, seconds per generation (from the first generation's end to the
last's, so that the initial population is not counted) in wall time and in the process's
CPU time (which other work on a shared machine does not inflate), the time to the first
generation, and the process's peak memory (max RSS). The slope of log(CPU seconds per
generation) against log(n) says how a generation grows with n; a log-log plot shows it.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from dispatcher.tools.bench import BenchError, check_instance

SCALE_INSTANCES = "eil51,eil76,kroA100,kroA200,lin318,rat575,pr1002,u1432,vm1748,pcb3038"
Progress = Callable[[str], None]
MEMORY_SEEN_MB = 5.0
"""An instance's peak memory counts in the fitted slope once it is this far above the
process's peak before it (the loaded kernels)."""


def peak_rss_mb() -> float:
    """This process's peak resident memory so far, in MB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass(frozen=True)
class ScaleRow:
    """One instance of `bench scale`, as its child process measured it."""

    instance: str
    n: int
    generations: int
    seconds_per_generation: float | None  # wall; None: fewer than two generations
    cpu_per_generation: float | None  # this process's CPU seconds (the machine may be shared)
    first_generation_s: float | None  # None: no generation at all
    elapsed_s: float
    cost: float
    baseline_mb: float  # peak RSS once the kernels are loaded, before the instance
    peak_mb: float


def _run_child(args: Sequence[str], env: dict[str, str] | None = None) -> tuple[dict, float]:
    """Run this module in a fresh process; its JSON answer and the process's wall seconds."""
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", __name__, *args], capture_output=True, text=True, env=env
    )
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"bench child {' '.join(args)} failed:\n{done.stderr}")
    return json.loads(done.stdout.strip().splitlines()[-1]), wall


def bench_compile(progress: Progress = lambda line: None) -> str:
    """Kernels ready from an empty numba cache, then from the cache that left; Markdown."""
    lines = [
        "Each in a fresh process (`agrifleet warm`'s work); NUMBA_CACHE_DIR a new empty "
        "directory for the cold one, kept for the cached one.",
        "",
        "| numba cache | functions compiled | compile or load s | process wall s | peak MB |",
        "|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory(prefix="agrifleet-numba-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for label in ("cold (fresh install)", "cached (later runs)"):
            answer, wall = _run_child(["compile"], env)
            row = (
                f"| {label} | {answer['compiled']} | {answer['seconds']:.2f} | {wall:.2f} "
                f"| {answer['peak_mb']:.0f} |"
            )
            lines.append(row)
            progress(row)
    return "\n".join(lines) + "\n"


def scale_instances(text: str) -> list[str]:
    """``eil51,kroA200`` as shipped instance names; an unknown one is an error."""
    names = [part.strip() for part in text.split(",") if part.strip()]
    for name in names:
        check_instance(name, "--instances")
    if not names:
        raise BenchError("--instances: no instance given")
    return names


def measure_scale(
    instances: Sequence[str],
    salesmen: int,
    seconds: float,
    seed: int,
    algorithm: str,
    progress: Progress = lambda line: None,
) -> list[ScaleRow]:
    """Each instance solved for ``seconds`` in a fresh process (its own peak memory)."""
    rows = []
    for name in instances:
        answer, _ = _run_child(["solve", name, str(salesmen), str(seconds), str(seed), algorithm])
        rows.append(ScaleRow(**answer))
        progress(f"{name}: {answer}")
    return rows


def fit_slope(ns: Sequence[float], values: Sequence[float]) -> float | None:
    """The least-squares slope of log(value) against log(n) (None: fewer than 2 points)."""
    import numpy as np

    if len(ns) < 2:
        return None
    slope, _ = np.polyfit(np.log(np.asarray(ns, float)), np.log(np.asarray(values, float)), 1)
    return float(slope)


def _exponent(slope: float | None) -> str:
    return "–" if slope is None else f"{slope:.2f}"


def _timed(rows: Sequence[ScaleRow]) -> list[ScaleRow]:
    return [r for r in rows if r.cpu_per_generation is not None]


def scale_table(rows: Sequence[ScaleRow], plot: str | None = None) -> str:
    """The Markdown table of `bench scale`, with the fitted slopes (and the plot's link)."""
    lines = [
        "| instance | n | generations | CPU s per generation | wall s per generation "
        "| first generation at s | peak MB | peak before the instance MB | cost |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        per = "–" if r.seconds_per_generation is None else f"{r.seconds_per_generation:.4g}"
        cpu = "–" if r.cpu_per_generation is None else f"{r.cpu_per_generation:.4g}"
        first = "–" if r.first_generation_s is None else f"{r.first_generation_s:.2f}"
        lines.append(
            f"| {r.instance} | {r.n} | {r.generations} | {cpu} | {per} | {first} | {r.peak_mb:.0f} "
            f"| {r.baseline_mb:.0f} | {r.cost:.2f} |"
        )
    timed = _timed(rows)
    slope = fit_slope([r.n for r in timed], [r.cpu_per_generation or 0.0 for r in timed])
    # Peak memory is a maximum: an instance shows only once it needs more than the kernels.
    grown = [r for r in rows if r.peak_mb - r.baseline_mb >= MEMORY_SEEN_MB]
    memory = fit_slope([r.n for r in grown], [r.peak_mb - r.baseline_mb for r in grown])
    large = sorted(timed, key=lambda r: r.n)[len(timed) // 2 :]
    upper = fit_slope([r.n for r in large], [r.cpu_per_generation or 0.0 for r in large])
    lines += [
        "",
        f"CPU seconds per generation grow as n^{_exponent(slope)} (least squares on log-log, "
        f"{len(timed)} instances with 2+ generations), as n^{_exponent(upper)} over the "
        f"larger half (n ≥ {large[0].n if large else '–'}); peak memory above the loaded kernels "
        f"as n^{_exponent(memory)} ({len(grown)} instances {MEMORY_SEEN_MB:g} MB or more "
        "above them).",
    ]
    if plot:
        lines += ["", f"![seconds per generation against n, log-log]({plot})"]
    return "\n".join(lines) + "\n"


def plot_scale(rows: Sequence[ScaleRow], path: str | Path, title: str) -> Path:
    """Seconds per generation against n on log-log axes, with the fitted line; a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    timed = _timed(rows)
    ns = np.array([r.n for r in timed], float)
    per = np.array([r.cpu_per_generation for r in timed], float)
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=110)
    ax.loglog(ns, per, "o", color="tab:blue", label="measured")
    for r in timed:
        ax.annotate(
            r.instance,
            (r.n, r.cpu_per_generation or 0.0),
            fontsize=7,
            xytext=(4, -10),
            textcoords="offset points",
        )
    slope = fit_slope(ns.tolist(), per.tolist())
    if slope is not None:
        intercept = float(np.mean(np.log(per) - slope * np.log(ns)))
        xs = np.geomspace(ns.min(), ns.max(), 50)
        ax.loglog(
            xs, np.exp(intercept) * xs**slope, "--", color="tab:gray", label=f"fit: n^{slope:.2f}"
        )
    ax.set_xlabel("n (cities)")
    ax.set_ylabel("CPU seconds per generation")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def bench_scale(
    instances: Sequence[str],
    salesmen: int,
    seconds: float,
    seed: int,
    algorithm: str,
    plot: Path | None,
    progress: Progress = lambda line: None,
) -> str:
    """Measure, draw the plot (when ``plot``) and return the Markdown report."""
    rows = measure_scale(instances, salesmen, seconds, seed, algorithm, progress)
    head = (
        f"{algorithm}, minsum, m = {salesmen}, {seconds:g} s per instance, seed {seed}, "
        "each instance in a fresh process."
    )
    if plot is not None:
        plot_scale(rows, plot, f"agrifleet {algorithm}, m={salesmen}, {seconds:g} s per instance")
    return head + "\n\n" + scale_table(rows, None if plot is None else plot.name)


def _child_compile() -> dict:
    from planner.kernels import compile_kernels

    done = compile_kernels()
    return {"seconds": done.seconds, "compiled": done.compiled, "peak_mb": peak_rss_mb()}


def _child_solve(name: str, salesmen: int, seconds: float, seed: int, algorithm: str) -> dict:
    from planner.kernels import compile_kernels
    from planner.paper import TSPLIB_DIR
    from planner.solve import solve, stop_after
    from planner.tsplib import read_instance

    compile_kernels()
    baseline = peak_rss_mb()
    ticks: list[tuple[int, float, float]] = []
    problem = read_instance(TSPLIB_DIR / f"{name}.tsp").to_problem(salesmen)
    result = solve(
        problem,
        "minsum",
        algorithm,
        stop_after(None, seconds),
        seed=seed,
        on_generation=lambda gen, best, elapsed: ticks.append((gen, elapsed, time.process_time())),
    )
    per = cpu = None
    if len(ticks) >= 2:
        (g0, t0, c0), (g1, t1, c1) = ticks[0], ticks[-1]
        per, cpu = (t1 - t0) / (g1 - g0), (c1 - c0) / (g1 - g0)
    row = ScaleRow(
        instance=name,
        n=problem.num_tasks + 1,  # the TSPLIB dimension: the depot and the cities
        generations=result.generations,
        seconds_per_generation=per,
        cpu_per_generation=cpu,
        first_generation_s=ticks[0][1] if ticks else None,
        elapsed_s=result.elapsed_s,
        cost=result.cost,
        baseline_mb=baseline,
        peak_mb=peak_rss_mb(),
    )
    return asdict(row)


def _child(argv: Sequence[str]) -> int:
    if argv[0] == "compile":
        answer = _child_compile()
    else:
        name, salesmen, seconds, seed, algorithm = argv[1:]
        answer = _child_solve(name, int(salesmen), float(seconds), int(seed), algorithm)
    print(json.dumps(answer))
    return 0


if __name__ == "__main__":
    sys.exit(_child(sys.argv[1:]))
