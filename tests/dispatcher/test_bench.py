"""`agrifleet bench mtsp|farm`: arguments, the BKS table, the farm generator and bound, peers."""

import numpy as np
import pytest
from agrifleet_bench.farm import generate_farm, makespan_lower_bound, service_hours

from dispatcher.cli.main import EXIT_BAD_INPUT, main
from dispatcher.tools.bench import BenchError, Cell, Runs, bench_mtsp, parse_cells, parse_farms
from planner.cost import figures
from planner.paper import BKS_MINSUM, TSPLIB_DIR, best_known
from planner.problem import Machine, Problem, Task
from planner.tsplib import read_instance


def test_cells_and_farms_are_parsed_and_bad_ones_named():
    assert parse_cells("eil51:3, kroA200:4") == [Cell("eil51", 3), Cell("kroA200", 4)]
    assert parse_farms("100x10,500x30") == [(100, 10), (500, 30)]
    with pytest.raises(BenchError, match="'nope:3'"):
        parse_cells("eil51:3,nope:3")
    with pytest.raises(BenchError, match="'eil51:0'"):
        parse_cells("eil51:0")
    with pytest.raises(BenchError, match="'10x20'"):
        parse_farms("10x20")


def test_a_bad_cell_or_run_setting_exits_2(capsys):
    assert main(["bench", "mtsp", "--cells", "eil51:x"]) == EXIT_BAD_INPUT
    assert "eil51:x" in capsys.readouterr().err
    assert main(["bench", "farm", "--runs", "0"]) == EXIT_BAD_INPUT
    assert "--runs" in capsys.readouterr().err


def test_the_bks_table_has_both_objectives_with_sources():
    table = best_known()
    minmax = table[("kroA200", "minmax", 3)]
    assert minmax.value == 10691.03 and any("He" in s for s in minmax.sources)
    assert table[("eil51", "minmax", 10)].sources == ("optimal",)
    assert BKS_MINSUM[("lin318", 3)] == 42404.55


def test_the_farm_generator_is_seeded_and_heterogeneous():
    a, b, c = generate_farm(40, 5, seed=3), generate_farm(40, 5, seed=3), generate_farm(40, 5, 4)
    assert np.array_equal(a.dist, b.dist) and np.array_equal(a.work_hours, b.work_hours)
    assert not np.array_equal(a.dist, c.dist)
    assert len(set(a.machine_array("road_speed_kmh"))) == 5
    hours = service_hours(a)
    # Service times depend on the machine, and not by one factor per machine alone.
    ratios = hours / hours[:, :1]
    assert not np.allclose(ratios[0], ratios[1])


def test_the_lower_bound_is_exact_on_related_machines_and_below_any_schedule():
    machines = [Machine(f"m{i}", 1.0, cap, 20.0, 0.0, 1.0, 1.0) for i, cap in enumerate((1, 3))]
    tasks = [Task(f"t{j}", float(j), 0.0, area_m2=a) for j, a in enumerate((2.0, 4.0, 6.0))]
    problem = Problem.build(machines, tasks, (0.0, 0.0), min_tasks_per_machine=0)
    assert makespan_lower_bound(problem) == pytest.approx(12.0 / 4.0, rel=1e-3)
    farm = generate_farm(60, 6, seed=1)
    bound = makespan_lower_bound(farm)
    hours = service_hours(farm)
    load = np.zeros(6)
    for j in np.argsort(-hours.min(axis=0)):  # greedy: earliest finish, travel ignored
        i = int(np.argmin(load + hours[:, j]))
        load[i] += hours[i, j]
    assert hours.min(axis=0).max() <= bound <= load.max()


def test_bench_mtsp_without_a_peer_reports_ours_beside_the_bks():
    report = bench_mtsp([Cell("eil51", 3)], None, "minmax", Runs(0.3, 1, 1, "ighoa"))
    row = next(line for line in report.splitlines() if line.startswith("| eil51"))
    assert "| 159.57 |" in row  # the BKS column


@pytest.mark.parametrize("peer", ["ortools", "pyvrp"])
def test_peers_give_complete_routes_with_every_salesman_busy(peer):
    pytest.importorskip(peer)
    from agrifleet_bench import peers

    problem = read_instance(TSPLIB_DIR / "eil51.tsp").to_problem(4)
    if peer == "ortools":
        routes = peers.ortools_mtsp(problem, minmax=True, time_limit=0.5)
    else:
        routes = peers.pyvrp_mtsp(problem, time_limit=0.5, seed=1)
    assert sorted(j for r in routes for j in r) == list(range(problem.num_tasks))
    assert len(routes) == 4 and all(routes)
    assert figures(problem, routes).distance_m > 0


def test_the_ortools_farm_model_covers_every_field():
    pytest.importorskip("ortools")
    from agrifleet_bench import peers

    problem = generate_farm(20, 3, seed=2)
    routes = peers.ortools_farm(problem, time_limit=0.5)
    assert sorted(j for r in routes for j in r) == list(range(20))
