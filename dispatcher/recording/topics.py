"""The run's channels: topic names, schemas and message building, one owner for the MCAP
log and the live view (``dispatcher.recording.live``), so both carry the same messages on
the same topics.

The ``foxglove.*`` messages are built with the foxglove-sdk's typed messages and carry its
schemas (protobuf); the ``agrifleet.*`` ones are JSON with our own loose JSON Schemas.
:func:`decode` turns any of them back into a plain dict (the protobuf ones into the shape
of Foxglove's JSON schemas: ``timestamp`` as ``{sec, nsec}``, enums as integers), so logs
written before the switch to protobuf read the same.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any, Final

from foxglove.messages import (
    GeoJson,
    KeyValuePair,
    LocationFix,
    LocationFixPositionCovarianceType,
    Log,
    LogLevel,
    Timestamp,
)
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError

from dispatcher.link import wire

LOG_TOPIC: Final = "/log"
PLAN_GEOJSON_TOPIC: Final = "/plan/geojson"
FIELDS_GEOJSON_TOPIC: Final = "/fields/geojson"
"""The fields coloured by their state (``FIELD_STATE_COLOURS``), at each status."""
EVENTS_TOPIC: Final = "/dispatcher/events"
"""Every change of the fleet state (``dispatcher.daemon.events``), as applied: review
replays them."""

MAVLINK_ENCODING: Final = "mavlink2"
JSON_ENCODING: Final = "json"
PROTOBUF_ENCODING: Final = "protobuf"
JSONSCHEMA_ENCODING: Final = "jsonschema"

FIELD_STATE_COLOURS: Final[dict[str, str]] = {
    "done": "#2ca02c",  # green
    "working": "#ff7f0e",  # orange: in progress
    "pending": "#7f7f7f",  # grey: waiting
}
"""The colour of a field on the map by its status in the status document."""


def location_topic(vehicle_id: str) -> str:
    """The topic of a vehicle's position fixes (``foxglove.LocationFix``)."""
    return f"/vehicle/{vehicle_id}/fix"


def json_topic(key: str) -> str:
    """The topic of the decoded (JSON) twin of the frames on Zenoh key ``key``."""
    return f"{key}/json"


def plan_topic(farm_id: str) -> str:
    """The plan document's topic: its Zenoh key expression."""
    return wire.dispatcher_plan(farm_id)


def status_topic(farm_id: str) -> str:
    """The status document's topic: its Zenoh key expression."""
    return wire.dispatcher_status(farm_id)


# --- schemas ---------------------------------------------------------------------------


@dataclass(frozen=True)
class SchemaDef:
    """A schema as both MCAP and the Foxglove WebSocket protocol want it, with the
    encoding of the messages that use it."""

    name: str
    encoding: str  # the schema's: "protobuf" or "jsonschema"
    data: bytes
    message_encoding: str


def _json_schema(doc: dict[str, Any]) -> SchemaDef:
    data = json.dumps(doc, separators=(",", ":")).encode()
    return SchemaDef(doc["title"], JSONSCHEMA_ENCODING, data, JSON_ENCODING)


def _sdk_schema(message: Any) -> SchemaDef:
    schema = message.get_schema()
    return SchemaDef(schema.name, schema.encoding, bytes(schema.data), PROTOBUF_ENCODING)


MAVLINK_JSON_SCHEMA: Final[dict[str, Any]] = {
    "title": "agrifleet.MAVLink",
    "description": "One decoded MAVLink message: its name and fields (bytes as lists of ints)",
    "type": "object",
    "properties": {"mavpackettype": {"type": "string", "description": "MAVLink message name"}},
    "required": ["mavpackettype"],
    "additionalProperties": True,
}

PLAN_SCHEMA: Final[dict[str, Any]] = {
    "title": "agrifleet.Plan",
    "description": "The dispatcher's plan document (plan.json)",
    "type": "object",
    "properties": {
        "plan_id": {"type": "string"},
        "farm_id": {"type": "string"},
        "objective": {"type": "string"},
        "fields": {"type": "object"},
        "machines": {"type": "array"},
        "totals": {"type": "object"},
    },
    "additionalProperties": True,
}

STATUS_SCHEMA: Final[dict[str, Any]] = {
    "title": "agrifleet.Status",
    "description": "The dispatcher's status of every vehicle and field",
    "type": "object",
    "properties": {
        "plan_id": {"type": "string"},
        "vehicles": {"type": "object"},
        "fields": {"type": "object"},
    },
    "additionalProperties": True,
}

EVENT_SCHEMA: Final[dict[str, Any]] = {
    "title": "agrifleet.Event",
    "description": "A change of the fleet state (dispatcher.daemon.events), as applied",
    "type": "object",
    "properties": {"kind": {"type": "string"}, "vehicle": {"type": "string"}},
    "required": ["kind", "vehicle"],
    "additionalProperties": True,
}

SCHEMAS: Final[dict[str, SchemaDef]] = {
    s.name: s
    for s in (
        _sdk_schema(LocationFix),
        _sdk_schema(GeoJson),
        _sdk_schema(Log),
        *map(_json_schema, (MAVLINK_JSON_SCHEMA, PLAN_SCHEMA, STATUS_SCHEMA, EVENT_SCHEMA)),
    )
}
LOCATION_FIX: Final = "foxglove.LocationFix"
GEOJSON: Final = "foxglove.GeoJSON"
LOG: Final = "foxglove.Log"
MAVLINK_JSON: Final = "agrifleet.MAVLink"
PLAN: Final = "agrifleet.Plan"
STATUS: Final = "agrifleet.Status"
EVENT: Final = "agrifleet.Event"
assert {LOCATION_FIX, GEOJSON, LOG} <= set(SCHEMAS), "foxglove-sdk renamed a schema"


# --- building messages -----------------------------------------------------------------

_LOG_LEVELS: Final[dict[str, LogLevel]] = {
    "debug": LogLevel.Debug,
    "info": LogLevel.Info,
    "warn": LogLevel.Warning,
    "warning": LogLevel.Warning,
    "error": LogLevel.Error,
    "critical": LogLevel.Fatal,
    "fatal": LogLevel.Fatal,
}


def _timestamp(ns: int) -> Timestamp:
    sec, nsec = divmod(ns, 1_000_000_000)
    return Timestamp(sec, nsec)


def location_fix(
    vehicle_id: str,
    lat: float,
    lon: float,
    log_time_ns: int,
    *,
    altitude_m: float = 0.0,
    heading_deg: float | None = None,
    sim_time_s: float | None = None,
) -> bytes:
    """A ``foxglove.LocationFix`` (encoded): the position in degrees, the heading when known
    (given in degrees clockwise from north, written in radians clockwise from north as
    Foxglove's schema has it), the vehicle's own clock as ``sim_time_s`` metadata."""
    metadata = None
    if sim_time_s is not None and math.isfinite(sim_time_s):
        metadata = [KeyValuePair(key="sim_time_s", value=repr(float(sim_time_s)))]
    heading = None
    if heading_deg is not None and math.isfinite(heading_deg):
        heading = math.radians(float(heading_deg) % 360.0)
    return LocationFix(
        timestamp=_timestamp(log_time_ns),
        frame_id=vehicle_id,
        latitude=float(lat),
        longitude=float(lon),
        altitude=float(altitude_m),
        position_covariance=[0.0] * 9,
        position_covariance_type=LocationFixPositionCovarianceType.Unknown,
        heading=heading,
        metadata=metadata,
    ).encode()


def geojson(text: str) -> bytes:
    """A ``foxglove.GeoJSON`` (encoded) holding the GeoJSON document ``text``."""
    return GeoJson(geojson=text).encode()


def log_line(level: str, text: str, log_time_ns: int, *, name: str, file: str, line: int) -> bytes:
    """A ``foxglove.Log`` (encoded); ``level`` is a ``logging`` level name, anything else
    is UNKNOWN."""
    return Log(
        timestamp=_timestamp(log_time_ns),
        level=_LOG_LEVELS.get(level.lower(), LogLevel.Unknown),
        message=text,
        name=name,
        file=file,
        line=max(int(line), 0),
    ).encode()


def fields_state(
    plan_geojson: Mapping[str, Any], status_doc: Mapping[str, Any]
) -> dict[str, Any] | None:
    """The plan's fields as GeoJSON, each coloured by its status in ``status_doc``
    (``FIELD_STATE_COLOURS``) and named with it ("F3: working (t2)"); None when the plan
    has no field."""
    states = status_doc.get("fields") or {}
    features = []
    for feature in plan_geojson.get("features", ()):
        props = feature.get("properties") or {}
        if props.get("kind") != "field":
            continue
        state = states.get(props.get("id")) or {}
        status = str(state.get("status", "pending"))
        by = f" ({state['vehicle']})" if state.get("vehicle") else ""
        features.append(
            {
                "type": "Feature",
                "properties": {
                    "kind": "field_state",
                    "id": props.get("id"),
                    "status": status,
                    "name": f"{props.get('id')}: {status}{by}",
                    "style": {
                        "color": FIELD_STATE_COLOURS.get(status, FIELD_STATE_COLOURS["pending"]),
                        "fillOpacity": 0.35,
                        "weight": 1,
                    },
                },
                "geometry": feature.get("geometry"),
            }
        )
    return {"type": "FeatureCollection", "features": features} if features else None


# --- reading them back -----------------------------------------------------------------


@cache
def _message_class(schema_name: str) -> Callable[[], Any]:
    schema = SCHEMAS[schema_name]
    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for proto in files.file:
        pool.Add(proto)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def _repeated(fd: Any) -> bool:
    if hasattr(fd, "is_repeated"):  # protobuf 6.31 and later have no ``label``
        return bool(fd.is_repeated)
    return bool(fd.label == fd.LABEL_REPEATED)


def _as_dict(message: Any) -> dict[str, Any]:
    """A protobuf message as Foxglove's JSON schemas have it."""
    out: dict[str, Any] = {}
    for fd in message.DESCRIPTOR.fields:
        value = getattr(message, fd.name)
        if fd.message_type is not None and fd.message_type.full_name == (
            "google.protobuf.Timestamp"
        ):
            out[fd.name] = {"sec": value.seconds, "nsec": value.nanos}
        elif fd.message_type is not None:
            if _repeated(fd):
                out[fd.name] = [_as_dict(v) for v in value]
            elif message.HasField(fd.name):
                out[fd.name] = _as_dict(value)
        elif _repeated(fd):
            out[fd.name] = list(value)
        elif fd.has_presence and not message.HasField(fd.name):
            continue  # an optional field not set (a fix's unknown heading)
        else:
            out[fd.name] = value
    return out


def decode(schema_name: str, message_encoding: str, data: bytes) -> Any:
    """A recorded message as a plain value: JSON parsed, protobuf (``foxglove.*``) as the
    dict of Foxglove's JSON schema. Raises ValueError for data that does not decode."""
    if message_encoding != PROTOBUF_ENCODING:
        return json.loads(data)
    if schema_name not in SCHEMAS:
        raise ValueError(f"no schema {schema_name!r} to decode a protobuf message with")
    message = _message_class(schema_name)()
    try:
        message.ParseFromString(data)
    except DecodeError as exc:
        raise ValueError(f"not a {schema_name}: {exc}") from exc
    return _as_dict(message)
