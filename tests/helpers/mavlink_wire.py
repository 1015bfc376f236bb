"""Helpers for tests that talk to a simulated vehicle over real MAVLink frames.

A :class:`Wire` passes every message through a MAVLink 2 frame each way, so a test sees
exactly what a ground station and the vehicle would (ids, sequence numbers, CRC, float32
rounding). The builders make ground-station messages with the usual addressing.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from dispatcher.link import mavlink as mc
from dispatcher.link import wire as contract
from sim_vehicles.mission_server import StoredItem

HOME = StoredItem(
    seq=0,
    frame=mc.MAV_FRAME_GLOBAL,
    command=mc.MAV_CMD_NAV_WAYPOINT,
    current=0,
    autocontinue=1,
    param1=0.0,
    param2=0.0,
    param3=0.0,
    param4=0.0,
    x=440030000,
    y=872995000,
    z=0.0,
)
"""Item 0 of a simulated vehicle's mission, as ArduPilot reports its home."""


@dataclass
class Wire:
    """A ground station (system 255, component 190) and one vehicle."""

    vehicle_system: int
    vehicle_component: int = mc.MAV_COMP_ID_AUTOPILOT1
    gcs_system: int = contract.DISPATCHER_SYSTEM_ID
    gcs_component: int = contract.DISPATCHER_COMPONENT_ID
    _codecs: dict[str, mc.Codec] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        gcs = (self.gcs_system, self.gcs_component)
        vehicle = (self.vehicle_system, self.vehicle_component)
        self._codecs = {
            "gcs": mc.Codec(*gcs),
            "gcs_rx": mc.Codec(*gcs),
            "vehicle": mc.Codec(*vehicle),
            "vehicle_rx": mc.Codec(*vehicle),
        }

    def up(self, msg: mc.MAVLinkMessage) -> mc.MAVLinkMessage:
        """``msg`` from the ground station, as the vehicle decodes it."""
        decoded = self._codecs["vehicle_rx"].decode_one(self._codecs["gcs"].encode(msg))
        if decoded is None:
            raise ValueError(f"{msg.get_type()} did not survive its frame")
        return decoded

    def down(self, messages: Iterable[mc.MAVLinkMessage]) -> list[mc.MAVLinkMessage]:
        """The vehicle's ``messages``, as the ground station decodes them."""
        out: list[mc.MAVLinkMessage] = []
        for msg in messages:
            decoded = self._codecs["gcs_rx"].decode_one(self._codecs["vehicle"].encode(msg))
            if decoded is None:
                raise ValueError(f"{msg.get_type()} did not survive its frame")
            out.append(decoded)
        return out

    def command_long(self, command: int, *params: float) -> mc.MAVLinkMessage:
        """COMMAND_LONG to the vehicle; missing params are 0."""
        p = (list(params) + [0.0] * 7)[:7]
        return mc.message(
            "COMMAND_LONG",
            target_system=self.vehicle_system,
            target_component=self.vehicle_component,
            command=command,
            confirmation=0,
            param1=p[0],
            param2=p[1],
            param3=p[2],
            param4=p[3],
            param5=p[4],
            param6=p[5],
            param7=p[6],
        )

    def mission_msg(self, name: str, **fields: object) -> mc.MAVLinkMessage:
        """A mission-protocol message to the vehicle (mission_type MISSION unless given)."""
        fields.setdefault("mission_type", mc.MAV_MISSION_TYPE_MISSION)
        return mc.message(
            name,
            target_system=self.vehicle_system,
            target_component=self.vehicle_component,
            **fields,
        )


def types(messages: Iterable[mc.MAVLinkMessage]) -> list[str]:
    """The MAVLink names of ``messages``."""
    return [m.get_type() for m in messages]


def only(messages: Iterable[mc.MAVLinkMessage], *kinds: str) -> list[mc.MAVLinkMessage]:
    """The messages of the given kinds, in order."""
    return [m for m in messages if m.get_type() in kinds]
