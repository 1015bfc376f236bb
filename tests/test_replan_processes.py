"""A tractor dies: the dispatcher plans the rest of the work over the others and the farm
is finished. Real processes on loopback (`agrifleet serve`, one simulator per tractor)."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.processes import (
    Processes,
    free_port,
    log_of,
    status_reader,
    wait_for,
    wait_for_share,
)
from helpers.review import assert_each_segment_worked_once

from dispatcher.recording.mcap_file import EVENTS_TOPIC, LOG_TOPIC, LogContents, read_logs
from dispatcher.review.report import review_contents, review_table

SCENARIO = Path(__file__).parent / "data" / "restart.toml"  # two tractors of one width


def scenario_with(tmp_path: Path, dispatcher: str) -> Path:
    """SCENARIO with ``dispatcher`` as its [dispatcher] table, in ``tmp_path``."""
    scenario = tmp_path / "scenario.toml"
    farm = SCENARIO.parent / "tiny-farm.geojson"
    scenario.write_text(
        SCENARIO.read_text().replace('farm = "tiny-farm.geojson"', f'farm = "{farm}"')
        + f"\n[dispatcher]\n{dispatcher}\n"
    )
    return scenario


def run_with_a_fault(
    procs: Processes, scenario: Path, tmp_path: Path, fault: signal.Signals
) -> LogContents:
    """Serve ``scenario`` with v1 and v2 simulated at 20x; once v2 has done 30 % of its work,
    send its simulator ``fault`` (SIGKILL: dead; SIGUSR1: stalled); the run's log once
    ``serve`` ended with exit 0."""
    port = free_port()
    serve = procs.serve(scenario, port, tmp_path / "logs", "--time-limit", "1")
    procs.sim(scenario, port, 20, "v1")
    v2 = procs.sim(scenario, port, 20, "v2")
    with status_reader(port, "restart") as status:
        wait_for_share(status, ("v2",), 0.3, 120.0, procs.report)
        os.kill(v2.pid, fault)
    wait_for("the run to end", lambda: serve.poll() is not None, 240.0, procs.report)
    assert serve.returncode == 0, procs.report()
    return read_logs([log_of(Processes.output(serve))])


def assert_left_out_planned_to_where_they_got(review) -> None:
    """A vehicle a re-plan left out is planned up to the item it reached: its planned hours
    near its mission's hours to there (formula 6 against the waypoints' legs), whatever
    plan gave it that mission (cut from a later re-plan's figures for the rest alone, v3
    showed 0.030 h planned for 0.042 h)."""
    for v in review.vehicles:
        if v.left_out and v.mission_time_h:
            assert v.planned_time_h == pytest.approx(v.mission_time_h, rel=0.2), review_table(
                review
            )


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    group = Processes(tmp_path)
    yield group
    group.stop_all()


def test_a_killed_tractors_work_is_done_by_the_other(procs: Processes, tmp_path: Path) -> None:
    log = run_with_a_fault(procs, SCENARIO, tmp_path, signal.SIGKILL)
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any("re-planning the rest of the work: v2 lost" in ln for ln in lines), lines
    assert any("the rest of the work over v1; v2 left out" in ln for ln in lines), lines
    review = review_contents(log)
    status_doc = log.on("agrifleet/restart/dispatcher/status")[-1].decode_json()
    assert {f["status"] for f in status_doc["fields"].values()} == {"done"}, status_doc
    table = review_table(review)
    assert all(f.done for f in review.fields), table
    assert_each_segment_worked_once(review)
    assert [x.vehicle for x in review.losses] == ["v2"], table
    assert review.losses[0].lat is not None, review.losses
    assert review.vehicle("v2").left_out and not review.vehicle("v1").left_out, table
    # what v2 still had to do went to v1, and the review says so
    taken = [(f, a, b) for rp in review.replans for f, a, b in rp.taken_over]
    assert taken and all((a, b) == ("v2", "v1") for _, a, b in taken), review.replans
    assert {f for f, _, _ in taken} <= set(review.vehicle("v1").fields_done), table
    # A field v2 began and v1 finished starts on v2's clock, from v2's set-off (from v1's,
    # the start was off by the two clocks' difference).
    v1r, v2r = review.vehicle("v1"), review.vehicle("v2")
    handed = [f for f in review.fields if f.started_by == "v2" and f.vehicle == "v1"]
    assert handed, table
    for f in handed:
        assert f.started_s == pytest.approx(f.started_clock_s - v2r.start_clock_s), table
        assert f.finished_s == pytest.approx(f.finished_clock_s - v1r.start_clock_s), table
        assert f.started_s <= v2r.last_report_h * 3600, table
        assert f"{f.id} " in table and "(begun by v2)" in table and "(handed over to v1)" in table
    # The plan's totals are the farm's once: v2's plan counts to where it got, the rest is
    # in v1's (before, v2's whole mission counted as well, its unfinished part twice).
    planned = sum(v.planned_distance_m for v in review.vehicles)
    driven = sum(v.distance_m for v in review.vehicles)
    assert planned == pytest.approx(driven, rel=0.05), table
    assert_left_out_planned_to_where_they_got(review)


def test_missions_in_windows_are_topped_up_and_a_killed_tractors_work_still_done(
    procs: Processes, tmp_path: Path
) -> None:
    # Windows of about 20 items (a field): each tractor gets its mission a field at a time.
    scenario = scenario_with(tmp_path, "window_items = 20")
    log = run_with_a_fault(procs, scenario, tmp_path, signal.SIGKILL)
    events = [r.decode_json() for r in log.on(EVENTS_TOPIC)]
    uploads = [e["items"] for e in events if e["kind"] == "upload_started" and e["vehicle"] == "v1"]
    plan = log.on("agrifleet/restart/dispatcher/plan")[0].decode_json()
    planned = len(next(m for m in plan["machines"] if m["id"] == "v1")["items"])
    assert uploads and uploads[0] < planned, uploads  # a window, not the whole mission
    topups = [e["items"] for e in events if e["kind"] == "window_extended" and e["vehicle"] == "v1"]
    assert topups, events
    review = review_contents(log)
    table = review_table(review)
    assert all(f.done for f in review.fields), table
    assert_each_segment_worked_once(review)
    assert [x.vehicle for x in review.losses] == ["v2"], table


def test_a_stalled_tractor_is_held_and_its_work_done_by_the_other(
    procs: Processes, tmp_path: Path
) -> None:
    scenario = scenario_with(tmp_path, "stall_after_s = 30")
    # SIGUSR1: it stops moving; its radio and autopilot go on
    log = run_with_a_fault(procs, scenario, tmp_path, signal.SIGUSR1)
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any(ln.startswith("v2: stalled") and "HOLD" in ln for ln in lines), lines
    assert any("re-planning the rest of the work: v2 lost (stalled" in ln for ln in lines), lines
    review = review_contents(log)
    assert all(f.done for f in review.fields), review_table(review)
    assert_each_segment_worked_once(review)
    assert [(x.vehicle, x.why.startswith("stalled")) for x in review.losses] == [("v2", True)]


def test_a_second_loss_while_re_planning_the_first_leaves_all_to_the_last(
    procs: Processes, tmp_path: Path
) -> None:
    scenario = SCENARIO.parent / "restart3.toml"
    port = free_port()
    serve = procs.serve(scenario, port, tmp_path / "logs", "--time-limit", "1")
    procs.sim(scenario, port, 20, "v1")
    v2 = procs.sim(scenario, port, 20, "v2")
    v3 = procs.sim(scenario, port, 20, "v3")
    with status_reader(port, "restart3") as status:
        wait_for_share(status, ("v2", "v3"), 0.3, 120.0, procs.report)
    os.kill(v2.pid, signal.SIGKILL)
    os.kill(v3.pid, signal.SIGKILL)  # the second loss comes while the first is re-planned
    wait_for("the run to end", lambda: serve.poll() is not None, 300.0, procs.report)
    assert serve.returncode == 0, procs.report()
    log = read_logs([log_of(Processes.output(serve))])
    review = review_contents(log)
    table = review_table(review)
    assert all(f.done for f in review.fields), table
    assert [v.id for v in review.vehicles if not v.left_out] == ["v1"], table
    # v1's mission went on through the re-plans: its planned turns are its mission's,
    # counted as the driven ones are (before: the re-plan's formula for the rest plus the
    # turns done by then, 15 planned for 22 driven).
    v1 = review.vehicle("v1")
    assert v1.mission_complete and v1.planned_turns == v1.turns, table
    assert_left_out_planned_to_where_they_got(review)
    assert_each_segment_worked_once(review)
    assert any("v3: lost; the rest of its work was re-planned" in w for w in review.warnings), table
