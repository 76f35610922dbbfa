"""Run-level comparison of the raw and enhanced paths (report table and summary.json).

``path_comparison(rows)`` takes the judged rows (``verdict.apply_verdicts``) and returns, per
path, how many frames it ran on, had a homography on and decided, and the medians of its
matches, inlier ratio and corner error over the frames where it ran (corner error: where it had
a homography). ``disagreement`` says per frame whether the two paths fall on different sides of
the threshold.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from typing import Any

PATHS = ("raw", "enhanced")


def _finite(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return float(v)


def _median(vals: list[float]) -> float | None:
    return statistics.median(vals) if vals else None


def disagreement(row: Mapping[str, Any]) -> bool | None:
    """True when raw and enhanced verdicts differ: the row's ``disagree`` if it has one, else
    from ``raw_verdict`` / ``enhanced_verdict`` (PASS / FAIL), else from the raw and enhanced
    corner errors against ``threshold_px``. None when one path has no result."""
    if "disagree" in row:  # judged by the verdict stage (None: a path was not verifiable)
        given = row["disagree"]
        return given if isinstance(given, bool) else None
    rv, ev = row.get("raw_verdict"), row.get("enhanced_verdict")
    if rv in ("PASS", "FAIL") and ev in ("PASS", "FAIL"):
        return rv != ev
    raw = _finite(row.get("corner_error_px_raw"))
    enh = _finite(row.get("corner_error_px_enhanced"))
    thr = _finite(row.get("threshold_px"))
    if raw is None or enh is None or thr is None:
        return None
    return (raw > thr) != (enh > thr)


def _decided(row: Mapping[str, Any]) -> Any:
    """The path the row's verdict rests on (``decided_by``; ``verdict_path`` in rows judged
    before it was recorded)."""
    return row["decided_by"] if "decided_by" in row else row.get("verdict_path")


def path_comparison(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """``{"raw": stats, "enhanced": stats, "frames_both": n, "frames_disagree": n}``.

    stats: ``frames_ran`` (the path matched), ``frames_with_homography``, ``frames_decided``
    (``decided_by``: the path the verdict rests on), ``frames_above_threshold``, ``median_matches``, ``median_inliers``,
    ``median_inlier_ratio`` (over frames where the path ran) and ``median_corner_error_px``
    (over frames where it had a homography).
    """
    out: dict[str, Any] = {}
    for p in PATHS:
        ran = [r for r in rows if _finite(r.get(f"n_matches_{p}")) is not None]
        errs = [e for r in ran if (e := _finite(r.get(f"corner_error_px_{p}"))) is not None]
        above = 0
        for r in ran:
            e, t = _finite(r.get(f"corner_error_px_{p}")), _finite(r.get("threshold_px"))
            above += e is not None and t is not None and e > t
        out[p] = {
            "frames_ran": len(ran),
            "frames_with_homography": len(errs),
            "frames_decided": sum(1 for r in rows if _decided(r) == p),
            "frames_above_threshold": above,
            "median_matches": _median([float(r[f"n_matches_{p}"]) for r in ran]),
            "median_inliers": _median(
                [v for r in ran if (v := _finite(r.get(f"n_inliers_{p}"))) is not None]),
            "median_inlier_ratio": _median(
                [v for r in ran if (v := _finite(r.get(f"inlier_ratio_{p}"))) is not None]),
            "median_corner_error_px": _median(errs),
        }
    flags = [disagreement(r) for r in rows]
    out["frames_both"] = sum(1 for f in flags if f is not None)
    out["frames_disagree"] = sum(1 for f in flags if f)
    return out
