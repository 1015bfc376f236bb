"""The paper's published tables and the means to rerun every cell beside them.

Tables 2-5: TSPLIB mTSP, total distance (real-valued), node 1 the depot.
Tables 8-10: the 16 fields of Table 7 with the machines of Table 6; the paper does not
give field positions, so ours come from ``config/paper-table7.toml`` (documented there).
"""

from __future__ import annotations

import statistics
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

from planner.problem import Machine, Problem, Task
from planner.solve import Result, solve, stop_after
from planner.tsplib import read_instance

# Installed with agrifleet (benchmarks/tsplib and config/ in a checkout).
TSPLIB_DIR = Path(str(files("agrifleet_tsplib")))
TABLE7_LAYOUT = Path(str(files("agrifleet_config") / "paper-table7.toml"))


@dataclass(frozen=True)
class MTSPCell:
    """One row of Tables 2-5: the paper's IGHOA figure and its competitors."""

    table: int
    instance: str
    salesmen: int
    ighoa: float
    competitors: dict[str, float]

    @property
    def best_competitor(self) -> tuple[str, float]:
        usable = {k: v for k, v in self.competitors.items() if k not in SUSPECT.get(self.key, ())}
        name = min(usable, key=usable.__getitem__)
        return name, usable[name]

    @property
    def key(self) -> tuple[int, str, int]:
        return (self.table, self.instance, self.salesmen)


# Values the paper prints that cannot be right: GAG on eil101 with m = 6 is printed as
# 75.62, below the TSP optimum (629); left out of "best competitor".
SUSPECT: dict[tuple[int, str, int], tuple[str, ...]] = {(3, "eil101", 6): ("GAG",)}


def _rows(table: int, names: tuple[str, ...], rows: list[tuple]) -> list[MTSPCell]:
    return [
        MTSPCell(table, inst, m, values[-1], dict(zip(names, values[:-1], strict=True)))
        for inst, m, *values in rows
    ]


MTSP_CELLS: list[MTSPCell] = [
    *_rows(
        2,
        ("IPGA", "GA2PC"),
        [
            ("eil51", 3, 478, 543, 471.77),
            ("eil51", 5, 549, 586, 506.13),
            ("kroA100", 3, 24288, 26653, 25041.00),
            ("kroA100", 5, 30710, 30408, 31147.00),
            ("kroA150", 3, 35428, 47418, 33606.00),
            ("kroA150", 5, 43725, 49947, 39063.00),
        ],
    ),
    *_rows(
        3,
        ("GA", "GAG", "HCGA", "SAGA"),
        [
            ("eil51", 3, 657.97, 509.99, 476.30, 472.56, 471.77),
            ("eil51", 4, 569.20, 549.20, 522.97, 503.34, 487.28),
            ("eil51", 5, 624.18, 608.55, 581.89, 567.32, 506.13),
            ("eil76", 3, 980.54, 666.80, 661.20, 653.96, 610.98),
            ("eil76", 4, 849.18, 695.06, 694.64, 690.94, 635.35),
            ("eil76", 5, 1018.18, 780.27, 771.50, 747.34, 627.57),
            ("eil76", 6, 862.45, 825.35, 804.21, 800.84, 642.42),
            ("eil101", 4, 1092.61, 817.89, 803.38, 796.96, 772.50),
            ("eil101", 5, 1137.01, 847.48, 857.54, 867.24, 770.23),
            ("eil101", 6, 1099.08, 75.62, 900.34, 900.90, 803.34),
            ("eil101", 7, 1062.69, 900.97, 898.77, 900.72, 803.11),
        ],
    ),
    *_rows(
        4,
        ("GA", "HCGA"),
        [
            ("eil101", 4, 921.2, 813.0, 772.50),
            ("lin318", 4, 135188.2, 71646.4, 49237.60),
            ("rat575", 4, 33008.9, 13057.0, 8541.41),
            ("pr1002", 3, 3218723.7, 721022.8, 305517.00),
            ("pr1002", 6, 1524822.4, 538609.8, 317816.00),
            ("u1432", 3, 2072059.0, 483942.8, 170505.00),
            ("u1432", 6, 914170.0, 308176.0, 171523.00),
            ("vm1748", 3, 7719677.9, 1858539.5, 609624.00),
            ("vm1748", 6, 3365320.0, 938670.90, 697024.00),
            ("pcb3038", 3, 3699627.9, 1302418.6, 163582.00),
            ("pcb3038", 4, 1837962.6, 657501.3, 163248.00),
            ("pcb3038", 6, 1497143.3, 427950.6, 165281.20),
        ],
    ),
    *_rows(
        5,
        ("GA-PMX", "GA-OX", "GA-CX"),
        [
            ("att48", 2, 52343.48, 52023.49, 52773.84, 37752.60),
            ("att48", 4, 64954.87, 66324.27, 64803.34, 37514.20),
            ("att48", 6, 75357.03, 78344.59, 77401.42, 40504.60),
            ("att48", 8, 93423.03, 96930.30, 94066.53, 44422.40),
            ("kroA100", 2, 32145.24, 32872.40, 32423.66, 24948.00),
            ("kroA100", 4, 46748.49, 48820.87, 47549.87, 29006.00),
            ("kroA100", 6, 57152.93, 59349.57, 56772.45, 26652.00),
            ("kroA100", 8, 58265.54, 65924.12, 62509.56, 28524.70),
            ("kroA150", 2, 43113.54, 43381.04, 42835.79, 32203.00),
            ("kroA150", 4, 59332.85, 61113.17, 61185.34, 36903.00),
            ("kroA150", 6, 71069.14, 74566.69, 72132.12, 35202.00),
            ("kroA150", 8, 81819.18, 86174.12, 84449.72, 35568.70),
            ("kroA200", 2, 48368.55, 46622.32, 48537.27, 36763.30),
            ("kroA200", 4, 66758.95, 67152.20, 69299.25, 36669.10),
            ("kroA200", 6, 82791.72, 82620.29, 84913.85, 38508.00),
            ("kroA200", 8, 95258.01, 97601.72, 99075.72, 39036.50),
        ],
    ),
]


@dataclass(frozen=True)
class FleetCell:
    """One row of Tables 8-10: a method's fleet totals Σs (m), Σc (L), Σt (h)."""

    table: int
    machines: int
    method: str  # "GA" or "IGHOA"
    distance_m: float
    fuel_l: float
    time_h: float


FLEET_CELLS: list[FleetCell] = [
    FleetCell(8, 4, "GA", 6461.30, 181.81, 35.61),
    FleetCell(8, 4, "IGHOA", 4444.20, 181.64, 28.96),
    FleetCell(9, 5, "GA", 7206.40, 181.65, 39.13),
    FleetCell(9, 5, "IGHOA", 4972.70, 181.69, 31.54),
    FleetCell(10, 6, "GA", 7502.2, 181.59, 40.2952),
    FleetCell(10, 6, "IGHOA", 5897.3, 181.59, 34.7590),
]

# Table 6: width m, capacity m²/h, road km/h, working L/h, road L/h, turn h.
TABLE6 = [
    (6.9, 7000.0, 10.0, 7.0, 3.0, 0.004),
    (5.5, 5000.0, 10.0, 5.0, 2.5, 0.003),
    (3.7, 4000.0, 10.0, 4.0, 2.0, 0.002),
]


def table6_fleet(count: int) -> list[Machine]:
    """``count`` machines of Table 6, repeating the three types as the paper does."""
    fleet = []
    for k in range(count):
        width, cap, road, work_fuel, road_fuel, turn = TABLE6[k % 3]
        fleet.append(Machine(f"AM{k + 1}", width, cap, road, turn, road_fuel, work_fuel))
    return fleet


def table7_problem(machines: int, layout: Path = TABLE7_LAYOUT) -> Problem:
    """The 16 fields of Table 7 at our positions, with ``machines`` machines of Table 6."""
    data = tomllib.loads(layout.read_text())
    tasks = [
        Task(
            str(f["id"]),
            float(f["x"]),
            float(f["y"]),
            float(f["area"]),
            float(f["width"]),
            float(f["length"]),
        )
        for f in data["field"]
    ]
    garage = data["garage"]
    return Problem.build(
        table6_fleet(machines),
        tasks,
        (float(garage["x"]), float(garage["y"])),
        name=f"table7-{machines}",
    )


@dataclass(frozen=True)
class Run:
    """Our results for one cell over several seeds."""

    results: tuple[Result, ...]

    def values(self, pick: Callable[[Result], float]) -> list[float]:
        return [pick(r) for r in self.results]

    def mean(self, pick: Callable[[Result], float]) -> float:
        return statistics.fmean(self.values(pick))

    def best(self, pick: Callable[[Result], float]) -> float:
        return min(self.values(pick))


def run_mtsp_cell(
    cell: MTSPCell, runs: int, time_limit: float, generations: int, algorithm: str = "ighoa"
) -> Run:
    problem = read_instance(TSPLIB_DIR / f"{cell.instance}.tsp").to_problem(cell.salesmen)
    return Run(
        tuple(
            solve(problem, "distance", algorithm, stop_after(generations, time_limit), seed=seed)
            for seed in range(1, runs + 1)
        )
    )


def run_fleet_cell(cell: FleetCell, runs: int, time_limit: float, generations: int) -> Run:
    problem = table7_problem(cell.machines)
    algorithm = "ighoa" if cell.method == "IGHOA" else "ga"
    return Run(
        tuple(
            solve(problem, "distance", algorithm, stop_after(generations, time_limit), seed=seed)
            for seed in range(1, runs + 1)
        )
    )


BKS_FILE = Path(str(files("agrifleet_tsplib") / "mtsp-bks.toml"))


@dataclass(frozen=True)
class BestKnown:
    """A best-known solution value of one mTSP cell and where it was published."""

    value: float
    sources: tuple[str, ...]  # full references (or "optimal": equal to a proven bound)


def best_known(path: Path = BKS_FILE) -> dict[tuple[str, str, int], BestKnown]:
    """The BKS table, keyed ``(instance, objective, m)`` with objective ``minsum`` or
    ``minmax`` (benchmarks/tsplib/mtsp-bks.toml; benchmarks/mtsp-bks.md explains it)."""
    raw = tomllib.loads(path.read_text())
    refs: dict[str, str] = raw["sources"]
    table: dict[tuple[str, str, int], BestKnown] = {}
    for row in raw["bks"]:
        for m, value in row["values"].items():
            keys = row["sources"][m].split()
            table[(row["instance"], row["objective"], int(m))] = BestKnown(
                float(value), tuple(refs.get(k, k) for k in keys)
            )
    return table


# Best-known min-sum solutions for the cells that have one.
BKS_MINSUM: dict[tuple[str, int], float] = {
    (inst, m): bks.value for (inst, obj, m), bks in best_known().items() if obj == "minsum"
}


def bench_report(
    tables: set[int],
    runs: int,
    time_limit: float,
    generations: int,
    progress: Callable[[str], None] = lambda line: None,
    algorithm: str = "ighoa",
) -> str:
    """Rerun the cells of ``tables`` and return a Markdown report beside the paper: the
    TSPLIB tables with ``algorithm`` (``ighoa``: the paper's own; ``hybrid``: ours), the
    farm tables (8-10) with the paper's two, IGHOA and GA."""
    lines = [
        f"Stop: {generations} generations or {time_limit:g} s per run, whichever first; "
        f"{runs} seeds (1..{runs}) per cell; real-valued distances.",
        "",
    ]
    mtsp = [c for c in MTSP_CELLS if c.table in tables]
    if mtsp:
        lines += [
            f"| table | instance | m | {algorithm} mean | {algorithm} best | paper IGHOA "
            f"| best other in paper | {algorithm}/paper | BKS | mean s/run |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for cell in mtsp:
            run = run_mtsp_cell(cell, runs, time_limit, generations, algorithm)
            mean, best = run.mean(lambda r: r.cost), run.best(lambda r: r.cost)
            other, other_value = cell.best_competitor
            bks = BKS_MINSUM.get((cell.instance, cell.salesmen))
            row = (
                f"| {cell.table} | {cell.instance} | {cell.salesmen} | {mean:.2f} | {best:.2f} "
                f"| {cell.ighoa:.2f} | {other} {other_value:.2f} | {mean / cell.ighoa:.3f} "
                f"| {f'{bks:.2f}' if bks else '–'} | {run.mean(lambda r: r.elapsed_s):.1f} |"
            )
            lines.append(row)
            progress(row)
        lines.append("")
    fleet = [c for c in FLEET_CELLS if c.table in tables]
    if fleet:
        lines += [
            "Tables 8-10: the 16 fields of Table 7 at OUR positions (config/paper-table7.toml; "
            "the paper gives none), machines of Table 6, objective Σs.",
            "",
            "| table | machines | method | ours Σs m (best) | paper Σs | ours Σc L | paper Σc "
            "| ours Σt h | paper Σt | Σs ours/paper |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for fc in fleet:
            run = run_fleet_cell(fc, runs, time_limit, generations)
            s = run.mean(lambda r: r.figures.distance_m)
            row = (
                f"| {fc.table} | {fc.machines} | {fc.method} | {s:.1f} "
                f"({run.best(lambda r: r.figures.distance_m):.1f}) | {fc.distance_m:.1f} "
                f"| {run.mean(lambda r: r.figures.fuel_l):.2f} | {fc.fuel_l:.2f} "
                f"| {run.mean(lambda r: r.figures.time_h):.2f} | {fc.time_h:.2f} "
                f"| {s / fc.distance_m:.3f} |"
            )
            lines.append(row)
            progress(row)
        lines.append("")
    return "\n".join(lines)
