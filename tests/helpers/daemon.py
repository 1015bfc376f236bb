"""A daemon driven by hand, without Zenoh: its state fed reports, its frames kept."""

from __future__ import annotations

from dispatcher.daemon import events as ev
from dispatcher.link import mavlink as mc
from helpers.messages import from_vehicle


def feed(state, vid, msg, now):
    """A report from a vehicle, and the events it implies, as the daemon does."""
    for event in state.on_message(vid, msg, now):
        state.apply(event, now)


def heartbeat(sysid):
    msg = mc.message(
        "HEARTBEAT",
        type=mc.MAV_TYPE_GROUND_ROVER,
        autopilot=mc.MAV_AUTOPILOT_ARDUPILOTMEGA,
        base_mode=0,
        custom_mode=10,
        system_status=4,
        mavlink_version=3,
    )
    return mc.Codec(255, 190).decode_one(mc.Codec(sysid, 1).encode(msg))


class Pub:
    def __init__(self):
        self.frames = []

    def put(self, frame):
        self.frames.append(frame)

    def sent(self, system=11):
        return [mc.Codec(system, 1).decode_one(f) for f in self.frames]


def daemon_for(dispatch):
    """A daemon of ``dispatch``'s job whose frames to each vehicle are kept (``Pub``)."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher

    daemon = Dispatcher(DaemonConfig(job=dispatch.job()))
    daemon.publishers = {vid: Pub() for vid in dispatch.missions}
    return daemon


def running_events(vid, reached):
    return [
        ev.VehicleSeen(vid),
        ev.UploadStarted(vid, 1),
        ev.UploadAcked(vid),
        ev.StartRequested(vid, 1),
        ev.MissionStarted(vid, 1),
        ev.ItemReached(vid, reached, 100.0),
    ]


def mission_current(sysid, seq, total, state):
    msg = mc.message("MISSION_CURRENT", seq=seq, total=total, mission_state=state, mission_mode=1)
    return from_vehicle(msg, sysid)


def deliver(daemon, vid, msg, now, sysid=11):
    """A frame from vehicle ``vid`` (system ``sysid``) through the daemon's own handling,
    as it arrives over Zenoh (recorded, decoded, its events applied, the link moved on)."""
    from dispatcher.link import wire

    payload = mc.Codec(sysid, 1).encode(msg)
    daemon._handle(("frame", wire.vehicle_from(daemon.farm, vid), payload, int(now * 1e9)), now)
