"""Coverage-guided fuzzing with atheris (libFuzzer), beside the hypothesis tests here.

Not a pytest test (atheris runs until stopped, and is no dependency of the project: install
it with ``.venv/bin/pip install atheris``). Run one target for a number of inputs::

    .venv/bin/python tests/fuzz/atheris_harness.py decoder -runs=200000
    .venv/bin/python tests/fuzz/atheris_harness.py mission -runs=50000
    .venv/bin/python tests/fuzz/atheris_harness.py farm -runs=50000

Targets: ``decoder`` (dispatcher.link.mavlink.Codec.decode on the bytes, in pieces;
decode_one), ``mission`` (the bytes as a sequence of mission-protocol messages from several
senders, fed to a MissionServer and a MissionUpload/MissionDownload: no exception may
escape), ``farm`` (planner.farm.farm_from_geojson on the bytes as JSON: only GeometryError;
the crashes test_fuzz_loaders.py lists as known are left out). A crash leaves the input in
``crash-*`` in the working directory.
"""

from __future__ import annotations

import json
import sys

import atheris

with atheris.instrument_imports():
    from dispatcher.link import mavlink as mc
    from dispatcher.link.mission_protocol import MissionDownload, MissionUpload
    from planner.errors import PlannerError
    from planner.farm import farm_from_geojson
    from sim_vehicles.mission_server import MissionServer, StoredItem

HOME = StoredItem(0, 0, 16, 0, 1, 0.0, 0.0, 0.0, 0.0, 440030000, 872995000, 0.0)
SENDERS = [(255, 190), (21, 1), (254, 190), (21, 191)]
KINDS = [
    "MISSION_REQUEST_INT",
    "MISSION_REQUEST",
    "MISSION_ACK",
    "MISSION_COUNT",
    "MISSION_ITEM_INT",
    "MISSION_ITEM",
    "MISSION_REQUEST_LIST",
    "MISSION_CLEAR_ALL",
]


def decoder(data: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(data)
    codec = mc.Codec(255, 190)
    while fdp.remaining_bytes():
        for msg in codec.decode(fdp.ConsumeBytes(fdp.ConsumeIntInRange(1, 64))):
            mc.as_dict(msg)
    codec.decode_one(data)


def _message(fdp: atheris.FuzzedDataProvider) -> mc.MAVLinkMessage:
    kind = KINDS[fdp.ConsumeIntInRange(0, len(KINDS) - 1)]
    address = {"target_system": 21, "target_component": 1}
    mtype = fdp.PickValueInList([0, 0, 0, 1, 255])
    if kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
        return mc.message(kind, **address, seq=fdp.ConsumeIntInRange(0, 65535), mission_type=mtype)
    if kind == "MISSION_ACK":
        return mc.message(kind, **address, type=fdp.ConsumeIntInRange(0, 255), mission_type=mtype)
    if kind == "MISSION_COUNT":
        return mc.message(kind, **address, count=fdp.ConsumeIntInRange(0, 8), mission_type=mtype)
    if kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
        floats = [fdp.ConsumeRegularFloat() if fdp.ConsumeBool() else 0.0 for _ in range(5)]
        if kind == "MISSION_ITEM_INT":
            x, y = (
                fdp.ConsumeIntInRange(-(2**31), 2**31 - 1),
                fdp.ConsumeIntInRange(-(2**31), 2**31 - 1),
            )
        else:
            x, y = fdp.ConsumeRegularFloat(), fdp.ConsumeRegularFloat()
        return mc.message(
            kind,
            **address,
            seq=fdp.ConsumeIntInRange(0, 8),
            frame=fdp.ConsumeIntInRange(0, 255),
            command=fdp.PickValueInList([16, 178, 183, 203, 65535]),
            current=fdp.ConsumeIntInRange(0, 3),
            autocontinue=1,
            param1=floats[0],
            param2=floats[1],
            param3=floats[2],
            param4=floats[3],
            x=x,
            y=y,
            z=floats[4],
            mission_type=mtype,
        )
    return mc.message(kind, **address, mission_type=mtype)


def _framed(sender: tuple[int, int], msg: mc.MAVLinkMessage) -> mc.MAVLinkMessage | None:
    try:
        frame = mc.Codec(*sender).encode(msg)
    except (OverflowError, ValueError, TypeError, mc.mavlink2.MAVError):
        return None  # the provider's float does not fit a float32 field
    return mc.Codec(240, 1).decode_one(frame)


def mission(data: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(data)
    server = MissionServer(lambda: HOME)
    items = [HOME.message(21, 1) for _ in range(fdp.ConsumeIntInRange(0, 4))]
    client = MissionUpload(items, 21) if fdp.ConsumeBool() else MissionDownload(21)
    now = 0.0
    client.start(now)
    while fdp.remaining_bytes():
        now += fdp.ConsumeIntInRange(0, 3000) / 1000.0
        msg = _framed(SENDERS[fdp.ConsumeIntInRange(0, len(SENDERS) - 1)], _message(fdp))
        if msg is None:
            continue
        for reply in server.on_message(msg, now) + server.on_tick(now):
            mc.Codec(21, 1).encode(reply)
        client.on_message(msg, now)
        client.on_tick(now)


def farm(data: bytes) -> None:
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):  # not JSON, or a known crash of load_farm
        return
    if '"' not in data.decode() and "[" not in data.decode():
        return
    try:
        farm_from_geojson(doc, "fuzz.geojson")
    except PlannerError:
        pass
    except OverflowError:  # known: an integer too big for a float (test_fuzz_loaders.py)
        pass


TARGETS = {"decoder": decoder, "mission": mission, "farm": farm}

if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in TARGETS:
        sys.exit(f"usage: {sys.argv[0]} {{{'|'.join(TARGETS)}}} [libFuzzer options]")
    target = TARGETS[sys.argv.pop(1)]
    atheris.Setup(sys.argv, target)
    atheris.Fuzz()
