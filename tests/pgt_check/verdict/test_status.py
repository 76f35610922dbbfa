"""The statuses of the run-level checks (``verdict/status.py``): the strings summary.json and
the report read."""

from __future__ import annotations

from pgt_check.verdict import status


def test_statuses_are_the_documented_distinct_strings():
    values = (status.PASSED, status.FAILED, status.INCONCLUSIVE, status.NOT_CHECKED, status.FINDING)
    assert values == ("passed", "failed", "inconclusive", "not_checked", "finding")
    assert len(set(values)) == 5
