"""Stage 2 over a run: verdicts for stored measurements, as flat rows for the outputs."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from pgt_check.config import RunConfig
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.decide import decide

#: the verdict columns every row gets beside the measurement columns
VERDICT_COLUMNS = ("verdict", "reason", "threshold_px")


def apply_verdicts(
    measurements: Iterable[FrameMeasurement], config: RunConfig
) -> list[dict[str, Any]]:
    """One flat row per measurement (``FrameMeasurement.row()``) plus verdict, reason and
    threshold_px. Measurements are not changed (records.jsonl stays as measured)."""
    rows = []
    for m in measurements:
        verdict, reason = decide(m, config.verdict)
        row = m.row()
        row["verdict"], row["reason"] = verdict.value, reason
        row["threshold_px"] = config.verdict.threshold_for(m.width, m.height)
        rows.append(row)
    return rows
