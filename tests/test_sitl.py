"""The dispatcher and the bridge against the real autopilot: ArduPilot Rover in SITL.

Each test starts ``ardurover`` (see tests/helpers/sitl.py; skipped with the reason when
the binary is not there), ``agrifleet serve`` and ``agrifleet bridge`` on loopback, and
reads the run back from its MCAP log with ``agrifleet review``: every field done exactly
once, the driven track on the swaths, the implement never down outside a field.
"""

from __future__ import annotations

import contextlib
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.processes import planned_items
from helpers.review import assert_each_segment_worked_once
from helpers.sitl import (
    ARDUROVER,
    PARAMS,
    Processes,
    Sitl,
    free_port,
    log_of,
    needs_ardurover,
    status_reader,
    wait_for,
)

from dispatcher.daemon.plausibility import leg_end, leg_start, metres, off_leg_m
from dispatcher.link import mavlink as mc
from dispatcher.mission.build import IMPLEMENT_LOWERED, implement_set_before
from dispatcher.recording.mcap_file import EVENTS_TOPIC, LOG_TOPIC, read_log, read_logs
from dispatcher.review.report import Review, review_contents, review_log, review_table

pytestmark = needs_ardurover
SCENARIO = Path(__file__).parent / "data" / "sitl.toml"
SPEEDUP = 20.0
RUN_TIMEOUT_S = 240.0  # wall seconds for one job (about 400 s of vehicle time)


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    group = Processes(tmp_path)
    yield group
    group.stop_all()


@pytest.fixture
def sitl(tmp_path: Path) -> Iterator[Sitl]:
    assert ARDUROVER is not None
    autopilot = Sitl(ARDUROVER, tmp_path / "sitl", speedup=SPEEDUP)
    yield autopilot
    autopilot.stop()


def finished(proc, procs: Processes, sitl: Sitl, timeout_s: float = RUN_TIMEOUT_S) -> int:
    wait_for(
        "the dispatcher to finish",
        lambda: proc.poll() is not None,
        timeout_s,
        lambda: procs.report(sitl),
    )
    return int(proc.returncode)


def r1_under_way(procs: Processes, sitl: Sitl, serve, status, share: float, state: dict):  # type: ignore[no-untyped-def]
    """A check: whether r1 drives its mission with ``share`` of it done (the dispatcher's
    ``status``, kept in ``state``); fails at once if ``serve`` exits."""

    def under_way() -> bool:
        if serve.poll() is not None:
            raise AssertionError(f"serve exited early\n{procs.report(sitl)}")
        state.update(status().get("vehicles", {}).get("r1", {}))
        return state.get("phase") == "running" and state.get("share_done", 0) >= share

    return under_way


def serve_r1(  # type: ignore[no-untyped-def]
    procs: Processes, sitl: Sitl, tmp_path: Path, *serve_args: str, scenario: Path = SCENARIO
):
    """The autopilot started afresh, the dispatcher serving ``scenario`` on a free port
    (its logs in ``tmp_path``/logs, ``serve_args`` added) and r1's bridge: the port, the
    serve process and the bridge's."""
    port = free_port()
    sitl.start(wipe=True)
    serve = procs.serve(scenario, port, tmp_path / "logs", *serve_args)
    return port, serve, procs.bridge(scenario, "r1", sitl, port)


def wait_under_way(procs: Processes, sitl: Sitl, serve, port: int, share: float) -> None:  # type: ignore[no-untyped-def]
    """Until r1 drives its mission with ``share`` of it done (the dispatcher's status);
    fails at once if ``serve`` exits."""
    with status_reader(port, "sitl") as status:
        under_way = r1_under_way(procs, sitl, serve, status, share, {})
        wait_for(
            f"{share:.0%} of the mission", under_way, RUN_TIMEOUT_S, lambda: procs.report(sitl)
        )


def caught_up(status_check) -> None:  # type: ignore[no-untyped-def]
    """Two status periods after the autopilot froze, the dispatcher's status read again
    (``status_check``, an ``r1_under_way``): it has heard all the autopilot said."""
    time_mark = time.monotonic()
    wait_for("two status periods", lambda: time.monotonic() - time_mark > 2.5, 5.0)
    status_check()


def check_worked_once(review: Review, driven_as_planned: bool = True) -> None:
    """Every field done, each exactly once, the implement never down outside a field; with
    ``driven_as_planned``, on swaths driven as planned and turns without a loop."""
    (vehicle,) = review.vehicles
    assert sorted(vehicle.fields_done) == sorted(vehicle.fields_planned), review_table(review)
    assert len(set(vehicle.fields_done)) == len(vehicle.fields_done)
    assert vehicle.mission_complete
    q = vehicle.quality
    assert q is not None and q.swath_median_m is not None, review_table(review)
    assert q.outside_down_s == 0.0, review_table(review)
    if not driven_as_planned:
        return
    assert q.swath_median_m < 0.3, review_table(review)
    assert q.swath_p95_m is not None and q.swath_p95_m < 1.0, review_table(review)
    assert q.loops == 0, review_table(review)


def test_a_run_started_while_the_autopilot_boots_then_a_second_job_without_a_reboot(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    port = free_port()
    # The dispatcher and the bridge first: the autopilot's first heartbeats say it is
    # still initialising, and a mission sent then is refused (MAV_MISSION_NO_SPACE).
    serve = procs.serve(SCENARIO, port, tmp_path / "logs1")
    bridge = procs.bridge(SCENARIO, "r1", sitl, port)
    sitl.start(wipe=True)
    assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    first = review_log(log_of(Processes.output(serve)))
    check_worked_once(first)
    (v,) = first.vehicles
    assert v.upload_attempts == 1 and not v.reboots, review_table(first)

    # A second job on the same autopilot: it finished the first one in AUTO and was parked.
    bridge.terminate()
    bridge.wait(15)
    serve = procs.serve(SCENARIO, port, tmp_path / "logs2")
    procs.bridge(SCENARIO, "r1", sitl, port)
    assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    second = review_log(log_of(Processes.output(serve)))
    check_worked_once(second)
    assert sitl.starts == 1 and not second.vehicles[0].reboots
    assert not any("Internal Error" in t for t in second.vehicles[0].autopilot_problems)


def test_an_autopilot_reboot_mid_mission_is_armed_again_and_resumed(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    with r1_job(procs, sitl, tmp_path, 0.4) as (serve, state, well_under_way, _):
        # A power cut: the autopilot stops, and restarts on its eeprom where the tractor
        # stands (SITL would put it back in the garage): read where that is once the
        # dispatcher has heard its last position.
        sitl.freeze()
        wait_for("the status to catch up", lambda: well_under_way() and "lat" in state, 10.0)
        caught_up(well_under_way)
        reached = state["reached"]
        sitl.kill()
        sitl.start(home=(state["lat"], state["lon"]), heading=state.get("heading_deg") or 0)
        assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    path = log_of(Processes.output(serve))
    review = review_log(path)
    check_worked_once(review)
    (v,) = review.vehicles
    assert len(v.reboots) == 1, review_table(review)  # one event, not "time went back"
    # Nothing driven twice. ArduPilot drives about 10 % more than the mission's legs even
    # without a reboot (it weaves through the turns' arc points, docs/coverage.md), so this
    # only catches a swath or a field driven again.
    assert v.distance_m < v.planned_distance_m * 1.2, review_table(review)
    log = read_log(path)
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    resumed = [ln for ln in lines if "rebooted; resuming at item" in ln]
    assert resumed, lines
    resume_item = int(resumed[0].rsplit(" ", 1)[1])
    assert resume_item > reached
    seqs = [
        r.decode_json()["seq"]
        for r in log.on("agrifleet/sitl/vehicle/r1/mavlink/from/json")
        if r.decode_json().get("mavpackettype") == "MISSION_ITEM_REACHED"
    ]
    assert seqs == sorted(seqs), seqs  # progress never goes back
    # Resumed in a field, its implement set as the mission has it there before it arms
    # (the item that lowered it is behind, and the rebooted outputs are at their boot
    # values), and ArduPilot takes that command as it takes the mission's own.
    to = [r.decode_json() for r in log.on("agrifleet/sitl/vehicle/r1/mavlink/to/json")]
    answers = [r.decode_json() for r in log.on("agrifleet/sitl/vehicle/r1/mavlink/from/json")]
    uploaded = {m["seq"]: m for m in to if m.get("mavpackettype") == "MISSION_ITEM_INT"}
    implement = (mc.MAV_CMD_DO_SET_SERVO, mc.MAV_CMD_DO_SET_RELAY)
    setting = next(
        uploaded[k] for k in range(resume_item - 1, 0, -1) if uploaded[k]["command"] in implement
    )
    sent = [
        m
        for m in to
        if m.get("mavpackettype") == "COMMAND_LONG" and m["command"] == setting["command"]
    ]
    assert sent, f"no {setting['command']} sent at the resume"
    assert (sent[-1]["param1"], sent[-1]["param2"]) == (setting["param1"], setting["param2"])
    acks = [
        m["result"]
        for m in answers
        if m.get("mavpackettype") == "COMMAND_ACK" and m["command"] == setting["command"]
    ]
    assert acks and set(acks) == {mc.MAV_RESULT_ACCEPTED}, acks


def swaths_lowered_at_their_start(  # type: ignore[no-untyped-def]
    items, lowered_before: bool = False
) -> dict[int, tuple[int, int]]:
    """For each item after which the mission drives a swath whose lowering comes after the
    swath's start (a field's first, one after a turn; ``lowered_before``: before it, the
    lines of a field one after another with the implement down), the swath's start and
    end, when that swath is well away from the garage."""
    garage = (items[0].lat, items[0].lon)
    out = {}
    for reached in range(1, len(items) - 1):
        start, end = leg_start(items, reached + 1), leg_end(items, reached + 1)
        if start is None or end is None or items[end].role != "swath_end":
            continue
        k = implement_set_before(items, end)
        far = off_leg_m(items, reached + 1, garage)
        if k is None or items[k].role not in IMPLEMENT_LOWERED or far <= 50.0:
            continue
        if (k < start) == lowered_before:
            out[reached] = (start, end)
    return out


@contextlib.contextmanager
def r1_job(procs: Processes, sitl: Sitl, tmp_path: Path, share: float = 0.0):  # type: ignore[no-untyped-def]
    """r1's job under way, ``share`` of it done: the serve process, r1's status as last
    read, the check that reads it (:func:`r1_under_way`) and r1's mission items."""
    port, serve, _ = serve_r1(procs, sitl, tmp_path)
    with status_reader(port, "sitl") as status:
        state: dict = {}
        under_way = r1_under_way(procs, sitl, serve, status, share, state)
        wait_for(
            f"{share:.0%} of the mission",
            under_way,
            RUN_TIMEOUT_S,
            lambda: f"last status of r1: {state}\n{procs.report(sitl)}",
        )
        yield serve, state, under_way, planned_items(port, "sitl", "r1")


def back_in_the_garage(sitl: Sitl, under_way, state: dict) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    """A power cut (the autopilot frozen, then killed), the item r1 reached last once the
    status has caught up (``under_way`` fills ``state``), and the autopilot started again
    in the garage at the tests' speedup: that item, and when (wall ns) it restarted."""
    sitl.freeze()
    caught_up(under_way)
    reached = int(state["reached"])
    sitl.kill()
    sitl.speedup = SPEEDUP
    restarted_ns = time.time_ns()
    sitl.start()  # SITL's home: the garage
    return reached, restarted_ns


def test_an_autopilot_back_in_the_garage_from_a_swath_works_it_from_its_start(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    """A power cut along a swath, the autopilot back in the garage (SITL restarts at its
    home; a tractor towed home). Sent on to the swath's end with the implement up, it
    would leave the swath unworked: it starts where the swath starts, the implement up, and
    ArduPilot drives there, runs the mission's own lowering and works the swath."""
    sitl.speedup = 2.0  # slow until the cut: a swath in seconds of wall time, to stop it on
    with r1_job(procs, sitl, tmp_path) as (serve, state, under_way, items):
        swaths = swaths_lowered_at_their_start(items)
        assert swaths, [it.role for it in items]
        on: list[tuple[int, int]] = []

        def early_on_a_swath() -> bool:
            if not under_way() or state.get("reached") not in swaths or state.get("lat") is None:
                return False
            here = (state["lat"], state["lon"])
            start, end = swaths[state["reached"]]
            far = metres(here, (items[end].lat, items[end].lon))
            past = metres(here, (items[start].lat, items[start].lon))
            on[:] = [(start, end)]
            return past > 2.0 and far > 12.0

        wait_for(
            "r1 early on a swath",
            early_on_a_swath,
            # At 2x, the swaths it may be cut on can come late in its mission: the cut came
            # 172 s of wall time after the dispatcher started (2026-11-29, make test).
            1.5 * RUN_TIMEOUT_S,
            lambda: f"last status of r1: {state}\n{procs.report(sitl)}",
        )
        reached, restarted_ns = back_in_the_garage(sitl, under_way, state)
        assert swaths.get(reached) == on[0], (state, on)  # cut on that swath
        assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    path = log_of(Processes.output(serve))
    review = review_log(path)
    check_worked_once(review, driven_as_planned=False)
    start, end = on[0]
    log = read_log(path)
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any(f"from item {start}, where the leg starts" in ln for ln in lines), lines
    after = [
        r.decode_json()["seq"]
        for r in log.on("agrifleet/sitl/vehicle/r1/mavlink/from/json")
        if r.decode_json().get("mavpackettype") == "MISSION_ITEM_REACHED"
        and r.log_time_ns >= restarted_ns
    ]
    # Back at the swath's start after the reboot (ArduPilot reports the DO_CHANGE_SPEED
    # after it reached, not the waypoint), then along the swath to its end.
    assert after and start <= after[0] < end and end in after, (start, end, after)


def test_an_autopilot_back_in_the_garage_from_a_line_is_lowered_where_the_line_starts(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    """The same on a field's lines worked one after another with the implement down,
    lowered once before the first: the mission does not lower it again, so the dispatcher
    starts it where the line starts, the implement up, and lowers it by a command once it
    is past that item; ArduPilot takes the command in AUTO."""
    with r1_job(procs, sitl, tmp_path) as (serve, state, under_way, items):
        lines = swaths_lowered_at_their_start(items, lowered_before=True)
        # Well inside a run of such lines: still in it once the status has caught up (a
        # status period, ~40 m of the rover's at this speedup, is a few items of a ring;
        # rings with corners of 30 degree steps have runs of 11 on this farm).
        inside = {r for r in lines if all(r + d in lines for d in range(8))}
        assert inside, [it.role for it in items]
        on_a_line = lambda: under_way() and state.get("reached") in inside  # noqa: E731
        wait_for(
            "r1 on a field's lines",
            on_a_line,
            RUN_TIMEOUT_S,
            lambda: f"last status of r1: {state}\n{procs.report(sitl)}",
        )
        reached, restarted_ns = back_in_the_garage(sitl, under_way, state)
        assert reached in lines, state
        assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    path = log_of(Processes.output(serve))
    review = review_log(path)
    check_worked_once(review, driven_as_planned=False)
    start, _ = lines[reached]
    log = read_log(path)
    messages = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any(f"from item {start}, where the leg starts" in m for m in messages), messages
    assert any(f"past item {start}, where its leg starts" in m for m in messages), messages
    lowering = items[implement_set_before(items, start + 1) or 0]
    to = [
        r.decode_json()
        for r in log.on("agrifleet/sitl/vehicle/r1/mavlink/to/json")
        if r.log_time_ns >= restarted_ns
    ]
    sent = [
        m
        for m in to
        if m.get("mavpackettype") == "COMMAND_LONG"
        and m["command"] == lowering.command
        and m["param2"] == lowering.param2
    ]
    assert sent, "no lowering sent"
    acks = [
        r.decode_json()["result"]
        for r in log.on("agrifleet/sitl/vehicle/r1/mavlink/from/json")
        if r.log_time_ns >= restarted_ns
        and r.decode_json().get("mavpackettype") == "COMMAND_ACK"
        and r.decode_json()["command"] == lowering.command
    ]
    assert acks and set(acks) == {mc.MAV_RESULT_ACCEPTED}, acks


def test_an_arm_refusal_says_why_in_the_status_the_log_and_the_review(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    sitl.params = {**sitl.params, "BATT_ARM_VOLT": 50.0}  # SITL's battery has 12.6 V
    port, serve, _ = serve_r1(procs, sitl, tmp_path)
    with status_reader(port, "sitl") as status:
        seen: dict = {}

        def refused_with_a_reason() -> bool:
            seen.update(status().get("vehicles", {}).get("r1", {}))
            return "ARM_DISARM refused" in seen.get("error", "") and "(autopilot:" in seen["error"]

        wait_for(
            "the refusal and its reason",
            refused_with_a_reason,
            60.0,
            lambda: f"last status of r1: {seen}\n{procs.report(sitl)}",
        )
    reason = seen["error"].split("(autopilot: ", 1)[1]
    assert "Battery" in reason or "battery" in reason, seen
    sitl.set_param("BATT_ARM_VOLT", 0.0)  # the operator fixes it; the dispatcher asks again
    assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    path = log_of(Processes.output(serve))
    lines = [r.decode_json()["message"] for r in read_log(path).on(LOG_TOPIC)]
    assert any("refused" in ln and "Battery" in ln for ln in lines), lines
    review = review_log(path)
    check_worked_once(review)
    assert any("Battery" in w for w in review.warnings), review_table(review)


def test_a_rover_held_by_its_ground_station_failsafe_goes_on_once_it_hears_the_dispatcher(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    # The radio gone (the bridge stopped) for longer than FS_GCS_TIMEOUT, not long enough for
    # the dispatcher to take the rover for lost: ArduPilot holds, says so ("... Failsafe"),
    # and stays in HOLD when our heartbeats reach it again ("GCS Failsafe Cleared").
    sitl.params = {**sitl.params, "FS_GCS_TIMEOUT": 1.5 * SPEEDUP}  # 1.5 wall seconds
    port, serve, bridge = serve_r1(procs, sitl, tmp_path)
    wait_under_way(procs, sitl, serve, port, 0.3)
    bridge.send_signal(signal.SIGSTOP)
    try:
        gone = time.monotonic()  # the outage: 3.5 s, the dispatcher's limit is 5 s
        wait_for("the radio to be gone 3.5 s", lambda: time.monotonic() - gone > 3.5, 5.0)
    finally:
        bridge.send_signal(signal.SIGCONT)
    assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    path = log_of(Processes.output(serve))
    lines = [r.decode_json()["message"] for r in read_log(path).on(LOG_TOPIC)]
    assert any("its failsafe held it" in ln and "going on at item" in ln for ln in lines), lines
    # (The bridge's Zenoh liveliness token may lapse while it is stopped, under load: the
    # rover is then also taken for lost and back, which is not what this test is about.)
    review = review_log(path)
    check_worked_once(review)
    (v,) = review.vehicles
    assert any("Failsafe" in t for t in v.autopilot_problems), review_table(review)


def test_a_dispatcher_killed_mid_mission_finds_the_rover_on_its_mission_and_keeps_it(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    data = ("--data-dir", str(tmp_path / "data"))
    port, first, _ = serve_r1(procs, sitl, tmp_path, *data)
    wait_under_way(procs, sitl, first, port, 0.4)
    first.kill()
    first.wait(10)
    second = procs.serve(SCENARIO, port, tmp_path / "logs", *data)
    assert finished(second, procs, sitl) == 0, procs.report(sitl)
    out = Processes.output(second)
    # ArduPilot's mission read back is ours item by item: the rover is not stopped, and
    # nothing is uploaded again.
    assert "reading them back" in out and "uploading" not in out, out
    assert "still driving its mission" in out or "going on at item" in out, out
    review = review_contents(read_logs([tmp_path / "logs"]))
    check_worked_once(review)
    (v,) = review.vehicles
    assert v.distance_m < v.planned_distance_m * 1.2, review_table(review)


def test_a_mission_in_windows_is_topped_up_under_the_driving_rover(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    # Windows of a field: ArduPilot holds the first field's items, then is given the
    # rest (the longer prefix uploaded while it drives, the new items read back; or, far
    # enough in and far enough from the item it drives to, only the items from where it
    # is: dispatcher/link/numbering.py).
    scenario = tmp_path / "windows.toml"
    farm = SCENARIO.parent / "sitl-farm.geojson"
    scenario.write_text(
        SCENARIO.read_text().replace('farm = "sitl-farm.geojson"', f'farm = "{farm}"')
        + "\n[dispatcher]\nwindow_items = 10\ntopup_lead_s = 2.0\n"
    )
    _, serve, _ = serve_r1(procs, sitl, tmp_path, scenario=scenario)
    assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    log = read_log(log_of(Processes.output(serve)))
    events = [r.decode_json() for r in log.on(EVENTS_TOPIC)]
    plan = log.on("agrifleet/sitl/dispatcher/plan")[0].decode_json()
    planned = len(plan["machines"][0]["items"])
    first = [e["items"] for e in events if e["kind"] == "upload_started"]
    topups = [e["items"] for e in events if e["kind"] == "window_extended"]
    assert first and first[0] < planned and topups and topups[-1] == planned, events
    review = review_contents(log)
    # Not how it drove: ArduPilot restarts the command it drives when an upload changes the
    # commands its mission change detector looks ahead at ("Auto mission changed,
    # restarted command"), and a rover whose next window comes late slows to a stop at the
    # end of the one it holds and sets off again: 0.33 m swath median, 2.1 m p95, a turn
    # with a loop, each in some runs (benchmarks/RESULTS.md, issue 10). Every field once,
    # in windows, is what this test is for; the other SITL tests check the driving.
    check_worked_once(review, driven_as_planned=False)
    assert not review.vehicles[0].reboots


def test_a_lost_rovers_work_goes_to_the_other_while_it_drives(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    # Two rovers; r2's autopilot dies mid-mission (kill -9). r1 is re-planned while it
    # drives: it keeps the window it holds, its new route (r2's rest) goes on board under
    # it, and it finishes both rovers' work, every segment once.
    scenario = tmp_path / "two.toml"
    farm = Path(__file__).parents[1] / "benchmarks" / "sitl-farm4.geojson"
    text = SCENARIO.read_text().replace('farm = "sitl-farm.geojson"', f'farm = "{farm}"')
    machine = text[text.index("[[machine]]") : text.index("[solver]")]
    second = machine.replace('id = "r1"', 'id = "r2"').replace("system_id = 1", "system_id = 2")
    scenario.write_text(text.replace("[solver]", second + "[solver]"))
    assert ARDUROVER is not None
    sitl.start(wipe=True)  # before the second picks its instance number (ports) free now
    other = Sitl(ARDUROVER, tmp_path / "sitl2", speedup=SPEEDUP, params={**PARAMS, "MAV_SYSID": 2})
    try:
        port = free_port()
        other.start(wipe=True)
        serve = procs.serve(scenario, port, tmp_path / "logs")
        procs.bridge(scenario, "r1", sitl, port)
        procs.bridge(scenario, "r2", other, port)
        with status_reader(port, "sitl") as status:

            def both_under_way() -> bool:
                if serve.poll() is not None:
                    raise AssertionError(f"serve exited early\n{procs.report(sitl)}")
                vehicles = status().get("vehicles", {})
                r1, r2 = vehicles.get("r1", {}), vehicles.get("r2", {})
                return r1.get("reached", 0) >= 40 and r2.get("phase") == "running"

            wait_for("r1 at item 40", both_under_way, RUN_TIMEOUT_S, lambda: procs.report(sitl))
        other.kill()
        assert finished(serve, procs, sitl) == 0, procs.report(sitl)
    finally:
        other.stop()
    log = read_log(log_of(Processes.output(serve)))
    lines = [r.decode_json()["message"] for r in log.on(LOG_TOPIC)]
    assert any("re-planning the rest of the work: r2 lost" in ln for ln in lines), lines
    review = review_contents(log)
    table = review_table(review)
    assert all(f.done for f in review.fields), table
    assert_each_segment_worked_once(review)
    assert [x.vehicle for x in review.losses] == ["r2"], table
    assert review.vehicle("r1").mission_complete, table
    taken = [(a, b) for rp in review.replans for _, a, b in rp.taken_over]
    assert taken and set(taken) == {("r2", "r1")}, review.replans


def test_an_autopilot_given_the_key_signs_and_takes_nothing_unsigned_on_its_other_ports(
    procs: Processes, sitl: Sitl, tmp_path: Path
) -> None:
    """`bridge --setup-signing` on the autopilot's USB port (SERIAL0): ArduPilot stores
    the key and signs from then on, the bridge sees it and takes only signed frames, the
    dispatcher drives it; on SERIAL1 a ground station's unsigned PARAM_SET is refused and
    one signed with the key is taken (no test ran the real autopilot's signing: review)."""
    from dispatcher.link.keys import read_key

    port = free_port()
    sitl.start(wipe=True)
    serve = procs.serve(SCENARIO, port, tmp_path / "logs")
    bridge = procs.bridge(SCENARIO, "r1", sitl, port, "--setup-signing")
    report = lambda: procs.report(sitl)  # noqa: E731
    signs = "the autopilot signs: its link takes only signed frames now"
    wait_for("the autopilot to sign", lambda: signs in Processes.output(bridge), 60.0, report)
    wait_under_way(procs, sitl, serve, port, 0.05)
    with pytest.raises(AssertionError, match="did not confirm"):
        sitl.set_param("BATT_ARM_VOLT", 0.5, timeout_s=5.0)  # unsigned: refused
    sitl.set_param("BATT_ARM_VOLT", 0.5, key=read_key(procs.keys(SCENARIO), "r1"))
    assert "signed with a key other than" not in Processes.output(bridge), report()
