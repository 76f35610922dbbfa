"""Report plots (matplotlib, Agg backend, imported lazily) written as PNG files under assets/.

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

logger = logging.getLogger(__name__)

VERDICT_COLOURS = {"PASS": "#2e7d32", "FAIL": "#c62828", "UNVERIFIABLE": "#9e9e9e"}
PLOT_DPI = 96


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _figure(figsize: tuple[float, float], ncols: int = 1, right: float = 0.97):
    """A figure with fixed margins: a layout engine (constrained / tight) measures every label's
    extent at each draw, which took about half the report's plotting time
    (reports/pipeline_timing.md, report files)."""
    fig, axes = _pyplot().subplots(1, ncols, figsize=figsize)
    fig.subplots_adjust(left=0.1 if ncols == 1 else 0.08, right=right, bottom=0.15, top=0.9,
                        wspace=0.3)
    return fig, axes


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


def _integer_axis(axis) -> None:
    """Ticks at whole numbers only (frame counts, frame indices)."""
    from matplotlib.ticker import MaxNLocator

    axis.set_major_locator(MaxNLocator(integer=True))


def _save(fig, out_dir: Path, name: str) -> str:
    rel = f"assets/plot_{name}.png"
    path = out_dir / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    # no metadata: the PNG carries no machine-specific text
    fig.savefig(path, dpi=PLOT_DPI, metadata={"Software": None})
    _pyplot().close(fig)
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
    fig, ax = _figure((6, 3.6))
    errs = {
        v: np.array([_num(r, "corner_error_px") for r in records if r.get("verdict") == v])
        for v in ("PASS", "FAIL")
    }
    allv = np.concatenate([e[np.isfinite(e)] for e in errs.values()])
    if len(allv):
        lo = max(min(allv.min(), thr if math.isfinite(thr) else allv.min()), 1e-2)
        hi = max(allv.max(), thr if math.isfinite(thr) else allv.max(), lo * 10)
        bins = np.geomspace(lo, hi * 1.01, 40)
        data = [np.clip(e[np.isfinite(e)], lo, None) for e in errs.values()]
        ax.hist(
            data,
            bins=bins,
            stacked=True,
            label=list(errs),
            color=[VERDICT_COLOURS[v] for v in errs],
        )
        ax.set_xscale("log")
    else:
        ax.text(0.5, 0.5, "no frame was measured", ha="center", transform=ax.transAxes)
    if math.isfinite(thr):
        ax.axvline(thr, color="k", ls="--", lw=1.2, label=f"threshold {thr:.1f} px")
    n_unv = sum(1 for r in records if r.get("verdict") == "UNVERIFIABLE")
    ax.set_xlabel("corner error [px] (log)")
    ax.set_ylabel("frames")
    _integer_axis(ax.yaxis)
    ax.set_title(f"Corner error ({n_unv} UNVERIFIABLE frames not shown)", fontsize=10)
    ax.legend(fontsize=8)
    return _save(fig, out_dir, "error_hist")


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
    fig, ax = _figure((6, 3.6), right=0.74)  # the legend stands right of the axes
    finite = err[np.isfinite(err) & (err > 0)]
    floor = float(finite.min()) / 2 if len(finite) else 0.1
    order = np.argsort(x, kind="stable")
    ok = np.isfinite(err[order])
    ax.plot(x[order][ok], np.maximum(err[order][ok], floor), color="#90a4ae", lw=0.6, zorder=1)
    for v in ("PASS", "FAIL"):
        m = (verdict == v) & np.isfinite(err)
        ax.scatter(
            x[m], np.maximum(err[m], floor), s=8, color=VERDICT_COLOURS[v], label=v, zorder=2
        )
    m = verdict == "UNVERIFIABLE"
    if m.any():
        ax.scatter(
            x[m],
            np.full(m.sum(), floor),
            marker="x",
            s=14,
            color=VERDICT_COLOURS["UNVERIFIABLE"],
            label="UNVERIFIABLE",
            zorder=2,
        )
    if math.isfinite(thr) and thr > 0:
        ax.axhline(thr, color="k", ls="--", lw=1.0, label="threshold")
    if len(finite) or (math.isfinite(thr) and thr > 0):
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    if xlabel == "frame index":
        _integer_axis(ax.xaxis)
    ax.set_ylabel("corner error [px] (log)")
    ax.set_title("Corner error along the trajectory", fontsize=10)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    return _save(fig, out_dir, "error_time")


def plot_raw_vs_enhanced(records, summary, out_dir: Path) -> str:
    thr = _threshold(records, summary)
    fig, axes = _figure((8, 3.8), ncols=2)
    for ax, key, label, log in (
        (axes[0], "corner_error_px", "corner error [px]", True),
        (axes[1], "inlier_ratio", "inlier ratio", False),
    ):
        raw = np.array([_num(r, f"{key}_raw") for r in records])
        enh = np.array([_num(r, f"{key}_enhanced") for r in records])
        verdict = np.array([str(r.get("verdict")) for r in records])
        ok = np.isfinite(raw) & np.isfinite(enh)
        if log:
            ok &= (raw > 0) & (enh > 0)
        for v, col in VERDICT_COLOURS.items():
            m = ok & (verdict == v)
            if m.any():
                ax.scatter(raw[m], enh[m], s=8, color=col, label=v)
        if ok.any():
            lo, hi = min(raw[ok].min(), enh[ok].min()), max(raw[ok].max(), enh[ok].max())
            ax.plot([lo, hi], [lo, hi], color="k", lw=0.8, ls=":")
        if log:
            ax.set_xscale("log")
            ax.set_yscale("log")
            if math.isfinite(thr):
                ax.axvline(thr, color="k", ls="--", lw=0.8)
                ax.axhline(thr, color="k", ls="--", lw=0.8)
        ax.set_xlabel(f"raw {label}")
        ax.set_ylabel(f"enhanced {label}")
        ax.set_title(f"{label}: raw vs enhanced ({int(ok.sum())} frames)", fontsize=10)
    if axes[0].get_legend_handles_labels()[0]:
        axes[0].legend(fontsize=8)
    else:  # no frame has both a raw and an enhanced value (e.g. raw matching failed everywhere)
        axes[0].text(0.5, 0.5, "no frame measured on both paths", ha="center",
                     transform=axes[0].transAxes)
    return _save(fig, out_dir, "raw_vs_enhanced")


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
    fig, ax = _figure((6, 3.6))
    ax.plot(x, eff, color="#1565c0", lw=1.2, marker=".", ms=4, label="drift effect")
    if np.isfinite(lo).any():
        ax.fill_between(x, np.where(np.isfinite(lo), lo, eff), eff, color="#90caf9", alpha=0.5,
                        label="lower bound .. estimate")
    if math.isfinite(thr):
        ax.axhline(thr, color="k", ls="--", lw=1.0, label=f"threshold {thr:.1f} px")
    ax.set_xlabel("frame index")
    _integer_axis(ax.xaxis)
    ax.set_ylabel("drift effect [px]")
    ax.set_ylim(bottom=0)
    ax.set_title("Drift along the trajectory", fontsize=10)
    ax.legend(fontsize=8)
    return _save(fig, out_dir, "drift")


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
    fig, ax = _figure((6, 3.8))
    ax.plot(xy[:, 0], xy[:, 1], color="#cfd8dc", lw=0.6, zorder=1)
    for verdict in ("PASS", "UNVERIFIABLE", "FAIL"):
        m = verdicts_a == verdict
        if m.any():
            ax.scatter(
                xy[m, 0],
                xy[m, 1],
                s=10,
                color=VERDICT_COLOURS[verdict],
                label=verdict,
                zorder=3 if verdict == "FAIL" else 2,
            )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("1st principal axis [world units]")
    ax.set_ylabel("2nd principal axis")
    ax.set_title("Camera centres, top view (plane of largest spread)", fontsize=10)
    ax.legend(fontsize=8)
    return _save(fig, out_dir, "top_view")


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
    stale = {f"plot_{p}.png" for p in ("raw_vs_enhanced", "top_view", "drift")} - {
        Path(p["path"]).name for p in plots
    }
    for name in stale:  # a regenerated report must not show a plot of an older run
        (out_dir / "assets" / name).unlink(missing_ok=True)
    logger.debug("wrote %d plots", len(plots))
    return plots
