"""Recording: the MCAP written by Recorder, read back with mcap's own readers (seeking and
streaming) and with ours, files cut short at every byte, bad files, lifecycle, threads."""

from __future__ import annotations

import io
import json
import logging
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap.records import Footer, Header, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import Writer

from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.recording.mcap_file import (
    FLUSH_BOUND_S,
    LIBRARY,
    SCHEMAS,
    SOFTWARE_VERSION,
    Recorder,
    RecorderLogHandler,
    RecorderStateError,
    RecordingError,
    iter_records,
    log_files,
    metadata,
    open_log,
    read_log,
    read_logs,
)

FARM = "changji"
T0 = 1_704_067_200_000_000_000  # 2024-01-01T00:00:00Z
FROM_T1 = wire.vehicle_from(FARM, "t1")
TO_T1 = wire.vehicle_to(FARM, "t1")
PLAN_DOC = {"plan_id": "abc123", "farm_id": FARM, "machines": [{"id": "t1"}]}
GEOJSON = {
    "type": "FeatureCollection",
    "features": [
        {
            "type": "Feature",
            "properties": {"kind": "garage"},
            "geometry": {"type": "Point", "coordinates": [87.0, 44.0]},
        }
    ],
}


def _clock() -> int:
    return T0


def _heartbeat() -> mc.MAVLinkMessage:
    return mc.message(
        "HEARTBEAT",
        type=mc.MAV_TYPE_GROUND_ROVER,
        autopilot=mc.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode=0,
        custom_mode=0,
        system_status=4,
        mavlink_version=3,
    )


def _write_run(rec: Recorder) -> None:
    """A small run touching every record kind."""
    vehicle = mc.Codec(system_id=1, component_id=mc.MAV_COMP_ID_AUTOPILOT1)
    dispatcher = mc.Codec(wire.DISPATCHER_SYSTEM_ID, wire.DISPATCHER_COMPONENT_ID)
    rec.record_plan(PLAN_DOC, GEOJSON, T0)
    for i in range(6):
        t = T0 + (i + 1) * 100_000_000
        hb = _heartbeat()
        rec.record_frame(FROM_T1, vehicle.encode(hb), t, mc.as_dict(hb))
        rec.record_location("t1", 44.0 + i * 1e-5, 87.0, t, i / 10)
        if i % 2:
            rec.record_frame(TO_T1, dispatcher.encode(hb), t + 1, None)
    rec.record_status({"plan_id": "abc123", "vehicles": {"t1": {"phase": "working"}}}, T0 + 10**9)
    rec.record_log("warning", "t1 is slow", T0 + 10**9 + 1)


def _small_log(**options: Any) -> bytes:
    buf = io.BytesIO()
    options = {"chunk_size": 600, "max_chunk_age_s": None, "clock": _clock, **options}
    with Recorder(buf, FARM, {"plan_id": "abc123"}, **options) as rec:
        _write_run(rec)
    return buf.getvalue()


@pytest.fixture(scope="module")
def small_log() -> bytes:
    return _small_log()


EXPECTED_COUNTS = {
    wire.dispatcher_plan(FARM): 1,
    "/plan/geojson": 1,
    FROM_T1: 6,
    FROM_T1 + "/json": 6,
    "/vehicle/t1/fix": 6,
    TO_T1: 3,
    wire.dispatcher_status(FARM): 1,
    "/log": 1,
}


# --- the file, as mcap's own readers see it ------------------------------------------------


def test_seeking_reader_sees_channels_schemas_counts_and_metadata(small_log: bytes) -> None:
    reader = make_reader(io.BytesIO(small_log))
    header = reader.get_header()
    assert (header.profile, header.library) == ("agrifleet", LIBRARY)
    summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == set(EXPECTED_COUNTS)
    counts = {
        summary.channels[cid].topic: n
        for cid, n in summary.statistics.channel_message_counts.items()
    }
    assert counts == EXPECTED_COUNTS
    assert len(summary.chunk_indexes) > 1  # small chunks: the truncation tests need several

    raw = channels[FROM_T1]
    assert (raw.message_encoding, raw.schema_id) == ("mavlink2", 0)
    schema_of = {
        topic: summary.schemas[c.schema_id] for topic, c in channels.items() if c.schema_id
    }
    assert {t: s.name for t, s in schema_of.items()} == {
        wire.dispatcher_plan(FARM): "agrifleet.Plan",
        "/plan/geojson": "foxglove.GeoJSON",
        FROM_T1 + "/json": "agrifleet.MAVLink",
        "/vehicle/t1/fix": "foxglove.LocationFix",
        wire.dispatcher_status(FARM): "agrifleet.Status",
        "/log": "foxglove.Log",
    }
    for topic, schema in schema_of.items():
        ours = SCHEMAS[schema.name]
        assert (schema.encoding, schema.data) == (ours.encoding, ours.data)
        # Foxglove's own schemas as its SDK has them (protobuf), ours as JSON Schema
        foxglove = schema.name.startswith("foxglove.")
        assert schema.encoding == ("protobuf" if foxglove else "jsonschema")
        assert channels[topic].message_encoding == ("protobuf" if foxglove else "json")
    assert len(summary.schemas) == 6  # each registered once

    [meta] = list(reader.iter_metadata())
    assert meta.name == "agrifleet"
    assert meta.metadata["farm_id"] == FARM
    assert meta.metadata["plan_id"] == "abc123"
    assert meta.metadata["software_version"] == SOFTWARE_VERSION
    assert meta.metadata["start_time"] == "2024-01-01T00:00:00+00:00"
    assert meta.metadata["start_time_ns"] == str(T0)

    times = [m.log_time for _, _, m in reader.iter_messages()]
    assert times == sorted(times) and times[0] == T0


def test_stream_reader_sees_every_record(small_log: bytes) -> None:
    records = list(StreamReader(io.BytesIO(small_log), validate_crcs=True).records)
    assert isinstance(records[0], Header)
    assert isinstance(records[-1], Footer)
    assert sum(isinstance(r, Message) for r in records) == sum(EXPECTED_COUNTS.values())
    assert [r.name for r in records if isinstance(r, Metadata)] == ["agrifleet"]


# --- our reader ------------------------------------------------------------------------------


def test_read_log_same_with_seeking_and_streaming_reader(small_log: bytes) -> None:
    with open_log(io.BytesIO(small_log)) as log:
        assert log.reader_kind == "seeking"
    with open_log(io.BytesIO(small_log), streaming=True) as log:
        assert log.reader_kind == "streaming"
    seeking = read_log(io.BytesIO(small_log))
    streaming = read_log(io.BytesIO(small_log), streaming=True)
    for contents in (seeking, streaming):
        assert contents.complete and contents.problem is None
        assert contents.profile == "agrifleet"
        assert contents.topic_counts() == EXPECTED_COUNTS
        assert contents.metadata["plan_id"] == "abc123"
    assert seeking.records == streaming.records


def test_decoded_frame_round_trip(small_log: bytes) -> None:
    log = read_log(io.BytesIO(small_log))
    [raw, *_] = log.on(FROM_T1)
    [decoded, *_] = log.on(FROM_T1 + "/json")
    assert (raw.schema_name, raw.message_encoding) == ("", "mavlink2")
    assert decoded.log_time_ns == raw.log_time_ns == T0 + 100_000_000
    msg = mc.Codec(255, 190).decode_one(raw.data)
    assert msg is not None
    assert decoded.decode_json() == mc.as_dict(msg) == mc.as_dict(_heartbeat())


def test_location_fix_is_foxglove_location_fix(small_log: bytes) -> None:
    fixes = read_log(io.BytesIO(small_log)).on("/vehicle/t1/fix")
    assert [f.schema_name for f in fixes] == ["foxglove.LocationFix"] * 6
    fix = fixes[1].decode_json()
    assert fix == {
        "timestamp": {"sec": 1_704_067_200, "nsec": 200_000_000},
        "frame_id": "t1",
        "latitude": 44.00001,
        "longitude": 87.0,
        "altitude": 0.0,
        "position_covariance": [0.0] * 9,
        "position_covariance_type": 0,
        "metadata": [{"key": "sim_time_s", "value": "0.1"}],
    }  # no heading: not known


def test_location_fix_heading() -> None:
    buf = io.BytesIO()
    with Recorder(buf, FARM) as rec:
        rec.record_location("t1", 44.0, 87.0, T0, heading_deg=370.0)
        rec.record_location("t1", 44.0, 87.0, T0 + 1, heading_deg=float("nan"))
    first, second = (r.decode_json() for r in read_log(buf).on("/vehicle/t1/fix"))
    # Foxglove's LocationFix.heading is in radians clockwise from north.
    assert first["heading"] == pytest.approx(math.radians(10.0)) and "heading" not in second


@pytest.mark.parametrize(
    ("lat", "lon"), [(0.0, 0.0), (91.0, 87.0), (44.0, -181.0), (float("inf"), 87.0)]
)
def test_position_that_is_no_fix_not_recorded(lat: float, lon: float) -> None:
    # An autopilot without a GPS fix reports 0, 0: no LocationFix at the Gulf of Guinea.
    buf = io.BytesIO()
    with Recorder(buf, FARM) as rec:
        rec.record_location("t1", lat, lon, T0, 1.0, heading_deg=90.0)
        rec.record_location("t1", 44.0, 87.0, T0 + 1, 2.0, heading_deg=90.0)
    fixes = [r.decode_json() for r in read_log(buf).on("/vehicle/t1/fix")]
    assert [(f["latitude"], f["longitude"]) for f in fixes] == [(44.0, 87.0)]


def test_field_states_drawn_when_they_change() -> None:
    field = {
        "type": "Feature",
        "properties": {"kind": "field", "id": "F1", "name": "north"},
        "geometry": {"type": "Polygon", "coordinates": [[[87, 44], [87.1, 44], [87, 44.1]]]},
    }
    plan_geo = {**GEOJSON, "features": [*GEOJSON["features"], field]}
    buf = io.BytesIO()
    with Recorder(buf, FARM) as rec:
        rec.record_plan(PLAN_DOC, plan_geo, T0)
        for i, status in enumerate(["pending", "working", "working", "done"]):
            doc = {"vehicles": {}, "fields": {"F1": {"status": status, "vehicle": "t1"}}}
            rec.record_status(doc, T0 + i)
    shown = [json.loads(r.decode_json()["geojson"]) for r in read_log(buf).on("/fields/geojson")]
    assert [c["features"][0]["properties"]["status"] for c in shown] == [
        "pending",
        "working",
        "done",
    ]
    done = shown[-1]["features"][0]
    assert done["geometry"] == field["geometry"]
    assert done["properties"]["style"]["color"] == "#2ca02c"
    assert done["properties"]["name"] == "F1: done (t1)"


def test_plan_geojson_status_and_log_content(small_log: bytes) -> None:
    log = read_log(io.BytesIO(small_log))
    [plan] = log.on(wire.dispatcher_plan(FARM))
    assert plan.decode_json() == PLAN_DOC
    [geo] = log.on("/plan/geojson")
    assert json.loads(geo.decode_json()["geojson"]) == GEOJSON
    [status] = log.on(wire.dispatcher_status(FARM))
    assert status.decode_json()["vehicles"]["t1"]["phase"] == "working"
    [line] = log.on("/log")
    assert line.decode_json() == {
        "timestamp": {"sec": 1_704_067_201, "nsec": 1},
        "level": 3,
        "message": "t1 is slow",
        "name": "dispatcher",
        "file": "",
        "line": 0,
    }


@pytest.mark.parametrize(
    ("level", "number"),
    [("debug", 1), ("INFO", 2), ("warn", 3), ("error", 4), ("critical", 5), ("chatty", 0)],
)
def test_log_levels(level: str, number: int) -> None:
    buf = io.BytesIO()
    with Recorder(buf, FARM) as rec:
        rec.record_log(level, "x", T0)
    [line] = read_log(buf).on("/log")
    assert line.decode_json()["level"] == number


def test_metadata_added_later_and_new_plan_id(small_log: bytes) -> None:
    assert metadata(io.BytesIO(small_log))["plan_id"] == "abc123"
    buf = io.BytesIO()
    with Recorder(buf, FARM, clock=_clock) as rec:
        rec.record_plan(PLAN_DOC, GEOJSON, T0)  # plan id not given up front: taken from the plan
        rec.record_metadata({"vehicles": 3, "note": "rain"})
        rec.record_plan({**PLAN_DOC, "plan_id": "def456"}, GEOJSON, T0 + 1)
        assert rec.metadata["plan_id"] == "def456"
    meta = metadata(buf)
    assert meta["plan_id"] == "def456"
    assert (meta["vehicles"], meta["note"], meta["farm_id"]) == ("3", "rain", FARM)
    assert read_log(buf, streaming=True).metadata == meta


def test_nan_in_decoded_frame_becomes_null() -> None:
    buf = io.BytesIO()
    with Recorder(buf, FARM) as rec:
        rec.record_frame(FROM_T1, b"\xfd", T0, {"mavpackettype": "X", "v": [1.0, float("nan")]})
        rec.record_location("t1", float("nan"), 87.0, T0)  # skipped: JSON cannot carry it
    log = read_log(buf)
    assert log.on(FROM_T1 + "/json")[0].decode_json() == {"mavpackettype": "X", "v": [1.0, None]}
    assert log.on("/vehicle/t1/fix") == []


def test_iter_records_filters_topics(small_log: bytes) -> None:
    got = list(iter_records(io.BytesIO(small_log), topics=["/log", TO_T1]))
    assert Counter(r.topic for r in got) == {"/log": 1, TO_T1: 3}


def test_non_seekable_source(small_log: bytes) -> None:
    class Pipe(io.RawIOBase):
        def __init__(self, data: bytes) -> None:
            self._data = io.BytesIO(data)

        def readable(self) -> bool:
            return True

        def readinto(self, b: Any) -> int:
            chunk = self._data.read(len(b))
            b[: len(chunk)] = chunk
            return len(chunk)

    assert read_log(io.BufferedReader(Pipe(small_log))).topic_counts() == EXPECTED_COUNTS


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compressions(compression: str) -> None:
    data = _small_log(compression=compression)
    assert read_log(io.BytesIO(data)).topic_counts() == EXPECTED_COUNTS
    assert read_log(io.BytesIO(data), streaming=True).topic_counts() == EXPECTED_COUNTS


# --- files cut short ---------------------------------------------------------------------------


def test_truncated_anywhere_gives_a_prefix(small_log: bytes) -> None:
    """Cut at every byte of the data section (header, metadata, chunks) and at every 5th
    byte of the summary after it: never an exception, always complete=False and the
    messages of the finished chunks before the cut."""
    full = read_log(io.BytesIO(small_log)).records
    [footer] = [r for r in StreamReader(io.BytesIO(small_log)).records if isinstance(r, Footer)]
    data_end = footer.summary_start
    assert 0 < data_end < len(small_log)
    cuts = [*range(1, data_end + 1), *range(data_end + 1, len(small_log), 5), len(small_log) - 1]
    previous = 0
    for cut in cuts:
        log = read_log(io.BytesIO(small_log[:cut]))
        assert not log.complete, cut
        assert log.problem and "cut short" in log.problem, cut
        assert log.records == full[: len(log.records)], cut
        assert len(log.records) >= previous, cut
        previous = len(log.records)
        if log.profile:
            assert log.profile == "agrifleet"
    assert previous == len(full)  # cut inside the summary: every message is still there
    assert read_log(io.BytesIO(small_log)).complete


def test_broken_summary_falls_back_to_streaming(small_log: bytes) -> None:
    data = bytearray(small_log)
    footer_fields = len(data) - 8 - 20  # Footer: summary_start, summary_offset_start, crc
    data[footer_fields : footer_fields + 8] = (len(data) * 2).to_bytes(8, "little")
    with open_log(io.BytesIO(bytes(data))) as log:
        assert log.reader_kind == "streaming"
        assert list(log.records()) == read_log(io.BytesIO(small_log)).records
        assert log.complete


@pytest.mark.parametrize("streaming", [False, True])
def test_damaged_chunk_stops_reading_there(small_log: bytes, streaming: bool) -> None:
    summary = make_reader(io.BytesIO(small_log)).get_summary()
    assert summary is not None
    second = summary.chunk_indexes[1]
    data = bytearray(small_log)
    data[second.chunk_start_offset + second.chunk_length - 20] ^= 0xFF  # inside the zstd data
    full = read_log(io.BytesIO(small_log)).records
    log = read_log(io.BytesIO(bytes(data)), streaming=streaming)
    assert not log.complete
    assert log.problem is not None and "broken record" in log.problem
    assert 0 < len(log.records) < len(full) and log.records == full[: len(log.records)]


def test_crash_before_finish_keeps_finished_chunks(tmp_path: Path) -> None:
    rec = Recorder.create_in(tmp_path, FARM, max_chunk_age_s=0.0)  # a chunk per record
    assert rec.path is not None
    for i in range(5):
        rec.record_log("info", f"line {i}", T0 + i)
    rec.drain()  # the writer has taken (and, at age 0, flushed) every record
    # No finish(): read the file as a crash would leave it.
    log = read_log(rec.path)
    assert not log.complete
    assert [r.decode_json()["message"] for r in log.records] == [f"line {i}" for i in range(5)]
    assert log.metadata["farm_id"] == FARM
    rec.finish()
    assert read_log(rec.path).complete


def test_chunks_are_size_bounded_without_age_limit() -> None:
    buf = io.BytesIO()
    rec = Recorder(buf, FARM, chunk_size=1024, max_chunk_age_s=None)
    rec.start()
    for i in range(200):
        rec.record_log("info", f"line {i}", T0 + i)
    rec.drain()
    log = read_log(io.BytesIO(buf.getvalue()))
    assert not log.complete
    assert 100 < len(log.records) < 200  # the chunk being built is not in the file yet
    rec.finish()


# --- not our file ------------------------------------------------------------------------------


def test_empty_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    path.write_bytes(b"")
    with pytest.raises(RecordingError, match=r"empty\.mcap is empty"):
        read_log(path)


def test_not_an_mcap_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(PLAN_DOC))
    with pytest.raises(RecordingError, match=r"plan\.json is not an MCAP file"):
        read_log(path)
    with pytest.raises(RecordingError, match="not an MCAP"):
        metadata(io.BytesIO(b"\x89MCAX0\r\n" + bytes(100)))


def test_missing_file_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot open log .*nope.mcap"):
        read_log(tmp_path / "nope.mcap")


@pytest.mark.parametrize("finished", [True, False])
def test_other_mcap_is_not_an_agrifleet_log(tmp_path: Path, finished: bool) -> None:
    path = tmp_path / "robot.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="rosbag2")
        writer.add_message(writer.register_channel("/chatter", "json", 0), 1, b"{}", 1)
        if finished:
            writer.finish()
    not_ours = r"robot\.mcap is an MCAP file but not an agrifleet log \(profile 'ros2'"
    with pytest.raises(RecordingError, match=not_ours):
        read_log(path)


# --- lifecycle -----------------------------------------------------------------------------------


def test_finish_is_idempotent_and_closes_the_recorder() -> None:
    buf = io.BytesIO()
    rec = Recorder(buf, FARM)
    with pytest.raises(RecorderStateError, match="not started"):
        rec.record_log("info", "too early", T0)
    rec.start()
    with pytest.raises(RecorderStateError, match="already started"):
        rec.start()
    rec.record_log("info", "hello", T0)
    rec.finish()
    size = len(buf.getvalue())
    rec.finish()
    assert len(buf.getvalue()) == size and rec.finished and not buf.closed
    with pytest.raises(RecorderStateError, match="finished"):
        rec.record_frame(FROM_T1, b"\xfd", T0, None)
    with pytest.raises(RecorderStateError, match="finished"):
        rec.record_metadata({"late": 1})
    assert read_log(buf).complete


def test_finish_without_start_leaves_a_valid_log() -> None:
    buf = io.BytesIO()
    Recorder(buf, FARM).finish()
    log = read_log(buf)
    assert log.complete and log.records == [] and log.metadata["farm_id"] == FARM


def test_context_manager_finishes_on_error() -> None:
    buf = io.BytesIO()
    with pytest.raises(KeyError), Recorder(buf, FARM) as rec:
        rec.record_log("info", "before the error", T0)
        raise KeyError("boom")
    log = read_log(buf)
    assert log.complete and len(log.records) == 1


def test_bad_values_are_refused() -> None:
    with pytest.raises(RecordingError, match="farm_id"):
        Recorder(io.BytesIO(), "a/b")
    with Recorder(io.BytesIO(), FARM) as rec:
        with pytest.raises(RecordingError, match="log_time_ns must be integer nanoseconds"):
            rec.record_log("info", "x", 1.5)  # type: ignore[arg-type]
        with pytest.raises(RecordingError, match="cannot record status document"):
            rec.record_status({"x": object()}, T0)


def test_create_in_names_files_by_farm_and_utc_time(tmp_path: Path) -> None:
    first = Recorder.create_in(tmp_path / "logs", FARM, {"plan_id": "p"}, clock=_clock)
    second = Recorder.create_in(tmp_path / "logs", FARM, clock=_clock)
    first.finish()
    second.finish()
    assert first.path == tmp_path / "logs" / "changji-20240101-000000.mcap"
    assert second.path == tmp_path / "logs" / "changji-20240101-000000-1.mcap"
    assert metadata(first.path)["plan_id"] == "p"
    assert read_log(second.path).complete


def test_path_output(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with Recorder(path, FARM) as rec:
        rec.record_location("t2", 44.0, 87.0, T0, altitude_m=512.5)
    [fix] = read_log(str(path)).records
    assert fix.topic == "/vehicle/t2/fix" and fix.decode_json()["altitude"] == 512.5


def test_log_handler_copies_logging_records() -> None:
    buf = io.BytesIO()
    logger = logging.getLogger("agrifleet.test.recording")
    with Recorder(buf, FARM) as rec:
        handler = RecorderLogHandler(rec)
        logger.addHandler(handler)
        try:
            logger.warning("field %s done", "f1")
        finally:
            logger.removeHandler(handler)
    [line] = read_log(buf).on("/log")
    entry = line.decode_json()
    assert (entry["level"], entry["message"], entry["name"]) == (3, "field f1 done", logger.name)
    assert entry["file"].endswith("test_recording.py") and entry["line"] > 0


def test_four_threads_writing() -> None:
    buf = io.BytesIO()
    per_thread = 400
    barrier = threading.Barrier(4)
    errors: list[BaseException] = []

    def work(n: int) -> None:
        try:
            key = wire.vehicle_from(FARM, f"t{n}")
            barrier.wait()
            for i in range(per_thread):
                t = T0 + i * 1000 + n
                rec.record_frame(key, bytes([n, i % 256]), t, {"mavpackettype": "X", "i": i})
                rec.record_location(f"t{n}", 44.0, 87.0, t)
                rec.record_log("info", f"{n}:{i}", t)  # all threads share this channel
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    with Recorder(buf, FARM, chunk_size=4096) as rec:
        threads = [threading.Thread(target=work, args=(n,)) for n in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert errors == []
    log = read_log(buf)
    assert log.complete and len(log.records) == 4 * per_thread * 4
    for n in range(4):
        key = wire.vehicle_from(FARM, f"t{n}")
        assert [r.decode_json()["i"] for r in log.on(key + "/json")] == list(range(per_thread))
        assert [r.data for r in log.on(key)] == [bytes([n, i % 256]) for i in range(per_thread)]
    lines = sorted(r.decode_json()["message"] for r in log.on("/log"))
    assert lines == sorted(f"{n}:{i}" for n in range(4) for i in range(per_thread))
    # Per-channel sequence numbers: each written once, none skipped.
    reader = make_reader(io.BytesIO(buf.getvalue()))
    seqs: dict[int, list[int]] = {}
    for _, channel, message in reader.iter_messages(log_time_order=False):
        seqs.setdefault(channel.id, []).append(message.sequence)
    assert all(sorted(s) == list(range(len(s))) for s in seqs.values())


# --- the writer thread: flush bound, kill -9, back-pressure ------------------------------------

_KILLED_RECORDER = """
import sys, time
from dispatcher.recording.mcap_file import Recorder

rec = Recorder(sys.argv[1], "changji")
rec.start()
begin = time.monotonic()
for i in range(200):  # a record every 10 ms for 2 s
    time.sleep(max(begin + i * 0.01 - time.monotonic(), 0.0))
    t = time.time_ns()
    rec.record_log("info", f"line {i}", t)
    print(i, t, flush=True)
print("quiet", flush=True)
time.sleep(60)
"""


def _wait_for(condition: Any, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.002)


@pytest.mark.parametrize("when", ["mid-run", "quiet"])
def test_kill_9_loses_only_the_last_half_second(tmp_path: Path, when: str) -> None:
    """A recorder killed with SIGKILL, while recording every 10 ms or after it went quiet,
    leaves a file holding every record made more than FLUSH_BOUND_S before the kill."""
    path = tmp_path / "killed.mcap"
    child = subprocess.Popen(
        [sys.executable, "-c", _KILLED_RECORDER, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).parents[2],
    )
    assert child.stdout is not None
    stamps: dict[str, int] = {}
    try:
        for line in child.stdout:
            if line.strip() == "quiet":
                time.sleep(FLUSH_BOUND_S + 0.05)  # the bound is the time that must pass
                break
            i, t = line.split()
            stamps[f"line {i}"] = int(t)
            if when == "mid-run" and len(stamps) == 150:
                break
        kill_ns = time.time_ns()
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait()
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    log = read_log(path)
    assert not log.complete and log.problem is not None and "cut short" in log.problem
    got = [r.decode_json()["message"] for r in log.records]
    assert got == list(stamps)[: len(got)]  # what is there is a prefix, in order
    old_enough = [m for m, t in stamps.items() if t < kill_ns - FLUSH_BOUND_S * 1e9]
    assert len(old_enough) >= (80 if when == "mid-run" else 200)
    assert set(old_enough) <= set(got)
    if when == "quiet":
        assert got == list(stamps)


def test_quiet_record_reaches_the_file_within_the_bound(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with Recorder(path, FARM) as rec:
        recorded = time.monotonic()
        rec.record_log("info", "alone", T0)
        _wait_for(lambda: len(read_log(path).records) == 1, timeout_s=5.0)
        assert time.monotonic() - recorded <= FLUSH_BOUND_S
        assert rec.flush_count == 1


class _GatedStream(io.BytesIO):
    """A stream whose writes wait while ``gate`` is clear (a disk that stalls; ``stalled``
    is set then) and fail once ``fail`` is set (a full disk)."""

    def __init__(self) -> None:
        super().__init__()
        self.gate = threading.Event()
        self.gate.set()
        self.stalled = threading.Event()
        self.fail = False

    def write(self, data: Any) -> int:
        if not self.gate.is_set():
            self.stalled.set()
        self.gate.wait()
        if self.fail:
            raise OSError(28, "No space left on device")
        return super().write(data)


def test_full_queue_blocks_the_caller_and_drops_nothing(caplog: pytest.LogCaptureFixture) -> None:
    stream = _GatedStream()
    rec = Recorder(stream, FARM, queue_size=2, max_chunk_age_s=0.0)
    rec.start()
    stream.gate.clear()
    rec.record_log("info", "line 0", T0)
    assert stream.stalled.wait(10)  # the writer is stuck writing line 0's chunk
    done = threading.Event()

    def record() -> None:
        for i in range(1, 50):
            rec.record_log("info", f"line {i}", T0 + i)
            if i == 20:
                rec.record_metadata({"halfway": i})
        done.set()

    caller = threading.Thread(target=record)
    with caplog.at_level(logging.WARNING, logger="dispatcher.recording.mcap_file"):
        caller.start()
        try:
            _wait_for(lambda: rec.blocked_count == 1)
            assert not done.is_set() and caller.is_alive()  # waiting for room, not dropping
            assert rec._queue.qsize() == 2
        finally:
            stream.gate.set()
        caller.join(timeout=10)
        assert done.is_set()
        rec.finish()
    warnings = [r for r in caplog.records if "is behind" in r.getMessage()]
    assert len(warnings) == 1  # one warning per 10 s however often it waits
    assert "(2 records queued)" in warnings[0].getMessage()
    assert rec.blocked_count >= 1 and rec.blocked_s > 0
    log = read_log(stream)
    assert log.complete and log.metadata["halfway"] == "20"
    assert [r.decode_json()["message"] for r in log.records] == [f"line {i}" for i in range(50)]
    assert rec.message_count == 50


def test_writer_failure_is_raised_to_the_callers_never_hangs_them() -> None:
    stream = _GatedStream()
    rec = Recorder(stream, FARM, queue_size=1, max_chunk_age_s=0.0)
    rec.start()
    stream.fail = True
    with pytest.raises(RecordingError, match="cannot write log <stream>: .*No space left"):
        for i in range(10_000):
            rec.record_log("info", f"line {i}", T0 + i)
            time.sleep(0.0005)
    with pytest.raises(RecordingError, match="No space left"):
        rec.finish()
    assert rec.finished


def test_unfinished_recorder_is_finished_at_exit(tmp_path: Path) -> None:
    path = tmp_path / "forgotten.mcap"
    program = (
        "import sys\n"
        "from dispatcher.recording.mcap_file import Recorder\n"
        "rec = Recorder(sys.argv[1], 'changji', max_chunk_age_s=None)\n"
        "rec.start()\n"
        "for i in range(100):\n"
        "    rec.record_log('info', f'line {i}', 1_704_067_200_000_000_000 + i)\n"
    )
    subprocess.run(
        [sys.executable, "-c", program, str(path)],
        check=True,
        timeout=60,
        cwd=Path(__file__).parents[2],
    )
    log = read_log(path)
    assert log.complete and len(log.records) == 100


def test_flush_writes_the_open_chunk_now(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with Recorder(path, FARM, max_chunk_age_s=None) as rec:
        for i in range(3):
            rec.record_log("info", f"line {i}", T0 + i)
        rec.drain()
        assert read_log(path).records == []  # in the open chunk, in memory
        rec.flush()
        assert len(read_log(path).records) == 3


# --- several files of one run ------------------------------------------------------------------


def _run_file(directory: Path, start_s: int, times_s: list[float], *, finish: bool = True) -> Path:
    start = T0 + start_s * 10**9
    rec = Recorder.create_in(
        directory, FARM, {"plan_id": f"p{start_s}"}, clock=lambda: start, max_chunk_age_s=0.0
    )
    for t in times_s:
        rec.record_log("info", f"at {t}", T0 + int(t * 1e9))
    rec.drain()  # at age 0 every record is in the file now
    assert rec.path is not None
    crashed = rec.path.read_bytes()
    rec.finish()
    if not finish:  # the file as a crash would have left it
        rec.path.write_bytes(crashed)
    return rec.path


def test_read_logs_merges_files_by_time(tmp_path: Path) -> None:
    restarted = _run_file(tmp_path, 30, [30.0, 31.5, 33.0])
    first = _run_file(tmp_path, 0, [0.0, 1.0, 31.0], finish=False)  # cut short by a crash
    (tmp_path / "notes.txt").write_text("not a log")
    for given in ([restarted, first], [tmp_path]):
        log = read_logs(given)
        assert [r.decode_json()["message"] for r in log.records] == [
            "at 0.0",
            "at 1.0",
            "at 30.0",
            "at 31.0",
            "at 31.5",
            "at 33.0",
        ]
        assert log.metadata["plan_id"] == "p0"  # the first file's
        assert log.complete  # the last file is
        assert log.problem is not None and first.name in log.problem
        assert "cut short" in log.problem and restarted.name not in log.problem
    assert read_logs([tmp_path]).source == str(tmp_path)
    assert read_logs([restarted, first]).source == f"{first} (+1 more)"
    assert read_logs([restarted]) == read_log(restarted)


def test_read_logs_reads_a_log_named_twice_once(tmp_path: Path) -> None:
    # The same log by another path (a link to its folder, as pytest's "...current"), a copy
    # of it, or a copy of what it held before it was finished: read twice, a run's records
    # (its track, its events) would count twice.
    logs = tmp_path / "logs"
    logs.mkdir()
    first = _run_file(logs, 0, [0.0, 1.0, 31.0], finish=False)
    _run_file(logs, 30, [30.0, 31.5, 33.0])
    (tmp_path / "current").symlink_to(logs, target_is_directory=True)
    copied = tmp_path / "copied"
    copied.mkdir()
    shutil.copy(first, copied / "renamed.mcap")
    early = tmp_path / "early"  # the same run copied while its file held two messages
    early.mkdir()
    _run_file(early, 0, [0.0, 1.0], finish=False)
    once = read_logs([logs])
    assert len(log_files([logs, tmp_path / "current", first])) == 2
    for given in (
        [logs, tmp_path / "current"],
        [logs, copied],
        [copied, logs, first, tmp_path / "current" / first.name],
        [early, logs],
    ):
        merged = read_logs(given)
        assert merged.records == once.records, given
    # The same message twice in one file is two messages.
    doubled = _run_file(tmp_path, 0, [5.0, 5.0])
    assert len(read_logs([doubled, copied]).records) == 5


def test_read_logs_incomplete_when_the_last_is(tmp_path: Path) -> None:
    _run_file(tmp_path, 0, [0.0])
    last = _run_file(tmp_path, 10, [10.0], finish=False)
    log = read_logs([tmp_path])
    assert not log.complete and log.problem is not None and last.name in log.problem
    assert len(log.records) == 2


def test_read_logs_names_a_damaged_file(tmp_path: Path) -> None:
    good = _run_file(tmp_path, 0, [0.0, 1.0])
    bad = _run_file(tmp_path, 10, [10.0, 11.0])
    summary = make_reader(io.BytesIO(bad.read_bytes())).get_summary()
    assert summary is not None
    chunk = summary.chunk_indexes[1]
    data = bytearray(bad.read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length - 10] ^= 0xFF
    bad.write_bytes(bytes(data))
    log = read_logs([good, bad])
    assert not log.complete
    assert log.problem is not None and f"{bad} has a broken record" in log.problem
    assert [r.decode_json()["message"] for r in log.records] == ["at 0.0", "at 1.0", "at 10.0"]


def test_read_logs_refuses_what_is_not_one_run(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="holds no .mcap log"):
        read_logs([tmp_path])
    with pytest.raises(RecordingError, match="cannot open log .*nope.mcap"):
        read_logs([tmp_path / "nope.mcap"])
    with pytest.raises(RecordingError, match="no log given"):
        read_logs([])
    mine = _run_file(tmp_path, 0, [0.0])
    other = tmp_path / "other.mcap"
    with Recorder(other, "otherfarm", clock=_clock) as rec:
        rec.record_log("info", "x", T0)
    with pytest.raises(RecordingError, match="different farms"):
        read_logs([mine, other])
    (tmp_path / "other.mcap").write_bytes(b"junk")
    with pytest.raises(RecordingError, match=r"other\.mcap is not an MCAP file"):
        read_logs([tmp_path])
