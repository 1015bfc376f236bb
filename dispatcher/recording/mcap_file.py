"""Recording a run to MCAP, and reading it back.

One run, one MCAP file: every MAVLink frame sent or received (raw, and as JSON when
decoded), the vehicles' positions, the plan, the status documents and the dispatcher's
log lines, all stamped with integer nanoseconds since the Unix epoch (the receive or send
time). Topics, schemas and messages come from ``dispatcher.recording.topics`` (listed in
``docs/recording.md``): the ``foxglove.*`` ones are the foxglove-sdk's, so the file opens
in Foxglove as it is, and a live view attached (``Recorder.live``) serves the same.

The record calls queue their messages for a writer thread (a bounded queue: a full one
makes the caller wait, nothing is dropped), which writes them in chunks and hands each
chunk to the operating system when it is full or at most ``max_chunk_age_s`` after its
oldest record: a record is in the file at most ``FLUSH_BOUND_S`` (0.5 s) after it was
recorded, so a run killed mid-way leaves a readable file holding all but its last half
second. :func:`read_log` and :func:`open_log` read finished files through the summary
(seeking reader) and fall back to a streaming read up to the first broken record for
files cut short, saying so with ``complete=False``; :func:`read_logs` reads the several
files of one run (a dispatcher restarted) as one.
"""

from __future__ import annotations

import atexit
import copy
import dataclasses
import io
import json
import logging
import math
import os
import struct
import threading
import time
import weakref
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Final, NamedTuple, Protocol, Self, cast

from mcap.exceptions import EndOfFile, McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from dispatcher.config.errors import DispatcherError
from dispatcher.link.mavlink import has_fix
from dispatcher.recording import topics
from dispatcher.recording.topics import (  # noqa: F401 - the names log readers use
    EVENTS_TOPIC,
    FIELDS_GEOJSON_TOPIC,
    JSON_ENCODING,
    LOG_TOPIC,
    MAVLINK_ENCODING,
    PLAN_GEOJSON_TOPIC,
    SCHEMAS,
    location_topic,
)

try:  # Chunk compression codecs are optional: mcap works (uncompressed) without them.
    import zstandard
except ImportError:  # pragma: no cover - zstandard comes with mcap's own requirements
    zstandard = None  # type: ignore[assignment]
try:
    import lz4.frame as lz4_frame
except ImportError:  # pragma: no cover
    lz4_frame = None

logger = logging.getLogger(__name__)

PROFILE: Final = "agrifleet"
METADATA_NAME: Final = "agrifleet"
# The metadata key that says which run a log is of: when the run began (ISO 8601, UTC). A
# dispatcher restarted mid-run writes the run's own start again in its new log, so the logs
# of one run share it and a log folder's runs are told apart (read_logs).
RUN_STARTED_KEY: Final = "run_started"
MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
DEFAULT_CHUNK_SIZE: Final = 256 * 1024
# A record is in the file (handed to the OS) at most FLUSH_BOUND_S after its record call:
# the writer closes the chunk DEFAULT_MAX_CHUNK_AGE_S after the oldest record it holds was
# queued, which leaves the rest for the writing itself and a writer briefly behind.
FLUSH_BOUND_S: Final = 0.5
DEFAULT_MAX_CHUNK_AGE_S: Final = 0.25
DEFAULT_QUEUE_SIZE: Final = 4096
_WARNING_INTERVAL_S: Final = 10.0  # at most one back-pressure warning this often
_EXIT_TIMEOUT_S: Final = 5.0  # finishing unfinished logs at interpreter exit
# Records longer than this are taken as corruption rather than read into memory.
_RECORD_SIZE_LIMIT: Final = 256 * 2**20


def _software_version() -> str:
    try:
        return version("agrifleet")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "0+unknown"


SOFTWARE_VERSION: Final = _software_version()
LIBRARY: Final = f"agrifleet {SOFTWARE_VERSION}"


class RecordingError(DispatcherError, ValueError):
    """A log file that cannot be read as an agrifleet log, or a value that cannot be recorded;
    the message names the file or the value."""


class RecorderStateError(DispatcherError, RuntimeError):
    """A record call on a recorder that is not started yet or already finished."""


# --- writing ---------------------------------------------------------------------------


class _DirectFile:
    """An unbuffered output file: each batch of records the writer emits goes straight to
    the OS, so a crash loses only the chunk still being built in memory."""

    def __init__(self, path: Path, mode: str) -> None:
        self.path = path
        self._raw = open(path, mode, buffering=0)  # noqa: SIM115 - closed by Recorder.finish

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            written = self._raw.write(view)
            view = view[written or 0 :]
        return len(data)

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        """Nothing is buffered here."""

    def close(self) -> None:
        self._raw.close()


def _compression_type(name: str) -> CompressionType:
    if name == "auto":
        if zstandard is not None:
            return CompressionType.ZSTD
        if lz4_frame is not None:
            return CompressionType.LZ4
        return CompressionType.NONE
    types = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
    if name not in types:
        raise RecordingError(f"compression must be auto, zstd, lz4 or none, not {name!r}")
    if (name == "zstd" and zstandard is None) or (name == "lz4" and lz4_frame is None):
        raise RecordingError(f"{name} compression needs the {name} package, which is missing")
    return types[name]


def _check_farm_id(farm_id: str) -> str:
    if not isinstance(farm_id, str) or not farm_id or "/" in farm_id or "*" in farm_id:
        raise RecordingError(
            f"farm_id must be a non-empty string without '/' or '*', not {farm_id!r}"
        )
    return farm_id


def _json_default(value: Any) -> Any:
    tolist = getattr(value, "tolist", None)  # numpy scalars and arrays
    if callable(tolist):
        return tolist()
    if isinstance(value, bytes | bytearray):
        return list(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _finite(value: Any) -> Any:
    """``value`` with every NaN or infinity replaced by None (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _dumps(doc: Any, what: str) -> bytes:
    """Compact JSON bytes of ``doc``; NaN and infinities become null."""
    try:
        try:
            text = json.dumps(doc, separators=(",", ":"), allow_nan=False, default=_json_default)
        except ValueError:  # a NaN somewhere: rare, so only then walk the document
            text = json.dumps(
                _finite(json.loads(json.dumps(doc, default=_json_default))),
                separators=(",", ":"),
                allow_nan=False,
            )
    except (TypeError, ValueError, RecursionError) as exc:
        raise RecordingError(f"cannot record {what}: not JSON-serialisable ({exc})") from exc
    return text.encode()


def _metadata_value(value: object) -> str:
    if isinstance(value, str):
        return value
    try:
        return json.dumps(value, default=_json_default)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"metadata value {value!r} is not JSON-serialisable") from exc


def _check_time(log_time_ns: int) -> None:
    if type(log_time_ns) is not int or not 0 <= log_time_ns < 2**64:
        raise RecordingError(
            f"log_time_ns must be integer nanoseconds since the epoch, got {log_time_ns!r}"
        )


_PROTOBUF: Final = topics.PROTOBUF_ENCODING


class LiveSink(Protocol):
    """Takes every message as it is recorded (``dispatcher.recording.live.LiveView``)."""

    def publish(
        self, items: Sequence[tuple[str, str, str | None, bytes]], log_time_ns: int
    ) -> None:
        """``items``: (topic, message encoding, schema name or None, data)."""


# What the record calls queue for the writer thread: (kind, payload, time.monotonic() when
# queued). Payloads: _MESSAGES ((topic, encoding, schema name, data), ...), log_time_ns;
# _METADATA a dict; _FLUSH and _SYNC an Event set when done; _STOP None.
_Item = tuple[str, str, str | None, bytes]
_Entry = tuple[int, Any, float]
_MESSAGES: Final = 0
_METADATA: Final = 1
_FLUSH: Final = 2
_SYNC: Final = 3
_STOP: Final = 4
# The writer takes what is queued this often (or when the queue is half full, or for a
# flush, drain or finish): a wake-up per record would cost more than the writing.
_BATCH_INTERVAL_S: Final = 0.05


class _WriteQueue:
    """A bounded FIFO from the record calls to the writer thread. ``put`` waits while it
    holds ``maxsize`` entries; the writer takes every entry queued at once, and is woken
    only when it sleeps with nothing to do, when the queue is half full, or when asked."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._wake_at = max(maxsize // 2, 1)
        self._items: list[_Entry] = []
        lock = threading.Lock()
        self._has_items = threading.Condition(lock)
        self._has_room = threading.Condition(lock)
        self._writer_idle = False  # the writer waits with no timeout: wake it for anything

    def qsize(self) -> int:
        return len(self._items)

    def try_put(self, entry: _Entry, wake: bool = False) -> bool:
        """Queue ``entry`` if there is room; False if the queue is full."""
        with self._has_items:
            return self._put_locked(entry, wake)

    def put(self, entry: _Entry, timeout: float, wake: bool = False) -> bool:
        """Queue ``entry``, waiting up to ``timeout`` for room; False if there was none."""
        with self._has_items:
            deadline = time.monotonic() + timeout
            while len(self._items) >= self.maxsize:
                self._has_items.notify()
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._has_room.wait(remaining)
            return self._put_locked(entry, wake)

    def _put_locked(self, entry: _Entry, wake: bool) -> bool:
        items = self._items
        if len(items) >= self.maxsize:
            return False
        items.append(entry)
        if wake or self._writer_idle or len(items) >= self._wake_at:
            self._has_items.notify()
        return True

    def take(self, timeout: float | None) -> list[_Entry]:
        """Everything queued (oldest first), after waiting up to ``timeout`` (None: until
        something comes) unless woken earlier; maybe nothing."""
        with self._has_items:
            if not self._items or (timeout is not None and len(self._items) < self._wake_at):
                self._writer_idle = timeout is None
                self._has_items.wait(timeout)
                self._writer_idle = False
            batch, self._items = self._items, []
            if batch:
                self._has_room.notify_all()
            return batch


class Recorder:
    """Writes one run to one MCAP file: ``start()`` → ``record_*()`` → ``finish()``.

    ``output`` is a path (created or truncated) or a binary stream (left open by
    ``finish``). Every ``record_*`` takes ``log_time_ns``, integer nanoseconds since the
    epoch. All methods are thread-safe. Used as a context manager it starts on entry and
    finishes on exit.

    A ``record_*`` call turns its document into JSON (so a bad value is refused at the
    call, and the caller may change its dict afterwards) and puts the message on a queue
    of ``queue_size`` entries; a writer thread does the MCAP encoding, the compression
    and the writing. When the queue is full the call waits for room (back-pressure, never
    a dropped record), counted in ``blocked_count`` and ``blocked_s`` and logged as a
    warning. Records go into chunks of ``chunk_size`` bytes (compressed with
    ``compression``: auto, zstd, lz4 or none); the writer also closes the chunk and hands
    the file everything at most ``max_chunk_age_s`` after the oldest record not yet
    handed over was recorded (``None``: only full chunks and :meth:`flush`), so a crash
    or a ``kill -9`` loses at most the records of the last ``FLUSH_BOUND_S`` seconds.
    """

    def __init__(
        self,
        output: str | os.PathLike[str] | IO[bytes],
        farm_id: str,
        metadata: Mapping[str, object] | None = None,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "auto",
        max_chunk_age_s: float | None = DEFAULT_MAX_CHUNK_AGE_S,
        queue_size: int = DEFAULT_QUEUE_SIZE,
        clock: Callable[[], int] = time.time_ns,
    ) -> None:
        self.farm_id = _check_farm_id(farm_id)
        if chunk_size < 1:
            raise RecordingError(f"chunk_size must be positive, got {chunk_size}")
        if max_chunk_age_s is not None and not 0 <= max_chunk_age_s < math.inf:
            raise RecordingError(f"max_chunk_age_s must be >= 0 or None, got {max_chunk_age_s}")
        if queue_size < 1:
            raise RecordingError(f"queue_size must be positive, got {queue_size}")
        compression_type = _compression_type(compression)
        self._initial_metadata = {k: _metadata_value(v) for k, v in (metadata or {}).items()}
        # Checked everything: only now create the file.
        self.path: Path | None = None
        self._file: _DirectFile | None = None
        stream: Any = output
        if isinstance(output, str | os.PathLike):
            stream = _DirectFile(Path(output), "wb")
        if isinstance(stream, _DirectFile):  # ours: closed by finish()
            self.path, self._file = stream.path, stream
        self._stream = stream
        self._writer = Writer(
            cast(IO[Any], stream), chunk_size=chunk_size, compression=compression_type
        )
        self._clock = clock
        self._max_chunk_age_s = max_chunk_age_s
        self._metadata: dict[str, str] = {}
        # Held by callers around check-and-enqueue, so nothing is queued after the stop
        # entry; never taken by the writer thread.
        self._lock = threading.Lock()
        self._queue = _WriteQueue(queue_size)
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None  # what stopped the writer thread
        # Writer thread only: the channel cache (topic -> [channel id, next sequence]).
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, list[int]] = {}
        self._started = False
        self._finished = False
        self._last_warning = -math.inf
        self.message_count = 0  # messages written (by the writer thread)
        self.flush_count = 0  # times the writer handed the file a closed chunk on time
        self.blocked_count = 0  # record calls that waited for room in the queue
        self.blocked_s = 0.0  # and how long they waited in all
        # Where every message also goes as it is recorded (the live view), if anywhere.
        self.live: LiveSink | None = None
        self._plan_geojson: dict[str, Any] | None = None  # the last plan's, for field states
        self._fields_shown: dict[str, Any] | None = None  # field states last drawn

    @classmethod
    def create_in(
        cls,
        log_dir: str | os.PathLike[str],
        farm_id: str,
        metadata: Mapping[str, object] | None = None,
        **options: Any,
    ) -> Recorder:
        """A started recorder writing a new ``log_dir/<farm_id>-<YYYYmmdd-HHMMSS>.mcap``
        (UTC; ``-1``, ``-2`` ... appended if that name is taken)."""
        _check_farm_id(farm_id)
        clock: Callable[[], int] = options.get("clock", time.time_ns)
        directory = Path(log_dir)
        directory.mkdir(parents=True, exist_ok=True)
        stamp = datetime.fromtimestamp(clock() / 1e9, UTC).strftime("%Y%m%d-%H%M%S")
        for n in range(10_000):
            path = directory / f"{farm_id}-{stamp}{'' if n == 0 else f'-{n}'}.mcap"
            try:
                file = _DirectFile(path, "xb")  # claims the name even against other processes
            except FileExistsError:
                continue
            break
        else:  # pragma: no cover - ten thousand runs in one second
            raise RecordingError(f"no free log file name for {farm_id}-{stamp} in {directory}")
        try:
            recorder = cls(cast(IO[bytes], file), farm_id, metadata, **options)
            recorder.start()
        except BaseException:
            file.close()
            path.unlink(missing_ok=True)
            raise
        return recorder

    # --- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        """Write the MCAP header and the "agrifleet" metadata record, start the writer."""
        with self._lock:
            if self._started:
                raise RecorderStateError(f"recorder for {self._name()} is already started")
            self._start_locked()

    def _start_locked(self) -> None:
        self._started = True
        self._writer.start(profile=PROFILE, library=LIBRARY)
        start_ns = self._clock()
        base = {
            "farm_id": self.farm_id,
            "software_version": SOFTWARE_VERSION,
            "start_time": datetime.fromtimestamp(start_ns / 1e9, UTC).isoformat(),
            "start_time_ns": str(start_ns),
        }
        values = {**base, **self._initial_metadata}
        self._writer.add_metadata(METADATA_NAME, values)
        self._metadata.update(values)
        self._writer.flush()
        self._thread = threading.Thread(
            target=self._run, name=f"mcap writer {self._name()}", daemon=True
        )
        self._thread.start()
        _unfinished.add(self)

    def record_metadata(self, values: Mapping[str, object]) -> None:
        """Add keys to the log's "agrifleet" metadata (a later value wins on reading)."""
        strings = {k: _metadata_value(v) for k, v in values.items()}
        with self._lock:
            self._check_open()
            self._add_metadata_locked(strings)

    def flush(self) -> None:
        """Close the chunk being built and hand everything recorded so far to the OS;
        returns when that is done."""
        self._wait_for(_FLUSH)

    def drain(self) -> None:
        """Wait until the writer has taken every record so far into the MCAP writer (the
        chunk being built may still be in memory: :meth:`flush` writes it)."""
        self._wait_for(_SYNC)

    def _wait_for(self, kind: int) -> None:
        done = threading.Event()
        with self._lock:
            self._check_open()
            self._put_locked((kind, done, time.monotonic()), wake=True)
        done.wait()
        self._raise_if_failed()

    def finish(self) -> None:
        """Write every queued record, the summary and index, and close the file (not a
        caller's stream). Idempotent; a recorder never started is started first, so the
        file is a valid log. Raises :class:`RecordingError` if writing failed."""
        with self._lock:
            if self._finished:
                return
            self._finished = True
            try:
                if not self._started:
                    self._start_locked()
                self._put_locked((_STOP, None, time.monotonic()), wake=True)
            except BaseException:
                if self._file is not None:
                    self._file.close()
                raise
        try:
            if self._thread is not None:
                self._thread.join()
            if self._error is None:
                self._writer.finish()
                if self._file is None:
                    self._stream.flush()
        except OSError as exc:
            self._error = exc
        finally:
            _unfinished.discard(self)
            if self._file is not None:
                self._file.close()
        self._raise_if_failed()
        logger.debug(
            "finished %s: %d messages, %d record calls waited for the writer",
            self._name(),
            self.message_count,
            self.blocked_count,
        )

    @property
    def finished(self) -> bool:
        return self._finished

    @property
    def metadata(self) -> dict[str, str]:
        """The "agrifleet" metadata written so far."""
        with self._lock:
            return dict(self._metadata)

    def __enter__(self) -> Self:
        if not self._started:
            self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.finish()

    # --- records -------------------------------------------------------------------------
    def record_frame(
        self, key: str, frame: bytes, log_time_ns: int, decoded: Mapping[str, Any] | None = None
    ) -> None:
        """One MAVLink frame on Zenoh key ``key``: the raw bytes on topic ``key``, and when
        ``decoded`` (from ``mavlink_codec.as_dict``) is given, that JSON on ``key/json``."""
        _check_time(log_time_ns)
        if decoded is None:
            self._write(((key, MAVLINK_ENCODING, None, bytes(frame)),), log_time_ns)
            return
        self._write(
            (
                (key, MAVLINK_ENCODING, None, bytes(frame)),
                (topics.json_topic(key), JSON_ENCODING, topics.MAVLINK_JSON, _dumps(decoded, key)),
            ),
            log_time_ns,
        )

    def record_location(
        self,
        vehicle_id: str,
        lat: float,
        lon: float,
        log_time_ns: int,
        sim_time_s: float | None = None,
        *,
        altitude_m: float = 0.0,
        heading_deg: float | None = None,
    ) -> None:
        """A position fix (degrees) on ``/vehicle/<id>/fix`` as ``foxglove.LocationFix``,
        stamped with the log time, with the heading (degrees clockwise from north) when
        known; ``sim_time_s`` (the vehicle's own clock) goes into the fix's metadata. A
        position that is no fix (not finite, off the globe, or the 0, 0 of an autopilot
        without one) is skipped: the raw frame is on the MAVLink topic."""
        _check_time(log_time_ns)
        if not (has_fix(lat, lon) and math.isfinite(altitude_m)):
            logger.debug("skipping non-finite fix of %s: %s, %s", vehicle_id, lat, lon)
            return
        data = topics.location_fix(
            vehicle_id,
            lat,
            lon,
            log_time_ns,
            altitude_m=altitude_m,
            heading_deg=heading_deg,
            sim_time_s=sim_time_s,
        )
        self._write(
            ((location_topic(vehicle_id), _PROTOBUF, topics.LOCATION_FIX, data),), log_time_ns
        )

    def record_plan(
        self, plan_doc: Mapping[str, Any], geojson: Mapping[str, Any], log_time_ns: int
    ) -> None:
        """The plan document on ``agrifleet/<farm>/dispatcher/plan`` and its fields and
        routes as ``foxglove.GeoJSON`` on ``/plan/geojson``; a new ``plan_id`` in the plan
        is added to the metadata. The fields' states (``/fields/geojson``) are drawn from
        this plan's fields from now on."""
        _check_time(log_time_ns)
        plan = _dumps(plan_doc, "plan document")
        geo = topics.geojson(_dumps(geojson, "plan GeoJSON").decode())
        self._plan_geojson = copy.deepcopy(dict(geojson))
        self._fields_shown = None
        self._write(
            (
                (topics.plan_topic(self.farm_id), JSON_ENCODING, topics.PLAN, plan),
                (PLAN_GEOJSON_TOPIC, _PROTOBUF, topics.GEOJSON, geo),
            ),
            log_time_ns,
        )
        plan_id = plan_doc.get("plan_id")
        if plan_id is not None:
            value = _metadata_value(plan_id)
            with self._lock:
                self._check_open()
                if self._metadata.get("plan_id") != value:
                    self._add_metadata_locked({"plan_id": value})

    def record_event(self, event: Mapping[str, Any], log_time_ns: int) -> None:
        """A fleet-state event (its JSON form) on ``EVENTS_TOPIC``; ``log_time_ns`` is when
        it was applied."""
        _check_time(log_time_ns)
        data = _dumps(event, "fleet event")
        self._write(((EVENTS_TOPIC, JSON_ENCODING, topics.EVENT, data),), log_time_ns)

    def record_status(self, status_doc: Mapping[str, Any], log_time_ns: int) -> None:
        """A status document on ``agrifleet/<farm>/dispatcher/status``, and the fields of
        the last plan recorded coloured by their state on ``/fields/geojson`` when a
        field's state changed."""
        _check_time(log_time_ns)
        data = _dumps(status_doc, "status document")
        items: list[_Item] = [
            (topics.status_topic(self.farm_id), JSON_ENCODING, topics.STATUS, data)
        ]
        shown = {
            k: (f.get("status"), f.get("vehicle")) for k, f in status_doc.get("fields", {}).items()
        }
        if self._plan_geojson is not None and shown != self._fields_shown:
            fields = topics.fields_state(self._plan_geojson, status_doc)
            self._fields_shown = shown
            if fields is not None:
                geo = topics.geojson(_dumps(fields, "fields GeoJSON").decode())
                items.append((FIELDS_GEOJSON_TOPIC, _PROTOBUF, topics.GEOJSON, geo))
        self._write(tuple(items), log_time_ns)

    def record_log(
        self,
        level: str,
        text: str,
        log_time_ns: int,
        *,
        name: str = "dispatcher",
        file: str = "",
        line: int = 0,
    ) -> None:
        """A log line on ``/log`` as ``foxglove.Log``; ``level`` is a ``logging`` level
        name (debug, info, warning, error, critical), anything else is UNKNOWN."""
        _check_time(log_time_ns)
        data = topics.log_line(level, text, log_time_ns, name=name, file=file, line=line)
        self._write(((LOG_TOPIC, _PROTOBUF, topics.LOG, data),), log_time_ns)

    # --- internals: the caller's side ----------------------------------------------------
    def _write(self, items: tuple[_Item, ...], log_time_ns: int) -> None:
        with self._lock:
            self._check_open()
            self._put_locked((_MESSAGES, (items, log_time_ns), time.monotonic()))
        if self.live is not None:
            self.live.publish(items, log_time_ns)

    def _add_metadata_locked(self, values: dict[str, str]) -> None:
        self._put_locked((_METADATA, values, time.monotonic()))
        self._metadata.update(values)

    def _put_locked(self, entry: _Entry, wake: bool = False) -> None:
        """Queue ``entry`` for the writer thread; wait for room when the queue is full."""
        if self._queue.try_put(entry, wake):
            return
        waited_from = time.monotonic()
        self.blocked_count += 1
        if waited_from - self._last_warning >= _WARNING_INTERVAL_S:
            self._last_warning = waited_from
            logger.warning(
                "the log writer for %s is behind (%d records queued): recording waits for it "
                "(%d waits so far, %.2f s waited before this one)",
                self._name(),
                self._queue.maxsize,
                self.blocked_count,
                self.blocked_s,
            )
        while not self._queue.put(entry, timeout=0.5, wake=wake):
            self._raise_if_failed()  # a dead writer would never make room
        self.blocked_s += time.monotonic() - waited_from

    def _check_open(self) -> None:
        if not self._started:
            raise RecorderStateError(f"recorder for {self._name()} is not started: call start()")
        if self._finished:
            raise RecorderStateError(
                f"recorder for {self._name()} is finished; nothing more can be recorded"
            )
        self._raise_if_failed()

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise RecordingError(f"cannot write log {self._name()}: {self._error}") from self._error

    def _name(self) -> str:
        return str(self.path) if self.path is not None else "<stream>"

    # --- internals: the writer thread ----------------------------------------------------
    def _run(self) -> None:
        """Take entries off the queue and write them; close the chunk and hand it to the
        file when the oldest record not yet handed over is ``max_chunk_age_s`` old."""
        max_age = self._max_chunk_age_s
        due: float | None = None  # when what is held in memory must be in the file
        timeout: float | None = None
        while True:
            batch = self._queue.take(timeout)
            for kind, payload, queued_at in batch:
                try:
                    if kind == _STOP:
                        return
                    if self._error is not None:
                        continue  # writing failed: keep taking entries so no caller waits
                    if kind == _MESSAGES:
                        self._add_messages(*payload)
                    elif kind == _METADATA:
                        self._writer.add_metadata(METADATA_NAME, payload)
                    elif kind == _FLUSH:
                        self._writer.flush()
                        due = None
                        continue
                    else:  # _SYNC
                        continue
                    if max_age is not None:
                        if due is None:
                            due = queued_at + max_age
                        if time.monotonic() >= due:
                            self._flush_file()
                            due = None
                except BaseException as exc:  # noqa: BLE001 - kept and raised to the callers
                    self._error = exc
                    logger.error("writing log %s failed: %s", self._name(), exc)
                finally:
                    if kind in (_FLUSH, _SYNC):
                        payload.set()
            now = time.monotonic()
            if due is not None and now >= due:
                self._flush_file()
                due = None
            # After a batch more may come soon: look again after a while, unwoken.
            timeout = _BATCH_INTERVAL_S if batch else None
            if due is not None:
                timeout = min(timeout or math.inf, max(due - now, 0.0))

    def _flush_file(self) -> None:
        try:
            self._writer.flush()
            self.flush_count += 1
        except BaseException as exc:  # noqa: BLE001 - kept and raised to the callers
            self._error = exc
            logger.error("writing log %s failed: %s", self._name(), exc)

    def _add_messages(self, items: tuple[_Item, ...], log_time_ns: int) -> None:
        add_message = self._writer.add_message
        for topic, encoding, schema_name, data in items:
            entry = self._channels.get(topic)
            if entry is None:
                entry = self._register(topic, encoding, schema_name)
            add_message(entry[0], log_time_ns, data, log_time_ns, entry[1])
            entry[1] = (entry[1] + 1) & 0xFFFFFFFF
        self.message_count += len(items)

    def _register(self, topic: str, encoding: str, schema_name: str | None) -> list[int]:
        schema_id = 0
        if schema_name is not None:
            schema_id = self._schemas.get(schema_name, 0)
            if not schema_id:
                schema = SCHEMAS[schema_name]
                schema_id = self._writer.register_schema(schema.name, schema.encoding, schema.data)
                self._schemas[schema_name] = schema_id
        entry = [self._writer.register_channel(topic, encoding, schema_id), 0]
        self._channels[topic] = entry
        return entry


# Recorders started and not finished: finished at interpreter exit, so a program that
# returns without finish() still leaves a whole log (a kill leaves what was flushed).
_unfinished: weakref.WeakSet[Recorder] = weakref.WeakSet()


@atexit.register
def _finish_at_exit() -> None:
    recorders = list(_unfinished)
    if not recorders:
        return

    def finish_all() -> None:
        for recorder in recorders:
            try:
                recorder.finish()
            except Exception as exc:  # noqa: BLE001 - nothing left to raise to at exit
                logger.error("could not finish log %s at exit: %s", recorder._name(), exc)

    # A writer stuck on a stalled disk must not hang the exit: give up after a while.
    finisher = threading.Thread(target=finish_all, name="finish logs at exit", daemon=True)
    try:
        finisher.start()
    except RuntimeError:  # no new threads this late in some Pythons: finish here
        finish_all()
        return
    finisher.join(_EXIT_TIMEOUT_S)
    if finisher.is_alive():
        logger.error(
            "could not finish %s within %.0f s at exit; they hold what was flushed",
            ", ".join(r._name() for r in recorders),
            _EXIT_TIMEOUT_S,
        )


class RecorderLogHandler(logging.Handler):
    """Copies ``logging`` records into a recorder's ``/log`` topic (dropped once it is
    finished)."""

    def __init__(self, recorder: Recorder, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.recorder = recorder

    def emit(self, record: logging.LogRecord) -> None:
        if record.name == __name__ or self.recorder.finished:
            return  # never feed the recorder's own messages back into it
        try:
            self.recorder.record_log(
                record.levelname,
                record.getMessage(),
                int(record.created * 1e9),
                name=record.name,
                file=record.pathname,
                line=record.lineno or 0,
            )
        except Exception:  # a log handler must not raise into the code that logs
            self.handleError(record)


# --- reading ---------------------------------------------------------------------------


class LogRecord(NamedTuple):
    """One message of a log."""

    topic: str
    schema_name: str  # "" for a schema-less channel (the raw MAVLink frames)
    message_encoding: str
    log_time_ns: int
    data: bytes

    def decode_json(self) -> Any:
        """The message as a plain value: JSON parsed, a ``foxglove.*`` (protobuf) message
        as the dict of Foxglove's JSON schema (``topics.decode``). Raises ValueError for
        data that does not decode."""
        return topics.decode(self.schema_name, self.message_encoding, self.data)


@dataclass(frozen=True)
class LogContents:
    """Everything in a log. ``complete`` is False when the file was cut short or has a
    broken record; ``records`` then holds what came before it and ``problem`` says why."""

    source: str
    profile: str
    library: str
    metadata: dict[str, str]
    records: list[LogRecord]
    complete: bool
    problem: str | None
    # What the reader chose and left out (read_logs on a folder of several runs), or None.
    note: str | None = None

    def topic_counts(self) -> dict[str, int]:
        """Number of messages per topic."""
        return dict(Counter(r.topic for r in self.records))

    def on(self, topic: str) -> list[LogRecord]:
        """The messages of one topic, in file order."""
        return [r for r in self.records if r.topic == topic]


# Everything a damaged MCAP makes the mcap readers raise.
_BROKEN: tuple[type[BaseException], ...] = (
    McapError,
    struct.error,
    ValueError,  # includes mcap's CRCValidationError and bad UTF-8
    EOFError,
    KeyError,
    IndexError,
    RuntimeError,  # lz4
    OverflowError,
)
if zstandard is not None:
    _BROKEN += (zstandard.ZstdError,)


def _describe(exc: BaseException, name: str) -> str:
    if isinstance(exc, EndOfFile | struct.error | EOFError):
        return f"{name} is cut short (the recorder did not finish: crash, kill or full disk)"
    detail = str(exc) or type(exc).__name__
    return f"{name} has a broken record ({detail}); what follows it cannot be read"


class LogReader:
    """An open agrifleet log: ``header``, ``metadata`` at once, messages from
    :meth:`records`. A seekable stream is read from its start.

    Finished files are read through their summary (``reader_kind == "seeking"``); others,
    or all with ``streaming=True``, record by record up to the first broken one
    (``"streaming"``). ``complete`` is False for a file cut short or damaged, and
    ``problem`` says why; :meth:`records` may find damage the open did not and clears
    ``complete`` then. Raises :class:`RecordingError` for a file that is not an MCAP or
    not an agrifleet log.
    """

    def __init__(self, source: str | os.PathLike[str] | IO[bytes], *, streaming: bool = False):
        self._owned: IO[bytes] | None = None
        if isinstance(source, str | os.PathLike):
            self.name = str(source)
            try:
                self._owned = open(source, "rb")  # noqa: SIM115 - closed by close()
            except OSError as exc:
                raise RecordingError(f"cannot open log {self.name}: {exc.strerror}") from exc
            stream: IO[bytes] = self._owned
        else:
            self.name = str(getattr(source, "name", "<stream>"))
            stream = source if source.seekable() else io.BytesIO(source.read())
        self._stream = stream
        self.header: Header | None = None
        self.metadata: dict[str, str] = {}
        self.complete = False
        self.problem: str | None = None
        self.reader_kind = "streaming"
        self._seeking: SeekingReader | None = None
        try:
            self._open(streaming)
        except BaseException:
            self.close()
            raise

    @property
    def profile(self) -> str:
        return self.header.profile if self.header else ""

    @property
    def library(self) -> str:
        return self.header.library if self.header else ""

    def _open(self, streaming: bool) -> None:
        stream = self._stream
        size = stream.seek(0, io.SEEK_END)
        stream.seek(0)
        start = stream.read(len(MCAP_MAGIC))
        if not start:
            raise RecordingError(f"{self.name} is empty: not an agrifleet log")
        if not MCAP_MAGIC.startswith(start):
            raise RecordingError(f"{self.name} is not an MCAP file (no MCAP magic at its start)")
        if not streaming and size >= 2 * len(MCAP_MAGIC):
            stream.seek(-len(MCAP_MAGIC), io.SEEK_END)
            if stream.read(len(MCAP_MAGIC)) == MCAP_MAGIC and self._open_seeking():
                return
        self._open_streaming()

    def _open_seeking(self) -> bool:
        """Read header, summary and metadata of a finished file; False to read it as a stream."""
        try:
            self._stream.seek(0)
            reader = SeekingReader(
                self._stream, validate_crcs=True, record_size_limit=_RECORD_SIZE_LIMIT
            )
            header = reader.get_header()
            self._check_header(header)
            summary = reader.get_summary()
            if summary is None or not summary.chunk_indexes:
                return False
            metadata: dict[str, str] = {}
            for record in reader.iter_metadata():
                if record.name == METADATA_NAME:
                    metadata.update(record.metadata)
        except RecordingError:
            raise
        except _BROKEN as exc:
            logger.debug("%s: summary unreadable (%s), reading it as a stream", self.name, exc)
            return False
        self.header, self.metadata, self._seeking = header, metadata, reader
        self.complete, self.problem, self.reader_kind = True, None, "seeking"
        return True

    def _open_streaming(self) -> None:
        """One pass over the records (chunks left compressed) for header, metadata and
        whether the file ends properly."""
        self._stream.seek(0)
        reader = StreamReader(self._stream, emit_chunks=True, record_size_limit=_RECORD_SIZE_LIMIT)
        try:
            for record in reader.records:
                if isinstance(record, Header):
                    self._check_header(record)
                    self.header = record
                elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                    self.metadata.update(record.metadata)
        except RecordingError:
            raise
        except _BROKEN as exc:
            self.complete, self.problem = False, _describe(exc, self.name)
        else:
            self.complete, self.problem = True, None

    def _check_header(self, header: Header) -> None:
        if header.profile != PROFILE:
            profile = header.profile or "none"
            raise RecordingError(
                f"{self.name} is an MCAP file but not an agrifleet log "
                f"(profile {profile!r}, written by {header.library!r})"
            )

    def records(self, topics: Iterable[str] | None = None) -> Iterator[LogRecord]:
        """The messages (of ``topics`` only, if given), up to the first broken record:
        in log-time order from a finished file, in the order written from one cut short
        (the same order unless threads recorded out of time order)."""
        wanted = None if topics is None else set(topics)
        if self._seeking is not None:
            yield from self._records_seeking(self._seeking, wanted)
        else:
            yield from self._records_streaming(wanted)

    def _records_seeking(
        self, reader: SeekingReader, wanted: set[str] | None
    ) -> Iterator[LogRecord]:
        try:
            # Log-time order reads chunk by chunk; insert order would read them all first.
            for schema, channel, message in reader.iter_messages(wanted, log_time_order=True):
                yield LogRecord(
                    channel.topic,
                    schema.name if schema is not None else "",
                    channel.message_encoding,
                    message.log_time,
                    message.data,
                )
        except _BROKEN as exc:
            self._broken(exc)

    def _records_streaming(self, wanted: set[str] | None) -> Iterator[LogRecord]:
        self._stream.seek(0)
        reader = StreamReader(
            self._stream, validate_crcs=True, record_size_limit=_RECORD_SIZE_LIMIT
        )
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        try:
            for record in reader.records:
                if isinstance(record, Message):
                    channel = channels[record.channel_id]
                    if wanted is not None and channel.topic not in wanted:
                        continue
                    schema = schemas.get(channel.schema_id)
                    yield LogRecord(
                        channel.topic,
                        schema.name if schema is not None else "",
                        channel.message_encoding,
                        record.log_time,
                        record.data,
                    )
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Schema):
                    schemas[record.id] = record
        except _BROKEN as exc:
            self._broken(exc)

    def _broken(self, exc: BaseException) -> None:
        if self.complete or self.problem is None:
            self.problem = _describe(exc, self.name)
        self.complete = False

    def close(self) -> None:
        if self._owned is not None:
            self._owned.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def open_log(source: str | os.PathLike[str] | IO[bytes], *, streaming: bool = False) -> LogReader:
    """An agrifleet log opened for reading (a context manager); see :class:`LogReader`."""
    return LogReader(source, streaming=streaming)


def read_log(source: str | os.PathLike[str] | IO[bytes], *, streaming: bool = False) -> LogContents:
    """Everything in an agrifleet log, in memory. Raises :class:`RecordingError` if
    ``source`` is not an MCAP file or not an agrifleet log."""
    with LogReader(source, streaming=streaming) as log:
        records = list(log.records())
        return LogContents(
            source=log.name,
            profile=log.profile,
            library=log.library,
            metadata=dict(log.metadata),
            records=records,
            complete=log.complete,
            problem=log.problem,
        )


def log_files(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The log files named by ``paths``: files as given, and every ``*.mcap`` directly in
    a directory (by name); each file once, however often and by whatever path it is named
    (through a link to its folder, say). Raises :class:`RecordingError` for a path that
    does not exist, a directory without logs, or no path at all."""
    files: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = sorted(p for p in path.glob("*.mcap") if p.is_file())
            if not found:
                raise RecordingError(f"{path} holds no .mcap log")
            files.extend(found)
        elif path.exists():
            files.append(path)
        else:
            raise RecordingError(f"cannot open log {path}: no such file or directory")
    if not files:
        raise RecordingError("no log given")
    once: dict[Path, Path] = {}
    for path in files:
        once.setdefault(path.resolve(), path)
    return list(once.values())


def read_logs(paths: Iterable[str | os.PathLike[str]]) -> LogContents:
    """Several logs of one run (a dispatcher restarted mid-run writes a new file) read as
    one: the files of ``paths`` (see :func:`log_files`) in order of their start time, their
    messages merged in log-time order, a message that an earlier file holds too counted
    once (a copy of a log, or of the part of it written by then: read twice, a run's track
    and events would count twice). Header and metadata are those of the first file;
    ``complete`` is that of the last (an earlier one cut short is where the dispatcher was
    restarted); ``problem`` joins the problems of every file, each naming its file.

    A run is the logs of one farm with the same :data:`RUN_STARTED_KEY` (logs written
    before it was kept count as one run). One folder given that holds several runs (a
    dispatcher's ``--log-dir`` over days) is read as its latest run, and ``note`` says so
    and names the others. Raises :class:`RecordingError` for a file that is not an
    agrifleet log, or for files given of different farms or runs."""
    given = [Path(p) for p in paths]
    files = log_files(given)
    # A file of no bytes beside others (a dispatcher killed as it opened it): left out.
    blank = [f for f in files if len(files) > 1 and Path(f).stat().st_size == 0]
    if len(blank) == len(files):
        blank = []  # nothing else: said to be empty (read_log)
    logs = [read_log(path) for path in files if path not in blank]
    if len(logs) == 1 and not blank:
        return logs[0]
    notes = []
    empty = [log for log in logs if not log.records]
    if not empty or len(empty) == len(logs):
        empty = []  # none, or nothing else
    logs = [log for log in logs if log not in empty]  # a dispatcher killed as it started
    left_out = [Path(f).name for f in blank] + [Path(e.source).name for e in empty]
    if left_out:
        notes.append("left out, as they hold nothing: " + ", ".join(sorted(left_out)))
    logs.sort(key=_start_key)
    one_folder = len(given) == 1 and given[0].is_dir()
    runs: dict[tuple[str | None, str | None], list[LogContents]] = {}
    for log in logs:
        runs.setdefault(_run_of(log), []).append(log)
    if len(runs) > 1 and one_folder:
        latest = max(runs.values(), key=lambda run: _start_key(run[0]))
        others = [run for run in runs.values() if run is not latest]
        notes.insert(
            0,
            f"{given[0]} holds {len(runs)} runs; reviewing the latest, "
            f"{_run_listing(latest)}; the others: "
            + "; ".join(_run_listing(run) for run in others)
            + " (give a run's files to review it)",
        )
        logs = latest
    elif len(runs) > 1:
        farms = {log.metadata.get("farm_id") for log in logs}
        what = "farms" if len(farms) > 1 else "runs"
        raise RecordingError(
            f"these logs are of different {what}, not one run: "
            + "; ".join(_run_listing(run) for run in runs.values())
        )
    note = "; ".join(notes) or None
    if len(logs) == 1:
        return dataclasses.replace(logs[0], note=note)
    first, last = logs[0], logs[-1]
    # Each file is in log-time order (or nearly, if cut short): a stable sort merges them.
    seen: set[LogRecord] = set()
    merged: list[LogRecord] = []
    for log in logs:
        merged.extend(record for record in log.records if record not in seen)
        seen.update(log.records)
    records = sorted(merged, key=lambda r: r.log_time_ns)
    problems = [log.problem for log in logs if log.problem]
    if one_folder and len(runs) == 1:
        source = str(given[0])
    else:
        source = f"{first.source} (+{len(logs) - 1} more)"
    return LogContents(
        source=source,
        profile=first.profile,
        library=first.library,
        metadata=dict(first.metadata),
        records=records,
        complete=last.complete,
        problem="; ".join(problems) if problems else None,
        note=note,
    )


def _run_of(log: LogContents) -> tuple[str | None, str | None]:
    """Which run a log is of: its farm and when its run began (None for a log written
    before that was kept)."""
    return log.metadata.get("farm_id"), log.metadata.get(RUN_STARTED_KEY)


def _run_listing(run: list[LogContents]) -> str:
    """A run for a message: its farm, when it began, its files."""
    farm, started = _run_of(run[0])
    when = f"begun {started}" if started else "begun before runs were told apart"
    files = ", ".join(Path(log.source).name for log in run)
    return f"farm {farm!r} {when} ({files})"


def _start_key(log: LogContents) -> tuple[int, str]:
    """A log's start: its start_time_ns, else its first message, else never."""
    start = log.metadata.get("start_time_ns", "")
    if start.isdigit():
        return int(start), log.source
    first = min((r.log_time_ns for r in log.records), default=2**64)
    return first, log.source


def iter_records(
    source: str | os.PathLike[str] | IO[bytes], topics: Iterable[str] | None = None
) -> Iterator[LogRecord]:
    """The messages of an agrifleet log one by one (of ``topics`` only, if given); a log
    cut short yields what it holds and a warning is logged."""
    with LogReader(source) as log:
        yield from log.records(topics)
        if not log.complete:
            logger.warning("%s", log.problem)


def metadata(source: str | os.PathLike[str] | IO[bytes]) -> dict[str, str]:
    """The "agrifleet" metadata of a log (farm_id, software_version, start_time, plan_id ...)."""
    with LogReader(source) as log:
        return dict(log.metadata)
