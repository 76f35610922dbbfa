"""Run-level statistics of judged frames (``RunStatistics``: verdict counts, corner-error
percentiles / AUC, the systematic offset of the frames' homographies) and the CI gate over them
(``Gate``)."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from pgt_check.config import GateConfig
from pgt_check.geometry.homography import auc_at_thresholds
from pgt_check.measure.record import MeasureReason
from pgt_check.verdict.judgement import Verdict

if TYPE_CHECKING:  # pragma: no cover
    from pgt_check.verdict.result import RunResult

#: UNVERIFIABLE reasons that mean the tool itself failed on a frame (they count against the gate)
INTERNAL_REASONS = (MeasureReason.INTERNAL_ERROR.value, MeasureReason.WORKER_CRASHED.value)


def gate(
    counts: Mapping[str, int],
    config: GateConfig,
    reasons: Mapping[str, int] | None = None,
) -> tuple[bool, str]:
    """Run-level gate over verdict counts; returns (passed, explanation). Fails closed.

    Fails when no frame was checked or none was verified (PASS + FAIL = 0), when frames with an
    internal error or a crashed worker (``reasons``: UNVERIFIABLE reason counts) exceed
    ``max_internal_errors``, or when the FAIL or UNVERIFIABLE share exceeds its limit. The
    comparisons are written so that a non-finite limit (rejected by the config anyway) fails.
    """
    total = sum(counts.values())
    if total == 0:
        return False, "no frames were checked"
    n_fail = counts.get(Verdict.FAIL.value, 0)
    n_pass = counts.get(Verdict.PASS.value, 0)
    if n_pass + n_fail == 0:
        return False, f"no frame was verified (all {total} frames UNVERIFIABLE)"
    n_internal = sum(int((reasons or {}).get(r, 0)) for r in INTERNAL_REASONS)
    if not n_internal <= config.max_internal_errors:
        return False, (
            f"{n_internal} frames with internal errors or crashed workers > max "
            f"{config.max_internal_errors}"
        )
    fail = n_fail / total
    unv = counts.get(Verdict.UNVERIFIABLE.value, 0) / total
    if not fail <= config.max_fail_fraction:
        return False, f"FAIL fraction {fail:.3f} > max {config.max_fail_fraction:.3f}"
    if not unv <= config.max_unverifiable_fraction:
        return (
            False,
            f"UNVERIFIABLE fraction {unv:.3f} > max {config.max_unverifiable_fraction:.3f}",
        )
    return True, (
        f"FAIL fraction {fail:.3f} <= max {config.max_fail_fraction:.3f}, UNVERIFIABLE fraction "
        f"{unv:.3f} <= max {config.max_unverifiable_fraction:.3f}"
    )


@dataclass(frozen=True)
class SystematicOffset:
    """summary.json -> ``statistics.systematic_offset`` (``systematic_offset``): the median
    shift and zoom of the frames' homographies, the share of frames in the median direction,
    whether it is systematic, its sentence and the path it was measured on."""

    n_frames: int
    systematic: bool
    message: str
    median_dx_px: float | None = None
    median_dy_px: float | None = None
    median_shift_px: float | None = None
    direction_deg: float | None = None
    consistency: float | None = None
    median_zoom: float | None = None
    #: "raw" or "verdict_path" (``run_statistics``; "" where not set)
    path: str = ""

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"n_frames": self.n_frames, "systematic": self.systematic}
        if self.median_dx_px is not None:
            out.update(
                median_dx_px=self.median_dx_px,
                median_dy_px=self.median_dy_px,
                median_shift_px=self.median_shift_px,
                direction_deg=self.direction_deg,
                consistency=self.consistency,
                median_zoom=self.median_zoom,
            )
        out["message"] = self.message
        if self.path:
            out["path"] = self.path
        return out


def systematic_offset(
    shifts: Iterable[tuple[float, float]], zooms: Iterable[float], threshold_px: float
) -> SystematicOffset:
    """Detect a consistent image-space offset across frames (a calibration hint).

    shifts: per-frame mean corner displacement (dx, dy) in px of successfully measured frames;
    zooms: per-frame warped/original diagonal ratio. A pose error moves frames in varying
    directions; a calibration error (intrinsics, camera-to-rig, RGB vs depth camera) moves
    every frame the same way. We report the median shift and zoom, and ``consistency``: the
    fraction of frames whose shift lies within 45 degrees of the median direction. The offset is
    flagged systematic when its magnitude >= 25 % of the threshold (or the zoom differs from 1
    by >= 1 %) and consistency >= 0.7 over at least 5 frames.
    """
    s = np.asarray(list(shifts), dtype=np.float64).reshape(-1, 2)
    z = np.asarray(list(zooms), dtype=np.float64).reshape(-1)
    s = s[np.all(np.isfinite(s), axis=1)]
    z = z[np.isfinite(z)]
    if len(s) == 0:
        return SystematicOffset(0, False, "no frame was measured")
    med = np.median(s, axis=0)
    mag = float(np.hypot(*med))
    zoom = float(np.median(z)) if len(z) else 1.0
    consistency = _consistency(s, med, mag)
    direction = float(math.degrees(math.atan2(med[1], med[0])))
    systematic = len(s) >= 5 and (
        (mag >= 0.25 * threshold_px and consistency >= 0.7) or abs(zoom - 1.0) >= 0.01
    )
    return SystematicOffset(
        n_frames=int(len(s)),
        systematic=bool(systematic),
        message=_offset_message(med, mag, consistency, zoom, bool(systematic), threshold_px),
        median_dx_px=float(med[0]),
        median_dy_px=float(med[1]),
        median_shift_px=mag,
        direction_deg=direction,
        consistency=consistency,
        median_zoom=zoom,
    )


def _consistency(s: np.ndarray, med: np.ndarray, mag: float) -> float:
    """Fraction of the shifts s (N, 2) within 45 degrees of the median shift med (2,) of
    magnitude mag; 0 for a median shift of (about) zero."""
    if mag > 1e-9:
        u = med / mag
        n = np.linalg.norm(s, axis=1)
        cosang = (s @ u) / np.maximum(n, 1e-12)
        return float(np.mean(cosang >= math.cos(math.radians(45))))
    return 0.0


def _offset_message(
    med: np.ndarray,
    mag: float,
    consistency: float,
    zoom: float,
    systematic: bool,
    threshold_px: float,
) -> str:
    """The sentence ``systematic_offset`` reports: what is shifted or scaled, or that nothing is."""
    if not systematic:
        return (
            f"no systematic offset (median shift {mag:.1f} px, consistency {consistency:.0%}, "
            f"zoom {zoom:.3f})"
        )
    parts = []
    if mag >= 0.25 * threshold_px and consistency >= 0.7:
        parts.append(
            f"every frame's render is shifted by about ({med[0]:+.1f}, {med[1]:+.1f}) px "
            f"({consistency:.0%} of frames in the same direction)"
        )
    if abs(zoom - 1.0) >= 0.01:
        parts.append(f"the render is scaled by {zoom:.3f} relative to the photos")
    return (
        "systematic offset: "
        + " and ".join(parts)
        + ". A constant offset points at calibration (intrinsics, camera-to-rig or "
        "RGB-vs-depth camera extrinsics), not at individual bad poses."
    )


@dataclass(frozen=True)
class ErrorPercentiles:
    """summary.json -> ``statistics.corner_error_px``: the verdict path's corner error over the
    frames where it was measured (None without any)."""

    median: float | None
    p90: float | None
    max: float | None
    n_measured: int

    def to_json(self) -> dict[str, Any]:
        return {"median": self.median, "p90": self.p90, "max": self.max,
                "n_measured": self.n_measured}


@dataclass(frozen=True)
class RunStatistics:
    """Run-level statistics of the judged frames (summary.json -> ``statistics``): verdict
    counts (every ``Verdict``, in order), UNVERIFIABLE reason counts, corner-error
    percentiles, AUC and the systematic offset."""

    n_frames: int
    counts: Mapping[str, int]
    unverifiable_reasons: Mapping[str, int]
    corner_error_px: ErrorPercentiles
    auc: Mapping[str, float]
    systematic_offset: SystematicOffset

    def count(self, verdict: Verdict) -> int:
        return int(self.counts.get(verdict.value, 0))

    def to_json(self) -> dict[str, Any]:
        return {
            "n_frames": self.n_frames,
            "counts": dict(self.counts),
            "unverifiable_reasons": dict(self.unverifiable_reasons),
            "corner_error_px": self.corner_error_px.to_json(),
            "auc": dict(self.auc),
            "systematic_offset": self.systematic_offset.to_json(),
        }


@dataclass(frozen=True)
class Gate:
    """The CI gate's decision (summary.json -> ``gate``; the exit code): passed, and why."""

    passed: bool
    explanation: str

    def to_json(self) -> dict[str, Any]:
        return {"passed": self.passed, "explanation": self.explanation}

    @classmethod
    def of(cls, stats: RunStatistics, config: GateConfig) -> Gate:
        """``gate`` over the statistics' verdict and reason counts."""
        return cls(*gate(stats.counts, config, stats.unverifiable_reasons))


def run_statistics(result: RunResult, threshold_px: float) -> RunStatistics:
    """Run-level statistics of a judged run (``statistics_of_rows`` over its frames.csv view,
    ``RunResult.rows``)."""
    return statistics_of_rows(result.rows(), threshold_px)


def statistics_of_rows(records: Sequence[Mapping[str, Any]], threshold_px: float
                       ) -> RunStatistics:
    """Run-level statistics over judged frames.csv rows: verdict and reason counts, error
    percentiles, AUC, systematic offset."""
    counts = Counter(str(r["verdict"]) for r in records)
    reasons = Counter(
        str(r["reason"]) for r in records if r["verdict"] == Verdict.UNVERIFIABLE.value
    )
    errs = np.array(
        [r["corner_error_px"] if r.get("corner_error_px") is not None else np.inf for r in records],
        dtype=np.float64,
    )
    finite = errs[np.isfinite(errs)]
    # Systematic offset from the raw path where it was measured: an enhanced render borrows
    # its appearance from a neighbouring photo with the same calibration, which hides a shared
    # offset. Records without raw shifts (older runs) fall back to the verdict path.
    raw = [r for r in records if r.get("shift_dx_px_raw") is not None]
    if raw:
        shifts = [(r["shift_dx_px_raw"], r["shift_dy_px_raw"]) for r in raw]
        zooms = [r.get("zoom_raw", 1.0) for r in raw]
        source = "raw"
    else:
        ok = [r for r in records if r.get("shift_dx_px") is not None]
        shifts = [(r["shift_dx_px"], r["shift_dy_px"]) for r in ok]
        zooms = [r.get("zoom", 1.0) for r in ok]
        source = "verdict_path"
    return RunStatistics(
        n_frames=len(records),
        counts={v.value: counts.get(v.value, 0) for v in Verdict},
        unverifiable_reasons=dict(reasons),
        corner_error_px=ErrorPercentiles(
            float(np.median(finite)) if len(finite) else None,
            float(np.percentile(finite, 90)) if len(finite) else None,
            float(np.max(finite)) if len(finite) else None,
            int(len(finite)),
        ),
        auc=auc_at_thresholds(errs, (1.0, 3.0, 5.0, 10.0)),
        systematic_offset=replace(systematic_offset(shifts, zooms, threshold_px), path=source),
    )
