"""A Foxglove WebSocket client as the Foxglove app is one (the `websockets` package): connect
with the server's subprotocol, subscribe to a topic once it is advertised, take the first
binary message on it."""

from __future__ import annotations

import asyncio
import json
import struct
from collections.abc import Callable
from typing import Any

import websockets

from dispatcher.recording.live import SUBPROTOCOL

MESSAGE_DATA = 1  # the binary opcode of a message on a subscription
SUBSCRIPTION = 7


async def _first_message(
    url: str, topic: str, after_subscribing: Callable[[], None] | None
) -> tuple[dict[str, Any], bytes]:
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL], open_timeout=5) as ws:
        channel = None
        while channel is None:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
            if msg["op"] == "advertise":
                channel = next((c for c in msg["channels"] if c["topic"] == topic), None)
        request = {
            "op": "subscribe",
            "subscriptions": [{"id": SUBSCRIPTION, "channelId": channel["id"]}],
        }
        await ws.send(json.dumps(request))
        if after_subscribing is not None:
            await asyncio.sleep(0.2)  # the server takes the subscription
            after_subscribing()
        while not isinstance(frame := await asyncio.wait_for(ws.recv(), 5), bytes):
            pass
        opcode, subscription, _log_time = struct.unpack_from("<BIQ", frame)
        assert (opcode, subscription) == (MESSAGE_DATA, SUBSCRIPTION)
        return channel, frame[13:]


def first_message(
    url: str, topic: str, after_subscribing: Callable[[], None] | None = None
) -> tuple[dict[str, Any], bytes]:
    """The channel advertised for ``topic`` and the payload of the first message on it
    (``after_subscribing`` is called once subscribed, to make one)."""
    return asyncio.run(_first_message(url, topic, after_subscribing))
