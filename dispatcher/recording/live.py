"""The run live in Foxglove: a Foxglove WebSocket server (foxglove-sdk) fed with every
message the recorder records, on the same topics with the same schemas and bytes
(``dispatcher.recording.topics``); and the Foxglove layout for a farm's log or live view.

Attached to a :class:`~dispatcher.recording.mcap_file.Recorder` (``recorder.live =
view``), a :class:`LiveView` gets each message as it is recorded. Raw MAVLink frames (no
schema Foxglove reads) are not served; their decoded JSON twins are. A client that
subscribes late gets the last message of each state topic (positions, plan, field states,
status) with the next message served, at most a status period later. See docs/foxglove.md.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Final

import foxglove
import foxglove.layouts as fl
from foxglove.websocket import ChannelView, Client, ServerListener, WebSocketServer

from dispatcher.recording import topics
from dispatcher.recording.address import DEFAULT_HOST, DEFAULT_PORT, LiveViewError

__all__ = ["DEFAULT_HOST", "DEFAULT_PORT", "LiveView", "LiveViewError", "layout", "write_layout"]

log = logging.getLogger(__name__)

SUBPROTOCOL: Final = "foxglove.sdk.v1"
LATCHED_SCHEMAS: Final = frozenset(
    {topics.LOCATION_FIX, topics.GEOJSON, topics.PLAN, topics.STATUS}
)
"""Messages that are a state (the latest tells all): a late subscriber gets the last one."""


class _Listener(ServerListener):
    """The server's callbacks (its threads): only note what a late subscriber needs."""

    def __init__(self, view: LiveView) -> None:
        self.view = view

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self.view._lock:
            self.view._resend.add(channel.topic)


class LiveView:
    """A Foxglove WebSocket server on ``host:port`` (port 0: any free one, see
    :attr:`port`), serving what :meth:`publish` is given. Raises :class:`LiveViewError`
    when it cannot listen there. Thread-safe; :meth:`stop` when done."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, name: str = "agrifleet"):
        self._context = foxglove.Context()  # its own: the view serves only what it is given
        self._channels: dict[str, foxglove.Channel] = {}
        self._latched: dict[str, tuple[bytes, int]] = {}
        self._resend: set[str] = set()
        self._lock = threading.Lock()
        try:
            self.server: WebSocketServer = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                context=self._context,
                server_listener=_Listener(self),
            )
        except Exception as exc:  # the SDK raises a RuntimeError of its own making
            raise LiveViewError(
                f"the Foxglove live view cannot listen on {host}:{port}: {exc}"
            ) from exc
        self.host = host
        self.port = self.server.port
        self._stopped = False

    @property
    def url(self) -> str:
        """What to give Foxglove: Open connection → Foxglove WebSocket."""
        return f"ws://{self.host}:{self.port}"

    def publish(
        self, items: Sequence[tuple[str, str, str | None, bytes]], log_time_ns: int
    ) -> None:
        """Serve recorded messages: (topic, message encoding, schema name or None, data)."""
        with self._lock:
            if self._stopped:
                return
            for topic, encoding, schema_name, data in items:
                if schema_name is None:
                    continue  # raw MAVLink: Foxglove has no schema for it
                channel = self._channels.get(topic)
                if channel is None:
                    channel = self._channels[topic] = self._open(topic, encoding, schema_name)
                channel.log(data, log_time=log_time_ns)
                if schema_name in LATCHED_SCHEMAS:
                    self._latched[topic] = (data, log_time_ns)
            resend, self._resend = self._resend, set()
            for topic in resend - {item[0] for item in items}:  # not what was just sent
                if topic in self._latched:
                    data, t_ns = self._latched[topic]
                    self._channels[topic].log(data, log_time=t_ns)

    def _open(self, topic: str, encoding: str, schema_name: str) -> foxglove.Channel:
        schema = topics.SCHEMAS[schema_name]
        return foxglove.Channel(
            topic,
            schema=foxglove.Schema(name=schema.name, encoding=schema.encoding, data=schema.data),
            message_encoding=encoding,
            context=self._context,
        )

    def stop(self) -> None:
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        self.server.stop()


# --- the layout -------------------------------------------------------------------------


def layout(farm_id: str, vehicle_ids: Sequence[str]) -> fl.Layout:
    """A Foxglove layout for a farm's log or live view: the map (fields coloured by state,
    the planned routes, each vehicle's position and heading in its route's colour), the
    status, the dispatcher's log."""
    from dispatcher.mission.map import colour  # the plan's route colours (matplotlib: lazily)

    fixes = [topics.location_topic(vid) for vid in vehicle_ids]
    map_panel = fl.MapPanel(
        title="Fields by state (/fields/geojson), routes (/plan/geojson), tractors",
        config=fl.MapConfig(
            layer="satellite",
            zoom_level=15,
            follow_topic=fixes[0] if fixes else None,
            topic_colors={t: colour(k) for k, t in enumerate(fixes)},
            topic_config={
                t: fl.MapTopicSettings(history_mode="all", show_heading=True, point_size=6)
                for t in fixes
            },
        ),
    )
    status = fl.RawMessagesPanel(
        title="Status of every vehicle and field",
        config=fl.RawMessagesConfig(topic_path=topics.status_topic(farm_id)),
    )
    log_panel = fl.LogPanel(
        title="Dispatcher log (/log)",
        config=fl.LogConfig(topic_to_render=topics.LOG_TOPIC, min_log_level=1),
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3, content=map_panel),
                fl.SplitItem(
                    proportion=2,
                    content=fl.SplitContainer(
                        direction="column",
                        items=[
                            fl.SplitItem(proportion=3, content=status),
                            fl.SplitItem(proportion=2, content=log_panel),
                        ],
                    ),
                ),
            ],
        )
    )


def layout_path(log_path: Path) -> Path:
    """Where a log's layout is written: beside it, ``<log>.layout.json``."""
    return log_path.with_name(log_path.stem + ".layout.json")


def write_layout(path: Path, farm_id: str, vehicle_ids: Sequence[str]) -> Path:
    """Write :func:`layout` to ``path``; returns ``path``."""
    path.write_text(layout(farm_id, vehicle_ids).to_json() + "\n")
    return path
