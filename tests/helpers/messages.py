"""MAVLink messages the tests need again and again."""

from __future__ import annotations

from dispatcher.link import mavlink as mc


def from_vehicle(msg: mc.MAVLinkMessage, system: int, component: int = 1) -> mc.MAVLinkMessage:
    """``msg`` as if received from (system, component): encoded and decoded again."""
    codec = mc.Codec(system, component)
    decoded = codec.decode_one(codec.encode(msg))
    assert decoded is not None
    return decoded


def command_ack(command: int, result: int) -> mc.MAVLinkMessage:
    """A vehicle's COMMAND_ACK to the dispatcher (system 255, component 190)."""
    return mc.message(
        "COMMAND_ACK",
        command=command,
        result=result,
        progress=0,
        result_param2=0,
        target_system=255,
        target_component=190,
    )


def position(t_ms: int, lat_e7: int = 0, lon_e7: int = 0) -> mc.MAVLinkMessage:
    """A GLOBAL_POSITION_INT at ``t_ms`` on the vehicle's clock, standing still."""
    return mc.message(
        "GLOBAL_POSITION_INT",
        time_boot_ms=t_ms,
        lat=lat_e7,
        lon=lon_e7,
        alt=0,
        relative_alt=0,
        vx=0,
        vy=0,
        vz=0,
        hdg=0,
    )


def track(items, first: int, last: int, t0_ms: int = 1_000) -> list[mc.MAVLinkMessage]:
    """GLOBAL_POSITION_INT at each positioned item of ``items[first..last]`` in turn, a
    second apart: a vehicle's track that passes them (what makes its progress plausible)."""
    return [
        position(t0_ms + 1_000 * k, item.x, item.y)
        for k, item in enumerate(items[first : last + 1])
        if item.x or item.y
    ]


def waypoint(
    seq: int,
    x: int,
    y: int,
    target_system: int = 1,
    frame: int = mc.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
) -> mc.MAVLinkMessage:
    """A MISSION_ITEM_INT NAV_WAYPOINT: item ``seq`` at lat ``x``, lon ``y`` (degrees * 1e7)."""
    return mc.mission_item_int(
        target_system=target_system,
        target_component=1,
        seq=seq,
        frame=frame,
        command=mc.MAV_CMD_NAV_WAYPOINT,
        current=0,
        autocontinue=1,
        param1=0,
        param2=0,
        param3=0,
        param4=0,
        x=x,
        y=y,
        z=0,
    )


def waypoints(
    n: int, target_system: int = 1, step_x: int = 1, step_y: int = 1
) -> list[mc.MAVLinkMessage]:
    """A mission of ``n`` MISSION_ITEM_INT waypoints (seq 0 .. n-1), each ``step_x``,
    ``step_y`` (degrees * 1e7) from the one before."""
    return [
        waypoint(k, 440000000 + step_x * k, 873000000 + step_y * k, target_system) for k in range(n)
    ]
