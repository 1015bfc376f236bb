"""The live view (dispatcher/recording/live.py): what a recorder records is served over the
Foxglove WebSocket protocol on the same topics with the same bytes; a late subscriber gets
the present; the layout written beside each log; the --foxglove address."""

from __future__ import annotations

import io
import json
import math
from typing import Any

import pytest
from helpers.foxglove_client import first_message

from dispatcher.link import wire
from dispatcher.recording import topics
from dispatcher.recording.address import LiveViewError, parse_address
from dispatcher.recording.live import LiveView, layout, layout_path
from dispatcher.recording.mcap_file import Recorder, read_log

FARM = "changji"
T0 = 1_704_067_200_000_000_000
FIELD = {
    "type": "Feature",
    "properties": {"kind": "field", "id": "F1", "name": "north"},
    "geometry": {"type": "Polygon", "coordinates": [[[87, 44], [87.1, 44], [87, 44.1], [87, 44]]]},
}
PLAN_GEO = {"type": "FeatureCollection", "features": [FIELD]}
STATUS = {"plan_id": "p1", "vehicles": {}, "fields": {"F1": {"status": "working"}}}


@pytest.fixture
def live() -> Any:
    view = LiveView(port=0)
    recorder = Recorder(io.BytesIO(), FARM)
    recorder.start()
    recorder.live = view
    yield view, recorder
    recorder.finish()
    view.stop()


def test_a_recorded_fix_is_served_live_as_recorded(live: Any) -> None:
    view, recorder = live
    recorder.record_location("t1", 44.0, 87.0, T0, heading_deg=90.0)  # advertises the channel

    def move() -> None:
        recorder.record_location("t1", 44.001, 87.002, T0 + 1, 1.5, heading_deg=135.0)

    channel, data = first_message(view.url, "/vehicle/t1/fix", move)
    assert (channel["schemaName"], channel["encoding"]) == ("foxglove.LocationFix", "protobuf")
    fix = topics.decode(channel["schemaName"], channel["encoding"], data)
    # the latest position, not the one before the subscription
    assert (fix["frame_id"], fix["latitude"], fix["longitude"]) == ("t1", 44.001, 87.002)
    assert fix["heading"] == pytest.approx(math.radians(135.0))  # radians, as Foxglove has it
    assert fix["metadata"] == [{"key": "sim_time_s", "value": "1.5"}]


def test_a_late_subscriber_gets_the_plan_and_field_states(live: Any) -> None:
    view, recorder = live
    recorder.record_plan({"plan_id": "p1"}, PLAN_GEO, T0)
    recorder.record_status(STATUS, T0 + 1)  # published once each, before anyone looks
    again = {**STATUS, "vehicles": {"t1": {}}}  # the next status: same field states

    for topic in (topics.PLAN_GEOJSON_TOPIC, topics.FIELDS_GEOJSON_TOPIC):
        channel, data = first_message(
            view.url, topic, lambda: recorder.record_status(again, T0 + 2)
        )
        doc = json.loads(topics.decode(channel["schemaName"], channel["encoding"], data)["geojson"])
        assert doc["features"][0]["geometry"] == FIELD["geometry"]
    assert doc["features"][0]["properties"]["status"] == "working"


def test_raw_frames_are_not_served_but_everything_is_recorded(live: Any) -> None:
    view, recorder = live
    key = wire.vehicle_from(FARM, "t1")
    recorder.record_frame(key, b"\xfd\x00", T0, {"mavpackettype": "HEARTBEAT"})
    assert set(view._channels) == {topics.json_topic(key)}


def test_a_taken_port_is_a_clear_error(live: Any) -> None:
    view, _ = live
    with pytest.raises(LiveViewError, match=f"cannot listen on 127.0.0.1:{view.port}"):
        LiveView(port=view.port)


@pytest.mark.parametrize(
    ("text", "address"),
    [
        ("8765", ("127.0.0.1", 8765)),
        ("0.0.0.0:9000", ("0.0.0.0", 9000)),
        ("[::1]:0", ("::1", 0)),
        (":8765", ("127.0.0.1", 8765)),
    ],
)
def test_parse_address(text: str, address: tuple[str, int]) -> None:
    assert parse_address(text) == address


@pytest.mark.parametrize("text", ["", "host:", "x:port", "70000", "-1"])
def test_parse_address_refuses(text: str) -> None:
    with pytest.raises(LiveViewError, match=r"--foxglove wants \[HOST:\]PORT"):
        parse_address(text)


# --- the layout ----------------------------------------------------------------------------


def _panels(node: dict) -> list[dict]:
    if node.get("type") == "panel":
        return [node]
    return [p for item in node["items"] for p in _panels(item["content"])]


def test_layout_for_any_farm_names_its_topics() -> None:
    doc = json.loads(layout("north-farm", ["a", "b", "c"]).to_json())
    panels = {p["panelType"]: p["config"] for p in _panels(doc["content"])}
    assert set(panels) == {"Map", "RawMessages", "Log"}
    assert panels["RawMessages"]["topicPath"] == wire.dispatcher_status("north-farm")
    assert panels["Log"]["topicToRender"] == topics.LOG_TOPIC
    fixes = [topics.location_topic(v) for v in "abc"]
    assert list(panels["Map"]["topicColors"]) == fixes
    assert len(set(panels["Map"]["topicColors"].values())) == 3  # a colour each
    assert all(panels["Map"]["topicConfig"][t]["showHeading"] for t in fixes)


def test_layout_is_written_beside_the_log(tmp_path: Any) -> None:
    log = tmp_path / "changji-20240101-000000.mcap"
    assert layout_path(log) == tmp_path / "changji-20240101-000000.layout.json"


def test_the_log_holds_what_the_live_view_serves() -> None:
    """One owner: the MCAP channel and the live channel carry the same schema and bytes."""
    buf = io.BytesIO()
    with Recorder(buf, FARM) as recorder:
        recorder.record_log("info", "hello", T0)
    [line] = read_log(buf).on(topics.LOG_TOPIC)
    assert line.data == topics.log_line("info", "hello", T0, name="dispatcher", file="", line=0)
    assert line.schema_name == topics.LOG and line.message_encoding == "protobuf"
