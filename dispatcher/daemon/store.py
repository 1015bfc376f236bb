"""The dispatcher's memory across restarts: one SQLite database in its data directory.

It holds every run the dispatcher made on this farm: the job it dispatched (plan document,
missions as uploaded, GeoJSON), every event of :mod:`dispatcher.daemon.events` in the order
applied, and the current state of each vehicle and field (for a reader with ``sqlite3``; a
restart rebuilds the state by replaying the events through the same
:meth:`FleetState.apply <dispatcher.daemon.state.FleetState.apply>`). A run stays
*unfinished* until every field is done; ``agrifleet serve`` on a data directory with an
unfinished run resumes it instead of planning again (``--fresh`` abandons it, kept in the
database as such).

Durability. The database is in WAL mode. The daemon commits the events before it sends any
command that depends on them, and at the end of each turn of its loop. ``synchronous=FULL``
(the default) makes a commit survive a power cut, at the price of an fsync per commit (tens
a second with a busy fleet; ``make bench BENCH_ARGS=store`` measures one).
``normal`` skips that fsync: a commit still survives a crash of the dispatcher (the WAL is
written before the commit returns), but a power cut may lose the last commits. That is safe
for what we keep, because the vehicles are the other half of the truth: a restarted
dispatcher asks each vehicle which item it is on and catches up with what it missed. Pick it
for a gateway whose storage makes fsync slow (SD cards).

Schema (``PRAGMA user_version`` = :data:`SCHEMA_VERSION`, ``application_id`` =
:data:`APPLICATION_ID`)::

    meta(key, value)                 farm_id, created
    runs(id, plan_id, farm_id, fingerprint, started, ended, outcome,
         document, geojson)          outcome NULL while unfinished; the first plan's
                                     document, the last plan's GeoJSON
    missions(run, vehicle, items)    items: JSON arrays (dispatcher.mission.job), as last
                                     uploaded (a re-plan's document: its plan_replaced event)

One dispatcher a data directory: :meth:`Store.open` locks ``agrifleet.lock`` there.
    events(id, run, wall, vehicle, kind, body)
    vehicles(run, vehicle, phase, reached, items, reboots, error, updated)
    fields(run, field, vehicle, status, started_s, finished_s, swaths_done,
           started_by)       started_s on started_by's clock, finished_s on vehicle's

A database of schema 1 (no ``fields.started_by``) is brought to 2 when opened.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from dispatcher.config.errors import DispatcherError
from dispatcher.daemon import events as ev
from dispatcher.daemon.state import FleetState
from dispatcher.mission.document import PlanDocument, PlanDocumentError
from dispatcher.mission.job import DispatchJob

SCHEMA_VERSION = 2
APPLICATION_ID = 0x41475246  # "AGRF"
DB_NAME = "agrifleet.sqlite3"
LOCK_NAME = "agrifleet.lock"  # held by the dispatcher that has the database open
SYNC_MODES = ("full", "normal")

_SCHEMA = """
CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE runs(
    id INTEGER PRIMARY KEY,
    plan_id TEXT NOT NULL,
    farm_id TEXT NOT NULL,
    fingerprint TEXT NOT NULL,
    started REAL NOT NULL,
    ended REAL,
    outcome TEXT,
    document TEXT NOT NULL,
    geojson TEXT NOT NULL
);
CREATE TABLE missions(
    run INTEGER NOT NULL REFERENCES runs(id),
    vehicle TEXT NOT NULL,
    items TEXT NOT NULL,
    PRIMARY KEY(run, vehicle)
);
CREATE TABLE events(
    id INTEGER PRIMARY KEY,
    run INTEGER NOT NULL REFERENCES runs(id),
    wall REAL NOT NULL,
    vehicle TEXT NOT NULL,
    kind TEXT NOT NULL,
    body TEXT NOT NULL
);
CREATE INDEX events_by_run ON events(run, id);
CREATE TABLE vehicles(
    run INTEGER NOT NULL REFERENCES runs(id),
    vehicle TEXT NOT NULL,
    phase TEXT NOT NULL,
    reached INTEGER NOT NULL,
    items INTEGER NOT NULL,
    reboots INTEGER NOT NULL,
    error TEXT NOT NULL,
    updated REAL NOT NULL,
    PRIMARY KEY(run, vehicle)
);
CREATE TABLE fields(
    run INTEGER NOT NULL REFERENCES runs(id),
    field TEXT NOT NULL,
    vehicle TEXT NOT NULL,
    status TEXT NOT NULL,
    started_s REAL,
    finished_s REAL,
    swaths_done INTEGER NOT NULL,
    started_by TEXT,
    PRIMARY KEY(run, field)
);
"""


class StoreError(DispatcherError):
    """The data directory's database cannot be used for this farm or run; the message says
    which file and why, and what to do."""


class StoreWriteError(StoreError):
    """A write the database refused while a run goes on (a full disk, a file made
    read-only): not bad input; what was kept before it is intact, to resume from."""


def _quote(text: str) -> str:
    """An SQL string literal."""
    return "'" + text.replace("'", "''") + "'"


def default_data_dir(farm_id: str) -> Path:
    """``$XDG_STATE_HOME/agrifleet/FARM`` (``~/.local/state/agrifleet/FARM`` without it)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "agrifleet" / farm_id


@dataclass(frozen=True)
class StoredRun:
    """An unfinished run read back: its job (after a re-plan, the last plan's document
    and missions), its first plan's document, and its events ``(wall time, event)``."""

    id: int
    job: DispatchJob
    fingerprint: str
    started: float
    events: tuple[tuple[float, ev.Event], ...]
    first_document: PlanDocument

    @property
    def documents(self) -> tuple[PlanDocument, ...]:
        """Its plans' documents in order: the first, then each re-plan's."""
        replaced = (
            PlanDocument.from_json(e.document)
            for _, e in self.events
            if isinstance(e, ev.PlanReplaced)
        )
        return (self.first_document, *replaced)

    def replay(self) -> FleetState:
        """The fleet's state as the events left it (time: each event's wall time), from
        the run's first plan on (its re-plans are among the events)."""
        state = FleetState(self.first_document)
        for wall, event in self.events:
            state.apply(event, wall)
        return state


def _lock(data_dir: Path, option: str) -> int:
    """``data_dir``'s lock file, locked, with this process's id in it (its descriptor); a
    :class:`StoreError` naming the holder's when another process holds it (two dispatchers
    on one store would both command the fleet). The lock goes with the process."""
    path = data_dir / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise StoreError(f"data directory {data_dir}: {exc.strerror or exc}") from exc
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        holder = os.read(fd, 32).decode(errors="replace").strip() or "?"
        os.close(fd)
        raise StoreError(
            f"data directory {data_dir}: in use by another dispatcher (process {holder}); "
            f"stop that one first, or give this one another {option}"
        ) from None
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    return fd


class Store:
    """One farm's database (module doc). Used from the daemon's main thread only."""

    def __init__(
        self,
        path: Path,
        conn: sqlite3.Connection,
        farm_id: str,
        lock: int | None = None,
        option: str = "--data-dir",
    ) -> None:
        self.path = path
        self.option = option  # the command-line option that chose the directory
        self.conn = conn
        self._lock = lock  # held while open: one dispatcher a data directory
        self.farm_id = farm_id
        self.run_id: int | None = None
        self.run_started: float | None = None  # when that run began (time.time())
        self._in_transaction = False
        self._touched: set[str] = set()
        self.commits = 0

    # --- opening -------------------------------------------------------------------------
    @classmethod
    def open(
        cls, data_dir: Path, farm_id: str, sync: str = "full", option: str = "--data-dir"
    ) -> Store:
        """Open (or create) ``data_dir/agrifleet.sqlite3`` for ``farm_id``; ``option`` is
        the command-line option that chooses the directory, named in the errors."""
        if sync not in SYNC_MODES:
            raise StoreError(f"synchronous mode {sync!r}: one of {', '.join(SYNC_MODES)}")
        data_dir = Path(data_dir)
        try:
            data_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"data directory {data_dir}: {exc.strerror or exc}") from exc
        path = data_dir / DB_NAME
        lock = _lock(data_dir, option)
        try:
            conn = sqlite3.connect(path, isolation_level=None)
            store = cls(path, conn, farm_id, lock, option)
            store._check_or_create()  # before any change: a database refused stays as it was
            conn.execute("PRAGMA journal_mode=WAL")
            conn.execute(f"PRAGMA synchronous={sync.upper()}")
            conn.execute("PRAGMA foreign_keys=ON")
        except sqlite3.DatabaseError as exc:
            os.close(lock)
            raise StoreError(
                f"{path}: not a database agrifleet can use ({exc}): if it is this farm's, "
                "damaged, move it aside (`sqlite3 FILE .recover` may save its events; the "
                "logs hold the run) and serve again to start over; else use another "
                f"{option}"
            ) from exc
        except StoreError:
            os.close(lock)
            raise
        return store

    def _check_or_create(self) -> None:
        c = self.conn
        app = c.execute("PRAGMA application_id").fetchone()[0]
        version = c.execute("PRAGMA user_version").fetchone()[0]
        tables = c.execute("SELECT count(*) FROM sqlite_master").fetchone()[0]
        if app == 0 and version == 0 and tables == 0:  # a new file
            created = json.dumps(time.time())
            c.executescript(
                f"BEGIN IMMEDIATE; {_SCHEMA}"
                f"INSERT INTO meta VALUES ('farm_id', {_quote(self.farm_id)});"
                f"INSERT INTO meta VALUES ('created', '{created}');"
                f"PRAGMA application_id={APPLICATION_ID};"
                f"PRAGMA user_version={SCHEMA_VERSION}; COMMIT;"
            )
            return
        if app != APPLICATION_ID:
            raise StoreError(f"{self.path}: not an agrifleet database; use another {self.option}")
        if version not in (1, SCHEMA_VERSION):
            raise StoreError(
                f"{self.path}: database schema version {version}, this agrifleet reads "
                f"version {SCHEMA_VERSION}; use another {self.option}"
            )
        row = c.execute("SELECT value FROM meta WHERE key = 'farm_id'").fetchone()
        if row is None or row[0] != self.farm_id:
            held = row[0] if row else "?"
            raise StoreError(
                f"{self.path} holds the state of farm {held!r}, not {self.farm_id!r}: "
                f"give this farm its own {self.option}"
            )
        if version == 1:  # the fields' started_by came with 2
            c.executescript(
                "BEGIN IMMEDIATE; ALTER TABLE fields ADD COLUMN started_by TEXT; "
                f"PRAGMA user_version={SCHEMA_VERSION}; COMMIT;"
            )

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[None]:
        """Writes committed at once, with the events pending (one COMMIT)."""
        self._begin()
        try:
            yield
        except sqlite3.Error as exc:
            self._failed(exc)
        except BaseException:
            self._in_transaction = False
            self.conn.execute("ROLLBACK")
            raise
        self.commit()

    def _begin(self) -> None:
        if not self._in_transaction:
            try:
                self.conn.execute("BEGIN IMMEDIATE")
            except sqlite3.Error as exc:
                self._failed(exc)
            self._in_transaction = True

    def _failed(self, exc: sqlite3.Error) -> NoReturn:
        """A write the database refused (a full disk, a file made read-only): what is
        pending is rolled back, and the message says where and what to do."""
        self._in_transaction = False
        with contextlib.suppress(sqlite3.Error):
            self.conn.execute("ROLLBACK")
        raise StoreWriteError(
            f"{self.path}: cannot write the dispatcher's state ({exc}); is the data "
            "directory full or not writable? What was kept before is intact: free space "
            "and start the dispatcher again to resume"
        ) from exc

    def close(self, commit: bool = True) -> None:
        """Close the database (after a commit unless ``commit`` is false: what is pending
        is lost, as in a crash) and let another dispatcher have it."""
        if commit:
            self.commit()
        self.conn.close()
        if self._lock is not None:
            os.close(self._lock)  # and with it the lock
            self._lock = None

    # --- runs ----------------------------------------------------------------------------
    def unfinished_run(self) -> StoredRun | None:
        """The run that has not ended, with its events; None when there is none."""
        row = self.conn.execute(
            "SELECT id, fingerprint, started, document, geojson FROM runs "
            "WHERE outcome IS NULL ORDER BY id DESC LIMIT 1"
        ).fetchone()
        if row is None:
            return None
        run_id, fingerprint, started, document, geojson = row
        where = f"{self.path} run {run_id}"
        try:
            first = PlanDocument.from_json(document)
            items = {
                vid: json.loads(text)
                for vid, text in self.conn.execute(
                    "SELECT vehicle, items FROM missions WHERE run = ?", (run_id,)
                )
            }
            events = tuple(
                (wall, ev.from_dict(json.loads(body)))
                for wall, body in self.conn.execute(
                    "SELECT wall, body FROM events WHERE run = ? ORDER BY id", (run_id,)
                )
            )
            # The missions stored are the last plan's: after a re-plan, its document.
            replans = [e.document for _, e in events if isinstance(e, ev.PlanReplaced)]
            last = PlanDocument.from_json(replans[-1]) if replans else first
            job = DispatchJob.from_parts(last, items, json.loads(geojson))
        except (PlanDocumentError, ValueError) as exc:
            raise StoreError(f"{where}: {exc}") from exc
        unknown = {e.vehicle for _, e in events} - {m.id for m in first.machines} - {ev.FLEET}
        if unknown:
            raise StoreError(f"{where}: events of vehicles not in its plan: {sorted(unknown)}")
        return StoredRun(run_id, job, fingerprint, started, events, first)

    def begin_run(self, job: DispatchJob, fingerprint: str, started: float | None = None) -> int:
        """Keep a new run's job, begun at ``started`` (:func:`time.time`; default now); its
        events follow. There must be no unfinished run."""
        if job.farm_id != self.farm_id:
            raise StoreError(
                f"{self.path}: plan of farm {job.farm_id!r} in {self.farm_id!r}'s store"
            )
        with self._transaction():
            if self.conn.execute("SELECT 1 FROM runs WHERE outcome IS NULL").fetchone():
                raise StoreError(f"{self.path}: a run is unfinished; resume it or abandon it")
            started = time.time() if started is None else started
            cur = self.conn.execute(
                "INSERT INTO runs(plan_id, farm_id, fingerprint, started, document, geojson) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (
                    job.plan_id,
                    job.farm_id,
                    fingerprint,
                    started,
                    job.document.to_json(),
                    json.dumps(job.geojson),
                ),
            )
            run_id = int(cur.lastrowid or 0)
            self.conn.executemany(
                "INSERT INTO missions VALUES (?, ?, ?)",
                [(run_id, vid, json.dumps(job.items_json(vid))) for vid in job.missions],
            )
        self.run_id = run_id
        self.run_started = started
        return run_id

    def replace_missions(self, job: DispatchJob) -> None:
        """The missions and map of a re-planned job (its document travels in the
        plan_replaced event, stored before: the run's first document stays as it was, for
        the events to be replayed from)."""
        if self.run_id is None:
            raise StoreError("no run begun or resumed")
        # In one commit with the plan_replaced event pending: a crash between the two
        # would leave missions that are not the plan's, and a run that cannot resume.
        rows = [(self.run_id, vid, json.dumps(job.items_json(vid))) for vid in job.missions]
        geojson = json.dumps(job.geojson)
        with self._transaction():
            self.conn.executemany("INSERT OR REPLACE INTO missions VALUES (?, ?, ?)", rows)
            self.conn.execute("UPDATE runs SET geojson = ? WHERE id = ?", (geojson, self.run_id))

    def resume_run(self, run: StoredRun) -> None:
        """Append to ``run`` from now on."""
        self.run_id = run.id
        self.run_started = run.started

    def end_run(self, outcome: str, run_id: int | None = None) -> None:
        """Mark a run ended (``done``, or ``abandoned`` by ``--fresh``); it is not resumed."""
        run_id = self.run_id if run_id is None else run_id
        if run_id is None:
            raise StoreError("no run begun or resumed")
        with self._transaction():
            self.conn.execute(
                "UPDATE runs SET ended = ?, outcome = ? WHERE id = ?",
                (time.time(), outcome, run_id),
            )

    def abandon_unfinished(self) -> int | None:
        """``--fresh``: end the unfinished run (kept, marked abandoned); its id or None."""
        row = self.conn.execute("SELECT id FROM runs WHERE outcome IS NULL").fetchone()
        if row is None:
            return None
        self.end_run("abandoned", int(row[0]))
        return int(row[0])

    # --- events --------------------------------------------------------------------------
    def append(self, event: ev.Event, wall: float) -> None:
        """Add an event to the open transaction (committed by :meth:`commit`)."""
        if self.run_id is None:
            raise StoreError("no run begun or resumed")
        self._begin()
        try:
            self.conn.execute(
                "INSERT INTO events(run, wall, vehicle, kind, body) VALUES (?, ?, ?, ?, ?)",
                (self.run_id, wall, event.vehicle, event.kind, json.dumps(ev.to_dict(event))),
            )
        except sqlite3.Error as exc:
            self._failed(exc)
        self._touched.add(event.vehicle)

    @property
    def pending(self) -> bool:
        return self._in_transaction

    def signing_timestamp(self) -> int:
        """The MAVLink signing timestamp to start from (0: none kept)."""
        row = self.conn.execute("SELECT value FROM meta WHERE key = 'signing_timestamp'").fetchone()
        return int(row[0]) if row is not None else 0

    def keep_signing_timestamp(self, stamp: int) -> None:
        """Keep ``stamp`` as the signing timestamp to start from after a restart (at once:
        a frame may be signed beyond the last one kept only after this returns)."""
        with self._transaction():
            self.conn.execute(
                "INSERT OR REPLACE INTO meta VALUES ('signing_timestamp', ?)", (str(stamp),)
            )

    def commit(self, state: FleetState | None = None) -> None:
        """Commit what is pending (the events appended since the last commit, a re-plan's
        missions, ...), with the current state of the vehicles the events concern (and of
        those vehicles' fields) when ``state`` is given; without it, those rows wait for
        the next commit that has it."""
        if not self._in_transaction:
            if state is None or not self._touched:
                return
            self._begin()  # rows a commit without the state left to write
        try:
            if state is not None:
                self._write_state(state)
            self.conn.execute("COMMIT")
        except sqlite3.Error as exc:
            self._failed(exc)
        self._in_transaction = False
        if state is not None:
            self._touched.clear()
        self.commits += 1

    def _write_state(self, state: FleetState) -> None:
        now = time.time()
        for vid in sorted(self._touched & set(state.vehicles)):
            v = state.vehicles[vid]
            self.conn.execute(
                "INSERT OR REPLACE INTO vehicles VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (self.run_id, vid, v.phase.value, v.reached, len(v.items), v.reboots, v.error, now),
            )
        self.conn.executemany(
            "INSERT OR REPLACE INTO fields VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            [
                (
                    self.run_id,
                    f.id,
                    f.vehicle,
                    f.status,
                    f.started_s,
                    f.finished_s,
                    f.swaths_done,
                    f.started_by,
                )
                for f in state.fields.values()
                if f.vehicle in self._touched
            ],
        )

    def rows(self, sql: str, *args: Any) -> list[tuple[Any, ...]]:
        """Read-only query (tests, tools)."""
        return list(self.conn.execute(sql, args))
