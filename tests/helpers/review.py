"""Checks on a reviewed run shared by the tests that drive real processes."""

from __future__ import annotations

from dispatcher.link.wire import dispatcher_plan
from dispatcher.mission.document import PlanDocument
from dispatcher.recording.mcap_file import LogContents
from dispatcher.recording.topics import EVENTS_TOPIC
from dispatcher.review.report import Review, review_table


def assert_each_segment_worked_once(review: Review) -> None:
    """Every swath and headland edge of every field worked exactly once, as the recorded
    events tell, through every re-plan."""
    table = review_table(review)
    for f in review.fields:
        assert f.segments > 0, (f.id, table)
        assert f.worked_twice == () and f.never_worked == (), (f, table)


def segments_worked_while_lost(log: LogContents, vid: str, farm: str) -> set[tuple[str, int]]:
    """(field, segment) of what ``vid`` reported it worked between being lost and the
    re-plan that took it back: a tractor whose radio went quiet kept driving, and what it
    worked meanwhile may already have been in another's new route (on a farm the
    autopilot's ground-station failsafe holds it instead: docs/bridge.md)."""
    plans = [PlanDocument.from_json(r.decode_json()) for r in log.on(dispatcher_plan(farm))]
    items = next(m.items for m in plans[0].machines if m.id == vid)
    lost, out = False, set()
    for rec in log.on(EVENTS_TOPIC):
        event = rec.decode_json()
        if event.get("vehicle") == vid and event["kind"] in ("vehicle_lost", "vehicle_stalled"):
            lost = True
        elif event["kind"] == "plan_replaced" and event.get("reason") == f"{vid} back":
            break
        elif lost and event["kind"] == "item_reached" and event.get("vehicle") == vid:
            item = items[event["seq"]]
            if item.role == "swath_end" and item.field_id and item.segment is not None:
                out.add((item.field_id, item.segment))
    return out
