"""The dispatcher's SQLite store: a run kept, read back and replayed; bad databases refused."""

import sqlite3
from pathlib import Path

import pytest
from helpers.processes import free_port

from dispatcher.cli.main import main
from dispatcher.daemon import events as ev
from dispatcher.daemon.state import FleetState, Phase
from dispatcher.daemon.store import (
    DB_NAME,
    SCHEMA_VERSION,
    Store,
    StoreError,
    StoreWriteError,
    default_data_dir,
)
from dispatcher.mission.document import PlannedMachine
from dispatcher.mission.plan import DispatchPlan

DATA = Path(__file__).resolve().parents[1] / "data"


def run_events(vid: str, reached: int) -> list[ev.Event]:
    out: list[ev.Event] = [
        ev.VehicleSeen(vid),
        ev.UploadStarted(vid, 1),
        ev.UploadAcked(vid),
        ev.StartRequested(vid, 1),
        ev.MissionStarted(vid, 1),
    ]
    out += [ev.ItemReached(vid, seq, 10.0 * seq) for seq in range(1, reached + 1)]
    return out


def test_a_run_is_kept_and_read_back_as_it_was(dispatch: DispatchPlan, tmp_path: Path) -> None:
    job = dispatch.job()
    store = Store.open(tmp_path, "tiny")
    run_id = store.begin_run(job, "inputs-1")
    v1 = job.document.machines[0]
    events = run_events(v1.id, len(v1.items) - 1)  # v1 did all its work
    for k, event in enumerate(events):
        store.append(event, 1000.0 + k)
    store.commit()
    store.close()

    store = Store.open(tmp_path, "tiny")
    run = store.unfinished_run()
    assert run is not None and run.id == run_id and run.fingerprint == "inputs-1"
    assert run.job.document == job.document
    assert {vid: m.items for vid, m in run.job.missions.items()} == {
        vid: m.items for vid, m in job.missions.items()
    }
    assert run.job.missions[v1.id].traces == job.missions[v1.id].traces
    assert [e for _, e in run.events] == events
    state = run.replay()
    assert state.vehicles[v1.id].phase is Phase.DONE
    assert sorted(state.vehicles[v1.id].fields_done) == sorted(v1.fields)
    store.resume_run(run)
    store.end_run("done")
    assert store.unfinished_run() is None
    store.close()


def test_a_renumbered_vehicle_is_read_back_with_its_numbers(
    dispatch: DispatchPlan, tmp_path: Path
) -> None:
    """A vehicle renumbered under way (link/numbering.py): the dispatcher that resumes reads
    its reports in its new numbers (``mission_numbered`` was once left out of the events a
    store could read back, and a crash after a renumbering could not be resumed)."""
    job = dispatch.job()
    store = Store.open(tmp_path, "tiny")
    store.begin_run(job, "inputs-1")
    v1 = job.document.machines[0]
    events = [*run_events(v1.id, 35), ev.MissionNumbered(v1.id, 36, len(v1.items) - 35)]
    for k, event in enumerate(events):
        store.append(event, 1000.0 + k)
    store.commit()
    store.close()
    store = Store.open(tmp_path, "tiny")
    run = store.unfinished_run()
    store.close()
    assert run is not None and [e for _, e in run.events] == events
    numbering = run.replay().vehicles[v1.id].numbering
    assert (numbering.base, numbering.count) == (36, len(v1.items) - 35)
    assert numbering.to_vehicle(40) == 5


def test_a_run_keeps_when_it_began(dispatch: DispatchPlan, tmp_path: Path) -> None:
    """The start the daemon's re-planner counts a deadline from, given, or now."""
    store = Store.open(tmp_path, "tiny")
    store.begin_run(dispatch.job(), "x", started=1234.5)
    run = store.unfinished_run()
    assert run is not None and run.started == 1234.5
    store.end_run("done")
    store.begin_run(dispatch.job(), "y")
    run = store.unfinished_run()
    assert run is not None and run.started > 1234.5
    store.close()


def test_uncommitted_events_are_not_kept(dispatch: DispatchPlan, tmp_path: Path) -> None:
    store = Store.open(tmp_path, "tiny")
    store.begin_run(dispatch.job(), "x")
    store.append(ev.VehicleSeen("v1"), 1.0)
    store.commit()
    store.append(ev.VehicleLost("v1", "gone"), 2.0)  # the process dies before the commit
    store.close(commit=False)
    store = Store.open(tmp_path, "tiny")
    run = store.unfinished_run()
    store.close()
    assert run is not None and [e for _, e in run.events] == [ev.VehicleSeen("v1")]


def _v1_runs_its_mission(
    store: Store, dispatch: DispatchPlan, commit: bool = True
) -> tuple[PlannedMachine, FleetState]:
    """A run begun in ``store`` in which v1 drives its whole mission (committed with the
    state unless not ``commit``); v1 and the state."""
    job = dispatch.job()
    store.begin_run(job, "x")
    v1 = job.document.machines[0]
    state = store.unfinished_run().replay()  # type: ignore[union-attr]
    for event in run_events(v1.id, len(v1.items) - 1):
        state.apply(event, 0.0)
        store.append(event, 0.0)
    if commit:
        store.commit(state)
    return v1, state


def test_the_state_tables_follow_the_events(dispatch: DispatchPlan, tmp_path: Path) -> None:
    store = Store.open(tmp_path, "tiny", sync="normal")
    v1, _ = _v1_runs_its_mission(store, dispatch)
    rows = store.rows("SELECT vehicle, phase, reached FROM vehicles")
    assert rows == [(v1.id, "done", len(v1.items) - 1)]
    fields = dict(store.rows("SELECT field, status FROM fields"))
    assert fields == {fid: "done" for fid in v1.fields}
    assert store.rows("PRAGMA journal_mode") == [("wal",)]
    assert store.rows("PRAGMA synchronous") == [(1,)]  # NORMAL
    store.close()
    store = Store.open(tmp_path, "tiny")
    assert store.rows("PRAGMA synchronous") == [(2,)]  # FULL
    store.close()


def test_fresh_abandons_the_unfinished_run_and_keeps_it(
    dispatch: DispatchPlan, tmp_path: Path
) -> None:
    store = Store.open(tmp_path, "tiny")
    first = store.begin_run(dispatch.job(), "x")
    with pytest.raises(StoreError, match="unfinished"):
        store.begin_run(dispatch.job(), "x")
    assert store.abandon_unfinished() == first
    assert store.unfinished_run() is None
    second = store.begin_run(dispatch.job(), "y")
    assert store.rows("SELECT id, outcome FROM runs") == [(first, "abandoned"), (second, None)]
    store.close()


def test_a_database_of_another_farm_is_refused_with_both_names(tmp_path: Path) -> None:
    Store.open(tmp_path, "north").close()
    with pytest.raises(StoreError) as info:
        Store.open(tmp_path, "south")
    message = str(info.value)
    assert str(tmp_path / DB_NAME) in message and "'north'" in message and "'south'" in message


def test_foreign_and_newer_databases_are_refused(tmp_path: Path) -> None:
    other = tmp_path / "other"
    other.mkdir()
    with sqlite3.connect(other / DB_NAME) as db:
        db.execute("CREATE TABLE t(x)")
    with pytest.raises(StoreError, match="not an agrifleet database"):
        Store.open(other, "tiny")
    with sqlite3.connect(other / DB_NAME) as db:  # left as it was (not made WAL)
        assert db.execute("PRAGMA journal_mode").fetchone() == ("delete",)
    newer = tmp_path / "newer"
    Store.open(newer, "tiny").close()
    with sqlite3.connect(newer / DB_NAME) as db:
        db.execute("PRAGMA user_version = 99")
    with pytest.raises(StoreError, match="schema version 99"):
        Store.open(newer, "tiny")
    (tmp_path / "text").mkdir()
    (tmp_path / "text" / DB_NAME).write_text("not a database at all, but long enough " * 40)
    with pytest.raises(StoreError, match="not a database") as err:
        Store.open(tmp_path / "text", "tiny")
    assert "move it aside" in str(err.value) and "use another --data-dir" in str(err.value)
    half = tmp_path / "half"  # a database cut short (a disk full, a copy broken off)
    Store.open(half, "tiny").close()
    whole = (half / DB_NAME).read_bytes()
    (half / DB_NAME).write_bytes(whole[: len(whole) // 2])
    with pytest.raises(StoreError, match="not a database agrifleet can use .*move it aside"):
        Store.open(half, "tiny")
    assert (half / DB_NAME).read_bytes() == whole[: len(whole) // 2]  # left as it was
    with pytest.raises(StoreError, match="synchronous"):
        Store.open(tmp_path / "x", "tiny", sync="off")


def test_a_damaged_stored_run_names_the_run(dispatch: DispatchPlan, tmp_path: Path) -> None:
    store = Store.open(tmp_path, "tiny")
    run_id = store.begin_run(dispatch.job(), "x")
    store.conn.execute("UPDATE missions SET items = '[[1, 2]]' WHERE vehicle = 'v1'")
    with pytest.raises(StoreError, match=rf"run {run_id}: machine 'v1': 1 mission items"):
        store.unfinished_run()
    store.close()


def test_default_data_dir_is_under_the_user_state_dir(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", "/var/lib/somewhere")
    assert default_data_dir("farm1") == Path("/var/lib/somewhere/agrifleet/farm1")
    monkeypatch.delenv("XDG_STATE_HOME")
    assert default_data_dir("farm1") == Path.home() / ".local/state/agrifleet/farm1"


def test_serve_refuses_to_resume_a_run_of_other_inputs(
    dispatch: DispatchPlan, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    store = Store.open(tmp_path, "tiny")
    store.begin_run(dispatch.job(), "made-from-something-else")
    store.close()
    listen = f"tcp/127.0.0.1:{free_port()}"  # (not the scenario's 7447: a demo may be on it)
    args = ["serve", str(DATA / "tiny.toml"), "--data-dir", str(tmp_path), "--listen", listen]
    code = main([*args, "--unsigned"])
    assert code == 2
    err = capsys.readouterr().err
    assert "unfinished run 1" in err and "--fresh" in err and str(tmp_path / DB_NAME) in err


def test_a_second_dispatcher_on_the_same_data_directory_is_refused(tmp_path: Path) -> None:
    """Two dispatchers on one store would both command the fleet and both write its runs:
    the second is refused, naming the first's process; once that closed, it opens."""
    import os

    first = Store.open(tmp_path, "tiny")
    with pytest.raises(
        StoreError, match=rf"in use by another dispatcher \(process {os.getpid()}\)"
    ):
        Store.open(tmp_path, "tiny")
    first.close()
    Store.open(tmp_path, "tiny").close()


def test_a_database_of_schema_1_is_brought_to_2_keeping_its_run(
    dispatch: DispatchPlan, tmp_path: Path
) -> None:
    store = Store.open(tmp_path, "tiny")
    v1, _ = _v1_runs_its_mission(store, dispatch)
    store.close()
    with sqlite3.connect(tmp_path / DB_NAME) as db:  # as schema 1 had it
        db.execute("ALTER TABLE fields DROP COLUMN started_by")
        db.execute("PRAGMA user_version = 1")
    store = Store.open(tmp_path, "tiny")
    assert store.rows("PRAGMA user_version") == [(SCHEMA_VERSION,)] == [(2,)]
    run = store.unfinished_run()
    assert run is not None and len(run.events) == len(run_events(v1.id, len(v1.items) - 1))
    state = run.replay()
    store.resume_run(run)
    store.append(ev.VehicleSeen(v1.id), 1.0)
    store.commit(state)  # the fields' rows written again, with their starter
    rows = dict(store.rows("SELECT field, started_by FROM fields"))
    assert rows == {fid: v1.id for fid in v1.fields}
    store.close()


def test_a_re_plan_is_kept_whole_or_not_at_all(dispatch: DispatchPlan, tmp_path: Path) -> None:
    """The plan_replaced event and the new missions go in one commit: when the missions
    cannot be written, the event is not kept either (kept alone, the run could not be
    resumed: its missions were not the plan's)."""
    job = dispatch.job()
    store = Store.open(tmp_path, "tiny")
    store.begin_run(job, "x")
    store.conn.execute(
        "CREATE TRIGGER no_missions BEFORE INSERT ON missions "
        "BEGIN SELECT RAISE(ABORT, 'disk full'); END"
    )
    store.append(ev.PlanReplaced(ev.FLEET, "plan-2", "v2 lost", job.document.to_dict()), 1.0)
    with pytest.raises(StoreWriteError, match="cannot write the dispatcher's state .*disk full"):
        store.replace_missions(job)
    assert not store.pending
    assert store.rows("SELECT count(*) FROM events WHERE kind = 'plan_replaced'") == [(0,)]
    store.close()
    store = Store.open(tmp_path, "tiny")
    assert store.unfinished_run() is not None  # resumable, as before the re-plan
    store.close()


def test_the_state_rows_wait_for_a_commit_with_the_state(
    dispatch: DispatchPlan, tmp_path: Path
) -> None:
    # A commit without the state between (the signing mark's) left the rows unwritten.
    store = Store.open(tmp_path, "tiny")
    v1, state = _v1_runs_its_mission(store, dispatch, commit=False)
    store.keep_signing_timestamp(12345)
    store.commit(state)
    assert store.rows("SELECT vehicle, phase FROM vehicles") == [(v1.id, "done")]
    store.close()


def test_another_farms_database_of_schema_1_is_refused_not_upgraded(tmp_path: Path) -> None:
    north = tmp_path / "north"
    Store.open(north, "north").close()
    with sqlite3.connect(north / DB_NAME) as db:
        db.execute("ALTER TABLE fields DROP COLUMN started_by")
        db.execute("PRAGMA user_version = 1")
    with pytest.raises(StoreError, match="'north'"):
        Store.open(north, "south")
    with sqlite3.connect(north / DB_NAME) as db:
        assert db.execute("PRAGMA user_version").fetchone() == (1,)


def test_a_write_refused_says_where_and_what_to_do(dispatch: DispatchPlan, tmp_path: Path) -> None:
    store = Store.open(tmp_path, "tiny")
    store.begin_run(dispatch.job(), "x")
    store.conn.execute("PRAGMA query_only = ON")  # as a full disk or a read-only file
    with pytest.raises(StoreError) as info:
        store.append(ev.VehicleSeen("v1"), 1.0)
        store.commit()
    assert str(tmp_path / DB_NAME) in str(info.value) and "full or not writable" in str(info.value)
    assert not store.pending
    store.conn.execute("PRAGMA query_only = OFF")
    store.close()


def test_the_errors_name_the_option_that_chose_the_directory(tmp_path: Path) -> None:
    # The demo keeps its state under --log-dir: it has no --data-dir to give another of.
    first = Store.open(tmp_path, "tiny", option="--log-dir")
    with pytest.raises(StoreError, match="another --log-dir") as info:
        Store.open(tmp_path, "tiny", option="--log-dir")
    assert "--data-dir" not in str(info.value)
    first.close()
