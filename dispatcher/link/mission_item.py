"""One mission item as it goes over the wire (MISSION_ITEM_INT) and as an autopilot stores it:
the shape the dispatcher's missions, the mission protocol and the simulated autopilot share."""

from __future__ import annotations

from dataclasses import dataclass

from dispatcher.link import mavlink as mc


@dataclass(frozen=True)
class MissionItem:
    """One MISSION_ITEM_INT, as uploaded (x, y = lat, lon in degrees * 1e7)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = mc.MAV_MISSION_TYPE_MISSION

    @property
    def lat(self) -> float:
        """Latitude in degrees."""
        return self.x / 1e7

    @property
    def lon(self) -> float:
        """Longitude in degrees."""
        return self.y / 1e7

    @property
    def is_waypoint(self) -> bool:
        """True for navigation waypoints (home and return included)."""
        return self.command == mc.MAV_CMD_NAV_WAYPOINT

    def message(
        self, target_system: int, target_component: int = mc.MAV_COMP_ID_AUTOPILOT1
    ) -> mc.MissionItemIntMessage:
        """This item as a MISSION_ITEM_INT message addressed to ``target_system``."""
        return mc.mission_item_int(
            target_system=target_system,
            target_component=target_component,
            seq=self.seq,
            frame=self.frame,
            command=self.command,
            current=self.current,
            autocontinue=self.autocontinue,
            param1=self.param1,
            param2=self.param2,
            param3=self.param3,
            param4=self.param4,
            x=self.x,
            y=self.y,
            z=self.z,
            mission_type=self.mission_type,
        )
