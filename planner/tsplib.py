"""TSPLIB reader: EUC_2D, CEIL_2D, ATT and GEO instances as mTSP problems.

Node 1 is the depot (the garage) and nodes 2..N are the tasks. Distances are real-valued by
default (``euclidean``: the straight line on the coordinates, great circle for GEO), as in
the paper's tables; ``tsplib`` applies TSPLIB's official integer rules (nint, ceil,
pseudo-Euclidean ATT, GEO's truncated degrees and km), under which the known optimal tour
lengths hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from planner.errors import TSPLIBError
from planner.problem import FloatArray, Machine, Problem, Task

SUPPORTED = ("EUC_2D", "CEIL_2D", "ATT", "GEO")
DISTANCE_RULES = ("euclidean", "tsplib")


@dataclass(frozen=True)
class Instance:
    """The parsed file: its name, weight type and node coordinates (row k = node k + 1)."""

    name: str
    edge_weight_type: str
    coords: FloatArray

    @property
    def dimension(self) -> int:
        return int(self.coords.shape[0])

    def distance_matrix(self, rule: str = "euclidean") -> FloatArray:
        """All-pairs distances under ``rule``, ``euclidean`` (real) or ``tsplib`` (official)."""
        if rule not in DISTANCE_RULES:
            raise TSPLIBError(f"unknown distance rule {rule!r}; choose one of {DISTANCE_RULES}")
        x, y = self.coords[:, 0], self.coords[:, 1]
        if self.edge_weight_type == "GEO":
            return _geo_matrix(x, y, official=rule == "tsplib")
        # In place, two n x n arrays at most (pcb3038: 74 MB each): the peak memory of a
        # large instance is this matrix's making, not the solver's (benchmarks/RESULTS.md).
        d = np.subtract.outer(x, x)
        d *= d
        dy = np.subtract.outer(y, y)
        dy *= dy
        d += dy
        del dy
        if rule != "euclidean" and self.edge_weight_type == "ATT":
            d /= 10.0  # pseudo-Euclidean
        d = np.sqrt(d, out=d)
        if rule == "euclidean":
            return d
        if self.edge_weight_type == "EUC_2D":
            d += 0.5
            return np.floor(d, out=d)
        if self.edge_weight_type == "CEIL_2D":
            return np.ceil(d, out=d)
        # ATT: rounded up when nint falls short.
        t = np.floor(d + 0.5)
        return np.where(t < d, t + 1.0, t)

    def tour_length(self, tour: list[int], rule: str = "tsplib") -> float:
        """Length of a closed tour of 1-based node ids."""
        d = self.distance_matrix(rule)
        idx = [node - 1 for node in tour]
        return float(sum(d[a, b] for a, b in zip(idx, idx[1:] + idx[:1], strict=True)))

    def to_problem(self, salesmen: int, rule: str = "euclidean") -> Problem:
        """The mTSP of this instance: node 1 the depot, ``salesmen`` identical machines.

        Tasks have no area, so every objective is about the distances alone.
        """
        if salesmen < 1:
            raise TSPLIBError(f"{self.name}: the number of salesmen must be at least 1")
        d = self.distance_matrix(rule)
        dist, depot_dist = np.ascontiguousarray(d[1:, 1:]), d[0, 1:].copy()
        del d  # before Problem.build copies ``dist``: one n x n array fewer at the peak
        machines = [
            Machine(
                id=f"m{k + 1}",
                working_width_m=1.0,
                capacity_m2h=1.0,
                road_speed_kmh=1.0,
                turn_time_h=0.0,
                road_fuel_lh=0.0,
                work_fuel_lh=0.0,
            )
            for k in range(salesmen)
        ]
        tasks = [
            Task(id=str(k + 1), x=float(self.coords[k, 0]), y=float(self.coords[k, 1]))
            for k in range(1, self.dimension)
        ]
        depot = (float(self.coords[0, 0]), float(self.coords[0, 1]))
        return Problem.build(
            machines,
            tasks,
            depot,
            dist=dist,
            depot_dist=depot_dist,
            name=self.name,
        )


def read_instance(path: str | Path) -> Instance:
    """Parse a TSPLIB ``.tsp`` file with a NODE_COORD_SECTION."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise TSPLIBError(f"{path}: cannot read: {exc.strerror}") from exc
    header: dict[str, str] = {}
    coords: dict[int, tuple[float, float]] = {}
    section = None
    for lineno, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line == "EOF":
            if line == "EOF":
                break
            continue
        where = f"{path}:{lineno}"
        if section == "NODE_COORD_SECTION" and line[0].isdigit():
            parts = line.split()
            if len(parts) != 3:
                raise TSPLIBError(f"{where}: expected 'node x y', got {line!r}")
            try:
                node, x, y = int(parts[0]), float(parts[1]), float(parts[2])
            except ValueError:
                raise TSPLIBError(f"{where}: not a node id and two numbers: {line!r}") from None
            if not (math.isfinite(x) and math.isfinite(y)):
                raise TSPLIBError(f"{where}: coordinates must be finite: {line!r}")
            if node in coords:
                raise TSPLIBError(f"{where}: node {node} appears twice")
            coords[node] = (x, y)
            continue
        if line.endswith("_SECTION"):
            section = line
            if section != "NODE_COORD_SECTION":
                raise TSPLIBError(f"{where}: unsupported section {line}")
            continue
        if ":" not in line:
            raise TSPLIBError(f"{where}: expected 'KEY : value' or a coordinate line, got {line!r}")
        key, value = (part.strip() for part in line.split(":", 1))
        header[key.upper()] = value
    return _instance_from(path, header, coords)


def _instance_from(
    path: Path, header: dict[str, str], coords: dict[int, tuple[float, float]]
) -> Instance:
    kind = header.get("EDGE_WEIGHT_TYPE", "")
    if kind not in SUPPORTED:
        raise TSPLIBError(
            f"{path}: EDGE_WEIGHT_TYPE {kind or '(missing)'} is not supported; "
            f"supported: {', '.join(SUPPORTED)}"
        )
    try:
        dimension = int(header["DIMENSION"])
    except (KeyError, ValueError):
        raise TSPLIBError(f"{path}: DIMENSION is missing or not an integer") from None
    if sorted(coords) != list(range(1, dimension + 1)):
        missing = sorted(set(range(1, dimension + 1)) - set(coords))
        extra = sorted(set(coords) - set(range(1, dimension + 1)))
        raise TSPLIBError(
            f"{path}: DIMENSION is {dimension} but NODE_COORD_SECTION "
            f"lacks nodes {missing[:5]} / has unexpected nodes {extra[:5]}"
        )
    if dimension < 2:
        raise TSPLIBError(f"{path}: needs a depot and at least one task")
    xy = np.array([coords[k] for k in range(1, dimension + 1)], dtype=np.float64)
    return Instance(name=header.get("NAME", path.stem), edge_weight_type=kind, coords=xy)


def read_tour(path: str | Path) -> list[int]:
    """Parse a TSPLIB ``.tour`` file: the node ids of its TOUR_SECTION."""
    path = Path(path)
    tour: list[int] = []
    in_section = False
    for lineno, raw in enumerate(path.read_text().splitlines(), start=1):
        line = raw.strip()
        if line == "TOUR_SECTION":
            in_section = True
            continue
        if not in_section or not line:
            continue
        if line in ("-1", "EOF"):
            break
        try:
            tour.extend(int(tok) for tok in line.split())
        except ValueError:
            raise TSPLIBError(f"{path}:{lineno}: not a node id: {line!r}") from None
    if not tour:
        raise TSPLIBError(f"{path}: no TOUR_SECTION")
    return tour


def _geo_matrix(x: FloatArray, y: FloatArray, official: bool) -> FloatArray:
    """TSPLIB GEO: x = latitude, y = longitude in DDD.MM (degrees and minutes)."""

    def radians(v: FloatArray) -> FloatArray:
        deg = np.trunc(v)
        return math.pi * (deg + 5.0 * (v - deg) / 3.0) / 180.0

    pi = 3.141592 if official else math.pi
    lat, lon = radians(x) * pi / math.pi, radians(y) * pi / math.pi
    q1 = np.cos(lon[:, None] - lon[None, :])
    q2 = np.cos(lat[:, None] - lat[None, :])
    q3 = np.cos(lat[:, None] + lat[None, :])
    arc = np.arccos(np.clip(0.5 * ((1.0 + q1) * q2 - (1.0 - q1) * q3), -1.0, 1.0))
    d = 6378.388 * arc
    if official:
        d = np.trunc(d + 1.0)
        np.fill_diagonal(d, 0.0)
    return d
