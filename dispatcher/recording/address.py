"""Where the live view listens (``--foxglove [HOST:]PORT``): light, so that the command
line can name its defaults without loading the foxglove-sdk."""

from __future__ import annotations

from typing import Final

from dispatcher.config.errors import DispatcherError

DEFAULT_HOST: Final = "127.0.0.1"
DEFAULT_PORT: Final = 8765  # Foxglove's own default for a WebSocket connection


class LiveViewError(DispatcherError, ValueError):
    """A bad ``--foxglove`` address, or a live view that cannot listen there."""


def parse_address(text: str, default_host: str = DEFAULT_HOST) -> tuple[str, int]:
    """``[HOST:]PORT`` (``--foxglove``) as (host, port); port 0 is any free port."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host = default_host
    host = host.strip("[]") or default_host  # [::1]:8765
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise LiveViewError(f"--foxglove wants [HOST:]PORT (e.g. 8765, 0.0.0.0:8765), got {text!r}")
    return host, number
