"""Checks on a reviewed run shared by the tests that drive real processes."""

from __future__ import annotations

from dispatcher.review.report import Review, review_table


def assert_each_segment_worked_once(review: Review) -> None:
    """Every swath and headland edge of every field worked exactly once, as the recorded
    events tell, through every re-plan."""
    table = review_table(review)
    for f in review.fields:
        assert f.segments > 0, (f.id, table)
        assert f.worked_twice == () and f.never_worked == (), (f, table)
