"""What changes the dispatcher's knowledge of its fleet, one event at a time.

:meth:`dispatcher.daemon.state.FleetState.apply` is the only code that turns events into
state; the daemon produces them (from what the vehicles send, from its protocol exchanges
and from its timers), records them to the run's log and replays them on restart, and
``agrifleet review`` replays them from the log: the live status and the review cannot
disagree on when a field was started or finished.

Every event is a frozen dataclass with a ``kind``; :func:`to_dict` / :func:`from_dict`
give its JSON form (``{"kind": ..., field: value, ...}``).
"""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, fields
from typing import Any, ClassVar


@dataclass(frozen=True)
class Event:
    kind: ClassVar[str] = ""
    vehicle: str


@dataclass(frozen=True)
class VehicleSeen(Event):
    """The vehicle is there: its liveliness token, or a message after a loss of link."""

    kind: ClassVar[str] = "vehicle_seen"


@dataclass(frozen=True)
class VehicleLost(Event):
    """Token gone, heartbeats stopped, or never came alive."""

    kind: ClassVar[str] = "vehicle_lost"
    why: str


@dataclass(frozen=True)
class VehicleStalled(Event):
    """Armed in AUTO and heard, but it got nowhere for ``seconds`` of its own time: lost
    until it moves again."""

    kind: ClassVar[str] = "vehicle_stalled"
    seconds: float


@dataclass(frozen=True)
class UploadStarted(Event):
    """A mission upload begins: its first ``items`` (a window of it, mission/window.py;
    0: the whole mission)."""

    kind: ClassVar[str] = "upload_started"
    attempt: int
    items: int = 0


@dataclass(frozen=True)
class WindowExtended(Event):
    """A driving vehicle is given more of its mission (a top-up, or a re-planned route
    uploaded under way): it is to hold the first ``items`` (mission/window.py)."""

    kind: ClassVar[str] = "window_extended"
    items: int


@dataclass(frozen=True)
class UploadFailed(Event):
    """An upload attempt failed; ``final`` when no attempt is left."""

    kind: ClassVar[str] = "upload_failed"
    reason: str
    final: bool


@dataclass(frozen=True)
class UploadAcked(Event):
    """The vehicle acknowledged the whole mission: what it holds is the plan's."""

    kind: ClassVar[str] = "upload_acked"


@dataclass(frozen=True)
class MissionNumbered(Event):
    """The vehicle acknowledged a mission of ``count`` items (home included) that begins at
    the plan's item ``base`` (its item 1; dispatcher/link/numbering.py): its reports are
    read in those numbers from now on."""

    kind: ClassVar[str] = "mission_numbered"
    base: int
    count: int


@dataclass(frozen=True)
class Resumed(Event):
    """The dispatcher restarted on its stored state: the vehicle is to be heard again and
    asked where it is before anything is sent to it."""

    kind: ClassVar[str] = "resumed"


@dataclass(frozen=True)
class StartRequested(Event):
    """The mission was acknowledged; the start sequence runs from ``item``."""

    kind: ClassVar[str] = "start_requested"
    item: int


@dataclass(frozen=True)
class MissionStarted(Event):
    """Armed and in AUTO from ``item``."""

    kind: ClassVar[str] = "mission_started"
    item: int


@dataclass(frozen=True)
class StartFailed(Event):
    kind: ClassVar[str] = "start_failed"
    reason: str


@dataclass(frozen=True)
class AnsweringAgain(Event):
    """A vehicle failed for want of answers (its upload or its start), its work given to
    the others, acknowledged a command of ours: it hears us again and may be given work."""

    kind: ClassVar[str] = "answering_again"


@dataclass(frozen=True)
class StartRefused(Event):
    """The vehicle refused to arm or to start (pre-arm checks ...); asked again."""

    kind: ClassVar[str] = "start_refused"
    reason: str


@dataclass(frozen=True)
class LeftAuto(Event):
    """A running vehicle is out of AUTO or disarmed, not by our doing: ``by_operator``
    when neither its failsafe said so nor we told it to HOLD (left alone until put back in
    AUTO), else a failsafe's (started again once it hears us). It does not drive its
    mission."""

    kind: ClassVar[str] = "left_auto"
    reason: str
    by_operator: bool = False


@dataclass(frozen=True)
class BackInAuto(Event):
    """A vehicle that had left AUTO drives its mission again."""

    kind: ClassVar[str] = "back_in_auto"


@dataclass(frozen=True)
class ItemReached(Event):
    """MISSION_ITEM_REACHED ``seq`` at ``clock_s`` on the vehicle's run clock;
    ``caught_up`` when the vehicle did not say so but its MISSION_CURRENT shows it went
    past (items it reached while the dispatcher was down; ``clock_s`` is then when that was
    learnt)."""

    kind: ClassVar[str] = "item_reached"
    seq: int
    clock_s: float
    caught_up: bool = False


@dataclass(frozen=True)
class Rebooted(Event):
    """The autopilot restarted (its clock went back, or it reported booting again)."""

    kind: ClassVar[str] = "rebooted"


@dataclass(frozen=True)
class SwitchUploaded(Event):
    """A driving vehicle's new mission is on board (its upload acknowledged; it is read
    back next): from now on its reports are about the new mission's items."""

    kind: ClassVar[str] = "switch_uploaded"


@dataclass(frozen=True)
class RouteJoined(Event):
    """A re-planned vehicle that drove past the part of its old mission its new one keeps
    is sent to ``item`` of its new mission: the first not worked already (the swaths it did
    meanwhile are not done again). Items before it count as reached."""

    kind: ClassVar[str] = "route_joined"
    item: int


@dataclass(frozen=True)
class HeldForRoute(Event):
    """A re-planned vehicle reached the end of the part of its old mission its new one
    keeps before the new one was on board: it is told to HOLD there (beyond it, its old
    mission goes on to work the new plan may have given to another) and started on its new
    route once that is on board. Out of AUTO meanwhile by our doing, not a failsafe."""

    kind: ClassVar[str] = "held_for_route"


@dataclass(frozen=True)
class ProgressDoubted(Event):
    """An alarm: the vehicle said it reached item ``seq`` (MISSION_ITEM_REACHED, or
    MISSION_CURRENT past it) but its reported positions never came within reach of
    ``item`` (the first item of the claim it did not pass, :mod:`dispatcher.daemon.plausibility`),
    ``distance_m`` away at the closest. Nothing of the claim counts as done."""

    kind: ClassVar[str] = "progress_doubted"
    seq: int
    item: int
    distance_m: float
    source: str  # the message that claimed it
    field: str | None = None  # the field of the item claimed

    def text(self) -> str:
        where = f" (field {self.field})" if self.field else ""
        return (
            f"{self.vehicle}: {self.source} says item {self.seq}{where} reached, but its track "
            f"never came within reach of item {self.item} ({self.distance_m:g} m at the "
            "closest): not counted"
        )


@dataclass(frozen=True)
class ForeignCommand(Event):
    """An alarm: a frame on the vehicle's command key (``…/mavlink/to``) that the
    dispatcher did not send: ``message`` (its type, or "undecodable"), from MAVLink system
    ``system``, ``signed`` with the vehicle's key or not, ``replayed``: one of the
    dispatcher's own last frames sent again, byte for byte (its signature's time has
    passed); a frame signed anew, whatever its time, is a leaked key. The vehicle's
    mission is read back and restored if it is not the plan's."""

    kind: ClassVar[str] = "foreign_command"
    message: str
    system: int
    signed: bool
    replayed: bool = False

    def text(self) -> str:
        if self.replayed:
            how = "a replay of one of ours: its signature's time has passed, the vehicle refuses it"
        elif self.signed:
            how = "signed with its key: it has leaked"
        else:
            how = "not signed with its key"
        return (
            f"{self.vehicle}: a {self.message} from system {self.system} on its command key, "
            f"not sent by the dispatcher ({how})"
        )


ALARMS = (ProgressDoubted, ForeignCommand)


FLEET = "*"
"""The ``vehicle`` of an event about the whole fleet."""

STORED = "stored"
"""Key of an event a resumed dispatcher copies from its store into its new log (the earlier
log may lack the last of them): review takes these in place of the earlier log's."""


@dataclass(frozen=True)
class PlanReplaced(Event):
    """The rest of the work planned again (``reason``: who was lost): ``document`` is the
    new plan document's JSON form; its machines are the vehicles that go on, each with the
    mission it drives from now on (a driving one: its old mission up to where it is, then
    its new route). ``vehicle`` is :data:`FLEET`."""

    kind: ClassVar[str] = "plan_replaced"
    plan_id: str
    reason: str
    document: dict[str, Any]


def _kinds() -> dict[str, type[Event]]:
    found: dict[str, type[Event]] = {}
    todo = list(Event.__subclasses__())
    while todo:
        cls = todo.pop()
        todo += cls.__subclasses__()
        if not cls.kind or found.setdefault(cls.kind, cls) is not cls:
            raise TypeError(f"event {cls.__name__}: its kind {cls.kind!r} is empty or taken")
    return found


EVENTS: dict[str, type[Event]] = _kinds()
"""Every kind of event by its name: all of this module's (one forgotten in a hand-kept list,
``mission_numbered``, made a store with a renumbered vehicle in it fail to resume, and the
review skip its numbering)."""


def to_dict(event: Event) -> dict[str, Any]:
    return {"kind": event.kind, **asdict(event)}


def from_dict(doc: Any) -> Event:
    """An event from its JSON form; ValueError names what is wrong."""
    if not isinstance(doc, dict) or doc.get("kind") not in EVENTS:
        raise ValueError(f"not an event: {doc!r:.120}")
    cls = EVENTS[doc["kind"]]
    names = [f.name for f in fields(cls)]
    required = [f.name for f in fields(cls) if f.default is MISSING]
    missing = [n for n in required if n not in doc]
    if missing:
        raise ValueError(f"event {doc['kind']!r}: missing {', '.join(missing)}")
    return cls(**{n: doc[n] for n in names if n in doc})
