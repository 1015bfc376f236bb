"""Dispatcher benchmarks on loopback: mission upload latency, and telemetry load.

The dispatcher runs in this process (so its CPU time is this process's); the simulated
vehicles run as `agrifleet sim` child processes, always stopped at the end.
"""

from __future__ import annotations

import json
import math
import resource
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

MACHINE = """
[[machine]]
id = "v{k}"
system_id = {sysid}
working_width_m = {width}
capacity_m2h = 4000
work_speed_kmh = 1.08
road_speed_kmh = 10
turn_time_h = 0.002
min_turn_radius_m = 4.5
road_fuel_lh = 2.0
work_fuel_lh = 4.0
[machine.implement]
kind = "servo"
channel = 9
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _scenario(folder: Path, farm: str, machines: int, width: float, limit_s: float) -> Path:
    """A scenario of ``machines`` tractors, each with its MAVLink signing key (as on a
    farm: the simulators find them through the scenario's ``keys``)."""
    from dispatcher.link.keys import write_keys

    text = f'farm_id = "bench"\nfarm = "{farm}"\nkeys = "keys"\n'
    text += "".join(MACHINE.format(k=k + 1, sysid=k + 1, width=width) for k in range(machines))
    text += f"\n[solver]\ntime_limit_s = {limit_s}\ngenerations = 300\nseed = 1\n"
    path = folder / "scenario.toml"
    path.write_text(text)
    write_keys(folder / "keys", [f"v{k + 1}" for k in range(machines)])
    return path


def _keys(scenario: Path) -> dict[str, bytes]:
    """The signing keys of a scenario of :func:`_scenario`, for the dispatcher."""
    from dispatcher.config.scenario import load_scenario
    from dispatcher.link.keys import read_keys

    sc = load_scenario(scenario)
    assert sc.keys_dir is not None
    return read_keys(sc.keys_dir, [v.id for v in sc.vehicles])


def _grid_farm(folder: Path, count: int) -> str:
    """``count`` fields of 40 m x 30 m on a grid near 44 N 87.3 E, garage at the corner."""
    feats = []
    side = math.ceil(math.sqrt(count))
    for k in range(count):
        r, c = divmod(k, side)
        lon0 = 87.3 + c * 60 / (111320 * math.cos(math.radians(44.0)))
        lat0 = 44.0 + r * 50 / 110540
        dlon = 40 / (111320 * math.cos(math.radians(44.0)))
        dlat = 30 / 110540
        ring = [
            [lon0, lat0],
            [lon0 + dlon, lat0],
            [lon0 + dlon, lat0 + dlat],
            [lon0, lat0 + dlat],
            [lon0, lat0],
        ]
        feats.append(
            {
                "type": "Feature",
                "properties": {"kind": "field", "id": f"f{k}"},
                "geometry": {"type": "Polygon", "coordinates": [ring]},
            }
        )
    feats.append(
        {
            "type": "Feature",
            "properties": {"kind": "garage"},
            "geometry": {"type": "Point", "coordinates": [87.2995, 43.9995]},
        }
    )
    (folder / "grid.geojson").write_text(
        json.dumps({"type": "FeatureCollection", "features": feats})
    )
    return "grid.geojson"


def _plan(scenario: Path):  # type: ignore[no-untyped-def]
    from dispatcher.config.scenario import load_scenario
    from dispatcher.mission.plan import dispatch_plan
    from planner.field_plan import plan_farm
    from planner.solve import stop_after

    sc = load_scenario(scenario)
    plan = plan_farm(
        sc.farm,
        [v.machine for v in sc.vehicles],
        sc.solver.objective,
        sc.solver.algorithm,
        stop_after(sc.solver.generations, sc.solver.time_limit_s),
    )
    return dispatch_plan(sc, plan)


def _sim(  # type: ignore[no-untyped-def]
    scenario: Path,
    port: int,
    speedup: float,
    stats: Path,
    hz: float = 10.0,
    vehicle: str | None = None,
):
    """`agrifleet sim` for the whole fleet in one process, or for one ``vehicle``."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dispatcher.cli",
            "sim",
            str(scenario),
            *(["--vehicle", vehicle] if vehicle else ["--all"]),
            "--connect",
            f"tcp/127.0.0.1:{port}",
            "--speedup",
            str(speedup),
            "--telemetry-hz",
            str(hz),
            "--stats",
            str(stats),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def _stop(proc: subprocess.Popen) -> None:  # type: ignore[type-arg]
    if proc.poll() is None:
        proc.terminate()
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def bench_upload(repeats: int = 3) -> str:
    """Time from "plan ready and every vehicle alive" to "every mission acknowledged"."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.link import wire

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "changji.geojson").write_text((REPO / "config/changji.geojson").read_text())
        scenario = _scenario(folder, "changji.geojson", 6, 3.7, 20.0)
        dispatch = _plan(scenario)
        items = [len(m) for m in dispatch.missions.values()]
        spans = []
        for _ in range(repeats):
            port = free_port()
            daemon = Dispatcher(
                DaemonConfig(
                    job=dispatch.job(),
                    zenoh=wire.dispatcher_options((f"tcp/127.0.0.1:{port}",)),
                    log_dir=folder / "logs",
                    exit_when_done=False,
                    on_progress=lambda state: None,
                    keys=_keys(scenario),
                )
            )
            watcher_done = threading.Event()

            def stop_when_acked(
                d: Dispatcher = daemon, done: threading.Event = watcher_done
            ) -> None:
                started = time.monotonic()
                while not done.wait(0.05):
                    if d.all_acknowledged is not None or time.monotonic() - started > 60:
                        d.should_exit.set()
                        return

            daemon.startup()
            # One process per vehicle, as each real tractor has its own autopilot.
            sims = [
                _sim(scenario, port, 1.0, folder / f"stats-{vid}.json", vehicle=vid)
                for vid in dispatch.missions
            ]
            watcher = threading.Thread(target=stop_when_acked, daemon=True)
            watcher.start()
            try:
                daemon.main_loop()
            finally:
                watcher_done.set()
                for sim in sims:
                    _stop(sim)
                daemon.shutdown()
            if daemon.all_acknowledged is None or daemon.upload_started is None:
                spans.append(float("nan"))
            else:
                spans.append(daemon.all_acknowledged - daemon.upload_started)
    ok = [s for s in spans if s == s]
    return "\n".join(
        [
            f"### Mission upload: 6 vehicles, {min(items)}–{max(items)} items each "
            f"({sum(items)} in all), loopback",
            "",
            "| runs | median s | min s | max s | goal |",
            "|---|---|---|---|---|",
            f"| {len(spans)} | {statistics.median(ok):.3f} | {min(ok):.3f} | {max(ok):.3f} "
            "| < 1 s |"
            if ok
            else f"| {len(spans)} | failed | | | < 1 s |",
            "",
            "From the moment every vehicle's liveliness token is seen (uploads begin) to the last "
            "MISSION_ACK; all six uploads run in parallel, one MISSION_REQUEST per item; every "
            "simulated vehicle is its own process (2 cores shared with the dispatcher).",
            "",
        ]
    )


def bench_telemetry(vehicles: int = 100, hz: float = 10.0, seconds: float = 60.0) -> str:
    """``vehicles`` simulated vehicles at ``hz`` telemetry into one dispatcher for
    ``seconds``: share of the frames sent that are in the MCAP, dispatcher CPU."""
    from dispatcher.daemon.server import DaemonConfig, Dispatcher
    from dispatcher.link import wire
    from dispatcher.recording.mcap_file import read_log

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        farm = _grid_farm(folder, vehicles)
        scenario = _scenario(folder, farm, vehicles, 6.0, 20.0)
        dispatch = _plan(scenario)
        port = free_port()
        daemon = Dispatcher(
            DaemonConfig(
                job=dispatch.job(),
                zenoh=wire.dispatcher_options((f"tcp/127.0.0.1:{port}",)),
                log_dir=folder / "logs",
                exit_when_done=False,
                heartbeat_timeout_s=30.0,
                on_progress=lambda state: None,
                keys=_keys(scenario),
            )
        )
        daemon.startup()
        stats = folder / "stats.json"
        sim = _sim(scenario, port, 1.0, stats, hz)
        window: dict[str, float] = {}

        def measure() -> None:
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and not all(
                v.phase.value != "waiting" for v in daemon.state.vehicles.values()
            ):
                time.sleep(0.1)
            usage = resource.getrusage(resource.RUSAGE_SELF)
            window["cpu0"] = usage.ru_utime + usage.ru_stime
            window["t0"] = time.monotonic()
            time.sleep(seconds)
            usage = resource.getrusage(resource.RUSAGE_SELF)
            window["cpu1"] = usage.ru_utime + usage.ru_stime
            window["t1"] = time.monotonic()
            _stop(sim)  # the simulator writes how many frames it sent
            time.sleep(1.0)  # frames still in flight on loopback
            daemon.should_exit.set()

        thread = threading.Thread(target=measure, daemon=True)
        thread.start()
        try:
            daemon.main_loop()
        finally:
            _stop(sim)
            daemon.shutdown()
        thread.join()
        sent = json.loads(stats.read_text()) if stats.exists() else {}
        log = read_log(daemon.log_path) if daemon.log_path else None
        counts = log.topic_counts() if log else {}
        received = sum(n for t, n in counts.items() if t.endswith("/mavlink/from"))
        cpu = (window["cpu1"] - window["cpu0"]) / (window["t1"] - window["t0"])
        total_sent = sum(sent.values())
        share = 100.0 * received / total_sent if total_sent else float("nan")
    return "\n".join(
        [
            f"### Telemetry: {vehicles} simulated vehicles at {hz:g} Hz into one dispatcher, "
            f"{seconds:g} s",
            "",
            "| frames sent | frames in the MCAP | share | dispatcher CPU (cores) | goals |",
            "|---|---|---|---|---|",
            f"| {total_sent} | {received} | {share:.3f} % | {cpu:.3f} | 100 %, < 0.5 core |",
            "",
            "Frames sent counted by the simulator; frames in the MCAP are the raw `mavlink/from` "
            "records. CPU is the dispatcher process (all its threads, Zenoh's included) over the "
            "measured window, while the vehicles also run their missions and answer uploads.",
            "",
        ]
    )
