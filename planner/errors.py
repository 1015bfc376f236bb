"""The planner's exceptions: one hierarchy, messages a farm operator can act on; and the
:class:`Deadline` a time-limited plan is held to (whose expiry raises :class:`TimeLimitError`)."""

from __future__ import annotations

import math
import time


class PlannerError(Exception):
    """Base of every error the planner raises on bad input."""


class ProblemError(PlannerError, ValueError):
    """A problem instance (machines, tasks, arrays) is not valid."""


class NothingLeftError(ProblemError):
    """A re-plan finds no work left: every field done, or what is left of it in the part of
    a mission a vehicle keeps."""


class TSPLIBError(PlannerError, ValueError):
    """A TSPLIB file cannot be read; the message names the file and line."""


class GeometryError(PlannerError, ValueError):
    """A field polygon or coordinate cannot be used; the message names the field."""


class TimeLimitError(PlannerError):
    """Work that must come before any plan (a field's coverage) did not finish within the
    time limit; the message names the field and what took the time."""


class Deadline:
    """The moment (on :func:`time.monotonic`) by which a time-limited piece of work must be
    done: ``seconds`` from when it is made, or never (``None``).

    Long loops call :meth:`check`, which raises :class:`TimeLimitError` once the moment has
    passed; anytime work (the solver) asks :meth:`expired` and returns its best so far."""

    __slots__ = ("at", "seconds")

    def __init__(self, seconds: float | None = None) -> None:
        if seconds is not None and not (isinstance(seconds, int | float) and seconds > 0):
            raise ValueError(f"the time limit must be a positive number of seconds, not {seconds}")
        self.seconds = None if seconds is None else float(seconds)
        self.at = math.inf if seconds is None else time.monotonic() + float(seconds)

    @property
    def limited(self) -> bool:
        return self.at < math.inf

    def left(self) -> float:
        """Seconds left (negative once past; infinite without a limit)."""
        return self.at - time.monotonic() if self.limited else math.inf

    def expired(self) -> bool:
        return self.limited and time.monotonic() >= self.at

    def check(self, what: str, doing: str = "") -> None:
        """Raise :class:`TimeLimitError` ("``what``: not done within the time limit of S s
        (stopped while ``doing``)") once the deadline has passed."""
        if self.limited and time.monotonic() >= self.at:
            where = f" (stopped while {doing})" if doing else ""
            raise TimeLimitError(
                f"{what}: not done within the time limit of {self.seconds:g} s{where}"
            )

    def __repr__(self) -> str:
        if not self.limited:
            return "Deadline(None)"
        return f"Deadline({self.seconds:g}, {self.left():.3f} s left)"


NO_DEADLINE = Deadline()
"""A deadline that never passes (the default of everything that takes one)."""
