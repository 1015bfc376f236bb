"""A lossy radio: 30 % of the frames lost each way, 10 % duplicated, up to 200 ms late.

Real processes on loopback: ``agrifleet serve`` and simulated tractors whose radios are
impaired (``python -m sim_vehicles --loss --duplicate --delay``). Every mission must be
uploaded, read back, started and driven to the end; the review shows every field done once.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.processes import Processes, free_port, log_of, wait_for

from dispatcher.recording.mcap_file import LOG_TOPIC, read_logs
from dispatcher.review.report import review_contents, review_table

SCENARIO = Path(__file__).parent / "data" / "tiny.toml"
RADIO = ("--loss", "0.3", "--duplicate", "0.1", "--delay", "200")


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    group = Processes(tmp_path)
    yield group
    group.stop_all()


@pytest.mark.parametrize("seed", [1])
def test_a_run_through_a_lossy_radio_completes(procs: Processes, tmp_path: Path, seed: int):
    port = free_port()
    serve = procs.serve(SCENARIO, port, tmp_path / "logs", "--time-limit", "1")
    procs.sim(SCENARIO, port, 40, "v1", "v2", extra=(*RADIO, "--radio-seed", str(seed)))
    wait_for("the run to end", lambda: serve.poll() is not None, 240.0, procs.report)
    assert serve.returncode == 0, procs.report()
    log = read_logs([log_of(Processes.output(serve))])
    review = review_contents(log)
    table = review_table(review)
    done = sorted(f for v in review.vehicles for f in v.fields_done)
    assert done == sorted(f.id for f in review.fields), table
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert sum("read back, item by item ours" in ln for ln in lines) >= 2, lines
    sim_out = next(Processes.output(p) for p in procs.procs if "sim_vehicles" in p.args)
    assert "an impaired radio" in sim_out
