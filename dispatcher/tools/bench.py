"""`agrifleet bench mtsp` and `agrifleet bench farm`: ours and a peer solver side by side.

For every cell our solver runs ``runs`` times (seeds ``seed``, ``seed + 1``, …), then the
peer once (OR-Tools has no seed; PyVRP gets ``seed``), with the same time limit, one
after the other in this process, so that both see the same machine. Our compile time is
not charged (the kernels are compiled before the first clock starts); the peers' set-up
is. Every answer, ours and the peer's, is scored by our cost model
(:func:`planner.cost.figures`). The report is a Markdown table: ours (mean and best), the
peer, the best known (benchmarks/tsplib/mtsp-bks.toml) or, for the farm, two makespan
lower bounds (agrifleet_bench.farm: one that ignores travel, one that counts the travel no
plan avoids), the gaps, and ours / peer.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable
from dataclasses import dataclass

from dispatcher.config.errors import DispatcherError

DEFAULT_CELLS = "eil51:3,eil76:3,kroA200:3,lin318:3"
DEFAULT_FARMS = "100x10,500x30"
PEERS = ("ortools", "pyvrp")
Progress = Callable[[str], None]


class BenchError(DispatcherError, ValueError):
    """A bad benchmark argument (cell, farm size, peer); the message names it."""


@dataclass(frozen=True)
class Runs:
    """How ours runs on every cell: ``runs`` seeds from ``seed``, ``time_limit`` seconds
    each (the peer's limit too), with ``algorithm``."""

    time_limit: float
    runs: int
    seed: int
    algorithm: str

    def __post_init__(self) -> None:
        if self.runs < 1:
            raise BenchError(f"--runs must be at least 1, not {self.runs}")
        if not self.time_limit > 0:
            raise BenchError(f"--time-limit must be positive, not {self.time_limit}")

    @property
    def seeds(self) -> range:
        return range(self.seed, self.seed + self.runs)

    def describe(self, peer: str | None) -> str:
        return (
            f"{self.time_limit:g} s per run, ours = {self.algorithm} seeds {self.seed}.."
            f"{self.seed + self.runs - 1}, peer = {peer or 'none'} (one run)"
        )


@dataclass(frozen=True)
class Cell:
    instance: str
    salesmen: int


def check_instance(name: str, where: str) -> None:
    """A shipped TSPLIB instance's name, or an error that names ``where`` it was given (a
    path is none: its best known would not be found by the name)."""
    from planner.paper import TSPLIB_DIR

    if "/" in name or name.startswith(".") or not (TSPLIB_DIR / f"{name}.tsp").is_file():
        known = ", ".join(sorted(p.stem for p in TSPLIB_DIR.glob("*.tsp")))
        raise BenchError(f"{where}: no instance {name!r}; we ship {known}")


def parse_cells(text: str) -> list[Cell]:
    """``eil51:3,kroA200:4`` as cells; an unknown instance, a bad m or more salesmen than
    cities (node 1 is the depot) is an error, before any cell runs."""
    from planner.paper import TSPLIB_DIR
    from planner.tsplib import read_instance

    cells = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, _, m = item.partition(":")
        check_instance(name, f"--cells {item!r}")
        if not _whole(m) or int(m) < 1:
            raise BenchError(f"--cells {item!r}: give INSTANCE:M with M >= 1 salesmen")
        cities = read_instance(TSPLIB_DIR / f"{name}.tsp").dimension - 1
        if int(m) > cities:
            raise BenchError(f"--cells {item!r}: {m} salesmen for {cities} cities")
        cells.append(Cell(name, int(m)))
    if not cells:
        raise BenchError("--cells: no cell given")
    return cells


def parse_farms(text: str) -> list[tuple[int, int]]:
    """``100x10,500x30`` as (fields, machines) pairs."""
    sizes = []
    for item in filter(None, (part.strip() for part in text.split(","))):
        fields, _, machines = item.partition("x")
        if not (_whole(fields) and _whole(machines) and int(fields) >= int(machines) >= 1):
            raise BenchError(f"--farms {item!r}: give FIELDSxMACHINES, fields >= machines >= 1")
        if int(fields) > MAX_FARM_FIELDS:
            raise BenchError(
                f"--farms {item!r}: at most {MAX_FARM_FIELDS} fields (its distances alone "
                f"would take {8 * int(fields) ** 2 / 2**30:.1f} GiB)"
            )
        sizes.append((int(fields), int(machines)))
    if not sizes:
        raise BenchError("--farms: no farm given")
    return sizes


MAX_FARM_FIELDS = 5_000
"""The largest farm `bench farm` makes (a matrix of distances of 0.2 GB)."""


def _whole(text: str) -> bool:
    """A whole number written in ASCII digits (``str.isdigit`` takes '³', which int refuses)."""
    return text.isascii() and text.isdigit()


def _gap(value: float | None, reference: float | None) -> str:
    if value is None or not reference:
        return "–"
    gap = 100.0 * (value / reference - 1.0)
    return f"{max(gap, 0.0) if gap > -0.005 else gap:+.2f} %"  # no "-0.00 %" at the BKS


def _num(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def _ratio(ours: float | None, peer: float | None) -> str:
    return "–" if ours is None or not peer else f"{ours / peer:.4f}"


def _check_peer(peer: str | None) -> None:
    if peer is None:
        return
    if peer not in PEERS:
        raise BenchError(f"--peer {peer!r}: choose one of {', '.join(PEERS)}")
    try:
        __import__(peer)
    except ImportError:
        raise BenchError(
            f"--peer {peer}: {peer} is not installed; pip install 'agrifleet[bench]'"
        ) from None


def bench_mtsp(
    cells: list[Cell],
    peer: str | None,
    objective: str,
    runs: Runs,
    progress: Progress = lambda line: None,
) -> str:
    """Ours and ``peer`` on TSPLIB mTSP cells; returns the Markdown report."""
    from agrifleet_bench import peers

    from planner.choices import Objective
    from planner.cost import figures
    from planner.paper import TSPLIB_DIR, best_known
    from planner.solve import solve, stop_after
    from planner.tsplib import read_instance

    if objective not in ("minsum", "minmax"):
        raise BenchError(f"--objective {objective!r}: choose minsum or minmax")
    _check_peer(peer)
    minmax = objective == "minmax"
    note = ""
    if peer == "pyvrp" and minmax:
        note = "PyVRP has no min-max objective: no peer figure on min-max."
        peer = None
    bks_table = best_known()
    peer_label = peer or "peer"
    lines = [
        f"{objective}, {runs.describe(peer)}" + (f"; {note}" if note else ""),
        "",
        f"| instance | m | ours mean | ours best | {peer_label} | BKS | ours gap | "
        f"{peer_label} gap | ours / {peer_label} |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for cell in cells:
        problem = read_instance(TSPLIB_DIR / f"{cell.instance}.tsp").to_problem(cell.salesmen)
        ours = [
            solve(problem, objective, runs.algorithm, stop_after(None, runs.time_limit), seed=s)
            for s in runs.seeds
        ]
        peer_cost = None
        peer_text = "–"  # no peer, or one found no solution (said in the row)
        try:
            routes = None
            if peer == "ortools":
                routes = peers.ortools_mtsp(problem, minmax, runs.time_limit)
            elif peer == "pyvrp":
                routes = peers.pyvrp_mtsp(problem, runs.time_limit, runs.seed)
        except peers.PeerNoSolution:
            peer_text = f"none in {runs.time_limit:g} s"
        if routes is not None:
            peer_cost = figures(problem, routes).value(Objective.parse(objective))
            peer_text = _num(peer_cost)
        bks = bks_table.get((cell.instance, objective, cell.salesmen))
        bks_value = bks.value if bks else None
        mean = statistics.fmean(r.cost for r in ours)
        row = (
            f"| {cell.instance} | {cell.salesmen} | {mean:.2f} | {min(r.cost for r in ours):.2f} "
            f"| {peer_text} | {_num(bks_value)} | {_gap(mean, bks_value)} "
            f"| {_gap(peer_cost, bks_value)} | {_ratio(mean, peer_cost)} |"
        )
        lines.append(row)
        progress(row)
    return "\n".join(lines) + "\n"


def bench_farm(
    sizes: list[tuple[int, int]],
    peer: str | None,
    runs: Runs,
    progress: Progress = lambda line: None,
    makespan_slack: float = 0.0,
    land_km2: float | None = None,
    passes: int = 1,
) -> str:
    """Ours and OR-Tools on generated farms (makespan); returns the Markdown report.
    ``land_km2``: square kilometres of land per field (default the generator's,
    :data:`agrifleet_bench.farm.FIELD_DENSITY_KM2`): how spread out the farm is.
    ``passes``: how many times each field is worked (its hours that many times over).

    ``makespan_slack`` > 0 runs ours ε-lexicographic
    (:meth:`planner.hybrid.HybridParams.with_makespan_slack`): late in the run a makespan
    up to ``1 + makespan_slack`` times the best by then counts as equal to it and the road
    distance decides; 0: the makespan, then the road distance.

    With the peer, ours runs again with the peer's makespan as a deadline (``solve``'s
    ``finish_within_h``): the road km of ours among plans that finish no later than the
    peer's, set beside the peer's road km (the two objectives compared at one makespan)."""
    from agrifleet_bench import peers
    from agrifleet_bench.farm import (
        FIELD_DENSITY_KM2,
        assignment_makespan,
        generate_farm,
        makespan_lower_bound,
        service_hours,
        travel_free_assignment,
        travel_lower_bound,
    )

    from planner.choices import SLACK_SHARE, check_makespan_slack
    from planner.cost import figures
    from planner.solve import solve, stop_after

    if peer not in (None, "ortools"):
        raise BenchError(f"--peer {peer!r}: the farm's peer is ortools (PyVRP has no makespan)")
    try:
        check_makespan_slack(makespan_slack)
    except ValueError as exc:
        raise BenchError(f"--makespan-slack: {exc}") from None
    if makespan_slack > 0.0 and runs.algorithm != "hybrid":
        raise BenchError(f"--makespan-slack needs --algorithm hybrid, not {runs.algorithm}")
    land = FIELD_DENSITY_KM2 if land_km2 is None else land_km2
    if not 0.01 <= land <= 1000.0:
        raise BenchError(f"--land-per-field must be within [0.01, 1000] km², not {land:g}")
    if not 1 <= passes <= 100:
        raise BenchError(f"--passes must be within [1, 100], not {passes}")
    _check_peer(peer)
    order = (
        f"ours: a makespan within {100 * makespan_slack:g} % of the best counts as equal in the "
        f"last {100 * SLACK_SHARE:g} % of the time, road km decides"
        if makespan_slack > 0.0
        else "ours: makespan, then road km"
    )
    lines = [
        f"makespan (h) on generated farms (agrifleet_bench.farm, instance seed {runs.seed}, "
        f"{land:g} km² of land a field{f', each worked {passes} times' if passes > 1 else ''}), "
        f"{runs.describe(peer)}; {order}; road km = total road distance; LB ignores travel, "
        "LBt counts the travel no plan avoids; no travel: the makespan of an assignment that "
        "ignores travel (the travel-free optimum is between LB and it); "
        "ours within OR-Tools' makespan: ours again, "
        "with OR-Tools' makespan as its deadline (the road km at no more makespan).",
        "",
        "| farm | ours mean | ours best | ours road km | OR-Tools | OR-Tools road km | LB | LBt "
        "| no travel | no travel gap to LB | ours gap to LB | ours gap to LBt "
        "| OR-Tools gap to LB | OR-Tools gap to LBt "
        "| ours / OR-Tools | machines used ours/OR-Tools "
        "| ours within OR-Tools' makespan: h | its road km | its road km / OR-Tools' |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for fields, machines in sizes:
        problem = generate_farm(fields, machines, runs.seed, land, passes)
        bound, travel = makespan_lower_bound(problem), travel_lower_bound(problem)
        no_travel = assignment_makespan(service_hours(problem), travel_free_assignment(problem))
        results = [
            solve(
                problem,
                "makespan",
                runs.algorithm,
                stop_after(None, runs.time_limit),
                seed=s,
                makespan_slack=makespan_slack,
            )
            for s in runs.seeds
        ]
        spans = [r.cost for r in results]
        best = min(results, key=lambda r: r.cost)
        peer_span = peer_km = None
        peer_used = "–"
        within = []  # ours again, within the peer's makespan
        if peer == "ortools":
            routes = peers.ortools_farm(problem, runs.time_limit)
            figs = figures(problem, routes)
            peer_span, peer_km = figs.makespan_h, figs.distance_m / 1000.0
            peer_used = str(sum(1 for r in routes if r))
            if runs.algorithm == "hybrid":  # a deadline is hybrid's
                within = [
                    solve(
                        problem,
                        "makespan",
                        "hybrid",
                        stop_after(None, runs.time_limit),
                        seed=s,
                        finish_within_h=peer_span,
                    )
                    for s in runs.seeds
                ]
        within_span = statistics.fmean(r.cost for r in within) if within else None
        within_km = (
            statistics.fmean(r.figures.distance_m for r in within) / 1000.0 if within else None
        )
        # The peer's makespan may be out of reach (then ours comes as near as it can): no
        # road ratio "at equal makespan" for a plan that misses it.
        within_met = within_span is None or peer_span is None or within_span <= peer_span + 1e-6
        mean = statistics.fmean(spans)
        ours_km = statistics.fmean(r.figures.distance_m for r in results) / 1000.0
        row = (
            f"| {fields}x{machines} | {mean:.2f} | {best.cost:.2f} | {ours_km:.1f} "
            f"| {_num(peer_span)} | {'–' if peer_km is None else f'{peer_km:.1f}'} "
            f"| {bound:.2f} | {travel:.2f} | {no_travel:.2f} | {_gap(no_travel, bound)} "
            f"| {_gap(mean, bound)} | {_gap(mean, travel)} "
            f"| {_gap(peer_span, bound)} | {_gap(peer_span, travel)} "
            f"| {_ratio(mean, peer_span)} | {sum(1 for r in best.routes if r)}/{peer_used} "
            f"| {_num(within_span)}{'' if within_met else ' (not met)'} "
            f"| {'–' if within_km is None else f'{within_km:.1f}'} "
            f"| {_ratio(within_km, peer_km) if within_met else '–'} |"
        )
        lines.append(row)
        progress(row)
    return "\n".join(lines) + "\n"
