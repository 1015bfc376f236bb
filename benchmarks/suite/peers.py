"""The peers of ``agrifleet bench``: OR-Tools and PyVRP models of our problems.

Both are the optional extra ``agrifleet[bench]`` and imported only when a peer runs. Each
model returns routes as task indices per machine (the planner's numbering: TSPLIB node
k + 2 is task k), so our own cost model (:func:`planner.cost.figures`) scores the peers'
answers and ours alike. Costs are integers in both solvers: distances are scaled by
:data:`SCALE` and rounded, which moves a figure by well under 0.01 %.

mTSP, depot = node 1 (index 0 below), m salesmen, each visits at least one city:

- OR-Tools routing: one vehicle per salesman; a dimension counting visits whose end is at
  least 2 for every vehicle (start → city → end); min-sum: arc cost = distance; min-max:
  a distance dimension with a global span cost (coefficient 100) and the distance as arc
  cost. First solution PATH_CHEAPEST_ARC (looked for in a tenth of the limit, at most 2 s;
  where it finds none, with ~10 salesmen or more, the search starts from a sweep of the
  cities around the depot cut into m runs), then guided local search up to the time limit.
  OR-Tools has no seed: the same limit gives the same answer on an idle machine.
- PyVRP (min-sum only: it has no min-max objective): m vehicles without capacity; every
  city-to-city edge costs ``BIG`` more than its length, so a solution with more routes is
  always cheaper, and it uses all m (merging two routes saves at most two depot legs,
  less than BIG); the constant (n - m) BIG is taken off again.

The farm (makespan, machines of different speeds and service times): OR-Tools with a
time dimension whose transits are per machine (road time at its speed plus its service
time at the destination), a global span cost on it (makespan, weight
:data:`FARM_SPAN_WEIGHT` per second) and the road distance in metres as arc cost;
machines may stay idle. That naive model alone leaves most machines idle at 500 x 30
(its first solution fills few routes; at 10 s: 2 of 30 machines, makespan 17 x the lower
bound). The tuned model also caps every machine's time at :data:`FARM_CAP_OVER_BOUND`
times the travel-free lower bound (agrifleet_bench.farm), which makes the first solution
spread the fields (10 s, 500 x 30: 1.10 -> 57.0 h, 1.15 -> 59.8 h, 1.3 -> 67.6 h, 1.08 no
solution; soft upper bounds or parallel cheapest insertion did not help; measured when
the bound was 400 multiplicative steps' value, 0.8 % below the LP's that it is now at
500 x 30, hence 1.092 now: a looser cap of 1.10 times the LP's bound gave 56.98 h and
1565.6 road km at 500 x 30, 60 s, where the cap of before gave 56.20 h and 1618.5 km).
When the capped
model finds nothing, the naive one is run again with the same limit (logged).
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from planner.problem import Problem

log = logging.getLogger(__name__)

SCALE = 1000  # integer cost units per distance unit
FARM_SPAN_WEIGHT = 100  # arc-cost units (metres) per second of makespan
# Each machine's time cap / the travel-free makespan lower bound: tuned as 1.10 times the
# bound of 400 multiplicative steps, which is 1.092 times the LP's value the bound is now
# (500 x 30: 57.35 h then, 57.37 h now; 100 x 10: 34.73 h, 34.70 h), so the same caps.
FARM_CAP_OVER_BOUND = 1.092


class PeerUnavailable(RuntimeError):
    """The peer solver is not installed (``pip install agrifleet[bench]``)."""


class PeerNoSolution(RuntimeError):
    """The peer found no solution within the time limit (its row says so; ours stands)."""


def _full_matrix(problem: Problem) -> np.ndarray:
    """Depot (index 0) and tasks (1..n) as one matrix of machine 0's legs."""
    n = problem.num_tasks
    full = np.zeros((n + 1, n + 1))
    full[1:, 1:] = problem.dist
    full[0, 1:] = problem.start_dist[0]
    full[1:, 0] = problem.end_dist[0]
    return full


def _routes_from_ortools(manager, routing, solution, m: int) -> list[list[int]]:  # type: ignore[no-untyped-def]
    routes = []
    for v in range(m):
        route = []
        index = solution.Value(routing.NextVar(routing.Start(v)))
        while not routing.IsEnd(index):
            route.append(manager.IndexToNode(index) - 1)
            index = solution.Value(routing.NextVar(index))
        routes.append(route)
    return routes


def _ortools():  # type: ignore[no-untyped-def]
    try:
        from ortools.constraint_solver import pywrapcp, routing_enums_pb2
    except ImportError as exc:
        raise PeerUnavailable("OR-Tools is not installed: pip install 'agrifleet[bench]'") from exc
    return pywrapcp, routing_enums_pb2


def _search(pywrapcp, enums, time_limit: float):  # type: ignore[no-untyped-def]
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.first_solution_strategy = enums.FirstSolutionStrategy.PATH_CHEAPEST_ARC
    params.local_search_metaheuristic = enums.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    params.time_limit.FromMilliseconds(max(1, int(time_limit * 1000)))
    return params


def ortools_mtsp(problem: Problem, minmax: bool, time_limit: float) -> list[list[int]]:
    """OR-Tools on the mTSP of ``problem`` (identical machines from one depot)."""
    pywrapcp, enums = _ortools()
    m = problem.num_machines
    matrix = np.rint(_full_matrix(problem) * SCALE).astype(np.int64)
    manager = pywrapcp.RoutingIndexManager(matrix.shape[0], m, 0)
    routing = pywrapcp.RoutingModel(manager)
    transit = routing.RegisterTransitMatrix(matrix.tolist())
    routing.SetArcCostEvaluatorOfAllVehicles(transit)
    ones = routing.RegisterUnaryTransitVector([1] * matrix.shape[0])
    routing.AddDimension(ones, 0, matrix.shape[0] + 1, True, "visits")
    visits = routing.GetDimensionOrDie("visits")
    for v in range(m):
        visits.CumulVar(routing.End(v)).SetMin(2)
    if minmax:
        routing.AddDimension(transit, 0, int(matrix.sum(axis=1).max() * 2), True, "distance")
        routing.GetDimensionOrDie("distance").SetGlobalSpanCostCoefficient(100)
    # Its first-solution heuristics find no plan where every salesman needs a city once m
    # is ~10 (eil51 m=10: none in 10 s, the whole limit spent looking): a short look first,
    # and if it finds nothing, the search starts from a sweep of the cities (a review).
    started = time.monotonic()
    routing.CloseModelWithParameters(_search(pywrapcp, enums, time_limit))
    # (read before any search: after a failed one OR-Tools reads no routes)
    sweep = [[manager.NodeToIndex(k) for k in r] for r in _sweep_routes(problem)]
    start = routing.ReadAssignmentFromRoutes(sweep, True)
    probe = _search(pywrapcp, enums, min(PROBE_SHARE * time_limit, PROBE_MAX_S))
    probe.solution_limit = 1
    found = routing.SolveWithParameters(probe)
    left = max(time_limit - (time.monotonic() - started), 0.001)
    if found is not None:
        solution = routing.SolveWithParameters(_search(pywrapcp, enums, left))
    elif start is not None:
        solution = routing.SolveFromAssignmentWithParameters(start, _search(pywrapcp, enums, left))
    else:
        solution = None
    if solution is None:
        raise PeerNoSolution(f"OR-Tools found no solution to {problem.name} in {time_limit:g} s")
    return _routes_from_ortools(manager, routing, solution, m)


PROBE_SHARE, PROBE_MAX_S = 0.1, 2.0  # OR-Tools' first look for a plan of its own


def _sweep_routes(problem: Problem) -> list[list[int]]:
    """The cities (routing nodes from 1) by their angle around the depot, cut into
    ``num_machines`` runs of near-equal count: a plan where each salesman has a city."""
    depot = problem.depot or (0.0, 0.0)
    angles = [math.atan2(t.y - depot[1], t.x - depot[0]) for t in problem.tasks]
    order = sorted(range(problem.num_tasks), key=angles.__getitem__)
    m = problem.num_machines
    return [[j + 1 for j in part] for part in np.array_split(np.array(order), m)]


def pyvrp_mtsp(problem: Problem, time_limit: float, seed: int) -> list[list[int]]:
    """PyVRP on the min-sum mTSP of ``problem`` (see the module for the model)."""
    try:
        from pyvrp import Client, Depot, Location, ProblemData, VehicleType, solve
        from pyvrp.stop import MaxRuntime
    except ImportError as exc:
        raise PeerUnavailable("PyVRP is not installed: pip install 'agrifleet[bench]'") from exc
    m, n = problem.num_machines, problem.num_tasks
    matrix = np.rint(_full_matrix(problem) * SCALE).astype(np.int64)
    big = 2 * int(matrix.max()) + 1
    matrix[1:, 1:] += big
    np.fill_diagonal(matrix, 0)
    xy = [problem.depot or (0.0, 0.0)] + [(t.x, t.y) for t in problem.tasks]
    data = ProblemData(
        locations=[Location(float(x), float(y)) for x, y in xy],
        clients=[Client(location=k) for k in range(1, n + 1)],
        depots=[Depot(location=0)],
        vehicle_types=[VehicleType(num_available=m)],
        distance_matrices=[matrix],
        duration_matrices=[np.zeros_like(matrix)],
    )
    result = solve(data, MaxRuntime(time_limit), seed=seed, display=False)
    routes = [_pyvrp_clients(route) for route in result.best.routes()]
    routes += [[] for _ in range(m - len(routes))]
    return routes


def _pyvrp_clients(route) -> list[int]:  # type: ignore[no-untyped-def]
    """A PyVRP route's clients in order; client k (from 0) is our task k."""
    return [int(a.idx) for a in route if a.is_client()]


def ortools_farm(problem: Problem, time_limit: float) -> list[list[int]]:
    """OR-Tools on the farm's makespan (see the module for the model)."""
    from agrifleet_bench.farm import makespan_lower_bound

    cap_s = FARM_CAP_OVER_BOUND * makespan_lower_bound(problem) * 3600.0
    routes = _ortools_farm(problem, time_limit, cap_s)
    if routes is None:
        log.warning("OR-Tools: no farm plan under the time cap; running without it")
        routes = _ortools_farm(problem, time_limit, None)
    if routes is None:
        raise PeerNoSolution(f"OR-Tools found no solution to {problem.name} in {time_limit:g} s")
    return routes


def _ortools_farm(
    problem: Problem, time_limit: float, cap_s: float | None
) -> list[list[int]] | None:
    pywrapcp, enums = _ortools()
    from agrifleet_bench.farm import service_hours

    m, n = problem.num_machines, problem.num_tasks
    dist = _full_matrix(problem)
    service_s = np.zeros((m, n + 1))
    service_s[:, 1:] = service_hours(problem) * 3600.0
    road_s_per_m = 3.6 / problem.machine_array("road_speed_kmh")
    manager = pywrapcp.RoutingIndexManager(n + 1, m, 0)
    routing = pywrapcp.RoutingModel(manager)
    arc = routing.RegisterTransitMatrix(np.rint(dist).astype(np.int64).tolist())
    routing.SetArcCostEvaluatorOfAllVehicles(arc)
    per_machine = [
        routing.RegisterTransitMatrix(
            np.rint(dist * road_s_per_m[i] + service_s[i][None, :]).astype(np.int64).tolist()
        )
        for i in range(m)
    ]
    horizon = service_s.sum(axis=1).max() + dist.sum(axis=1).max() * road_s_per_m.max()
    capacity = int(2 * horizon if cap_s is None else cap_s)
    routing.AddDimensionWithVehicleTransits(per_machine, 0, capacity, True, "time")
    routing.GetDimensionOrDie("time").SetGlobalSpanCostCoefficient(FARM_SPAN_WEIGHT)
    solution = routing.SolveWithParameters(_search(pywrapcp, enums, time_limit))
    if solution is None:
        return None
    return _routes_from_ortools(manager, routing, solution, m)
