"""A running dispatcher (`agrifleet serve --foxglove`) with a simulated tractor: a Foxglove
WebSocket client decodes a live LocationFix, and a Zenoh peer joining after the uploads
gets the current plan and the fields' states at once (docs/foxglove.md, docs/link.md)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from helpers.foxglove_client import first_message
from helpers.processes import Processes, free_port, status_reader, wait_for

from dispatcher.link import wire
from dispatcher.recording import topics

SCENARIO = Path(__file__).parent / "data" / "tiny.toml"
FARM = "tiny"


@pytest.fixture(scope="module")
def running(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    workdir = tmp_path_factory.mktemp("live")
    procs = Processes(workdir)
    zenoh_port, live_port = free_port(), free_port()
    extra = ("--time-limit", "1", "--foxglove", str(live_port), "--data-dir", str(workdir / "d"))
    procs.serve(SCENARIO, zenoh_port, workdir / "logs", *extra)
    procs.sim(SCENARIO, zenoh_port, 20, "v1", "v2")
    try:
        with status_reader(zenoh_port, FARM) as status:
            # Every mission uploaded and acknowledged: the plan was published long before.

            def driving() -> bool:
                phases = [v.get("phase") for v in status().get("vehicles", {}).values()]
                return phases == ["running", "running"]

            wait_for("both tractors driving", driving, 60, procs.report)
            yield {"zenoh": zenoh_port, "live": live_port, "workdir": workdir, "status": status}
    finally:
        procs.stop_all()


def test_foxglove_client_decodes_a_live_location_fix(running: dict[str, Any]) -> None:
    channel, data = first_message(f"ws://127.0.0.1:{running['live']}", topics.location_topic("v1"))
    assert channel["schemaName"] == "foxglove.LocationFix"
    fix = topics.decode(channel["schemaName"], channel["encoding"], data)
    assert fix["frame_id"] == "v1"
    assert 40 < fix["latitude"] < 50 and 80 < fix["longitude"] < 90  # the tiny farm
    assert 0.0 <= fix["heading"] < 360.0
    [layout] = (running["workdir"] / "logs").glob("tiny-*.layout.json")
    assert wire.dispatcher_status(FARM) in layout.read_text()


def test_a_late_joiner_gets_the_plan_and_field_states_at_once(running: dict[str, Any]) -> None:
    conf = wire.client_options((f"tcp/127.0.0.1:{running['zenoh']}",)).config()
    with zenoh.open(conf) as late:  # joins after the plan was published and the uploads
        replies = {
            str(r.ok.key_expr): json.loads(r.ok.payload.to_string())
            for r in late.get(f"{wire.PREFIX}/{FARM}/dispatcher/*", timeout=5.0)
            if r.ok is not None
        }
    plan, status = replies[wire.dispatcher_plan(FARM)], replies[wire.dispatcher_status(FARM)]
    assert plan["plan_id"] == status["plan_id"] == running["status"]()["plan_id"]
    assert set(status["fields"]) == set(plan["fields"])
    assert {f["status"] for f in status["fields"].values()} <= {"pending", "working", "done"}
