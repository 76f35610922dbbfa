"""Progress lines without a TTY (``pgt_check.progress``)."""

from __future__ import annotations

import logging

from pgt_check.progress import log_progress


def test_log_progress_every_interval_and_at_the_end(caplog):
    t = iter([0.0, 1.0, 2.0, 6.0, 7.0, 12.5])
    with caplog.at_level(logging.INFO, logger="pgt_check.progress"):
        got = list(log_progress(range(5), 5, "pgt-check", interval_s=5.0,
                                       clock=lambda: next(t)))
    assert got == [0, 1, 2, 3, 4]
    lines = [r.getMessage() for r in caplog.records]
    # clock: start 0; items done at 1, 2, 6 (a line), 7, 12.5 (a line, the last: no repeat)
    assert len(lines) == 2, lines
    assert lines[0] == "pgt-check: 3/5 frames (60 %), 0.50 frames/s, about 4 s left"
    assert lines[1] == "pgt-check: 5/5 frames (100 %), 0.40 frames/s"
    caplog.clear()
    t2 = iter([0.0, 1.0, 1.5, 2.0])  # fast: no line in between, one at the end
    with caplog.at_level(logging.INFO, logger="pgt_check.progress"):
        list(log_progress("ab", 2, "x", interval_s=5.0, clock=lambda: next(t2)))
    assert [r.getMessage() for r in caplog.records] == ["x: 2/2 frames (100 %), 1.00 frames/s"]
    assert list(log_progress([], 0, "x", clock=lambda: 0.0)) == []
