"""Only the dispatcher commands the tractors, and forged progress counts for nothing
(issue 11): real processes on loopback (`agrifleet serve`, simulated tractors) and an
outside Zenoh session that attacks them.

On a plain loopback endpoint (MAVLink signing on, as everywhere but the demo), while the
fleet works: a foreign system uploads its own mission to v1 and arms it, disarms v2 (once
unsigned, once signed with a wrong key), spoofs ~1,400 mission-protocol frames and forges
the last MISSION_ITEM_REACHED of v1, unsigned and then signed with v1's real key (a leaked
key). Each attack fails; the dispatcher raises an alarm for each; no field is done that was
not worked; the run finishes; the review reports the alarms.

With mutual TLS and the farm's access-control list (`agrifleet certs`, `--tls`): a session
without a certificate cannot connect, and one with v2's certificate that publishes on v1's
keys reaches neither the dispatcher nor v1.
"""

from __future__ import annotations

import dataclasses
import json
import secrets
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from helpers.mavlink_wire import HOME
from helpers.processes import (
    Processes,
    free_port,
    log_of,
    status_asker,
    wait_for,
    wait_for_share,
)
from helpers.review import assert_each_segment_worked_once

from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.link.access import OPERATOR, TlsIdentity, make_farm_pki
from dispatcher.link.keys import read_key
from dispatcher.recording.mcap_file import read_logs
from dispatcher.review.report import review_contents, review_table

SCENARIO = Path(__file__).parent / "data" / "restart.toml"  # two tractors, farm "restart"
FARM = "restart"
ATTACKER = 77  # a MAVLink system id nobody on the farm uses
SPEEDUP = 20


@pytest.fixture
def procs(tmp_path: Path) -> Iterator[Processes]:
    group = Processes(tmp_path)
    yield group
    group.stop_all()


def outside(endpoint: str, tls: TlsIdentity | None = None) -> zenoh.Session:
    """A Zenoh session of someone else's on the dispatcher's endpoint (a peer: it connects
    once the dispatcher listens)."""
    return zenoh.open(wire.ZenohOptions(connect=(endpoint,), tls=tls).config())


def frames(codec: mc.Codec, *messages: mc.MAVLinkMessage) -> list[bytes]:
    return [codec.encode(m) for m in messages]


def arm(target: int, on: bool) -> mc.MAVLinkMessage:
    return mc.message(
        "COMMAND_LONG",
        target_system=target,
        target_component=1,
        command=mc.MAV_CMD_COMPONENT_ARM_DISARM,
        confirmation=0,
        param1=1.0 if on else 0.0,
        param2=21196.0,  # force, as a ground station may
        param3=0.0,
        param4=0.0,
        param5=0.0,
        param6=0.0,
        param7=0.0,
    )


def far_mission(target: int) -> list[mc.MAVLinkMessage]:
    """A mission of a foreign system's: one waypoint 1.5 km north of the farm."""
    count = mc.message("MISSION_COUNT", target_system=target, target_component=1, count=2)
    wp = [
        dataclasses.replace(
            HOME, seq=seq, x=int((44.0 + 0.0135 * seq) * 1e7), y=int(87.3 * 1e7)
        ).to_item_int(target, 1)
        for seq in range(2)
    ]
    return [count, *wp]


def test_foreign_commands_and_forged_progress_fail_raise_alarms_and_the_run_finishes(
    procs: Processes, tmp_path: Path
) -> None:
    # A router, as on a farm with more than one gateway: it carries anyone's frames to
    # anyone, so the attacks reach the tractors and their signing checks are what stops them.
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    procs.start("router", "router", "--listen", endpoint)
    client = ("--mode", "client")
    serve = procs.serve(
        SCENARIO,
        port,
        tmp_path / "logs",
        "--time-limit",
        "1",
        endpoint=(*client, "--connect", endpoint),
    )
    keys = procs.keys(SCENARIO)
    stranger = mc.Codec(ATTACKER, 190)
    wrong_key = mc.Codec(ATTACKER, 190, key=secrets.token_bytes(32))
    v1 = mc.Codec(11, 1, key=read_key(keys, "v1"), link_id=7)  # v1's leaked key
    with outside(endpoint) as session:
        status = status_asker(session, FARM)
        wait_for("the dispatcher", lambda: bool(status()), 60.0, procs.report)
        # ~1,400 spoofed protocol frames on v1's key, before and during its upload.
        spoof = [
            mc.message("MISSION_REQUEST_INT", target_system=255, target_component=190, seq=k)
            for k in range(0, 700)
        ] + [
            mc.message("MISSION_ACK", target_system=255, target_component=190, type=0)
            for _ in range(700)
        ]
        fake_v1 = mc.Codec(11, 1)  # v1's system id, no key
        for frame in frames(fake_v1, *spoof[:700]):
            session.put(wire.vehicle_from(FARM, "v1"), frame)
        procs.sim(SCENARIO, port, SPEEDUP, "v1", extra=client)
        procs.sim(SCENARIO, port, SPEEDUP, "v2", extra=client)
        for frame in frames(fake_v1, *spoof[700:]):
            session.put(wire.vehicle_from(FARM, "v1"), frame)
        wait_for_share(status, ("v1", "v2"), 0.2, 120.0, procs.report)
        # A foreign mission for v1, armed; v2 disarmed, unsigned and with a wrong key.
        for frame in frames(stranger, *far_mission(11), arm(11, True)):
            session.put(wire.vehicle_to(FARM, "v1"), frame)
        for frame in frames(stranger, arm(12, False)) + frames(wrong_key, arm(12, False)):
            session.put(wire.vehicle_to(FARM, "v2"), frame)
        # v1 "reached" its last item: unsigned, then signed with its real key.
        last = status()["vehicles"]["v1"]["items"] - 1
        forged = mc.message("MISSION_ITEM_REACHED", seq=last)
        session.put(wire.vehicle_from(FARM, "v1"), fake_v1.encode(forged))
        session.put(wire.vehicle_from(FARM, "v1"), v1.encode(forged))

        def alarmed() -> bool:
            doc = status()
            texts = " | ".join(doc.get("alarms", []))
            return "not counted" in texts and "v2: a COMMAND_LONG" in texts

        wait_for("the alarms", alarmed, 30.0, procs.report)
        doc = status()
        assert all(f["status"] != "done" for f in doc["fields"].values() if f["vehicle"] == "v1")
        assert doc["vehicles"]["v1"]["frames_refused"] >= 1400, doc["vehicles"]["v1"]
    wait_for("the run to end", lambda: serve.poll() is not None, 240.0, procs.report)
    assert serve.returncode == 0, procs.report()
    sims = "".join(Processes.output(p) for p in procs.procs[2:])
    assert "v1: dropped" in sims and "v2: dropped" in sims, sims[-3000:]
    log = read_logs([log_of(Processes.output(serve))])
    review = review_contents(log)
    table = review_table(review)
    assert all(f.done for f in review.fields), table
    assert_each_segment_worked_once(review)
    kinds = {(a.vehicle, a.kind) for a in review.alarms}
    assert {("v1", "foreign_command"), ("v2", "foreign_command")} <= kinds, table
    assert ("v1", "progress_doubted") in kinds, table
    assert review.vehicle("v1").frames_refused >= 1400, table
    # Counted to the end: the last status (which review reads) had none (review said 0).
    assert review.vehicle("v1").foreign_commands >= 1, table
    assert "alarm" in table.lower(), table
    # Every foreign frame is in the log, on the key it came in on.
    topics = log.topic_counts()
    assert wire.vehicle_to(FARM, "v1") in topics and wire.vehicle_to(FARM, "v2") in topics


def test_without_the_farms_certificate_or_on_anothers_keys_nothing_gets_through(
    procs: Processes, tmp_path: Path
) -> None:
    tls = tmp_path / "tls"
    make_farm_pki(tls, FARM, ["v1", "v2"])
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    serve = procs.serve(
        SCENARIO,
        port,
        tmp_path / "logs",
        "--time-limit",
        "1",
        endpoint=("--listen", endpoint, "--tls", str(tls)),
    )
    for vid in ("v1", "v2"):
        procs.sim(SCENARIO, port, SPEEDUP, vid, extra=("--tls", str(tls)), scheme="tls")
    with outside(endpoint, TlsIdentity(tls, OPERATOR)) as watcher:
        wait_for_share(status_asker(watcher, FARM), ("v1",), 0.1, 120.0, procs.report)
    # No certificate: the TLS handshake fails, no session.
    plain = wire.ZenohOptions(mode="client", connect=(endpoint,)).config()
    plain.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(tls / "ca.pem")))
    plain.insert_json5("connect/timeout_ms", "2000")
    with pytest.raises(zenoh.ZError):
        zenoh.open(plain)
    # v2's certificate, v1's keys: dropped where it comes in.
    junk = mc.Codec(ATTACKER, 190)
    with outside(endpoint, TlsIdentity(tls, "v2")) as session:
        for _ in range(50):
            session.put(wire.vehicle_to(FARM, "v1"), junk.encode(arm(11, False)))
            session.put(
                wire.vehicle_from(FARM, "v1"),
                junk.encode(mc.message("MISSION_ITEM_REACHED", seq=3)),
            )
    wait_for("the run to end", lambda: serve.poll() is not None, 240.0, procs.report)
    assert serve.returncode == 0, procs.report()
    # Anything that had got through would be counted by the end of the run.
    log = read_logs([log_of(Processes.output(serve))])
    doc = log.on(wire.dispatcher_status(FARM))[-1].decode_json()
    v1 = doc["vehicles"]["v1"]
    assert v1["frames_refused"] == 0 and "foreign_commands" not in v1, v1
    assert doc["alarms"] == [], doc["alarms"]
    sims = "".join(Processes.output(p) for p in procs.procs[1:])
    assert "dropped" not in sims, sims[-3000:]
