"""Write a :class:`~dispatcher.mission.build.Mission` as files ground stations open.

* ``.waypoints``: the plain-text "QGC WPL 110" format (mavlink.io/en/file_formats), read by
  MAVProxy / ``pymavlink.mavwp.MAVWPLoader``, Mission Planner and QGroundControl. One
  tab-separated line per item: seq, current, frame, command, param1..4, lat, lon, alt,
  autocontinue. Lat/lon are degrees, so frames are the float ones
  (``GLOBAL_RELATIVE_ALT`` = 3 rather than ``GLOBAL_RELATIVE_ALT_INT`` = 6), as
  ``MAVWPLoader`` builds MISSION_ITEM messages from them. Item 0 is home (QGroundControl
  reads a 110 file's first line as the planned home position).
* ``.plan``: QGroundControl's JSON plan (docs.qgroundcontrol.com, "Plan File Format";
  ``MissionController::save`` / ``_loadJsonMissionFileV2``). The home item is not in
  ``mission.items`` but in ``plannedHomePosition``: QGroundControl numbers the items from
  1 and, for ArduPilot, sends the planned home itself as item 0. So the plan holds
  ``len(mission) - 1`` SimpleItems whose ``doJumpId`` is their mission seq. The farm is
  its geofence (``geoFence.polygons``, each ``{"inclusion": bool, "polygon": [[lat, lon],
  ...] (not closed), "version": 1}``) and the garage its rally point
  (``rallyPoints.points``: ``[lat, lon, alt]``), as :mod:`dispatcher.mission.export` makes
  them.

Each writer writes the whole file to the path it is given in one go; writing to a
temporary name and renaming is the caller's business.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from dispatcher.link import mavlink as mc
from dispatcher.link.mission_item import MissionItem
from dispatcher.mission.build import Mission

WAYPOINTS_HEADER = "QGC WPL 110"

QGC_PLAN_FILE_VERSION = 1
QGC_MISSION_VERSION = 2
QGC_GEOFENCE_VERSION = 2
QGC_RALLY_VERSION = 2
QGC_FENCE_POLYGON_VERSION = 1  # QGCFencePolygon's own "version"
QGC_ALTITUDE_MODE_RELATIVE = 1  # QGroundControlQmlGlobal::AltitudeModeRelative

PathLike = str | os.PathLike[str]


def waypoints_text(mission: Mission) -> str:
    """The mission in QGC WPL 110 text, home first."""
    lines = [WAYPOINTS_HEADER]
    for item in mission.items:
        fields = [
            str(item.seq),
            str(item.current),
            str(mc.float_frame(item.frame)),
            str(item.command),
            _number(item.param1),
            _number(item.param2),
            _number(item.param3),
            _number(item.param4),
            _degrees(item.x),
            _degrees(item.y),
            _number(item.z),
            str(item.autocontinue),
        ]
        lines.append("\t".join(fields))
    return "\n".join(lines) + "\n"


def write_waypoints(mission: Mission, path: PathLike) -> None:
    """Write the mission as a ``.waypoints`` (QGC WPL 110) file at ``path``."""
    _write_text(path, waypoints_text(mission))


LatLonRing = Sequence[tuple[float, float]]


@dataclass(frozen=True)
class Fence:
    """A geofence and rally points for a ``.plan`` file, all in (lat, lon) degrees."""

    inclusion: Sequence[LatLonRing] = ()
    exclusion: Sequence[LatLonRing] = ()
    rally: Sequence[tuple[float, float]] = ()


def qgc_plan(mission: Mission, fence: Fence = Fence()) -> dict[str, Any]:
    """The mission as a QGroundControl plan document (a JSON-ready dict)."""
    if len(mission.items) == 0:
        raise ValueError(f"mission for {mission.machine_id!r} is empty: no home item")
    home, *rest = mission.items
    speeds = [item.param2 for item in rest if item.command == mc.MAV_CMD_DO_CHANGE_SPEED]
    cruise_speed = speeds[0] if speeds else 0.0
    hover_speed = speeds[1] if len(speeds) > 1 else cruise_speed
    return {
        "fileType": "Plan",
        "version": QGC_PLAN_FILE_VERSION,
        "groundStation": "QGroundControl",
        "mission": {
            "version": QGC_MISSION_VERSION,
            "firmwareType": mc.MAV_AUTOPILOT_ARDUPILOTMEGA,
            "vehicleType": mc.MAV_TYPE_GROUND_ROVER,
            # For QGroundControl's time estimate only: road speed, and working speed in
            # the multirotor-only hover slot (unused for a rover).
            "cruiseSpeed": cruise_speed,
            "hoverSpeed": hover_speed,
            "globalPlanAltitudeMode": QGC_ALTITUDE_MODE_RELATIVE,
            "plannedHomePosition": [home.x / 1e7, home.y / 1e7, home.z],
            "items": [_simple_item(item) for item in rest],
        },
        "geoFence": {
            "circles": [],
            "polygons": [
                {
                    "inclusion": inclusion,
                    "polygon": [[lat, lon] for lat, lon in ring],
                    "version": QGC_FENCE_POLYGON_VERSION,
                }
                for inclusion, rings in ((True, fence.inclusion), (False, fence.exclusion))
                for ring in rings
            ],
            "version": QGC_GEOFENCE_VERSION,
        },
        "rallyPoints": {
            "points": [[lat, lon, 0.0] for lat, lon in fence.rally],
            "version": QGC_RALLY_VERSION,
        },
    }


def write_qgc_plan(mission: Mission, path: PathLike, fence: Fence = Fence()) -> None:
    """Write the mission as a QGroundControl ``.plan`` file at ``path``."""
    text = json.dumps(qgc_plan(mission, fence), indent=4, sort_keys=True, allow_nan=False)
    _write_text(path, text + "\n")


def _simple_item(item: MissionItem) -> dict[str, Any]:
    return {
        "autoContinue": bool(item.autocontinue),
        "command": item.command,
        "doJumpId": item.seq,
        "frame": mc.float_frame(item.frame),
        "params": [
            item.param1,
            item.param2,
            item.param3,
            item.param4,
            item.x / 1e7,
            item.y / 1e7,
            item.z,
        ],
        "type": "SimpleItem",
    }


def _number(value: float) -> str:
    """Shortest text that reads back as the same float."""
    return repr(float(value))


def _degrees(scaled: int) -> str:
    """Degrees * 1e7 as exact decimal degrees."""
    return f"{scaled / 1e7:.7f}"


def _write_text(path: PathLike, text: str) -> None:
    with open(path, "w", encoding="utf-8", newline="\n") as stream:
        stream.write(text)
