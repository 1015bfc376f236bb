"""The dispatcher daemon: plan → upload every mission over Zenoh → start → follow → record.

Shaped like uvicorn's server: :class:`DaemonConfig` → :class:`Dispatcher` with
``startup`` / ``main_loop`` / ``shutdown`` and ``run()``. Signal handlers only set a
flag; shutdown is bounded by a timeout. Zenoh callbacks only queue what arrives (with its
receive time); the main loop decodes, records, updates :class:`FleetState` and answers.

Every frame sent or received is recorded to MCAP with its key expression: the raw bytes
and a decoded JSON view; positions as foxglove.LocationFix; plan and status JSON.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import zenoh

from dispatcher.config.errors import DispatcherError
from dispatcher.config.scenario import TOPUP_LEAD_S, WINDOW_ITEMS
from dispatcher.daemon import events as ev
from dispatcher.daemon.plausibility import REACH_M, leg_end, leg_start, metres, off_leg_m
from dispatcher.daemon.state import (
    ACTIVE,
    CURRENT_SETTLE_S,
    GONE,
    TEXT_WINDOW_S,
    FleetState,
    Phase,
    VehicleState,
)
from dispatcher.daemon.store import Store, StoredRun, StoreError
from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.link.mission_protocol import (
    GCS_HEARTBEAT_PERIOD_S,
    ROVER_MODE_AUTO,
    START_REFUSAL_WINDOW_S,
    Command,
    CommandSequence,
    MissionDownload,
    MissionUpload,
    Outcome,
    RoundTrip,
    gcs_heartbeat,
    hold_commands,
    mission_differences,
    park_commands,
    set_current_command,
    start_mission_commands,
)
from dispatcher.link.numbering import choose_base, command_to_vehicle, count_on_board, on_board
from dispatcher.link.signals import stop_on_signals
from dispatcher.mission.build import (
    IMPLEMENT_LOWERED,
    IMPLEMENT_RAISED,
    implement_down_after,
    implement_set_before,
)
from dispatcher.mission.document import PlannedItem
from dispatcher.mission.job import DispatchJob
from dispatcher.mission.window import shortest, window
from dispatcher.recording.live import LiveView, LiveViewError, layout_path, write_layout
from dispatcher.recording.mcap_file import RUN_STARTED_KEY, Recorder

log = logging.getLogger(__name__)

EXIT_OK = 0
EXIT_INCOMPLETE = 3  # the run ended with fields not done (vehicles failed or lost)
EXIT_INTERRUPTED = 130
LEFT_AUTO = "left AUTO"
LEFT_AUTO_AFTER_S = 5.0
"""Wall seconds a running vehicle may be out of AUTO (or disarmed) before it is flagged."""
OPERATOR_HOLDS = (
    "left to the operator: not armed or started by the dispatcher, and waited for, until "
    "put back in AUTO (it then drives on)"
)
"""What the dispatcher does with a vehicle the operator took out of AUTO (docs/bridge.md)."""
FAILSAFE_CLEAR_WAIT_S = 3.0
"""Wall seconds a vehicle stopped by its ground-station failsafe is to be heard after it
before it is started again without having said the failsafe is over (the text was lost):
three HEARTBEATs of ours have gone to it meanwhile."""
FOREIGN_ALARM_PERIOD_S = 1.0  # at most one foreign-command alarm a second per vehicle
RENUMBER_MARGIN_S = 0.5
"""Wall seconds a driving vehicle is to be at least that far from the item it drives to,
beyond twice the upload's time, for its mission to be renumbered under it."""
PROBE_PERIOD_S = 10.0
"""Wall seconds from a HOLD unanswered to the next, told a vehicle failed for want of
answers whose work went to the others, while it is heard: whether it hears us again
(Dispatcher._probe)."""
FIX_TIMEOUT_S = 120.0
"""Wall seconds a rebooted autopilot has to say where it is (a GPS fix: ArduPilot drives
no mission without one) before its start fails and its work goes to the others (when
there are others and work ahead of it; else it is waited for, with a warning every
FIX_TIMEOUT_S); it is asked again once it says where it is (Dispatcher._probe), and
rejoins if it answers."""
LOWERING_RETRIES = 2
"""Resends of a lowering of the implement (Dispatcher._lower_when_past) before it counts as
unanswered: each send is checked to be still right where the vehicle drives, so few."""
LOWER_WATCH_S = 5.0
"""Wall seconds after a lowering of ours during which the vehicle's MISSION_CURRENT is
watched for the mission's raising (Dispatcher._watch_raising): the lowering may have
reached it after that raising, and MISSION_CURRENT comes about once a second."""
RESUME_ASK_S = 5.0
"""After a restart, how long a booted vehicle has to say which mission it holds
(MISSION_CURRENT.total) before it is taken to hold none of ours and uploaded again."""


SIGNING_RESERVE = 60 * 100_000
"""Signing timestamps the store keeps ahead of the latest used (a minute, in 10 us)."""


class NoWorkLeft(DispatcherError):
    """What a replanner (``DaemonConfig.replanner``) raises when there is no work left to
    give: every field done, or what is left of it in the part of a mission kept. The plan
    goes on as it is; not an error."""


@dataclass
class DaemonConfig:
    job: DispatchJob
    zenoh: wire.ZenohOptions = field(default_factory=wire.dispatcher_options)
    log_dir: Path = Path("logs")
    heartbeat_timeout_s: float = 5.0  # wall seconds without a message: vehicle lost
    stall_after_s: float = 60.0  # its own seconds in AUTO getting nowhere: vehicle lost
    alive_timeout_s: float = 60.0  # wall seconds for every vehicle to show up
    lost_grace_s: float = 30.0  # wall seconds a lost vehicle has to come back before we give up
    upload_attempts: int = 3  # whole uploads tried before a vehicle is failed
    upload_backoff_s: float = 2.0  # pause before the second upload, doubled for each next
    # Whole starts tried on a vehicle still heard whose answers were all lost (a bad radio:
    # 9 tries of one command each time), before it is failed.
    start_attempts: int = 3
    status_period_s: float = 1.0
    shutdown_timeout_s: float = 5.0
    exit_when_done: bool = True
    on_progress: Callable[[FleetState], None] | None = None  # called at status_period_s
    # ... or this often (wall seconds) when shorter: the demo's faults looked for at 200x
    # (the status is still published and recorded at status_period_s)
    progress_period_s: float | None = None
    verify_missions: bool = True  # read each mission back before it is started
    store: Store | None = None  # where events are kept (begun or resumed on ``job``)
    # Plans the rest of the work from a copy of the fleet state, when a vehicle is lost:
    # the next job (dispatcher.tools.replan). Its second argument is set when the re-plan
    # is superseded (another vehicle lost meanwhile): it may stop at once, its result is
    # not used. None: a lost vehicle's work waits for it.
    replanner: Callable[[FleetState, threading.Event], DispatchJob] | None = None
    resume: StoredRun | None = None  # the stored run this one continues
    # Each vehicle's MAVLink signing key (dispatcher/link/keys.py): frames to it are
    # signed, frames from it taken only when signed with it. None: no signing.
    keys: Mapping[str, bytes] | None = None
    # Serve the run live to Foxglove on (host, port) (dispatcher/recording/live.py); None: not.
    foxglove: tuple[str, int] | None = None
    # Missions go in windows of about this many items (dispatcher/mission/window.py); 0: whole.
    window_items: int = WINDOW_ITEMS
    topup_lead_s: float = TOPUP_LEAD_S  # the scenario's [dispatcher] topup_lead_s


class _VehicleSender:
    """Frames to one vehicle, put on Zenoh by a thread of their own.

    Publishers use congestion control BLOCK (a frame is never dropped on a full queue), so
    a put to a vehicle whose link is stalled can block: here it blocks this vehicle's
    thread only, never the main loop, the other vehicles or the status answers."""

    def __init__(self, vid: str, publisher: Any) -> None:
        self.vid = vid
        self.publisher = publisher
        self.frames: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._run, name=f"send-{vid}", daemon=True)
        self.thread.start()

    def send(self, frame: bytes) -> None:
        self.frames.put(frame)

    @property
    def backlog(self) -> int:
        return self.frames.qsize()

    def close(self) -> None:
        self.frames.put(None)

    def _run(self) -> None:
        while (frame := self.frames.get()) is not None:
            try:
                self.publisher.put(frame)
            except Exception:  # noqa: BLE001 - the session is closing; the rest is dropped
                log.debug("%s: frame not sent (session closing)", self.vid, exc_info=True)


def _plan_numbers(doc: dict[str, Any], msg: mc.MAVLinkMessage, v: VehicleState) -> None:
    """A vehicle's report of a mission item, as recorded: with the item in the plan's
    numbers (``plan_seq``, ``plan_total``) when the vehicle's differ (link/numbering.py),
    read as the fleet state is about to read it."""
    numbering = v.numbering
    if numbering.base == 1 and numbering.old_base == 1:
        return
    kind = msg.get_type()
    if kind == "MISSION_CURRENT":
        total = getattr(msg, "total", None)
        seq, plan_total, _ = numbering.report(int(msg.seq), total)
        doc["plan_seq"] = seq
        if plan_total is not None:
            doc["plan_total"] = plan_total
    elif kind == "MISSION_ITEM_REACHED":
        doc["plan_seq"] = numbering.report(int(msg.seq))[0]


def _as_command(item: PlannedItem, optional: bool = False) -> Command:
    """A mission's DO item (the implement's setting) as a command to send in AUTO."""
    return Command(item.command, (item.param1, item.param2), optional=optional)


@dataclass
class _Link:
    """Per-vehicle protocol state: the upload, then the start commands, then parking."""

    upload: MissionUpload | None = None
    download: MissionDownload | None = None  # reading back what a vehicle holds
    start: CommandSequence | None = None
    hold: CommandSequence | None = None  # a lost vehicle told to stop where it is
    park: CommandSequence | None = None
    upload_at: float = 0.0  # not before (back-off after a failed upload)
    start_item: int = 1  # where the mission starts (or resumes after a reboot)
    since: float = 0.0  # when the current exchange began (for the autopilot's texts)
    ready_since: float | None = None  # resuming: when it was first heard booted
    switch_from: int | None = None  # re-planned while driving: the first item of its new route
    join: int | None = None  # and where it went on in it, having driven past the kept part
    topup_from: int | None = None  # topping up: how many items it held before
    sent_on_from: int = 0  # the end of the window it was last started again after
    # The upload under way: (the plan item it begins at, its items with home), the
    # vehicle's numbering once it is acknowledged (link/numbering.py).
    numbered: tuple[int, int] | None = None
    # Renumbered while driving: until it is seen driving the new mission, one whose mission
    # stopped (at the item it drove to from memory, the set-current late) is started again.
    renumbered: bool = False
    rejoin_asked: bool = False  # retired, back: a re-plan was asked to give it work again
    awaiting_fix: float | None = None  # rebooted: waiting for where it is since (said once)
    # Driving with the implement up where its mission has it down (started back at the
    # start of its leg, _start_at; or so found after a restart of ours, _implement_on):
    # (that item, the mission's lowering item, whether it has been seen heading there):
    # the lowering is sent once it is past the item (_lower_when_past). And the lowering
    # sent, and how many times it was sent for want of an answer.
    lower_after: tuple[int, int, bool] | None = None
    lower: CommandSequence | None = None
    lowerings: int = 0
    raising: int | None = None  # ``lower`` is the mission's raising at this item instead
    # After a lowering of ours: (its item, when no answer to it can come any more), for a
    # while: whether the mission raised the implement meanwhile (_watch_raising).
    watch: tuple[int, float] | None = None
    probe_at: float = 0.0  # failed, its work given away: when to ask it to HOLD next
    starts: int = 0  # start attempts unanswered in a row
    failsafe_seen: float = -math.inf  # the last failsafe it was started again after (wall)
    # Seen stopped while its clock ran on, by no failsafe's doing nor ours: the operator's,
    # should it reboot before that is said (LEFT_AUTO_AFTER_S); until it drives again.
    stopped_by_operator: bool = False
    heard_at: float | None = None  # when this process first heard the vehicle
    round_trip: RoundTrip = field(default_factory=RoundTrip)  # measured by its transfers

    def exchanges(self) -> tuple[MissionUpload | MissionDownload | CommandSequence | None, ...]:
        return (self.upload, self.download, self.start, self.hold, self.park, self.lower)

    @property
    def busy(self) -> bool:
        """An upload, download or command sequence with the vehicle is under way."""
        return any(x is not None and x.outcome is Outcome.RUNNING for x in self.exchanges())


class Dispatcher:
    def __init__(self, config: DaemonConfig) -> None:
        self.config = config
        self.job = config.job
        self.farm = self.job.farm_id
        self.store = config.store
        self.state = config.resume.replay() if config.resume else FleetState(self.job.document)
        # One codec per vehicle (its signing key, its streams' timestamps); an unsigned one
        # reads what anything else sends, for the recording only.
        self.codec = mc.Codec(wire.DISPATCHER_SYSTEM_ID, wire.DISPATCHER_COMPONENT_ID)
        self._signed_until = self.store.signing_timestamp() if self.store is not None else 0
        keys = config.keys or {}
        self.codecs = {
            vid: mc.Codec(
                wire.DISPATCHER_SYSTEM_ID,
                wire.DISPATCHER_COMPONENT_ID,
                key=keys.get(vid),
                timestamp=self._signed_until,
            )
            for vid in self.state.vehicles
        }
        # Whether a foreign frame on a vehicle's command key is signed with its key (a leak).
        self.command_checks = {
            vid: mc.Codec(wire.DISPATCHER_SYSTEM_ID, wire.DISPATCHER_COMPONENT_ID, key=key)
            for vid, key in keys.items()
        }
        self.foreign_frames: dict[str, int] = {}  # frames on a vehicle's key not sent by us
        # When each vehicle's last alarm of a kind of foreign frame was raised (by kind: a
        # decoy of one kind must not silence the next), and the vehicles whose mission is
        # read back again once the read-back under way ends.
        self._foreign_alarmed: dict[tuple[str, str], float] = {}
        self._check_again: set[str] = set()
        self._command_exprs: dict[str, zenoh.KeyExpr] | None = None  # (_addressed's)
        missing = [vid for vid in self.state.vehicles if config.keys and vid not in keys]
        if missing:
            raise ValueError(f"no signing key for {', '.join(missing)}")
        self.should_exit = threading.Event()
        self.inbox: queue.Queue[tuple[str, str, bytes, int]] = queue.Queue()
        self.links = {vid: _Link() for vid in self.state.vehicles}
        self.session: zenoh.Session | None = None
        self.recorder: Recorder | None = None
        self.live: LiveView | None = None
        self.publishers: dict[str, Any] = {}
        self._entities: list[Any] = []
        self._last_status = self._last_progress = 0.0
        self._next_heartbeat = 0.0
        self._started = time.monotonic()
        self.log_path: Path | None = None
        self._status_json = "{}"  # the last status, serialised in the main loop
        self._plan_json = self.job.document.to_json()  # the current plan, for late joiners
        self.senders: dict[str, _VehicleSender] = {}
        self.upload_started: float | None = None
        self.all_acknowledged: float | None = None
        self._replan_reason = ""  # a re-plan is wanted (why)
        self._replan_wanted_at = 0.0  # since when (the first ask not yet answered)
        self._replan: threading.Thread | None = None
        self._replan_cancel = threading.Event()  # the re-plan under way is superseded
        self._replan_asked: tuple[str, float] = ("", 0.0)  # the one under way: why, since
        self._replanned: tuple[DispatchJob, str, float] | Exception | None = None
        # Per re-plan: reason, seconds from the loss to the new plan, and to every changed
        # mission acknowledged (None until then).
        self.replans: list[list[Any]] = []
        self._awaiting_acks: tuple[int, set[str], float] | None = None
        self._adopted_at = 0.0
        # Each one's last upload: wall seconds it took, items uploaded and read back.
        self._upload_took: dict[str, tuple[float, int]] = {}
        self.topups: list[tuple[str, int]] = []  # (vehicle, items uploaded) per top-up
        self.window_waits = 0  # top-ups that came after the vehicle reached its window's end

    # --- lifecycle -----------------------------------------------------------------------
    def run(self) -> int:
        """Start, run until every field is done (or a signal), shut down; an exit code."""
        restore_signals = stop_on_signals(self.should_exit, "shutting down")
        try:
            self.startup()
            code = self.main_loop()
        finally:
            self.shutdown()
            restore_signals()
        return code

    def startup(self) -> None:
        cfg = self.config
        self._started = time.monotonic()
        # The logs of one run share when it began, a resumed run's too (read_logs).
        run_started = self.store.run_started if self.store is not None else None
        began = datetime.fromtimestamp(run_started or time.time(), UTC).isoformat()
        self.recorder = Recorder.create_in(
            cfg.log_dir,
            self.farm,
            metadata={"plan_id": self.job.plan_id, RUN_STARTED_KEY: began},
        )
        self.log_path = Path(self.recorder.path) if self.recorder.path else None
        log.info("recording to %s", self.log_path)
        self._start_live_view()
        self.session = cfg.zenoh.open()
        s = self.session
        self._entities.append(
            s.declare_subscriber(
                f"{wire.PREFIX}/{self.farm}/vehicle/*/mavlink/from", self._on_frame
            )
        )
        # Commands on a vehicle's key from anyone but us (our own are local): alarms.
        self._entities.append(
            s.declare_subscriber(
                wire.vehicle_to(self.farm, "*"),
                self._on_command,
                allowed_origin=zenoh.Locality.REMOTE,
            )
        )
        self._entities.append(
            s.liveliness().declare_subscriber(
                f"{wire.PREFIX}/{self.farm}/vehicle/*/alive", self._on_liveliness, history=True
            )
        )
        self._entities.append(
            s.declare_queryable(wire.dispatcher_status(self.farm), self._on_query)
        )
        self._entities.append(  # a late joiner asks for the plan (docs/link.md)
            s.declare_queryable(wire.dispatcher_plan(self.farm), self._on_plan_query)
        )
        for vid in self.state.vehicles:
            self.publishers[vid] = s.declare_publisher(
                wire.vehicle_to(self.farm, vid), congestion_control=zenoh.CongestionControl.BLOCK
            )
        self.senders = {
            vid: _VehicleSender(vid, self.publishers[vid]) for vid in self.state.vehicles
        }
        self.publishers["plan"] = s.declare_publisher(wire.dispatcher_plan(self.farm))
        now_ns = time.time_ns()
        self.recorder.record_plan(self.job.document.to_dict(), dict(self.job.geojson), now_ns)
        self.publishers["plan"].put(self._plan_json)
        if cfg.resume is not None:
            self._resume_run(cfg.resume)
        self._log(
            "info",
            f"plan {self.job.plan_id} published; waiting for {len(self.state.vehicles)} vehicles",
        )

    def main_loop(self) -> int:
        while not self.should_exit.is_set():
            try:
                item = self.inbox.get(timeout=0.05)
            except queue.Empty:
                item = None
            now = time.monotonic()
            while item is not None:
                self._handle(item, now)
                try:
                    item = self.inbox.get_nowait()
                except queue.Empty:
                    item = None
            self._tick(now)
            if self.store is not None:
                self.store.commit(self.state)
            if (
                self.config.exit_when_done
                and self.state.finished(now, self.config.lost_grace_s)
                and not self._parking()
                # A re-plan wanted or under way may give a vehicle that is done more work
                # (one failed when the rest were done: the run ended with its fields undone).
                and (
                    self.state.all_fields_done()
                    or (self._replan is None and not self._replan_reason)
                )
            ):
                self._publish_status(now)
                break
        if self.should_exit.is_set():
            self._log("warning", "interrupted")
            return EXIT_INTERRUPTED
        return EXIT_OK if self.state.all_fields_done() else EXIT_INCOMPLETE

    def shutdown(self) -> None:
        """Undeclare, close the session and finish the MCAP file, within the timeout."""
        done = threading.Event()

        for sender in self.senders.values():
            sender.close()
        deadline = time.monotonic() + 1.0  # what was queued goes out first, unless stalled
        for sender in self.senders.values():
            sender.thread.join(max(deadline - time.monotonic(), 0.0))

        def close() -> None:
            try:
                for entity in self._entities:
                    entity.undeclare()
                for pub in self.publishers.values():
                    pub.undeclare()
                if self.session is not None:
                    self.session.close()
            except Exception:  # noqa: BLE001 - shutting down anyway
                log.exception("closing the zenoh session")
            done.set()

        closer = threading.Thread(target=close, daemon=True)
        closer.start()
        done.wait(self.config.shutdown_timeout_s)
        if not done.is_set():
            log.warning("zenoh session did not close within %.1f s", self.config.shutdown_timeout_s)
        # Drain what arrived in the meantime so the log holds every received frame.
        while True:
            try:
                self._record_only(self.inbox.get_nowait())
            except queue.Empty:
                break
        if self.store is not None:
            try:
                self.store.commit(self.state)
                if self.state.all_fields_done():
                    self.store.end_run("done")
            except StoreError as exc:  # (a full disk): the log is still finished below
                log.error("%s", exc)
        if self.recorder is not None:
            self.recorder.record_status(self._status_doc(), time.time_ns())
            self.recorder.finish()
            log.info("log finished: %s", self.log_path)
        if self.live is not None:
            self.live.stop()

    def _start_live_view(self) -> None:
        """Serve what is recorded to Foxglove (``config.foxglove``), and write the log's
        Foxglove layout beside it. A view that cannot listen is reported, the run goes on."""
        if self.log_path is not None:
            write_layout(layout_path(self.log_path), self.farm, list(self.state.vehicles))
        if self.config.foxglove is None or self.recorder is None:
            return
        try:
            self.live = LiveView(*self.config.foxglove, name=f"agrifleet {self.farm}")
        except LiveViewError as exc:
            log.warning("%s; going on without it", exc)
            return
        self.recorder.live = self.live
        log.info("live view for Foxglove on %s", self.live.url)

    # --- zenoh callbacks (other threads): queue only ------------------------------------
    def _on_frame(self, sample: zenoh.Sample) -> None:
        self.inbox.put(("frame", str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))

    def _on_command(self, sample: zenoh.Sample) -> None:
        self.inbox.put(("command", str(sample.key_expr), sample.payload.to_bytes(), time.time_ns()))

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        kind = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
        self.inbox.put((kind, str(sample.key_expr), b"", time.time_ns()))

    def _on_query(self, query: zenoh.Query) -> None:
        # An immutable string: consistent. Its own key, also for a query on dispatcher/*.
        query.reply(wire.dispatcher_status(self.farm), self._status_json)

    def _on_plan_query(self, query: zenoh.Query) -> None:
        query.reply(wire.dispatcher_plan(self.farm), self._plan_json)

    # --- main loop -----------------------------------------------------------------------
    def _handle(self, item: tuple[str, str, bytes, int], now: float) -> None:
        kind, key, payload, t_ns = item
        vid = wire.vehicle_of(key)
        if kind == "command":
            self._foreign_command(key, payload, t_ns, now)
            return
        if vid not in self.state.vehicles:
            self._record_only(item)
            return
        if kind == "alive":
            self._log("info", f"{vid} is alive")
            self._apply(ev.VehicleSeen(vid), now)
            return
        if kind == "gone":
            self._log("warning", f"{vid} dropped its liveliness token")
            self._apply(ev.VehicleLost(vid, "liveliness token dropped"), now)
            return
        msg = self._record_only(item)
        if msg is None:
            return
        v = self.state.vehicles[vid]
        if msg.get_srcSystem() != v.system_id:
            return
        link = self.links[vid]
        for event in self.state.on_message(vid, msg, now):
            if isinstance(event, ev.Rebooted):
                link.awaiting_fix = None  # its wait for a fix counts from this reboot
            if isinstance(event, ev.Rebooted) and link.stopped_by_operator and not v.operator_hold:
                # It rebooted after the operator stopped it: it stays the operator's.
                reason = f"{LEFT_AUTO} before it rebooted"
                self._apply(ev.LeftAuto(vid, reason, by_operator=True), now)
                self._log("warning", f"{vid}: {reason}; {OPERATOR_HOLDS}")
            self._apply(event, now)
        for machine in link.exchanges():
            if machine is not None and machine.outcome is Outcome.RUNNING:
                self._send(vid, machine.on_message(msg, now))
        self._advance(vid, now)

    def _record_only(self, item: tuple[str, str, bytes, int]) -> mc.MAVLinkMessage | None:
        """Record a frame; the message when it is one to act on (from one of our vehicles,
        signed with its key when signing is on)."""
        kind, key, payload, t_ns = item
        if kind != "frame":
            return None
        vid = wire.vehicle_of(key)
        codec = self.codecs.get(vid) if vid is not None else None
        msg = codec.decode_one(payload) if codec is not None else None
        if vid is not None and codec is not None and msg is None and codec.signed:
            self._refused(vid, codec)
        if self.recorder is not None:
            # A refused frame is kept raw only: its decoded twin would read as the vehicle's.
            shown = msg if codec is not None else self.codec.decode_one(payload)
            doc = mc.as_dict(shown) if shown else None
            v = self.state.vehicles.get(vid) if vid is not None else None
            if doc is not None and v is not None and msg is not None:
                _plan_numbers(doc, msg, v)
            self.recorder.record_frame(key, payload, t_ns, doc)
            if (
                v is not None
                and msg is not None
                and msg.get_type() == "GLOBAL_POSITION_INT"
                and msg.get_srcSystem() == v.system_id
            ):
                # With its frame: also those still queued when the run ends (the last
                # position of every tractor, back in the garage, was missing on the map).
                course = mc.course_deg(msg)
                self.recorder.record_location(
                    v.id,
                    msg.lat / 1e7,
                    msg.lon / 1e7,
                    t_ns,
                    msg.time_boot_ms / 1000.0,
                    heading_deg=v.heading_deg if course is None else course,
                )
        return msg

    def _foreign_command(self, key: str, payload: bytes, t_ns: int, now: float) -> None:
        """A frame on a vehicle's command key that this dispatcher did not send: recorded,
        and for each vehicle the key reaches (a key expression with wildcards reaches
        several; a vehicle takes every put its key intersects) an alarm, the first of its
        kind (not signed with the vehicle's key, signed with it: leaked, or a replay of
        ours), then at most one of that kind a second per vehicle; all counted. The
        vehicle's mission is then read back and restored if it is not ours; a frame it may
        have taken (signed with its key, or signing off) that comes while that is under way
        has it read back again after (an alarm's rate limit let the upload that followed a
        decoy go unchecked: review)."""
        msg = self.codec.decode_one(payload)
        if self.recorder is not None:
            self.recorder.record_frame(key, payload, t_ns, mc.as_dict(msg) if msg else None)
        for vid in self._addressed(key):
            self._foreign_one(vid, msg, payload, now)

    def _addressed(self, key: str) -> list[str]:
        """The vehicles whose command key the key expression ``key`` reaches."""
        vid = wire.vehicle_of(key)
        if vid in self.state.vehicles and key == wire.vehicle_to(self.farm, vid):
            return [vid]
        try:
            expr = zenoh.KeyExpr(key)
        except zenoh.ZError:
            return []
        if self._command_exprs is None:
            self._command_exprs = {
                v: zenoh.KeyExpr(wire.vehicle_to(self.farm, v)) for v in self.state.vehicles
            }
        return [v for v, own in self._command_exprs.items() if own.intersects(expr)]

    def _foreign_one(
        self, vid: str, msg: mc.MAVLinkMessage | None, payload: bytes, now: float
    ) -> None:
        """A foreign frame on ``vid``'s command key (:meth:`_foreign_command`)."""
        self.foreign_frames[vid] = self.foreign_frames.get(vid, 0) + 1
        check = self.command_checks.get(vid)
        signed = check is not None and check.decode_one(payload) is not None
        replayed = signed and self.codecs[vid].sent_before(payload)
        taken = (signed and not replayed) or not self.codecs[vid].signed
        v = self.state.vehicles[vid]
        link = self.links.get(vid)
        if taken and v.verify_mission and link is not None and link.download is not None:
            self._check_again.add(vid)  # it may have changed what is being read back
        kind = "replayed" if replayed else "signed" if signed else "unsigned"
        if now - self._foreign_alarmed.get((vid, kind), -math.inf) < FOREIGN_ALARM_PERIOD_S:
            if taken and not v.verify_mission and v.phase is not Phase.FAILED and not v.retired:
                v.verify_mission = True  # read back once more (its alarm was said)
            return
        self._foreign_alarmed[(vid, kind)] = now
        what = msg.get_type() if msg is not None else "undecodable frame"
        system = msg.get_srcSystem() if msg is not None else -1
        self._apply(ev.ForeignCommand(vid, what, system, signed, replayed), now)
        self._log("error", self.state.alarms[-1][2] + f" ({self.foreign_frames[vid]} so far)")

    def _verify(self, v: VehicleState, link: _Link, now: float) -> None:
        """After a command on its key that we did not send: read the vehicle's mission back
        and, when it is not ours, upload ours again and go on where it was (or park it, if
        it was done)."""
        why = "a command on its key we did not send; reading its mission back"
        different = self._read_back(v, link, now, why)
        if different is None:
            return
        link.download = None
        if v.id in self._check_again and not different:
            # A foreign frame it may have taken came while it was read: read it again.
            self._check_again.discard(v.id)
            return
        self._check_again.discard(v.id)
        v.verify_mission = False
        if not different:
            self._log("info", f"{v.id}: its mission read back intact after the foreign command")
        elif v.phase is Phase.DONE:
            self._log("error", f"{v.id}: {different}; parked again (HOLD, disarm)")
            link.park = None
        else:
            link.start_item = v.resume_item
            self._log(
                "error",
                f"{v.id}: {different}; uploading ours again, then going on at item "
                f"{link.start_item}",
            )
            self._upload(v, link, now)

    def _read_back(self, v: VehicleState, link: _Link, now: float, why: str) -> str | None:
        """Read the vehicle's mission back (``why`` is logged as it begins): None while that
        is under way, then "" when it is ours item by item, else what is not."""
        if link.download is None:
            link.download = MissionDownload(v.system_id, round_trip=link.round_trip)
            link.since = now
            self._log("info", f"{v.id}: {why}")
            self._send(v.id, link.download.start(now))
            return None
        if link.download.outcome is Outcome.RUNNING:
            return None
        if link.download.outcome is Outcome.FAILED:
            return f"its mission could not be read back ({link.download.reason})"
        diffs = self._held_differences(v, link.download)
        return f"holds another mission (differs at {', '.join(diffs)})" if diffs else ""

    def _keep_signing_timestamps(self) -> None:
        """Signing timestamps never go back, across a restart too: the store keeps a mark
        a minute ahead of the latest used, and a restarted dispatcher starts from it."""
        if self.store is None:
            return
        latest = max((c.timestamp for c in self.codecs.values() if c.signed), default=0)
        if latest and latest > self._signed_until - SIGNING_RESERVE // 2:
            self._signed_until = latest + SIGNING_RESERVE
            self.store.keep_signing_timestamp(self._signed_until)

    def _refused(self, vid: str, codec: mc.Codec) -> None:
        """A frame on a vehicle's key that is not signed with its key (or is a replay):
        dropped; counted in the status, logged at the first and every hundredth."""
        v = self.state.vehicles[vid]
        stats = codec.signing_stats
        if stats.dropped == v.frames_refused:
            return  # garbage, not a signing matter
        v.frames_refused = stats.dropped
        if v.frames_refused == 1 or v.frames_refused % 100 == 0:
            self._log(
                "warning",
                f"{vid}: dropped {v.frames_refused} frame(s) not signed with its key "
                f"({stats.unsigned} unsigned, {stats.bad} with a wrong signature or replayed)",
            )

    def _tick(self, now: float) -> None:
        self._keep_signing_timestamps()
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + GCS_HEARTBEAT_PERIOD_S
            beat = gcs_heartbeat()
            for vid in self.state.vehicles:
                self._send(vid, [beat])
        for vid, v in self.state.vehicles.items():
            link = self.links[vid]
            for machine in link.exchanges():
                if machine is not None and machine.outcome is Outcome.RUNNING:
                    self._send(vid, machine.on_tick(now))
            self._advance(vid, now)
            if (
                v.phase in ACTIVE
                and v.last_seen is not None
                and now - v.last_seen > self.config.heartbeat_timeout_s
            ):
                self._log("warning", f"{vid}: no message for {self.config.heartbeat_timeout_s:g} s")
                self._apply(ev.VehicleLost(vid, "heartbeats stopped"), now)
                self._hold(v, link, now)  # in case it still hears us
            idle = self.state.stalled_for(v, self.config.stall_after_s, now)
            if idle is not None:
                self._apply(ev.VehicleStalled(vid, round(idle, 1)), now)
                self._log("warning", f"{vid}: {v.error}; told to HOLD")
                self._hold(v, link, now)
            if v.driving:
                link.stopped_by_operator = False
            elif (
                v.stopped_on_clock
                and v.phase is Phase.RUNNING
                and link.hold is None
                and not v.held_for_route
                and v.held_by_failsafe is None
            ):
                link.stopped_by_operator = True
            if (
                v.off_auto_since is not None
                and now - v.off_auto_since > LEFT_AUTO_AFTER_S
                and not v.error.startswith(LEFT_AUTO)
                and not v.retired  # left out of the plan: we told it to HOLD
            ):
                reason = f"{LEFT_AUTO}: mode {v.mode}, {'armed' if v.armed else 'disarmed'}"
                if failsafe := v.held_by_failsafe:
                    reason += f", held by its failsafe ({failsafe})"
                by_operator = not failsafe and link.hold is None and not v.held_for_route
                self._apply(ev.LeftAuto(vid, reason, by_operator=by_operator), now)
                self._log(
                    "warning",
                    f"{vid}: {reason}; not driving its mission"
                    + (f"; {OPERATOR_HOLDS}" if by_operator else ""),
                )
            if v.off_auto_since is None and (
                v.error.startswith(LEFT_AUTO) or (v.operator_hold and v.driving)
            ):
                self._apply(ev.BackInAuto(vid), now)
            if v.phase is Phase.WAITING and now - self._started > self._alive_timeout(v):
                # One left out of the plan before a restart: its work is the others'.
                # (one that worked before the dispatcher's restart did come alive then)
                why = "not heard since the restart" if v.resuming else "never came alive"
                self._log("info" if v.retired else "error", f"{vid}: {why}")
                self._apply(ev.VehicleLost(vid, why), now)
            elif (
                v.phase is Phase.ALIVE
                and v.mode is None  # no HEARTBEAT of it taken
                and link.heard_at is not None
                and now - link.heard_at > self.config.alive_timeout_s
            ):
                # Its liveliness token is there, but no frame of it was taken: a bridge
                # whose autopilot is silent, or frames that fail the key check.
                why = (
                    f"never heard: {v.frames_refused} frame(s) of it refused, not signed "
                    "with its key (is its key file the dispatcher's?)"
                    if v.frames_refused
                    else "never heard: its liveliness token is there, no frame of it came"
                )
                self._log("error", f"{vid}: {why}")
                self._apply(ev.VehicleLost(vid, why), now)
        self._replan_step(now)
        if now - self._last_status >= self.config.status_period_s:
            self._publish_status(now)
        elif (
            self.config.on_progress is not None
            and self.config.progress_period_s is not None
            and now - self._last_progress >= self.config.progress_period_s
        ):
            self._last_progress = now
            self.config.on_progress(self.state)

    def _advance(self, vid: str, now: float) -> None:
        """Move a vehicle's link on: upload once it is alive and booted, start once
        uploaded, start again after a reboot, park once done."""
        v = self.state.vehicles[vid]
        link = self.links[vid]
        self._lower_when_past(v, link, now)
        if v.phase is not Phase.RUNNING or not v.needs_restart or v.operator_hold:
            link.awaiting_fix = None  # (a wait for a fix counts from the last reboot)
        if link.numbered is not None and link.upload is not None:
            if link.upload.outcome is Outcome.DONE:
                self._numbered(v, link, now)
            elif link.upload.outcome is Outcome.FAILED:
                link.numbered = None
        if v.resuming:
            if v.phase is Phase.ALIVE and v.ready and v.mode is not None:
                link.ready_since = link.ready_since or now
                # What it told of its mission, and its clock (the time of the items it
                # reached meanwhile: 0 s before it is heard, FleetState), or what it did
                # not tell in time taken as not known.
                told = v.mission_total is not None and v.clock.now is not None
                if told or now - link.ready_since > RESUME_ASK_S:
                    self._resume(v, link, now)
            return
        if v.switch and v.phase is Phase.RUNNING:
            self._advance_switch(v, link, now)
            return
        if v.retired and v.phase is Phase.FAILED:
            self._probe(v, link, now)
            return
        if v.retired:
            # Its work went to the others: it stays where it is, and rejoins at a re-plan
            # asked for when it is heard again.
            if (
                v.phase not in GONE
                and v.phase is not Phase.DONE
                and not link.rejoin_asked
                and not self._replan_reason
                and self._replan is None
            ):
                link.rejoin_asked = True
                self._want_replan(f"{vid} back", now)
                if link.hold is None or link.hold.outcome is not Outcome.RUNNING:
                    link.hold = CommandSequence(hold_commands(), v.system_id)
                    self._send(vid, link.hold.start(now))
            elif (
                link.rejoin_asked
                and link.park is None
                and v.phase not in GONE
                and v.phase is not Phase.DONE
                and not self._replan_reason
                and self._replan is None
            ):
                # The re-plan asked for gave it nothing (no work left): parked where it
                # stands, not left armed in HOLD.
                link.park = CommandSequence(park_commands(), v.system_id)
                self._log("info", f"{vid}: back, but no work is left for it; HOLD and disarm")
                self._send(vid, link.park.start(now))
            return
        if v.verify_mission and v.phase in (Phase.RUNNING, Phase.DONE) and not v.switch:
            self._verify(v, link, now)
            return
        if v.operator_hold:
            pass  # the operator's: not started again by us (OPERATOR_HOLDS)
        elif (
            v.needs_restart and v.phase is Phase.RUNNING and v.ready and v.mission_total is not None
        ):
            # Once it says where it is since the reboot: the item it starts at and the
            # implement depend on it (ArduPilot drives no mission before it knows either).
            if v.where is not None:
                self._restart(v, link, now)
            elif link.awaiting_fix is None:
                link.awaiting_fix = now
                self._log("info", f"{vid}: the autopilot rebooted; waiting for its position")
            elif now - link.awaiting_fix > FIX_TIMEOUT_S and self._others_can_take(v):
                link.awaiting_fix = None
                error = (
                    f"start failed: no position in {FIX_TIMEOUT_S:g} s since its autopilot "
                    "rebooted (no GPS fix?)"
                )
                self._apply(ev.StartFailed(vid, error), now)
                self._log("error", f"{vid}: {error}")
            elif now - link.awaiting_fix > FIX_TIMEOUT_S:
                # Nobody to take its work: waited for (an RTK fix can take minutes), and
                # the operator told so every FIX_TIMEOUT_S (should others come back, its
                # start fails FIX_TIMEOUT_S after the last telling).
                link.awaiting_fix = now
                self._log(
                    "warning",
                    f"{vid}: still no position since its autopilot rebooted (no GPS fix?); "
                    "its work waits for it: no other tractor can take it",
                )
        elif not v.needs_restart and (failsafe := self._failsafe_over(v, link)):
            link.start_item = v.resume_item
            self._log(
                "warning",
                f"{vid}: its failsafe held it (autopilot: {failsafe}), for want of our "
                f"heartbeats; it hears us again: going on at item {link.start_item}",
            )
            self._start(v, link, now)
        elif (
            link.hold is not None
            and link.hold.outcome is not Outcome.RUNNING
            and v.phase is Phase.RUNNING
            and not v.needs_restart  # rebooted: started again above, from where it is
            and v.ready
            and self._replan is None  # a re-plan under way may have given its work away
            and not self._replan_reason
        ):
            # Back after we told it to HOLD when it was lost: on with its mission.
            link.hold = None
            link.start_item = v.resume_item
            self._log("info", f"{vid}: back; going on at item {link.start_item}")
            self._start(v, link, now)
        if v.phase is Phase.ALIVE and link.upload is None and self._fleet_ready():
            if not v.ready:
                return  # still booting: it would refuse the mission (MAV_MISSION_NO_SPACE)
            if link.heard_at is not None and now - link.heard_at < GCS_HEARTBEAT_PERIOD_S:
                # Not before it has had a HEARTBEAT of ours: an ArduPilot whose ground
                # station was away (FS_GCS_ENABLE) clears its GCS failsafe only then, and
                # one put in AUTO before that falls back to HOLD at once (SITL, a second
                # job without a reboot: its mission went up and started in 0.3 s).
                return
            if self.upload_started is None:
                self.upload_started = now
            self._upload(v, link, now)
        elif v.phase is Phase.UPLOADING and link.upload is not None:
            v.upload_retries = link.upload.stats.retries
            if link.upload.outcome is Outcome.DONE:
                if not v.acked:
                    self._apply(ev.UploadAcked(vid), now)
                    self._upload_took[vid] = (now - link.since, v.held)
                    self._log("info", f"{vid}: mission acknowledged")
                    if self.all_acknowledged is None and all(
                        lk.upload is not None and lk.upload.outcome is Outcome.DONE
                        for lk in self.links.values()
                    ):
                        self.all_acknowledged = now
                        self.state.upload_s = now - (self.upload_started or now)
                    if self.config.verify_missions:
                        # An ArduPilot upload is not atomic and the link may be lossy:
                        # read the mission back before it is driven (docs/restart.md).
                        link.download = MissionDownload(v.system_id, round_trip=link.round_trip)
                        self._send(vid, link.download.start(now))
                        return
                if link.download is not None:
                    if link.download.outcome is Outcome.RUNNING:
                        return
                    read, link.download = link.download, None
                    if read.outcome is Outcome.FAILED:
                        self._upload_failed(v, link, f"not read back ({read.reason})", now)
                        return
                    if diffs := self._held_differences(v, read):
                        self._upload_failed(
                            v, link, f"read back different ({', '.join(diffs)})", now
                        )
                        return
                    self._log("info", f"{vid}: mission read back, item by item ours")
                self._start(v, link, now)
            elif link.upload.outcome is Outcome.FAILED:
                self._upload_failed(v, link, v.explain(link.upload.reason, link.since - 1.0), now)
        elif v.phase is Phase.UPLOADING and link.upload is None and now >= link.upload_at:
            if v.ready:
                self._upload(v, link, now)
        elif v.phase is Phase.STARTING and link.start is not None:
            if link.start.outcome is Outcome.DONE:
                link.starts = 0
                self._apply(ev.MissionStarted(vid, link.start_item), now)
                self._log(
                    "info", f"{vid}: armed and in AUTO, mission started at item {link.start_item}"
                )
                for refusal in link.start.skipped:
                    self._log(
                        "warning",
                        f"{vid}: {refusal}; the implement stays as the autopilot has it "
                        "until the mission sets it (check the output's SERVOn_FUNCTION or "
                        "RELAYn_FUNCTION)",
                    )
            elif link.start.outcome is Outcome.FAILED:
                if self._start_again(v, link, now):
                    return
                link.starts = 0
                error = f"start failed: {v.explain(link.start.reason, link.since - 1.0)}"
                self._apply(ev.StartFailed(vid, error), now)
                self._log("error", f"{vid}: {error}")
            elif link.start.last_refusal:
                waiting = v.explain(link.start.last_refusal, now - TEXT_WINDOW_S)
                if waiting != v.error:
                    self._apply(ev.StartRefused(vid, waiting), now)
                    self._log("warning", f"{vid}: {waiting}; asking again")
        elif v.phase is Phase.DONE and link.park is None:
            link.park = CommandSequence(park_commands(), v.system_id)
            self._log("info", f"{vid}: mission complete; HOLD and disarm")
            self._send(vid, link.park.start(now))
        elif v.phase is Phase.RUNNING:
            if link.renumbered:
                self._after_renumbering(v, link, now)
            self._advance_topup(v, link, now)

    def _probe(self, v: VehicleState, link: _Link, now: float) -> None:
        """A vehicle failed for want of answers (or of a position since it rebooted), its
        work given to the others: told to HOLD while it is heard (and, rebooted, once it
        says where it is), PROBE_PERIOD_S after the last time went unanswered. Once
        it acknowledges, it hears us again (events.AnsweringAgain), and it rejoins as one
        back from a loss does (the retired branch of :meth:`_advance`: a re-plan gives it
        work from where it is). The HOLD stops one that drives its mission after all: its
        fields are the others' now."""
        if link.hold is not None:
            if link.hold.outcome is Outcome.RUNNING:
                return
            if link.hold.outcome is Outcome.DONE:
                link.starts = 0
                self._apply(ev.AnsweringAgain(v.id), now)
                self._log("info", f"{v.id}: answers our commands again; to be given work")
                return
            link.hold, link.probe_at = None, now + PROBE_PERIOD_S
        heard = v.last_seen is not None and now - v.last_seen <= self.config.heartbeat_timeout_s
        placed = v.where is not None or not v.needs_restart  # (rebooted: a fix first)
        if heard and now >= link.probe_at and not link.busy and placed:
            link.hold = CommandSequence(hold_commands(), v.system_id)
            self._send(v.id, link.hold.start(now))

    def _alive_timeout(self, v: VehicleState) -> float:
        """Wall seconds from the start for a vehicle to be heard: ``alive_timeout_s``; for
        one lost when a restarted dispatcher stopped, twice the heartbeat timeout (a
        re-plan of its work waits on it, and the others drive on meanwhile)."""
        if v.lost_before_restart:
            return min(self.config.alive_timeout_s, 2.0 * self.config.heartbeat_timeout_s)
        return self.config.alive_timeout_s

    def _failsafe_over(self, v: VehicleState, link: _Link) -> str | None:
        """What said a ground-station failsafe put a running vehicle out of AUTO (its text,
        or its HEARTBEAT's CRITICAL: :meth:`VehicleState.failsafe`), once it is over: the
        autopilot said so ("... Failsafe Cleared", or STANDBY again: a HEARTBEAT of ours
        reached it), or it has been heard for FAILSAFE_CLEAR_WAIT_S since. None otherwise,
        and for a vehicle out of AUTO with no such word (the operator's doing: left alone),
        one we told to HOLD (lost: started again when back), or while a re-plan may give
        its work away. Each failsafe once."""
        if v.phase is not Phase.RUNNING or v.off_auto_since is None or not v.ready:
            return None
        if link.busy or link.hold is not None or self._replan is not None or self._replan_reason:
            return None
        after = link.failsafe_seen + 1e-9
        found = v.failsafe(
            max(v.off_auto_since - TEXT_WINDOW_S, after), max(v.off_auto_since, after)
        )
        if found is None:
            return None
        at, text, cleared = found
        heard_since = (v.last_seen or 0.0) - max(at, v.off_auto_since)
        if not cleared and heard_since < FAILSAFE_CLEAR_WAIT_S:
            return None
        link.failsafe_seen = at
        return text

    def _held_differences(self, v: VehicleState, read: MissionDownload) -> list[str]:
        """Where what ``read`` read back differs from the part of our mission the vehicle
        is to hold (empty: the same)."""
        ours = on_board(self.job.missions[v.id].to_mavlink(v.system_id)[: v.held], v.numbering.base)
        return mission_differences(read.items, ours, first=read.first, count=read.count)

    def _topup_due(self, v: VehicleState, link: _Link) -> int | None:
        """How many items a driving vehicle that holds a window of its mission is to hold
        now, when it is due its next window (mission/window.py): it will reach the end of
        the one it holds, at its pace, within the scenario's ``topup_lead_s`` plus twice
        what the top-up should take at the pace of its last upload. None: not due."""
        if v.held >= len(v.items) or not self._window_free(v, link):
            return None
        more = window(v.items, v.held, self.config.window_items)
        left_s = self._left_s(v, v.held)
        if left_s is None:
            return more
        # What the next top-up takes: the whole longer prefix, and the new items read back.
        lead_s = self.config.topup_lead_s + self._upload_s(v, 2 * more - v.held)
        return more if left_s <= lead_s else None

    def _window_free(self, v: VehicleState, link: _Link) -> bool:
        """Whether what a driving vehicle holds may be extended, or it be sent on from its
        window's end, now: no re-plan under way (its next window may change), no new route
        or restart of its own to come, not held by us, no exchange with it running."""
        return not (
            self._replan is not None
            or bool(self._replan_reason)
            or v.switch
            or v.resuming
            or v.needs_restart
            or v.retired
            or link.hold is not None
            or link.busy
        )

    def _left_s(self, v: VehicleState, held: int) -> float | None:
        """Wall seconds until a driving vehicle reaches the last of the first ``held`` items
        of its mission, at its planned pace from the last item it reached (None: no plan
        of its times)."""
        if len(v.planned_s) != len(v.items) or not 0 < held <= len(v.items):
            return None
        return (v.planned_s[held - 1] - v.planned_s[v.reached]) / max(v.clock.rate, 1e-6)

    def _upload_s(self, v: VehicleState, count: int, margin: float = 2.0) -> float:
        """Wall seconds an upload (or read-back) of ``count`` items to the vehicle is to be
        given: ``margin`` times what it takes at the pace of its last upload (items a
        second); 1: what it should take."""
        took_s, items = self._upload_took.get(v.id, (0.0, 1))
        return margin * took_s * count / max(items, 1)

    def _advance_topup(self, v: VehicleState, link: _Link, now: float) -> None:
        """Give a driving vehicle the next window of its mission: upload the longer prefix
        under it (it keeps driving the items it holds), read the new items back, and start
        it again if it reached the end of its old window meanwhile (it stopped there)."""
        if link.topup_from is None:
            if self._stands_at_old_window_end(v, link, now):
                # Its reports of the end of its old window were lost when the top-up ended
                # (a 30 %-loss radio: taken to be driving, it stood there for good).
                self._on_from_window_end(v, link, now, v.held_before)
                return
            count = self._topup_due(v, link)
            if count is None:
                return
            link.topup_from, link.sent_on_from = v.held, 0
            self._apply(ev.WindowExtended(v.id, count), now)
            self._log(
                "info",
                f"{v.id}: topping up its mission with items {link.topup_from}..{count - 1} "
                f"of {len(v.items)}",
            )
            self._send_window(v, link, now)
            return
        if link.upload is not None:
            if link.upload.outcome is Outcome.RUNNING:
                return
            if link.upload.outcome is Outcome.FAILED:
                self._log("warning", f"{v.id}: top-up not uploaded ({link.upload.reason}); again")
                self._send_window(v, link, now)
                return
            link.upload = None
            link.download = MissionDownload(
                v.system_id,
                first=v.numbering.to_vehicle(link.topup_from),
                round_trip=link.round_trip,
            )
            self._send(v.id, link.download.start(now))
            return
        if link.download is None or link.download.outcome is Outcome.RUNNING:
            return
        read, link.download = link.download, None
        diffs = (
            [f"not read back ({read.reason})"]
            if read.outcome is Outcome.FAILED
            else self._held_differences(v, read)
        )
        if diffs:
            self._log("warning", f"{v.id}: top-up read back different ({', '.join(diffs)}); again")
            self._send_window(v, link, now)
            return
        old_end, link.topup_from = link.topup_from, None
        sent = count_on_board(v.held, v.numbering.base)
        self._upload_took[v.id] = (now - link.since, sent + v.held - old_end)
        self.topups.append((v.id, sent))
        if (
            (v.reached >= old_end - 1 and v.current < old_end)
            or v.mission_state == mc.MISSION_STATE_COMPLETE
            or (v.driving and v.mission_stopped)
        ):
            self._on_from_window_end(v, link, now, old_end)

    def _stands_at_old_window_end(self, v: VehicleState, link: _Link, now: float) -> bool:
        """Whether a driving vehicle given its next window says, since, that its mission is
        complete at the end of the window it held before (``v.held_before``), short of the
        end of what it holds now: it stands there, and nothing else will send it on. Not
        once it was sent on from there (a late report from before its start would start it
        twice), nor while its last start's news settles (CURRENT_SETTLE_S) or anything else
        is under way."""
        old_end = v.held_before
        return (
            0 < old_end < v.held
            and v.phase is Phase.RUNNING
            and v.driving
            and v.mission_state == mc.MISSION_STATE_COMPLETE
            and old_end - 1 <= v.current < v.held - 1
            and v.current_of_last_upload
            and link.sent_on_from != old_end
            and (v.started_at is None or now - v.started_at >= CURRENT_SETTLE_S)
            and not (link.renumbered or v.operator_hold)
            and self._window_free(v, link)
        )

    def _on_from_window_end(self, v: VehicleState, link: _Link, now: float, old_end: int) -> None:
        """Start again a vehicle that reached the end of what it held (``old_end`` items)
        before its next window was on board: it stands there, its mission complete; on
        from the next item (the first new one when its autopilot says so and what said it
        reached the last is lost). Or, renumbered under way, it stopped at the item it
        drove to from memory (or the set-current came after it): on after that one."""
        self.window_waits += 1
        link.sent_on_from = old_end
        complete = v.mission_state == mc.MISSION_STATE_COMPLETE
        if complete and v.current >= old_end - 1:
            link.start_item = max(v.go_on_item, old_end)
        elif complete or v.mission_stopped:
            link.start_item = v.go_on_item
        else:
            link.start_item = v.resume_item
        self._log("info", f"{v.id}: waited at the end of its window; on at item {link.start_item}")
        self._start(v, link, now, in_auto=True)

    def _send_window(self, v: VehicleState, link: _Link, now: float, switch: bool = False) -> None:
        """Upload the part of its mission the vehicle is to hold (``v.held`` items): home
        and the plan's items from a base on (link/numbering.py), the items before it left
        out when the vehicle is far enough past them. A driving vehicle is renumbered only
        when the upload should be on board before it reaches the item it drives to
        (:meth:`_outruns`), unless ``switch``: its new route after a re-plan, which the
        whole prefix would hold up for seconds (a 676-item switch took 14 s in a 20 %-loss
        soak, its tractor held at the end of its kept part for 10 of them); it may then
        stop at that item, and is started again after it (:meth:`_advance_switch`,
        :meth:`_after_renumbering`)."""
        link.since = now
        # The first item it may still need: the one it drives to, or after the last one it
        # reached if that is before (its reports lost); one standing still, where it is to
        # be started.
        first = min(v.resume_item, v.current if v.current > 0 else v.resume_item)
        if not v.driving:
            first = min(first, link.start_item)
        starting = link.start is not None and link.start.outcome is Outcome.RUNNING
        just_started = v.started_at is not None and now - v.started_at < CURRENT_SETTLE_S
        # Its mission runs: ArduPilot follows a change of it (not one complete or stopped).
        running = v.runs_mission
        if starting or just_started or (running and v.mission_state != mc.MISSION_STATE_ACTIVE):
            # Being started, or not yet heard driving the mission since (what it said before
            # the start may still stand: a tractor started at item 36 after a restart was
            # taken for standing still and renumbered past it): where it drives to is not
            # known for sure, and a new base might be past it.
            base = v.numbering.base
        else:
            base = choose_base(v.numbering, v.held, first, v.current)
            if (
                running
                and not switch
                and base != v.numbering.base
                and not self._outruns(v, link, base)
                and not self._stops_sooner(v, link, base)
            ):
                base = v.numbering.base
        if base < v.numbering.base and running:
            base = v.numbering.base  # never under a driving vehicle (its index would move)
        items = on_board(self.job.missions[v.id].to_mavlink(v.system_id)[: v.held], base)
        link.numbered = (base, len(items))
        if base != v.numbering.base:
            self._log(
                "info",
                f"{v.id}: its mission from item {base} on ({len(items)} items with home, "
                f"numbered from 1 on board)",
            )
        link.upload = MissionUpload(items, v.system_id, round_trip=link.round_trip)
        self._send(v.id, link.upload.start(now))

    def _after_renumbering(self, v: VehicleState, link: _Link, now: float) -> None:
        """A driving vehicle renumbered under way: once it drives the new mission, done;
        if its mission stopped meanwhile (it reached the item it drove to from memory
        before the set-current came, or the set-current came after and stopped it there),
        started again after the last item it reached."""
        if link.busy:
            return
        if link.topup_from is not None:
            return  # a renumbered top-up not yet read back: its end starts it if it stopped
        if not v.driving or v.held_for_route or link.hold is not None:
            link.renumbered = False  # stopped by us, or by its own failsafe: handled there
            return
        if v.mission_state == mc.MISSION_STATE_ACTIVE and v.current_of_last_upload:
            link.renumbered = False
            return
        if v.mission_stopped and v.go_on_item < v.held:
            link.renumbered = False
            link.start_item = v.go_on_item
            self._log(
                "info",
                f"{v.id}: stopped at item {v.current} as it was renumbered; on at item "
                f"{link.start_item}",
            )
            self._start(v, link, now, in_auto=True)

    def _outruns(self, v: VehicleState, link: _Link, base: int) -> bool:
        """Whether an upload from ``base`` should be on board, and the vehicle sent on in its
        new numbers, before a driving vehicle reaches the item it drives to: ArduPilot cuts
        the mission to the new count at the MISSION_COUNT, so it stops at that item, its
        mission complete, if it gets there first (link/numbering.py). Twice the time the
        upload takes at the pace of the last one, and half a second, against the distance
        to the item at the fastest speed of its mission and its clock's speedup."""
        if not 0 < v.current < len(v.items) or v.lat is None or v.lon is None:
            return False
        upload_s = self._upload_s(v, count_on_board(v.held, base)) + RENUMBER_MARGIN_S
        return self._to_current_s(v) >= upload_s

    def _to_current_s(self, v: VehicleState) -> float:
        """Wall seconds a driving vehicle (its position known) needs at the least to reach
        the item it drives to: the distance at the fastest speed of its mission and its
        clock's speedup."""
        assert v.lat is not None and v.lon is not None
        item = v.items[v.current]
        speed = v.witness.top_speed_ms * max(v.clock.rate, 1e-6)
        return metres((v.lat, v.lon), (item.lat, item.lon)) / speed

    def _stops_sooner(self, v: VehicleState, link: _Link, base: int) -> bool:
        """Whether a top-up renumbered from ``base`` has a driving vehicle stand still for
        less time than the whole prefix would, when the whole prefix should not be on
        board before it reaches the end of the window it holds (it would stop there and
        wait; both at the pace of its last upload): with the shorter upload it stops at
        the item it drives to instead (it cannot be sent on in the new numbers before it
        gets there, :meth:`_outruns`), and is started again sooner. A fast clock, or a slow
        radio, where the prefix takes longer to send than the vehicle takes to drive its
        window. Never where it would stand with its implement down (in a swath: a sprayer
        or a seeder standing there works the same ground on; windows end after the
        implement is raised for that reason)."""
        if link.topup_from is None or not 0 < v.current < len(v.items):
            return False
        left_s = self._left_s(v, link.topup_from)
        if left_s is None or v.lat is None or v.lon is None:
            return False
        if implement_down_after(v.items[: v.current]):
            return False
        whole = count_on_board(v.held, v.numbering.base)
        whole_wait_s = self._upload_s(v, whole, margin=1.0) - left_s
        short = count_on_board(v.held, base)
        short_wait_s = self._upload_s(v, short, margin=1.0) - self._to_current_s(v)
        return whole_wait_s > 0.0 and short_wait_s < whole_wait_s

    def _numbered(self, v: VehicleState, link: _Link, now: float) -> None:
        """An upload was acknowledged: the vehicle numbers its items as that upload did.
        A driving vehicle whose numbers changed is sent on to the item it drives to in the
        new numbers at once (its autopilot drives it from memory, and would stop there)."""
        assert link.numbered is not None
        base, count = link.numbered
        link.numbered = None
        was = v.numbering
        if base == was.base and (base == 1 or count == was.count):
            return
        self._apply(ev.MissionNumbered(v.id, base, count), now)
        if base == was.base:
            return
        # Watched until it drives the new mission: one whose mission stops short is started
        # again (_after_renumbering).
        link.renumbered = v.phase is Phase.RUNNING
        if not v.driving or v.mission_state != mc.MISSION_STATE_ACTIVE or v.current < base:
            return
        if v.switch and link.switch_from is not None and v.current > link.switch_from:
            return  # past the part its new mission keeps: the new route's item (_join)
        if link.start is None or link.start.outcome is not Outcome.RUNNING:
            link.start = CommandSequence([set_current_command(v.current)], v.system_id)
            self._send(v.id, link.start.start(now))

    def _upload_failed(self, v: VehicleState, link: _Link, reason: str, now: float) -> None:
        """An upload attempt failed: again after a pause, unless it was the last."""
        if v.upload_attempts < self.config.upload_attempts:
            # The vehicle may hold the whole mission and only its last ACK was lost, or it
            # gave up half-way, or it is busy: after a pause, upload again from the count.
            pause = self.config.upload_backoff_s * 2 ** (v.upload_attempts - 1)
            self._log(
                "warning", f"{v.id}: upload failed ({reason}); uploading again in {pause:g} s"
            )
            link.upload_at = now + pause
            link.upload = None
            self._apply(ev.UploadFailed(v.id, reason, final=False), now)
            return
        error = f"upload failed after {v.upload_attempts} attempts: {reason}"
        self._apply(ev.UploadFailed(v.id, error, final=True), now)
        self._log("error", f"{v.id}: {error}")

    def _upload(self, v: VehicleState, link: _Link, now: float) -> None:
        """Upload the vehicle's mission (a window of it from ``link.start_item``, when it is
        long: mission/window.py), to be started at ``link.start_item``."""
        count = window(v.items, link.start_item, self.config.window_items)
        self._apply(ev.UploadStarted(v.id, v.upload_attempts + 1, count), now)
        link.topup_from = None
        part = f" (the first {count} of {len(v.items)})" if count < len(v.items) else ""
        self._log("info", f"{v.id}: uploading {count} mission items{part}")
        self._send_window(v, link, now)

    def _start(self, v: VehicleState, link: _Link, now: float, in_auto: bool = False) -> None:
        """Start (or resume) its mission at ``link.start_item``, or at the start of the leg
        to it, which becomes ``link.start_item`` (:meth:`_start_at`); ``in_auto``: it is in
        AUTO though its last HEARTBEAT may not say so yet (put there less than a second
        ago)."""
        if link.start_item >= v.held:
            # Past the part of its mission it holds (at the end of a window): more first.
            self._upload(v, link, now)
            return
        if v.operator_hold:
            # The operator took it out of AUTO (before a reboot, a restart of ours, or a
            # re-plan that wants it on): not ours to start. Followed as running, started
            # at the right item (a restart) once the operator puts it back in AUTO.
            if v.phase is not Phase.RUNNING:
                self._apply(ev.MissionStarted(v.id, link.start_item), now)
            v.needs_restart = True
            self._log(
                "warning",
                f"{v.id}: to go on at item {link.start_item}, but out of AUTO by the "
                f"operator's hand (mode {v.mode}, {'armed' if v.armed else 'disarmed'}); "
                f"{OPERATOR_HOLDS}",
            )
            return
        in_auto = in_auto or v.mode == ROVER_MODE_AUTO
        # A lowering of an earlier start: not this one's (its commands set the implement).
        link.lower = link.raising = link.watch = None
        if link.lower_after is None or link.lower_after[0] != link.start_item:
            link.lower_after = None
            link.start_item = self._start_at(v, link, link.start_item)
        else:  # the same start again (_start_again): from where it went back to
            link.lower_after, link.lowerings = (link.start_item, link.lower_after[1], False), 0
        self._apply(ev.StartRequested(v.id, link.start_item), now)
        link.since = now
        speed = self.job.missions[v.id].speed_before(link.start_item)
        link.start = CommandSequence(
            start_mission_commands(
                link.start_item,
                in_auto=in_auto,
                speed_ms=speed,
                implement=(
                    self._implement_at(v, link.start_item)
                    if link.lower_after is None
                    else self._raised(v)
                ),
            ),
            v.system_id,
            refusal_window_s=START_REFUSAL_WINDOW_S,
        )
        self._send(v.id, link.start.start(now))

    def _start_at(self, v: VehicleState, link: _Link, seq: int) -> int:
        """Where a start meant for item ``seq`` begins: there, unless the vehicle stands off
        the leg to it (moved while the implement was down, or a simulator started again in
        the garage) where the implement is down along that leg. Then at the leg's start:
        it drives there with the implement up (:meth:`_implement_at`), and the leg is
        worked whole (what was worked of it before, again), rather than driven with the
        implement up and left unworked. Where the mission lowers the implement after the
        leg's start (a swath after a turn, a field's first swath) it does so itself; where
        it lowered it before (the lines of a field worked one after another with it down)
        the mission's lowering is sent as a command once the vehicle is past the leg's
        start (``link.lower_after``, :meth:`_lower_when_past`). Not where the leg's start
        is not on board (a mission renumbered from a later item) or before a re-plan's new
        route: up then, and said (:meth:`_implement_at`)."""
        end = leg_end(v.items, seq)
        k = None if end is None else implement_set_before(v.items, end)
        start = leg_start(v.items, seq)
        if (
            k is None
            or v.items[k].role not in IMPLEMENT_LOWERED
            or start is None
            or start < max(1, v.route_from, v.numbering.base)
            or v.where is None
        ):
            return seq
        off = off_leg_m(v.items, seq, v.where)
        if off is None or off <= REACH_M:
            return seq
        if start < k:
            how = "the mission lowers it there"
        else:
            link.lower_after, link.lowerings = (start, k, False), 0
            how = "lowered by our command once it is past that item"
        self._log(
            "warning",
            f"{v.id}: {off:.0f} m from the leg it goes on along at item {seq}: from item "
            f"{start}, where the leg starts, with the implement up; {how}, and what was "
            "worked of the leg is worked again",
        )
        return start

    def _lower_when_past(self, v: VehicleState, link: _Link, now: float) -> None:
        """Lower the implement (``link.lower_after``) once the vehicle, started at the start of its
        leg, has headed there (its MISSION_CURRENT at or before that item, or seen within
        :data:`REACH_M` of it) and gone past it (after it), onto a leg its mission drives
        with the implement down and within :data:`REACH_M` of it: ArduPilot takes the
        mission's DO_SET_SERVO or DO_SET_RELAY as a command in AUTO. Its MISSION_CURRENT
        comes about once a second: what it drives of the leg before the command arrives is
        not worked (~2 m at a tractor's working speed). A lowering unanswered is sent again
        (up to ``start_attempts`` rounds) while that still holds. Out of AUTO (the
        operator's, a failsafe), no more of it until it drives there again; past the legs
        its mission drives with the implement down, no more of it at all. One refused, or
        past those legs before it could be sent, is said. A lowering of ours may reach the
        vehicle after the mission raised the implement (a resend, an answer lost): after
        one, the vehicle is watched (:meth:`_watch_raising`)."""
        sent = link.lower
        if sent is not None and sent.outcome is Outcome.RUNNING:
            if v.phase is Phase.LOST:
                return  # (lost for a moment: it may drive on meanwhile)
            if link.raising is not None:  # the mission's raising, after a lowering of ours
                if implement_set_before(v.items, v.current) != link.raising or not v.driving:
                    link.lower = link.raising = None  # the mission sets it since
                return
            if link.lower_after is None:  # (a lowering runs with what it is for)
                link.lower = None
                return
            k = link.lower_after[1]
            # (Not on where it is: a position a moment ahead of its MISSION_CURRENT at a
            # corner would stop it on the line.)
            if self._lowering_holds(v, k, None):
                return
            link.lower = None
            link.watch = (k, now + sent.timeout_s)  # its answers may come until then
            if implement_set_before(v.items, v.current) != k:
                link.lower_after = None  # past the legs it was for
        elif sent is not None:
            link.lower = None
            raising, link.raising = link.raising is not None, None
            if not raising:
                link.watch = (link.lower_after[1] if link.lower_after else -1, now)
            if sent.outcome is Outcome.DONE:
                link.lower_after = None
            elif raising or not sent.unanswered or link.lowerings >= self.config.start_attempts:
                link.lower_after = None
                what = "raising, sent after a lowering of ours," if raising else "lowering"
                self._log(
                    "warning",
                    f"{v.id}: the implement's {what} failed ({sent.reason}): it may be "
                    f"{'down' if raising else 'up'} until its mission sets it again",
                )
        self._watch_raising(v, link, now)
        if link.lower_after is None or link.lower is not None or v.phase is Phase.LOST:
            return  # (lost for a moment: it may drive on meanwhile)
        item, k, headed = link.lower_after
        if v.phase not in (Phase.STARTING, Phase.RUNNING) or k >= len(v.items):
            link.lower_after = None  # done, failed, or its mission changed under it
            return
        if not headed:
            # Its MISSION_CURRENT at or before the item since our start, or (those reports
            # lost: it may get there in a second) seen there, started.
            start = v.items[item]
            there = v.where is not None and metres(v.where, (start.lat, start.lon)) <= REACH_M
            if v.current <= item or (there and v.phase is Phase.RUNNING):
                link.lower_after = (item, k, True)
            return
        if v.current <= item:
            return
        if implement_set_before(v.items, v.current) != k:
            link.lower_after = None
            self._log(
                "warning",
                f"{v.id}: past the legs its mission drives with the implement down after item "
                f"{item} before it could be lowered: if it was up, those were not worked",
            )
            return
        if v.where is not None and self._lowering_holds(v, k, v.where):
            link.lowerings += 1
            self._log("info", f"{v.id}: past item {item}, where its leg starts: implement down")
            self._set_implement(v, link, k, now)

    def _watch_raising(self, v: VehicleState, link: _Link, now: float) -> None:
        """After a lowering of ours (``link.watch``: the lowering's item, and when no answer
        to it can come any more), for :data:`LOWER_WATCH_S`: if its MISSION_CURRENT says
        the mission has raised the implement since, that raising is sent, in case ours came
        after it (a resend, or a report a second late), and sent again until the mission
        sets the implement again; not while a late answer to our lowering could pass for
        its answer (the same command), nor to one out of AUTO (the operator's)."""
        if link.watch is None or link.lower is not None or v.phase is Phase.LOST:
            return
        k, quiet = link.watch
        if now > quiet + LOWER_WATCH_S:
            link.watch = None
            return
        j = implement_set_before(v.items, v.current)
        if j is None or j == k or now < quiet:
            return
        link.watch = None
        up = v.items[j]
        if up.role in IMPLEMENT_RAISED and v.driving and not v.operator_hold:
            link.raising = j
            self._log("info", f"{v.id}: past item {j}, the mission's raising: sent again")
            self._set_implement(v, link, j, now)

    def _set_implement(self, v: VehicleState, link: _Link, k: int, now: float) -> None:
        """Send the mission's implement item ``k`` as a command (``link.lower``): a
        lowering must be taken, a raising may be refused (optional)."""
        item = v.items[k]
        command = _as_command(item, optional=item.role in IMPLEMENT_RAISED)
        link.lower = CommandSequence([command], v.system_id, max_retries=LOWERING_RETRIES)
        self._send(v.id, link.lower.start(now))

    def _lowering_holds(self, v: VehicleState, k: int, where: tuple[float, float] | None) -> bool:
        """Whether the mission's lowering at item ``k`` is right for the vehicle now: it
        drives its mission in AUTO (not the operator), towards an item its mission drives
        to with that lowering in force; and, given ``where`` it is, within :data:`REACH_M`
        of that leg."""
        on = where is None or (off_leg_m(v.items, v.current, where) or 0.0) <= REACH_M
        return (
            v.phase is Phase.RUNNING
            and v.driving
            and not v.operator_hold
            and implement_set_before(v.items, v.current) == k
            and on
        )

    def _implement_on(self, v: VehicleState, link: _Link, now: float) -> None:
        """A vehicle found driving its mission after a restart of ours, on its way to an
        item its mission drives to with the implement down: lowered on that leg
        (:meth:`_lower_when_past`), in case we had started it back at the start of a leg
        with the implement up and the lowering was still to come, which this process does
        not know. A lowering again is nothing to an implement already down. One not on
        that leg (on its way to the leg's start, from the garage say; or not placed yet)
        once it is past the item it heads to."""
        k = implement_set_before(v.items, v.current)
        if k is None or v.items[k].role not in IMPLEMENT_LOWERED:
            return
        off = None if v.where is None else off_leg_m(v.items, v.current, v.where)
        on = off is not None and off <= REACH_M
        link.lower_after, link.lowerings = (v.current - 1 if on else v.current, k, True), 0
        self._lower_when_past(v, link, now)

    def _raised(self, v: VehicleState) -> Command | None:
        """The mission's raising of the implement, as a command (None if it has none)."""
        up = next((it for it in v.items if it.role in IMPLEMENT_RAISED), None)
        return None if up is None else _as_command(up, optional=True)

    def _implement_at(self, v: VehicleState, seq: int) -> Command | None:
        """The implement as its mission has it when it drives to item ``seq`` (the item
        that set it, as a command), for a start there (``start_mission_commands``); up
        where nothing before sets it (a vehicle held in a field with it down, sent out on a
        new route from there). Down, but the vehicle stands off the leg it is to drive on
        (moved while it was down, or a simulator started again in the garage): up, or it
        would drive there with the implement down, and said; the mission lowers it again
        where it next does. None for a mission that never sets it."""
        k = implement_set_before(v.items, seq)
        if k is None:
            return self._raised(v)
        item = v.items[k]
        where = v.where
        if item.role in IMPLEMENT_LOWERED and where is not None:
            off = off_leg_m(v.items, seq, where)
            if off is not None and off > REACH_M:
                self._log(
                    "warning",
                    f"{v.id}: {off:.0f} m from the leg it goes on along at item {seq}: "
                    "the implement stays up until the mission lowers it again, and what it "
                    "drives before that is not worked",
                )
                return self._raised(v)
        return _as_command(item, optional=True)

    def _start_again(self, v: VehicleState, link: _Link, now: float) -> bool:
        """A start whose commands went unanswered, of a vehicle heard since it began: the
        radio lost the commands or their answers, not the vehicle. Start again (from the
        first command: the vehicle may have taken some), unless that was the last attempt."""
        start = link.start
        assert start is not None
        link.starts += 1
        heard = v.last_seen is not None and v.last_seen > link.since
        if not (start.unanswered and heard and link.starts < self.config.start_attempts):
            return False
        self._log(
            "warning",
            f"{v.id}: start unanswered ({start.reason}), though it is heard; starting again "
            f"(attempt {link.starts + 1} of {self.config.start_attempts})",
        )
        self._start(v, link, now)
        return True

    def _restart(self, v: VehicleState, link: _Link, now: float) -> None:
        """The autopilot rebooted while driving: it holds its mission (stored on board) but
        is disarmed in another mode. Arm it again and resume after the last item reached;
        upload again first if what it holds is not our mission."""
        v.needs_restart = False
        link.hold = None  # (told to HOLD while it was lost, rebooted: this is its start)
        link.awaiting_fix = None
        link.start_item = v.resume_item
        expected = v.held - 1  # MISSION_CURRENT.total counts the items after home
        if v.mission_total is not None and v.mission_total != expected:
            self._log(
                "warning",
                f"{v.id}: rebooted holding {v.mission_total + 1} items, not our "
                f"{v.held}; uploading again, then resuming at item {link.start_item}",
            )
            self._upload(v, link, now)
            return
        self._log("warning", f"{v.id}: the autopilot rebooted; resuming at item {link.start_item}")
        self._start(v, link, now)

    def _resume_run(self, run: StoredRun) -> None:
        """Continue a stored run: every vehicle not done is to be heard again and asked
        where it is (:meth:`_resume`) before anything is sent to it."""
        done = sum(f.status == "done" for f in self.state.fields.values())
        self._log(
            "warning",
            f"resuming run {run.id} of plan {run.job.plan_id} from its {len(run.events)} "
            f"stored events: {done}/{len(self.state.fields)} fields done; not planning again",
        )
        if self.recorder is not None:
            # The events it resumes from, into the new log as well (marked "stored"): the
            # old log may lack its last half second (kill -9), the store does not; review
            # takes these in place of the old log's.
            for wall, event in run.events:
                stored = {**ev.to_dict(event), ev.STORED: True}
                self.recorder.record_event(stored, int(wall * 1e9))
        now = time.monotonic()
        for vid in self.state.vehicles:
            self._apply(ev.Resumed(vid), now)  # one done is parked again (HOLD, disarm)

    def _resume(self, v: VehicleState, link: _Link, now: float) -> None:
        """After a restart, the vehicle has told where it is: keep it driving if it drives
        our mission, catch up with the items it reached meanwhile, go on from there; upload
        again first when what it holds is not our mission (an upload cut by the crash)."""
        last = v.held - 1
        different = ""
        if v.mission_total != last:
            held = "no mission it told" if v.mission_total is None else f"{v.mission_total + 1}"
            different = f"holds {held} items, not our {v.held}"
        else:  # the same length: read it back to be sure
            found = self._read_back(v, link, now, f"holds {v.held} items; reading them back")
            if found is None:
                return
            different = found
        if different:
            link.start_item = v.resume_item
            self._log(
                "warning",
                f"{v.id}: {different}; uploading again, then going on at item {link.start_item}",
            )
            self._upload(v, link, now)
            return
        if not v.acked:  # acknowledged before the crash, not yet stored: it is ours
            self._apply(ev.UploadAcked(v.id), now)
        # Complete: at the item it says (given its next window while it stood at the end of
        # the one it held, it says complete there, with the longer total: FleetState).
        on_vehicle = v.current if v.mission_state == mc.MISSION_STATE_COMPLETE else v.current - 1
        if on_vehicle > v.reached:
            self._log("info", f"{v.id}: reached items {v.reached + 1}..{on_vehicle} meanwhile")
            self._apply(ev.ItemReached(v.id, on_vehicle, v.sim_time_s, caught_up=True), now)
        if v.phase is Phase.DONE:
            self._log("info", f"{v.id}: finished its mission while the dispatcher was down")
        elif v.driving and v.mission_state in (None, mc.MISSION_STATE_ACTIVE):
            self._apply(ev.MissionStarted(v.id, v.current), now)
            self._log("info", f"{v.id}: still driving its mission at item {v.current}; kept")
            self._implement_on(v, link, now)
        else:
            link.start_item = v.resume_item
            self._log("warning", f"{v.id}: stopped; going on at item {link.start_item}")
            self._start(v, link, now)

    def _want_replan(self, reason: str, now: float, supersede: bool = False) -> None:
        """Ask for a re-plan, for ``reason``; asks made before one starts are answered by
        it, and it is timed from the first. With ``supersede`` (a vehicle lost), a re-plan
        under way is given up: its copy of the state still counts on that vehicle, and the
        next one, asked for at once, is timed from the ask it answered."""
        if not self._replan_reason:
            self._replan_wanted_at = now
        self._replan_reason = f"{self._replan_reason}; {reason}" if self._replan_reason else reason
        if supersede and self._replan is not None and not self._replan_cancel.is_set():
            self._replan_cancel.set()
            why, since = self._replan_asked
            self._replan_reason = f"{why}; {self._replan_reason}"
            self._replan_wanted_at = min(self._replan_wanted_at, since)
            self._log("warning", f"re-plan under way given up: {reason}; planning again")

    def _replan_step(self, now: float) -> None:
        """Take a re-plan's result on when it is there (unless it was superseded), and
        start the next re-plan when one is wanted (in a thread, on a copy of the state)."""
        replanner = self.config.replanner
        if replanner is None:
            return
        if self._replan is not None and not self._replan.is_alive():
            self._replan = None
            result, self._replanned = self._replanned, None
            if self._replan_cancel.is_set():
                pass  # superseded: the next one is wanted already
            elif isinstance(result, NoWorkLeft):
                self._log("info", f"re-planning: nothing to give out ({result}); going on")
            elif isinstance(result, Exception) or result is None:
                self._log("error", f"re-planning failed: {result}")
            else:
                job, reason, since = result
                # Timed on a clock read now: ``now`` was read before this loop's messages
                # were handled, which can take a while on a busy gateway.
                self.replans.append([reason, time.monotonic() - since, None])
                changed = self._adopt(job, reason, now)
                self._adopted_at = now
                self._awaiting_acks = (len(self.replans) - 1, changed, since)
                if not changed:
                    self.replans[-1][2] = time.monotonic() - since
                return
        if self._replan is None and self._replan_reason:
            if any(
                (v.resuming and v.phase not in GONE)
                or v.phase is Phase.STARTING
                or (v.phase is Phase.RUNNING and not v.clock.rate_known)
                for v in self.state.vehicles.values()
            ):
                # Not before every vehicle has said where it is (after a restart), nor while
                # one is being started (it is about to drive, and its kept part is cut from
                # where it drives: one started at item 21 during a re-plan was given its new
                # route from item 2), nor before it is known how fast a driving one's clock
                # runs (the kept part is a lead of wall time at its pace: heard for less
                # than a second after a restart, a 20x tractor was taken for 1x and drove
                # past its kept part before the new mission was on board). Found by the
                # restart-then-kill test.
                return
            reason, self._replan_reason = self._replan_reason, ""
            snapshot = copy.deepcopy(self.state)
            started = self._replan_wanted_at
            self._replan_asked = (reason, started)
            cancel = self._replan_cancel = threading.Event()

            def work() -> None:
                try:
                    self._replanned = (replanner(snapshot, cancel), reason, started)
                except Exception as exc:  # noqa: BLE001 - reported in the main loop
                    self._replanned = exc

            self._log("warning", f"re-planning the rest of the work: {reason}")
            self._replan = threading.Thread(target=work, name="replan", daemon=True)
            self._replan.start()

    def _adopt(self, job: DispatchJob, reason: str, now: float) -> set[str]:
        """Carry on with the next job: the plan replaced (an event), recorded and
        published; each vehicle whose mission changed given its new one (module doc of
        tools/replan). Returns those vehicles."""
        before = {vid: v.items for vid, v in self.state.vehicles.items()}
        relaid = {fid: len(f.relaid) for fid, f in self.state.fields.items()}
        self._apply(ev.PlanReplaced(ev.FLEET, job.plan_id, reason, job.document.to_dict()), now)
        for fid, f in self.state.fields.items():
            if len(f.relaid) > relaid.get(fid, 0):
                began, worked = f.relaid[-1]
                self._log(
                    "warning",
                    f"field {fid}: laid out anew for {f.vehicle}, of another working width or "
                    f"turning radius than {began}, who began it: the {worked} segments worked "
                    "of it are worked again",
                )
        self.job = job
        if self.store is not None:
            self.store.replace_missions(job)
        if self.recorder is not None:
            self.recorder.record_plan(job.document.to_dict(), dict(job.geojson), time.time_ns())
        self._plan_json = job.document.to_json()
        self.publishers["plan"].put(self._plan_json)
        self._publish_status(now)  # what each vehicle is to do now, at once
        gone = [vid for vid, v in self.state.vehicles.items() if v.retired]
        for vid in gone:
            v = self.state.vehicles[vid]
            if v.phase not in GONE and v.phase is not Phase.DONE:
                # Back while the re-plan ran: it must not go on (one failed for good, or
                # done, is not back: asking for it again would re-plan for ever).
                self.links[vid] = _Link(round_trip=self.links[vid].round_trip)
                self._hold(v, self.links[vid], now)
                self._want_replan(f"{vid} back", now)
        self._log(
            "warning",
            f"plan {job.plan_id}: the rest of the work over "
            f"{', '.join(m.id for m in job.document.machines)}"
            + (f"; {', '.join(gone)} left out" if gone else ""),
        )
        changed = set()
        for m in job.document.machines:
            v = self.state.vehicles[m.id]
            if not v.switch and v.phase is not Phase.ALIVE:
                # A mission that did not change (or not in what it holds): it goes on as it
                # is, or stays done.
                continue
            changed.add(m.id)
            if v.switch and v.items == before[m.id] and self.links[m.id].switch_from is not None:
                # Re-planned while its last new mission was on its way, and given the same
                # one again: that upload goes on (begun again at every re-plan, a 600-item
                # upload through a 20 %-loss radio never ended in a soak with a re-plan
                # every 40 s, its tractor held at the end of its kept part for 280 s).
                continue
            # A driving one told to HOLD while it was lost is started again on its new route.
            old = self.links[m.id]
            held = old.hold if v.switch else None
            link = self.links[m.id] = _Link(hold=held, round_trip=old.round_trip)
            # From its first item; one that finished while the re-plan ran, whose new
            # mission goes on after it, from there.
            link.start_item = v.resume_item
            if v.switch:  # driving: its new mission is uploaded under it
                link.switch_from = v.route_from
                if old.lower_after is not None and old.lower_after[0] < v.route_from:
                    # To be lowered along the part it keeps: still to be (or being) lowered.
                    link.lower_after, link.lowerings = old.lower_after, old.lowerings
                    link.lower, link.raising, link.watch = old.lower, old.raising, old.watch
                elif old.raising is not None and old.raising < v.route_from:
                    # The mission's raising after a lowering of ours, on the part it keeps
                    # (the same items): it goes on.
                    link.lower, link.raising = old.lower, old.raising
                elif old.watch is not None and old.lower is None and old.watch[0] < v.route_from:
                    link.watch = old.watch  # (after a lowering of ours, on that part)
                self._log(
                    "info", f"{m.id}: new route from item {v.route_from}; uploading under way"
                )
                self._upload_switch(v, link, now)
        kept = [m.id for m in job.document.machines if m.id not in changed]
        if kept:
            self._log("info", f"missions unchanged, not uploaded: {', '.join(kept)}")
        return changed

    def _upload_switch(self, v: VehicleState, link: _Link, now: float) -> None:
        """Upload a driving vehicle's new mission under it: the part it keeps, then its new
        route to the first place a window may end (the implement next raised, at a turn or
        the field's end: mission/window.py, ``shortest``); top-ups give it the rest."""
        count = window(v.items, v.route_from, shortest(self.config.window_items))
        if count != v.onboard:
            self._apply(ev.WindowExtended(v.id, count), now)
        self._send_window(v, link, now, switch=True)

    def _advance_switch(self, v: VehicleState, link: _Link, now: float) -> None:
        """A driving vehicle re-planned: upload, then make sure it drives the new route
        (set the current item when it went past the end of its old part), then read back."""
        if link.upload is None or link.upload.outcome is Outcome.RUNNING:
            self._hold_at_route_end(v, link, now)
            return
        if link.upload.outcome is Outcome.FAILED:
            self._log("warning", f"{v.id}: new mission not uploaded ({link.upload.reason}); again")
            self._upload_switch(v, link, now)
            return
        if link.download is None:
            if v.old_items is not None:
                self._apply(ev.SwitchUploaded(v.id), now)
                self._join(v, link, now)
            # Read back from the first item of the new route: those before it are the same
            # in the old mission and the new, so whatever part of the upload the autopilot
            # took, they are right (the count is read too).
            link.download = MissionDownload(
                v.system_id,
                first=v.numbering.to_vehicle(link.switch_from or 1),
                round_trip=link.round_trip,
            )
            self._send(v.id, link.download.start(now))
            return
        if link.download.outcome is Outcome.RUNNING:
            return
        read, link.download = link.download, None
        if read.outcome is Outcome.FAILED or self._held_differences(v, read):
            self._upload_switch(v, link, now)
            return
        self._apply(ev.UploadAcked(v.id), now)
        sent = count_on_board(v.held, v.numbering.base)
        self._upload_took[v.id] = (now - link.since, 2 * sent - read.first)
        starting = link.start is not None and link.start.outcome is Outcome.RUNNING
        if link.hold is not None or not v.driving or (v.mission_stopped and not starting):
            # Told to HOLD while it was lost (the order may still be on its way), or stopped
            # (disarmed, out of AUTO, or its mission complete at the end of what it held):
            # armed and in AUTO again, on its new route.
            link.hold = None
            link.start_item = link.join if link.join is not None else v.go_on_item
            if v.held_for_route and link.switch_from is not None:
                # Held where its new route begins: the kept part is behind it (the reports
                # of its last items may be lost), never driven again.
                link.start_item = max(link.start_item, link.switch_from)
            self._log(
                "info", f"{v.id}: not driving; on with its new route at item {link.start_item}"
            )
            self._start(v, link, now)
        else:
            self._log("info", f"{v.id}: new mission on board while driving")

    def _hold_at_route_end(self, v: VehicleState, link: _Link, now: float) -> None:
        """A vehicle whose new mission is still on its way, at the end of the part of its
        old mission the new one keeps: told to HOLD there. Beyond it, the old mission drives
        on to fields the re-plan may have given to others (two soaks under 20 % loss: a
        switch upload of ~750 items took 63-76 s, and two tractors worked a field each
        that another was given too). It is started on its new route once that is on board
        (:meth:`_advance_switch`); the wait is the price of never working a field twice."""
        first = link.switch_from
        if link.hold is not None or v.old_items is None or first is None or v.current < first:
            return
        self._apply(ev.HeldForRoute(v.id), now)
        link.hold = CommandSequence(hold_commands(), v.system_id)
        self._send(v.id, link.hold.start(now))
        self._log(
            "info",
            f"{v.id}: at the end of the part of its old mission the new one keeps (item "
            f"{first - 1}), its new route not on board yet: HOLD until it is",
        )

    def _join(self, v: VehicleState, link: _Link, now: float) -> None:
        """The new mission just went on board. A vehicle that went on past the part of its
        old mission the new one keeps now drives the new mission's item at its index,
        another one (an autopilot keeps its current index across an upload): sent at once
        to where its new route goes on, before the read-back (of the new route's items),
        so it does not work again what it did meanwhile."""
        first = link.switch_from or 1
        if v.current <= first:
            return
        link.join = self.state.join_item(v, first)
        self._apply(ev.RouteJoined(v.id, link.join), now)
        self._log(
            "warning",
            f"{v.id}: went past the part of its old mission the new one keeps; "
            f"on at item {link.join} of its new route (item {first} begins it)",
        )
        if link.hold is None and v.driving and v.mission_stopped:
            # It had stopped (at the end of the window it held): the item set current, it
            # would stand there still. Started again at the item, at once.
            link.start_item = link.join
            self._start(v, link, now, in_auto=True)
        elif link.hold is None and v.driving:
            link.start = CommandSequence([set_current_command(link.join)], v.system_id)
            self._send(v.id, link.start.start(now))

    def _hold(self, v: VehicleState, link: _Link, now: float) -> None:
        """Tell a lost vehicle to stop where it is (HOLD), once; it may not hear it."""
        for exchange in (link.upload, link.download, link.start):
            if exchange is not None and exchange.outcome is Outcome.RUNNING:
                exchange.outcome, exchange.reason = Outcome.FAILED, "vehicle lost"
        link.start = None
        link.topup_from = None
        link.hold = CommandSequence(hold_commands(), v.system_id)
        self._send(v.id, link.hold.start(now))

    def _parking(self) -> bool:
        return any(
            lk.park is not None and lk.park.outcome is Outcome.RUNNING for lk in self.links.values()
        )

    def _fleet_ready(self) -> bool:
        """Uploads begin once every vehicle has shown up (or been given up on)."""
        return all(v.phase is not Phase.WAITING for v in self.state.vehicles.values())

    def _send(self, vid: str, messages: list[mc.MAVLinkMessage]) -> None:
        if messages and self.store is not None:
            self.store.commit(self.state)  # what a command depends on is kept first
        key = wire.vehicle_to(self.farm, vid)
        sender = self.senders.get(vid)
        codec = self.codecs[vid]
        numbering = self.state.vehicles[vid].numbering if vid in self.state.vehicles else None
        for msg in messages:
            if numbering is not None:
                msg = command_to_vehicle(msg, numbering)
            frame = codec.encode(msg)
            if sender is not None:
                sender.send(frame)
            else:  # not started (a test driving the daemon by hand): straight out
                self.publishers[vid].put(frame)
            if self.recorder is not None:
                self.recorder.record_frame(key, frame, time.time_ns(), mc.as_dict(msg))

    def _status_doc(self) -> dict[str, Any]:
        """The fleet's status with each vehicle's count of frames on its command key we did
        not send (the last, at the end of the run, too: review read 0 from it)."""
        doc = self.state.status_doc(time.monotonic())
        for vid, count in self.foreign_frames.items():
            doc["vehicles"][vid]["foreign_commands"] = count
        return doc

    def _publish_status(self, now: float) -> None:
        self._last_status = now
        doc = self._status_doc()
        self._status_json = json.dumps(doc)
        if self.recorder is not None:
            self.recorder.record_status(doc, time.time_ns())
        if self.config.on_progress is not None:
            self._last_progress = now
            self.config.on_progress(self.state)

    def _apply(self, event: ev.Event, now: float) -> None:
        """Every change of the fleet's state goes through here: applied, then recorded
        (review replays the recorded events with the same ``FleetState.apply``)."""
        was = (
            self.state.vehicles[event.vehicle].phase
            if event.vehicle in self.state.vehicles
            else None
        )
        self.state.apply(event, now)
        if isinstance(event, ev.VehicleSeen) and event.vehicle in self.links:
            link = self.links[event.vehicle]
            link.heard_at = now if link.heard_at is None else link.heard_at
        # One time for its stored copy and its record: a resumed run's copy is told from
        # the original by it (a re-plan's, stored 0.12 s before it was recorded, was told
        # twice by the review).
        wall_ns = time.time_ns()
        if self.store is not None:
            self.store.append(event, wall_ns / 1e9)
        if isinstance(event, ev.UploadAcked) and self._awaiting_acks is not None:
            index, waiting, since = self._awaiting_acks
            if event.vehicle in waiting:
                self.state.upload_s = max(self.state.upload_s, now - self._adopted_at)
            waiting.discard(event.vehicle)
            if not waiting:
                self.replans[index][2] = time.monotonic() - since
                self._awaiting_acks = None
        deaf = isinstance(event, ev.StartFailed) or (
            isinstance(event, ev.UploadFailed) and event.final
        )
        if (
            (deaf or isinstance(event, ev.VehicleLost | ev.VehicleStalled))
            and self.config.replanner is not None
            and was not in (None, Phase.DONE, Phase.FAILED, Phase.LOST)
            and not self.state.vehicles[event.vehicle].retired  # its work is the others'
            and not self.state.all_fields_done()
        ):
            v = self.state.vehicles[event.vehicle]
            if not deaf:
                self._want_replan(f"{event.vehicle} lost ({v.error})", now, supersede=True)
            elif not v.runs_mission and self._work_left(v):
                # Heard, but deaf to our commands (a dead uplink: its failsafe holds it
                # where it is, or it stands at the end of its window), or never answering
                # them: its work goes to the others, as a lost one's does, and it is asked
                # now and then whether it hears us again (_probe). One heard running its
                # mission took the start after all: left be.
                what = "started" if isinstance(event, ev.StartFailed) else "given its mission"
                self._want_replan(
                    f"{event.vehicle} could not be {what} ({v.error})", now, supersede=True
                )
        if self.recorder is not None:
            self.recorder.record_event(ev.to_dict(event), wall_ns)

    def _others_can_take(self, v: VehicleState) -> bool:
        """Whether a re-plan would give the work ahead of ``v`` to other vehicles: there is
        a replanner, work ahead of it, and another vehicle not gone."""
        return (
            self.config.replanner is not None
            and self._work_left(v)
            and any(o.phase not in GONE for o in self.state.vehicles.values() if o is not v)
        )

    def _work_left(self, v: VehicleState) -> bool:
        """Whether fields not done lie ahead on the vehicle's mission."""
        fields = self.state.fields
        return any(
            item.field_id is not None and fields[str(item.field_id)].status != "done"
            for item in v.items[v.resume_item :]
        )

    def _log(self, level: str, text: str) -> None:
        getattr(log, level)(text)
        if self.recorder is not None:
            self.recorder.record_log(level, text, time.time_ns())
