"""`agrifleet bench scale`: the table, the fitted slope and the plot, on made-up rows."""

import pytest

from dispatcher.cli.main import EXIT_BAD_INPUT, main
from dispatcher.tools.bench import BenchError
from dispatcher.tools.bench_resources import (
    ScaleRow,
    fit_slope,
    plot_scale,
    scale_instances,
    scale_table,
)


def row(name, n, per, grown=True):
    wall = None if per is None else 1.5 * per
    return ScaleRow(name, n, 10, wall, per, 0.5, 10.0, 123.0, 180.0, 180.0 + grown * n / 10)


ROWS = [
    row("a", 50, 0.0025, grown=False),
    row("b", 100, 0.01),
    row("c", 400, 0.16),
    row("d", 3000, None),
]


def test_the_slope_is_fitted_on_log_log():
    assert fit_slope([50, 100, 400], [0.0025, 0.01, 0.16]) == pytest.approx(2.0)
    assert fit_slope([50], [1.0]) is None


def test_the_table_has_a_row_per_instance_and_the_slopes():
    table = scale_table(ROWS, "scale.png")
    lines = table.splitlines()
    assert lines[0].startswith("| instance | n | generations | CPU s per generation | wall s")
    assert "| a | 50 | 10 | 0.0025 | 0.00375 | 0.50 | 180 | 180 | 123.00 |" in lines
    assert "| d | 3000 | 10 | – | – |" in table  # fewer than two generations: no rate
    assert (
        "n^2.00 (least squares on log-log, 3 instances with 2+ generations), "
        "as n^2.00 over the larger half (n ≥ 100)" in table
    )
    assert "memory above the loaded kernels as n^1.00 (3 instances 5 MB or more" in table
    assert table.rstrip().endswith("(scale.png)")


def test_the_plot_is_a_png(tmp_path):
    path = plot_scale(ROWS, tmp_path / "scale.png", "test")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_an_unknown_instance_is_named():
    assert scale_instances("eil51, kroA200") == ["eil51", "kroA200"]
    with pytest.raises(BenchError, match="no instance 'nope'"):
        scale_instances("eil51,nope")


def test_bad_scale_arguments_exit_2():
    assert main(["bench", "scale", "--instances", "nope"]) == EXIT_BAD_INPUT
    assert main(["bench", "scale", "-m", "0"]) == EXIT_BAD_INPUT
    with pytest.raises(SystemExit) as stop:  # refused as the arguments are parsed
        main(["bench", "scale", "--time-limit", "0"])
    assert stop.value.code == EXIT_BAD_INPUT
