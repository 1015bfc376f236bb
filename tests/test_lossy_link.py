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
from helpers.review import assert_each_segment_worked_once, segments_worked_while_lost

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
    # v2's radio is the bad one (its mission is the shorter: the test stays short).
    procs.sim(SCENARIO, port, 40, "v1")
    procs.sim(SCENARIO, port, 40, "v2", extra=(*RADIO, "--radio-seed", str(seed)))
    wait_for("the run to end", lambda: serve.poll() is not None, 240.0, procs.report)
    assert serve.returncode == 0, procs.report()
    log = read_logs([log_of(Processes.output(serve))])
    review = review_contents(log)
    table = review_table(review)
    done = sorted(f for v in review.vehicles for f in v.fields_done)
    assert done == sorted(f.id for f in review.fields), table
    assert_each_segment_worked_once(review)
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert sum("read back, item by item ours" in ln for ln in lines) >= 2, lines
    assert any("an impaired radio" in Processes.output(p) for p in procs.procs)


def test_a_tractor_that_goes_quiet_is_re_planned_around_and_rejoins_when_it_is_back(
    procs: Processes, tmp_path: Path
) -> None:
    import os
    import signal

    from helpers.processes import status_reader, wait_for_share

    scenario = tmp_path / "quiet.toml"
    text = (Path(__file__).parent / "data" / "restart.toml").read_text()
    farm = Path(__file__).parent / "data" / "tiny-farm.geojson"
    scenario.write_text(
        text.replace('farm = "tiny-farm.geojson"', f'farm = "{farm}"')
        + "\n[dispatcher]\nlost_after_s = 2.0\n"
    )
    port = free_port()
    serve = procs.serve(scenario, port, tmp_path / "logs", "--time-limit", "1")
    v1 = procs.sim(scenario, port, 20, "v1")
    procs.sim(scenario, port, 20, "v2")
    with status_reader(port, "restart") as status:
        wait_for_share(status, ("v1",), 0.3, 120.0, procs.report)
        os.kill(v1.pid, signal.SIGSTOP)  # its radio goes quiet
        wait_for(
            "v1 lost",
            lambda: status().get("vehicles", {}).get("v1", {}).get("phase") == "lost",
            30.0,
            procs.report,
        )
        os.kill(v1.pid, signal.SIGCONT)
    wait_for("the run to end", lambda: serve.poll() is not None, 180.0, procs.report)
    assert serve.returncode == 0, procs.report()
    log = read_logs([log_of(Processes.output(serve))])
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any("v1: no message for 2 s" in ln for ln in lines), lines
    # Its work went to v2 at once; back, it was held and given work again by a re-plan.
    assert any("re-planning the rest of the work: v1 lost" in ln for ln in lines), lines
    assert any("re-planning the rest of the work: v1 back" in ln for ln in lines), lines
    review = review_contents(log)
    assert all(f.done for f in review.fields), review_table(review)
    # Every segment worked, and once but for what v1 worked while it could not be heard (it
    # kept driving; its re-planned work may have been worked by v2 meanwhile).
    quiet = segments_worked_while_lost(log, "v1", "restart")
    for f in review.fields:
        assert f.never_worked == (), review_table(review)
        assert {(f.id, s) for s in f.worked_twice} <= quiet, (f, quiet, review_table(review))


def test_a_tractor_deaf_to_the_dispatcher_is_re_planned_around_and_rejoins_once_it_hears(
    procs: Processes, tmp_path: Path
) -> None:
    """v1's uplink is dead for its first 750 simulated seconds (75 s at 10x): it is heard,
    but its mission upload goes unanswered, three times (~20 s each, failed at ~67 s), and
    its work goes to v2, done with its own by then (the run used to end there, v1's fields
    undone); v1 is told to HOLD now and then, and once it answers a re-plan is asked for
    to give it work again (on the tiny farm v2 holds what is left in the part of its
    mission it keeps). Every field is done, every segment once."""
    scenario = tmp_path / "deaf.toml"
    text = (Path(__file__).parent / "data" / "restart.toml").read_text()
    farm = Path(__file__).parent / "data" / "tiny-farm.geojson"
    scenario.write_text(text.replace('farm = "tiny-farm.geojson"', f'farm = "{farm}"'))
    port = free_port()
    serve = procs.serve(scenario, port, tmp_path / "logs", "--time-limit", "1")
    # Its deafness counts from its start: not before the dispatcher waits for it.
    wait_for(
        "the plan", lambda: "waiting for 2 vehicles" in Processes.output(serve), 120.0, procs.report
    )
    procs.sim(scenario, port, 10, "v1", extra=("--deaf-until", "v1:750"))
    procs.sim(scenario, port, 20, "v2")
    wait_for("the run to end", lambda: serve.poll() is not None, 240.0, procs.report)
    assert serve.returncode == 0, procs.report()
    log = read_logs([log_of(Processes.output(serve))])
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any("v1: upload failed after 3 attempts" in ln for ln in lines), lines
    assert any("re-planning the rest of the work: v1 could not be given its mission" in ln
               for ln in lines), lines  # fmt: skip
    assert any("v1: answers our commands again" in ln for ln in lines), lines
    assert any("re-planning the rest of the work: v1 back" in ln for ln in lines), lines
    review = review_contents(log)
    assert all(f.done for f in review.fields), review_table(review)
    assert_each_segment_worked_once(review)
