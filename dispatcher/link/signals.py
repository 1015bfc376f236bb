"""SIGINT and SIGTERM: for every long-running command the handlers only set a flag
(:func:`stop_on_signals`); for the others SIGTERM is Ctrl-C (:func:`sigterm_interrupts`)."""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable
from types import FrameType

log = logging.getLogger(__name__)


def stop_on_signals(stop: threading.Event, what: str = "stopping") -> Callable[[], None]:
    """Make SIGINT/SIGTERM set ``stop``; returns a function that puts the previous handlers
    back. Off the main thread (where Python allows no handlers) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def on_signal(signum: int, frame: FrameType | None) -> None:
        log.info("signal %d: %s", signum, what)
        stop.set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def sigterm_interrupts() -> Callable[[], None]:
    """Make SIGTERM stop a command as Ctrl-C does (KeyboardInterrupt: exit 130, not the
    signal's 143), where the command does not take it itself (:func:`stop_on_signals`);
    returns a function that puts the previous handler back. Off the main thread it does
    nothing."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def interrupt(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)

    def restore() -> None:
        signal.signal(signal.SIGTERM, previous)

    return restore
