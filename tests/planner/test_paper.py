"""The paper's tables as data, and the Table 7 layout we ship."""

import pytest

from planner.paper import FLEET_CELLS, MTSP_CELLS, TSPLIB_DIR, table6_fleet, table7_problem


def test_every_mtsp_cell_has_its_instance():
    for cell in MTSP_CELLS:
        assert (TSPLIB_DIR / f"{cell.instance}.tsp").exists(), cell.instance
    assert len([c for c in MTSP_CELLS if c.table == 5]) == 16


def test_suspect_value_is_not_the_best_competitor():
    cell = next(c for c in MTSP_CELLS if (c.table, c.instance, c.salesmen) == (3, "eil101", 6))
    assert cell.best_competitor == ("HCGA", 900.34)


def test_table7_layout_matches_the_paper():
    problem = table7_problem(4)
    assert problem.num_tasks == 16
    assert sum(t.area_m2 for t in problem.tasks) == pytest.approx(178142.0)
    assert [m.working_width_m for m in problem.machines] == [6.9, 5.5, 3.7, 6.9]
    # Field 1 of Table 7: its first column, 70 m, across at 6.9 m -> 11 U-turns for AM1.
    assert problem.turns[0, 0] == 11


# Routes the paper prints (fields by number, machine AM1 first) with its Σs (m) and Σt (h).
PRINTED = {
    "Table 8 IGHOA": (
        [[16, 13, 8, 4, 11, 3, 15, 2, 9, 6, 12], [5, 10, 7], [1], [14]],
        4444.2,
        28.96,
    ),
    "Table 8 GA": ([[12, 13], [14, 6, 9, 10, 7, 11, 8, 4, 15, 3, 16, 5], [1], [2]], 6461.3, 35.61),
    "Table 10 IGHOA": (
        [[14], [1], [12], [6, 9, 2], [5, 10, 7, 15, 3, 11, 4, 8, 13], [16]],
        5897.3,
        34.7590,
    ),
    "Table 10 GA": (
        [[14], [1], [7], [16, 13], [6], [9, 12, 5, 10, 4, 8, 15, 2, 11, 3]],
        7502.2,
        40.2952,
    ),
}


@pytest.mark.parametrize("row", sorted(PRINTED))
def test_formula_6_gives_the_papers_own_time_for_the_routes_it_prints(row):
    """The paper gives no formula for n_turn; with ours (rectangle_turns) formula (6) gives
    the Σt of its Tables 8 and 10 from the routes and Σs they print, to their last digit
    (the turns between swaths, ceil(d_T / d_i) - 1, gave 0.42 h more)."""
    routes, distance_m, time_h = PRINTED[row]
    problem = table7_problem(len(routes))
    index = {t.id: j for j, t in enumerate(problem.tasks)}
    (speed,) = {m.road_speed_kmh for m in problem.machines}  # Table 6: all alike
    road_h = distance_m / 1000.0 / speed  # Σ_i s_i / v_i
    field_h = sum(
        problem.turns[i, index[str(f)]] * problem.machines[i].turn_time_h
        + problem.work_hours[i, index[str(f)]]
        for i, route in enumerate(routes)
        for f in route
    )
    assert road_h + field_h == pytest.approx(time_h, abs=0.005)
    assert {c.machines for c in FLEET_CELLS} == {4, 5, 6}
    assert len(table6_fleet(6)) == 6
