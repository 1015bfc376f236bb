"""TSPLIB distances checked against the known optimal tour lengths."""

from pathlib import Path

import pytest

from planner.errors import TSPLIBError
from planner.tsplib import read_instance, read_tour

DATA = Path(__file__).parent.parent / "data"


@pytest.mark.parametrize(("name", "optimum"), [("att48", 10628), ("eil51", 426)])
def test_official_rules_give_known_optimum(name, optimum):
    instance = read_instance(DATA / f"{name}.tsp")
    tour = read_tour(DATA / f"{name}.opt.tour")
    assert sorted(tour) == list(range(1, instance.dimension + 1))
    assert instance.tour_length(tour, "tsplib") == optimum


def test_real_distances_are_the_default():
    instance = read_instance(DATA / "eil51.tsp")
    tour = read_tour(DATA / "eil51.opt.tour")
    assert instance.tour_length(tour, "euclidean") == pytest.approx(429.983, abs=1e-3)
    problem = instance.to_problem(3)
    assert problem.num_tasks == 50 and problem.num_machines == 3
    assert problem.tasks[0].id == "2"  # node 1 is the depot
    assert problem.start_dist[0, 0] == pytest.approx(((37 - 49) ** 2 + (52 - 49) ** 2) ** 0.5)


def test_malformed_file_names_the_line(tmp_path):
    bad = tmp_path / "bad.tsp"
    bad.write_text(
        "NAME : bad\nTYPE : TSP\nDIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\n"
        "NODE_COORD_SECTION\n1 0 0\n2 1 x\n3 2 2\nEOF\n"
    )
    with pytest.raises(TSPLIBError, match=r"bad\.tsp:7: not a node id and two numbers"):
        read_instance(bad)


def test_unsupported_type_and_missing_nodes(tmp_path):
    f = tmp_path / "x.tsp"
    f.write_text("DIMENSION : 2\nEDGE_WEIGHT_TYPE : EXPLICIT\nNODE_COORD_SECTION\n1 0 0\n2 1 1\n")
    with pytest.raises(TSPLIBError, match="EXPLICIT is not supported"):
        read_instance(f)
    f.write_text("DIMENSION : 3\nEDGE_WEIGHT_TYPE : EUC_2D\nNODE_COORD_SECTION\n1 0 0\n2 1 1\n")
    with pytest.raises(TSPLIBError, match=r"lacks nodes \[3\]"):
        read_instance(f)
    with pytest.raises(TSPLIBError, match="cannot read"):
        read_instance(tmp_path / "missing.tsp")


def test_geo_rules():
    # Two points one degree of latitude apart on TSPLIB's sphere: about 111 km.
    import numpy as np

    from planner.tsplib import Instance

    inst = Instance("geo", "GEO", np.array([[10.0, 20.0], [11.0, 20.0]]))
    assert inst.distance_matrix("tsplib")[0, 1] == 112.0  # trunc(111.3 + 1)
    assert inst.distance_matrix("euclidean")[0, 1] == pytest.approx(111.32, abs=0.01)
