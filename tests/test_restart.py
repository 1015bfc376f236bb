"""A dispatcher that restarts where it stopped.

Real processes on loopback: ``agrifleet serve`` keeping its state in a data directory and
simulated tractors (``python -m sim_vehicles``). The dispatcher is killed with SIGKILL in
the middle of a run and started again on the same data directory: it must not plan again,
must go on from what each vehicle reached, and the run's logs, reviewed as one, must show
every field done exactly once, no swath driven twice and reached items that never go back.

The tractors keep ArduPilot's ground-station failsafe on (``--gcs-failsafe``, HOLD when the
dispatcher's 1 Hz heartbeat stops), as docs/bridge.md asks of a real one, except where a
test wants one to go on driving while the dispatcher is down.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sqlite3
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh
from helpers.processes import Processes, free_port, status_reader, wait_for, wait_for_share
from helpers.review import assert_each_segment_worked_once

from dispatcher.daemon.store import DB_NAME
from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.recording.mcap_file import LOG_TOPIC, read_log, read_logs
from dispatcher.review.report import Review, review_contents, review_table

SCENARIO = Path(__file__).parent / "data" / "restart.toml"
FARM = "restart"
SPEEDUP = 20.0
FAILSAFE = ("--gcs-failsafe", f"{1.5 * SPEEDUP:g}")  # 1.5 wall seconds without the dispatcher
RUN_TIMEOUT_S = 150.0


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    group = Processes(tmp_path)
    yield group
    for p in group.procs:  # a test may leave one stopped (SIGSTOP)
        if p.poll() is None:
            os.kill(p.pid, signal.SIGCONT)
    group.stop_all()


def serve(procs: Processes, port: int, tmp_path: Path):  # type: ignore[no-untyped-def]
    return procs.serve(
        SCENARIO, port, tmp_path / "logs", "--data-dir", str(tmp_path / "data"), "--time-limit", "1"
    )


def killed(proc) -> None:  # type: ignore[no-untyped-def]
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)


def finished(proc, procs: Processes) -> int:  # type: ignore[no-untyped-def]
    wait_for(
        "the dispatcher to finish", lambda: proc.poll() is not None, RUN_TIMEOUT_S, procs.report
    )
    return int(proc.returncode)


def events(tmp_path: Path) -> list[tuple[str, str]]:
    """(vehicle, kind) of every stored event, in order."""
    with sqlite3.connect(tmp_path / "data" / DB_NAME) as db:
        return list(db.execute("SELECT vehicle, kind FROM events ORDER BY id"))


def review_run(tmp_path: Path) -> Review:
    log = read_logs([tmp_path / "logs"])
    assert log.note is None, log.note  # the restarted dispatcher's log is of the same run
    assert len(list((tmp_path / "logs").glob("*.mcap"))) > 1
    return review_contents(log)


def check_worked_once(review: Review, tight: set[str]) -> None:
    """Every field done exactly once, by its vehicle, each of its segments worked once
    (none twice, none never); the mission driven to its end, never more than 5 % beyond its
    length, and for the vehicles in ``tight`` (those whose whole track was recorded) not
    less than 3 % short of it. (A bound of 3 % beyond failed a clean-clone CI run once,
    at 3.04 %, a tractor stopped and started again across the restart; a swath here is
    about 5 % of a mission, and the segments say whether one was worked twice.)"""
    table = review_table(review)
    done = [f for v in review.vehicles for f in v.fields_done]
    assert sorted(done) == sorted(f.id for f in review.fields), table
    for f in review.fields:
        assert not f.worked_twice and not f.never_worked, table
    for v in review.vehicles:
        assert sorted(v.fields_done) == sorted(v.fields_planned), table
        assert v.mission_complete, table
        assert v.distance_m <= 1.05 * v.planned_distance_m, table
        if v.id in tight:
            assert v.distance_m >= 0.97 * v.planned_distance_m, table


def check_reached_never_back(tmp_path: Path) -> None:
    """No item is reached twice, across the restart or within a log (the radio may deliver
    two reports out of order, so the order of arrival is not checked)."""
    logs = sorted((tmp_path / "logs").glob("*.mcap"))
    assert len(logs) == 2, logs
    for vid in ("v1", "v2"):
        seqs = [
            r.decode_json()["seq"]
            for log in logs
            for r in read_log(log).on(f"{wire.PREFIX}/{FARM}/vehicle/{vid}/mavlink/from/json")
            if r.decode_json().get("mavpackettype") == "MISSION_ITEM_REACHED"
        ]
        assert seqs and len(seqs) == len(set(seqs)), (vid, seqs)


@contextlib.contextmanager
def watching(
    options: wire.ZenohOptions,
    vehicle: str,
    match: Callable[[mc.MAVLinkMessage], bool],
    then: Callable[[], None] = lambda: None,
) -> Iterator[threading.Event]:
    """Listen (a Zenoh session of ``options``) to what ``vehicle`` sends; the event is set
    once a frame ``match``es, and ``then`` runs at once, in the callback (before the next
    frame is handled)."""
    codec = mc.Codec(254, 190)
    seen = threading.Event()

    def on_frame(sample: zenoh.Sample) -> None:
        msg = codec.decode_one(sample.payload.to_bytes())
        if not seen.is_set() and msg is not None and match(msg):
            then()
            seen.set()

    with zenoh.open(options.config()) as session:
        sub = session.declare_subscriber(wire.vehicle_from(FARM, vehicle), on_frame)
        try:
            yield seen
        finally:
            sub.undeclare()


def log_lines(tmp_path: Path) -> list[str]:
    return [r.decode_json()["message"] for r in read_logs([tmp_path / "logs"]).on(LOG_TOPIC)]


def test_killed_at_40_percent_and_restarted_the_run_goes_on_where_it_stopped(
    procs: Processes, tmp_path: Path
) -> None:
    port = free_port()
    first = serve(procs, port, tmp_path)
    procs.sim(SCENARIO, port, SPEEDUP, "v1", "v2", extra=FAILSAFE)
    with status_reader(port, FARM) as status:
        seen: dict = {}

        def under_way() -> bool:
            seen.update(status().get("vehicles", {}))
            return min((v["share_done"] for v in seen.values()), default=0.0) >= 0.4

        wait_for("40 % of the work", under_way, RUN_TIMEOUT_S, procs.report)
    killed(first)
    before = events(tmp_path)
    assert ("v1", "mission_started") in before and ("v1", "item_reached") in before

    second = serve(procs, port, tmp_path)
    assert finished(second, procs) == 0, procs.report()
    out = Processes.output(second)
    assert "resuming run 1" in out and "plan " not in out.split("resuming run 1")[0], out
    review = review_run(tmp_path)
    check_worked_once(review, tight={"v1", "v2"})
    check_reached_never_back(tmp_path)
    lines = log_lines(tmp_path)
    assert sum("uploading" in ln for ln in lines) == 2, lines  # once each, before the kill
    with sqlite3.connect(tmp_path / "data" / DB_NAME) as db:
        assert db.execute("SELECT outcome FROM runs").fetchall() == [("done",)]

    # The run is over: the next serve plans a new one.
    third = serve(procs, port, tmp_path)
    wait_for("a new run", lambda: "run 2 kept in" in Processes.output(third), 60.0, procs.report)


def test_killed_during_an_upload_the_mission_is_uploaded_again(
    procs: Processes, tmp_path: Path
) -> None:
    port = free_port()
    first = serve(procs, port, tmp_path)
    # Freeze v1's tractor once it has asked for a few items: the upload is half done.
    started: list = []
    with watching(
        wire.client_options((f"tcp/127.0.0.1:{port}",)),
        "v1",
        lambda m: m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT") and m.seq >= 5,
        then=lambda: os.kill(started[0].pid, signal.SIGSTOP),
    ) as frozen:
        # Its radio answers 0 to 100 ms late, so that the upload lasts a few seconds.
        slow = (*FAILSAFE, "--delay", "100")
        started.append(v1 := procs.sim(SCENARIO, port, SPEEDUP, "v1", extra=slow))
        procs.sim(SCENARIO, port, SPEEDUP, "v2", extra=FAILSAFE)
        wait_for("v1 half-way through its upload", frozen.is_set, RUN_TIMEOUT_S, procs.report)
    killed(first)
    v1_events = [kind for vid, kind in events(tmp_path) if vid == "v1"]
    assert "upload_started" in v1_events and "upload_acked" not in v1_events, v1_events

    second = serve(procs, port, tmp_path)
    os.kill(v1.pid, signal.SIGCONT)
    assert finished(second, procs) == 0, procs.report()
    review = review_run(tmp_path)
    check_worked_once(review, tight={"v1", "v2"})
    check_reached_never_back(tmp_path)
    lines = log_lines(tmp_path)
    assert any("v1: holds" in ln and "uploading again" in ln for ln in lines), lines


def test_a_tractor_that_finished_while_the_dispatcher_was_down_is_not_started_again(
    procs: Processes, tmp_path: Path
) -> None:
    port = free_port()
    first = serve(procs, port, tmp_path)
    procs.sim(SCENARIO, port, SPEEDUP, "v1", extra=FAILSAFE)
    procs.sim(SCENARIO, port, SPEEDUP, "v2")  # drives on without the dispatcher
    with status_reader(port, FARM) as status:
        seen: dict = {}

        def v2_well_under_way() -> bool:
            seen.update(status().get("vehicles", {}))
            return seen.get("v2", {}).get("share_done", 0.0) >= 0.6

        wait_for("v2 at 60 %", v2_well_under_way, RUN_TIMEOUT_S, procs.report)
    killed(first)
    # Stand in for the dispatcher on its port (the tractors connect to it) and listen
    # until v2 says its mission is complete.
    with watching(
        wire.dispatcher_options((f"tcp/127.0.0.1:{port}",)),
        "v2",
        lambda m: (
            m.get_type() == "MISSION_CURRENT" and m.mission_state == mc.MISSION_STATE_COMPLETE
        ),
    ) as complete:
        wait_for("v2 to finish on its own", complete.is_set, RUN_TIMEOUT_S, procs.report)

    second = serve(procs, port, tmp_path)
    assert finished(second, procs) == 0, procs.report()
    review = review_run(tmp_path)
    # v2's end was driven with no one recording: review fills the gap with its mission.
    check_worked_once(review, tight={"v1", "v2"})
    check_reached_never_back(tmp_path)
    lines = log_lines(tmp_path)
    assert any("v2: finished its mission while the dispatcher was down" in ln for ln in lines)
    assert not any(ln.startswith("v2: uploading") for ln in lines[1:] if "again" in ln)


def test_restarted_and_then_a_tractor_dies_its_work_is_re_planned(
    procs: Processes, tmp_path: Path
) -> None:
    """A resumed run re-plans as a fresh one does: the fields' first layouts are laid out
    again from the stored plan, and every segment is still worked once."""
    port = free_port()
    first = serve(procs, port, tmp_path)
    procs.sim(SCENARIO, port, SPEEDUP, "v1", extra=FAILSAFE)
    v2 = procs.sim(SCENARIO, port, SPEEDUP, "v2", extra=FAILSAFE)
    with status_reader(port, FARM) as status:
        wait_for_share(status, ("v1", "v2"), 0.2, RUN_TIMEOUT_S, procs.report)
    killed(first)

    second = serve(procs, port, tmp_path)
    with status_reader(port, FARM) as status:
        wait_for_share(status, ("v2",), 0.4, RUN_TIMEOUT_S, procs.report)
    os.kill(v2.pid, signal.SIGKILL)
    assert finished(second, procs) == 0, procs.report()
    lines = log_lines(tmp_path)
    assert any("re-planning the rest of the work: v2 lost" in ln for ln in lines), lines
    review = review_run(tmp_path)
    table = review_table(review)
    assert all(f.done for f in review.fields), table
    assert_each_segment_worked_once(review)
