"""Real processes on loopback: `agrifleet serve` and `agrifleet sim` over Zenoh.

Each test starts the dispatcher and a simulated vehicle process on a free port with
multicast scouting off, waits on conditions (a process exit, a status answer), and always
stops the processes it started.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh
from helpers.processes import keys_for

from dispatcher.link import mavlink as mc
from dispatcher.link import wire
from dispatcher.recording.mcap_file import read_log

DATA = Path(__file__).parent / "data"
SCENARIO = DATA / "tiny.toml"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Processes:
    def __init__(self) -> None:
        self.procs: list[subprocess.Popen[str]] = []

    def start(self, *args: str, quiet: bool = False) -> subprocess.Popen[str]:
        out = subprocess.DEVNULL if quiet else subprocess.PIPE
        proc = subprocess.Popen(
            [sys.executable, "-m", "dispatcher.cli", *args], stdout=out, stderr=out, text=True
        )
        self.procs.append(proc)
        return proc

    def stop_all(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            for stream in (p.stdout, p.stderr):
                if stream is not None:
                    stream.close()


@pytest.fixture
def procs():
    group = Processes()
    yield group
    group.stop_all()


def serve(procs, port, log_dir, *extra):
    return procs.start(
        "serve",
        str(SCENARIO),
        "--listen",
        f"tcp/127.0.0.1:{port}",
        "--log-dir",
        str(log_dir),
        "--time-limit",
        "1",
        "--keys",
        keys_for(SCENARIO),
        *extra,
    )


def sim(procs, port, speedup, *vehicles):
    args = ["sim", str(SCENARIO), "--connect", f"tcp/127.0.0.1:{port}", "--speedup", str(speedup)]
    args += ["--keys", keys_for(SCENARIO)]
    for v in vehicles:
        args += ["--vehicle", v]
    return procs.start(*args, quiet=True)


def log_path(stdout: str) -> Path:
    lines = [ln for ln in stdout.splitlines() if ln.startswith("log: ")]
    assert lines, stdout
    return Path(lines[-1][5:])


def query_status(port: int, farm: str = "tiny", timeout_s: float = 20.0) -> dict:
    """Ask the dispatcher's status queryable until it answers."""
    conf = wire.client_options((f"tcp/127.0.0.1:{port}",)).config()
    deadline = time.monotonic() + timeout_s
    with zenoh.open(conf) as session:
        while time.monotonic() < deadline:
            for reply in session.get(wire.dispatcher_status(farm), timeout=2.0):
                if reply.ok is not None:
                    doc = json.loads(reply.ok.payload.to_string())
                    if doc:
                        return doc
            time.sleep(0.1)  # the dispatcher may not be up yet: ask again
    raise AssertionError("no status answer")


def test_upload_run_complete_cycle_recorded_to_mcap(procs, tmp_path):
    port = free_port()
    dispatcher = serve(procs, port, tmp_path)
    sim(procs, port, 400, "v1", "v2")
    out, err = dispatcher.communicate(timeout=120)
    assert dispatcher.returncode == 0, err[-3000:]
    log = read_log(log_path(out))
    assert log.complete
    assert log.metadata["farm_id"] == "tiny"
    counts = log.topic_counts()
    for vid in ("v1", "v2"):
        for direction in ("to", "from"):
            key = f"agrifleet/tiny/vehicle/{vid}/mavlink/{direction}"
            assert counts[key] > 0
            assert counts[f"{key}/json"] == counts[key]  # every frame decoded
        # A fix with each position (those heard as the run ended too: the map's last)
        heard = log.on(f"agrifleet/tiny/vehicle/{vid}/mavlink/from/json")
        positions = [r.decode_json() for r in heard]
        fixed = [
            d
            for d in positions
            if d["mavpackettype"] == "GLOBAL_POSITION_INT"
            and mc.has_fix(d["lat"] / 1e7, d["lon"] / 1e7)
        ]
        assert counts[f"/vehicle/{vid}/fix"] == len(fixed) > 0
    assert counts["/plan/geojson"] == 1
    # A decoded frame matches its raw bytes.
    raw = log.on("agrifleet/tiny/vehicle/v1/mavlink/to")
    decoded = log.on("agrifleet/tiny/vehicle/v1/mavlink/to/json")
    sent = [mc.Codec(11, 1).decode_one(r.data) for r in raw]
    assert all(m is not None for m in sent)
    assert decoded[0].decode_json() == mc.as_dict(sent[0])
    kinds = [m.get_type() for m in sent]
    # the ground-station heartbeat from the start, then the upload
    assert kinds[0] == "HEARTBEAT" and sent[0].type == mc.MAV_TYPE_GCS
    assert "MISSION_COUNT" in kinds
    # The final status: every field done exactly once, by its planned vehicle.
    status = log.on("agrifleet/tiny/dispatcher/status")[-1].decode_json()
    assert {f["status"] for f in status["fields"].values()} == {"done"}
    done = [f for v in status["vehicles"].values() for f in v["fields_done"]]
    assert sorted(done) == ["A", "B", "C"]
    # `agrifleet review` reads the same log back: every field done exactly once.
    plot = tmp_path / "review.png"
    review = subprocess.run(
        [
            sys.executable,
            "-m",
            "dispatcher.cli",
            "review",
            str(log_path(out)),
            "--json",
            "--plot",
            str(plot),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    doc = json.loads(review.stdout)
    assert {fid: f["done"] for fid, f in doc["fields"].items()} == {"A": True, "B": True, "C": True}
    worked = [fid for v in doc["vehicles"] for fid in v["fields_done"]]
    assert sorted(worked) == ["A", "B", "C"]
    # Review replays the recorded events with the daemon's FleetState.apply: it agrees with
    # the live status on when every field was started and finished.
    for fid, live in status["fields"].items():
        reviewed = doc["fields"][fid]
        assert reviewed["started_clock_s"] == round(live["started_s"], 1), fid
        assert reviewed["finished_clock_s"] == round(live["finished_s"], 1), fid
    # ... and on when each vehicle set off (SetOff, one rule live and in review).
    for v in doc["vehicles"]:
        assert v["start_clock_s"] == round(status["vehicles"][v["id"]]["set_off_s"], 3), v["id"]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_status_queryable_and_sigterm_leaves_a_readable_log(procs, tmp_path):
    port = free_port()
    dispatcher = serve(procs, port, tmp_path)
    sim(procs, port, 2, "v1", "v2")  # slow: the run is still going when we stop it
    deadline = time.monotonic() + 60
    status = query_status(port)
    while status["vehicles"]["v1"]["phase"] != "running":
        assert time.monotonic() < deadline, status
        status = query_status(port)
    assert set(status["fields"]) == {"A", "B", "C"}
    dispatcher.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    out, _ = dispatcher.communicate(timeout=30)
    assert time.monotonic() - t0 < 15  # bounded shutdown
    assert dispatcher.returncode == 130
    log = read_log(log_path(out))
    assert log.complete  # finished properly: summary written
    assert log.topic_counts()["agrifleet/tiny/vehicle/v1/mavlink/from"] > 0


def test_router_with_dispatcher_and_vehicles_in_client_mode(procs, tmp_path):
    """Beyond one gateway: everyone is a client of a Zenoh router."""
    port = free_port()
    router = procs.start("router", "--listen", f"tcp/127.0.0.1:{port}", quiet=True)
    endpoint = f"tcp/127.0.0.1:{port}"
    # Clients give up when no router answers as they start: wait until it listens.
    deadline = time.monotonic() + 30
    while True:
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", port)) == 0:
                break
        assert time.monotonic() < deadline and router.poll() is None, "router never listened"
        time.sleep(0.05)
    dispatcher = procs.start(
        "serve",
        str(SCENARIO),
        "--mode",
        "client",
        "--connect",
        endpoint,
        "--log-dir",
        str(tmp_path),
        "--time-limit",
        "1",
        "--keys",
        keys_for(SCENARIO),
    )
    for vid in ("v1", "v2"):
        procs.start(
            "sim",
            str(SCENARIO),
            "--keys",
            keys_for(SCENARIO),
            "--mode",
            "client",
            "--connect",
            endpoint,
            "--speedup",
            "400",
            "--vehicle",
            vid,
            quiet=True,
        )
    out, err = dispatcher.communicate(timeout=120)
    assert dispatcher.returncode == 0, err[-3000:]
    status = read_log(log_path(out)).on("agrifleet/tiny/dispatcher/status")[-1].decode_json()
    assert {f["status"] for f in status["fields"].values()} == {"done"}
    assert router.poll() is None  # the router outlives its clients


def test_a_stalled_vehicle_delays_neither_the_others_nor_the_status(procs, tmp_path):
    """One simulator frozen (SIGSTOP) with its Zenoh session: the other vehicle keeps
    progressing and the status keeps answering within a second."""
    port = free_port()
    serve(procs, port, tmp_path)
    frozen = sim(procs, port, 2, "v1")
    sim(procs, port, 2, "v2")
    conf = wire.client_options((f"tcp/127.0.0.1:{port}",)).config()
    session = zenoh.open(conf)

    def ask() -> tuple[dict, float]:
        t0 = time.monotonic()
        for reply in session.get(wire.dispatcher_status("tiny"), timeout=5.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_string()), time.monotonic() - t0
        return {}, time.monotonic() - t0

    try:
        deadline = time.monotonic() + 60
        status, _ = ask()
        while {v["phase"] for v in status.get("vehicles", {}).values()} != {"running"}:
            assert time.monotonic() < deadline, status
            time.sleep(0.1)  # the dispatcher's status changes once a second
            status, _ = ask()
        frozen.send_signal(signal.SIGSTOP)
        reached = status["vehicles"]["v2"]["reached"]
        slowest = 0.0
        moved = False
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not moved:
            status, took = ask()
            slowest = max(slowest, took)
            moved = status["vehicles"]["v2"]["reached"] > reached + 2
        assert moved, status["vehicles"]["v2"]
        assert slowest < 1.0, slowest
    finally:
        frozen.send_signal(signal.SIGCONT)
        session.close()
