"""Report plots, written as SVG files under assets/ (``svg_chart``: no plotting library).

Each function takes the judged records and writes one figure; ``write_plots`` writes all that
apply and returns ``[{"name", "title", "path"}]`` with paths relative to the output directory.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.files import atomic_write_text
from pgt_check.report.svg_chart import Axis, Chart, hstack

logger = logging.getLogger(__name__)

VERDICT_COLOURS = {"PASS": "#2e7d32", "FAIL": "#c62828", "UNVERIFIABLE": "#9e9e9e"}
#: every plot ``write_plots`` may write (assets/plot_<name>.svg)
PLOT_NAMES = ("error_hist", "error_time", "raw_vs_enhanced", "top_view", "drift")


def _chart(title: str, x: Axis, y: Axis, width: int = 600, height: int = 350, **kw) -> Chart:
    return Chart(width, height, title=title, x=x, y=y, **kw)


def _num(rec: Mapping[str, Any], key: str) -> float:
    v = rec.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return math.nan
    return float(v)


def has_enhanced(records: Sequence[Mapping[str, Any]]) -> bool:
    """True when some frame has both a raw and an enhanced value to compare (corner error or
    inlier ratio): otherwise the raw-vs-enhanced plot would be empty and is left out."""
    return any(
        all(math.isfinite(_num(r, f"{key}_{p}")) for p in ("raw", "enhanced"))
        for r in records
        for key in ("corner_error_px", "inlier_ratio")
    )


def _save(svg: str, out_dir: Path, name: str) -> str:
    rel = f"assets/plot_{name}.svg"
    path = out_dir / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, svg)  # a symlink there is replaced, never written through
    return rel


def _threshold(records: Sequence[Mapping[str, Any]], summary: Mapping[str, Any]) -> float:
    t = summary.get("threshold_px")
    if isinstance(t, (int, float)) and math.isfinite(t):
        return float(t)
    vals = [_num(r, "threshold_px") for r in records]
    vals = [v for v in vals if math.isfinite(v)]
    return float(np.median(vals)) if vals else math.nan


def plot_histogram(records, summary, out_dir: Path) -> str:
    thr = _threshold(records, summary)
    errs = {
        v: np.array([_num(r, "corner_error_px") for r in records if r.get("verdict") == v])
        for v in ("PASS", "FAIL")
    }
    allv = np.concatenate([e[np.isfinite(e)] for e in errs.values()])
    n_unv = sum(1 for r in records if r.get("verdict") == "UNVERIFIABLE")
    log = bool(len(allv))
    chart = _chart(f"Corner error ({n_unv} UNVERIFIABLE frames not shown)",
                   Axis("corner error [px]" + (" (log)" if log else ""), log=log),
                   Axis("frames", integer=True, lo=0.0))
    if len(allv):
        lo = max(min(allv.min(), thr if math.isfinite(thr) else allv.min()), 1e-2)
        hi = max(allv.max(), thr if math.isfinite(thr) else allv.max(), lo * 10)
        bins = np.geomspace(lo, hi * 1.01, 40)
        base = np.zeros(len(bins) - 1)
        for v, e in errs.items():
            counts, _ = np.histogram(np.clip(e[np.isfinite(e)], lo, None), bins=bins)
            chart.bars(bins, counts, VERDICT_COLOURS[v], base=base, label=v)
            base = base + counts
    else:
        chart.note = "no frame was measured"
    if math.isfinite(thr) and (thr > 0 or not chart.x.log):
        chart.vline(thr, label=f"threshold {thr:.1f} px")
    return _save(chart.svg(), out_dir, "error_hist")


def _order_key(records) -> tuple[np.ndarray, str]:
    ts = np.array([_num(r, "timestamp") for r in records])
    if len(ts) and np.all(np.isfinite(ts)):
        return ts, "timestamp"
    return np.arange(len(records), dtype=np.float64), "frame index"


def plot_error_along_trajectory(records, summary, out_dir: Path) -> str:
    thr = _threshold(records, summary)
    x, xlabel = _order_key(records)
    err = np.array([_num(r, "corner_error_px") for r in records])
    verdict = np.array([str(r.get("verdict")) for r in records])
    finite = err[np.isfinite(err) & (err > 0)]
    floor = float(finite.min()) / 2 if len(finite) else 0.1
    log = bool(len(finite)) or (math.isfinite(thr) and thr > 0)
    chart = _chart("Corner error along the trajectory",
                   Axis(xlabel, integer=xlabel == "frame index"),
                   Axis("corner error [px]" + (" (log)" if log else ""), log=log))
    order = np.argsort(x, kind="stable")
    ok = np.isfinite(err[order])
    chart.line(x[order][ok], np.maximum(err[order][ok], floor), "#90a4ae", width=0.6)
    for v in ("PASS", "FAIL"):
        m = (verdict == v) & np.isfinite(err)
        chart.points(x[m], np.maximum(err[m], floor), VERDICT_COLOURS[v], label=v)
    m = verdict == "UNVERIFIABLE"
    if m.any():
        chart.points(x[m], np.full(m.sum(), floor), VERDICT_COLOURS["UNVERIFIABLE"],
                     marker="x", label="UNVERIFIABLE (at the floor)")
    if math.isfinite(thr) and thr > 0:
        chart.hline(thr, label="threshold")
    return _save(chart.svg(), out_dir, "error_time")


def plot_raw_vs_enhanced(records, summary, out_dir: Path) -> str:
    thr = _threshold(records, summary)
    verdict = np.array([str(r.get("verdict")) for r in records])
    charts = []
    for key, label, log in (
        ("corner_error_px", "corner error [px]", True),
        ("inlier_ratio", "inlier ratio", False),
    ):
        raw = np.array([_num(r, f"{key}_raw") for r in records])
        enh = np.array([_num(r, f"{key}_enhanced") for r in records])
        ok = np.isfinite(raw) & np.isfinite(enh)
        if log:
            ok &= (raw > 0) & (enh > 0)
        chart = _chart(f"{label}: raw vs enhanced ({int(ok.sum())} frames)",
                       Axis(f"raw {label}", log=log), Axis(f"enhanced {label}", log=log),
                       width=440, height=360)
        first = not charts  # the legend is drawn once, beside the first chart
        for v, col in VERDICT_COLOURS.items():
            m = ok & (verdict == v)
            if m.any():
                chart.points(raw[m], enh[m], col, label=v if first else None)
        if ok.any():
            lo, hi = min(raw[ok].min(), enh[ok].min()), max(raw[ok].max(), enh[ok].max())
            chart.line([lo, hi], [lo, hi], "#000", width=0.8, dash="2,2")
        elif first:  # no frame has both a raw and an enhanced value (raw matching failed)
            chart.note = "no frame measured on both paths"
        if log and math.isfinite(thr) and thr > 0:
            chart.vline(thr, width=0.8)
            chart.hline(thr, width=0.8)
        charts.append(chart)
    return _save(hstack(charts), out_dir, "raw_vs_enhanced")


def drift_per_frame(summary: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """``summary["shared_errors"]["drift"]["per_frame"]`` entries with a finite index and
    effect, or [] when there are none."""
    se = summary.get("shared_errors")
    drift = se.get("drift") if isinstance(se, Mapping) else None
    per = drift.get("per_frame") if isinstance(drift, Mapping) else None
    if not isinstance(per, (list, tuple)):
        return []
    return [
        e for e in per
        if isinstance(e, Mapping) and math.isfinite(_num(e, "index"))
        and math.isfinite(_num(e, "effect_px"))
    ]


def plot_drift(records, summary, out_dir: Path) -> str | None:
    """Drift effect (and its lower bound) along the trajectory, with the threshold."""
    per = sorted(drift_per_frame(summary), key=lambda e: _num(e, "index"))
    if not per:
        return None
    drift = summary.get("shared_errors", {}).get("drift", {})
    thr = _num(drift, "threshold_px") if isinstance(drift, Mapping) else math.nan
    x = np.array([_num(e, "index") for e in per])
    eff = np.array([_num(e, "effect_px") for e in per])
    lo = np.array([_num(e, "lo_px") for e in per])
    chart = _chart("Drift along the trajectory", Axis("frame index", integer=True),
                   Axis("drift effect [px]", lo=0.0))
    if np.isfinite(lo).any():
        chart.band(x, np.where(np.isfinite(lo), lo, eff), eff, "#90caf9",
                   label="lower bound .. estimate")
    chart.line(x, eff, "#1565c0", width=1.2, marker="o", label="drift effect")
    if math.isfinite(thr):
        chart.hline(thr, label=f"threshold {thr:.1f} px")
    return _save(chart.svg(), out_dir, "drift")


def top_view_axes(centers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two world directions spanning the plane of largest spread of the camera centres.

    centers: (N, 3) float64. Returns two unit (3,) vectors; the normal is the direction of least
    variance (for ground-based captures, about the vertical). Fewer than 3 points: world x, y.
    """
    c = centers[np.all(np.isfinite(centers), axis=1)]
    if len(c) < 3:
        return np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    _, _, vt = np.linalg.svd(c - c.mean(axis=0), full_matrices=False)
    return vt[0], vt[1]


def plot_top_view(records, summary, out_dir: Path) -> str | None:
    centers = []
    verdicts = []
    for r in records:
        c = r.get("center")
        if isinstance(c, (list, tuple)) and len(c) == 3:
            try:
                arr = np.asarray(c, dtype=np.float64)
            except (TypeError, ValueError):
                continue
            if np.all(np.isfinite(arr)):
                centers.append(arr)
                verdicts.append(str(r.get("verdict")))
    if not centers:
        return None
    c = np.stack(centers)
    u, v = top_view_axes(c)
    xy = np.stack([(c - c.mean(axis=0)) @ u, (c - c.mean(axis=0)) @ v], axis=1)
    verdicts_a = np.array(verdicts)
    chart = _chart("Camera centres, top view (plane of largest spread)",
                   Axis("1st principal axis [world units]"), Axis("2nd principal axis"),
                   height=370, equal_aspect=True)
    chart.line(xy[:, 0], xy[:, 1], "#cfd8dc", width=0.6)
    for verdict in ("PASS", "UNVERIFIABLE", "FAIL"):  # FAIL drawn last, on top
        m = verdicts_a == verdict
        if m.any():
            chart.points(xy[m, 0], xy[m, 1], VERDICT_COLOURS[verdict], label=verdict, size=3)
    return _save(chart.svg(), out_dir, "top_view")


def write_plots(
    records: Sequence[Mapping[str, Any]], summary: Mapping[str, Any], out_dir: str | Path
) -> list[dict[str, str]]:
    """Write every applicable plot; returns [{name, title, path}] (paths relative to out_dir)."""
    out_dir = Path(out_dir)
    plots: list[dict[str, str]] = []
    specs = [
        ("error_hist", "Corner-error histogram", plot_histogram),
        ("error_time", "Corner error along the trajectory", plot_error_along_trajectory),
    ]
    if has_enhanced(records):
        specs.append(("raw_vs_enhanced", "Raw vs enhanced", plot_raw_vs_enhanced))
    specs.append(("top_view", "Camera centres (top view)", plot_top_view))
    specs.append(("drift", "Drift along the trajectory", plot_drift))
    for name, title, fn in specs:
        path = fn(records, summary, out_dir)
        if path:
            plots.append({"name": name, "title": title, "path": path})
    # a regenerated report must not show a plot of an older run (nor keep the PNG plots of
    # versions before the SVG ones)
    stale = {f"plot_{n}.{ext}" for n in PLOT_NAMES for ext in ("svg", "png")}
    stale -= {Path(p["path"]).name for p in plots}
    for name in stale:
        (out_dir / "assets" / name).unlink(missing_ok=True)
    logger.debug("wrote %d plots", len(plots))
    return plots
