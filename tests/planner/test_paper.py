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
    # Field 1 of Table 7: 127 m across at 6.9 m -> 18 U-turns for machine AM1.
    assert problem.turns[0, 0] == 18
    assert {c.machines for c in FLEET_CELLS} == {4, 5, 6}
    assert len(table6_fleet(6)) == 6
