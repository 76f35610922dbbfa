"""Report plots, drawn with matplotlib and written as SVG files under assets/.

Each function takes the judged records and writes one figure; ``write_plots`` writes all that
apply and returns ``[{"name", "title", "path"}]`` with paths relative to the output directory.

matplotlib is imported here only when a figure is drawn (importing this module imports nothing
of it: a run pays it once, in the report stage; reports/pipeline_timing.md, "Report figures").
The figures are ``matplotlib.figure.Figure`` objects, never pyplot: no global figure registry,
no interactive backend chosen, the caller's backend and rcParams left as they were. The SVG keeps
its text as text (``svg.fonttype: none``: searchable, read by screen readers), carries a
``<title>`` and a ``<desc>`` (what the figure shows, in numbers), no date, and the same ids at
each run. Marks tests and readers look for carry ids: ``bar-<verdict>-<i>`` (histogram bars),
``points-<verdict>`` (one marker per frame), ``threshold``, ``legend``.
"""

from __future__ import annotations

import io
import logging
import math
import re
from collections.abc import Callable, Mapping, Sequence
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pgt_check.common.files import atomic_write_text
from pgt_check.output_layout import OUTPUTS

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

logger = logging.getLogger(__name__)

VERDICT_COLOURS = {"PASS": "#2e7d32", "FAIL": "#c62828", "UNVERIFIABLE": "#9e9e9e"}
#: bins of the corner-error histogram (log-spaced; the threshold is one of the edges)
HIST_BINS = 39
#: what the SVG writer reads at save time: text kept as <text>, ids the same at every run
_SVG_RC: dict[Any, Any] = {"svg.fonttype": "none", "svg.hashsalt": "pgt-check"}
TITLE_SIZE = 10
LEGEND_SIZE = 8


def _figure(size: tuple[float, float], ncols: int = 1, right: float = 0.97,
            left: float | None = None) -> tuple[Figure, Any]:
    """A figure (inches) with fixed margins: a layout engine (constrained / tight) measures
    every label at each draw, a third of the plotting time."""
    from matplotlib.figure import Figure  # lazy: only the report stage pays the import

    fig = Figure(figsize=size)
    axes = fig.subplots(1, ncols)
    if left is None:
        left = 0.1 if ncols == 1 else 0.08
    fig.subplots_adjust(left=left, right=right, bottom=0.15, top=0.9,
                        wspace=0.3)
    return fig, axes


def _integer_axis(axis: Any) -> None:
    """Ticks at whole numbers only (frame counts, frame indices)."""
    from matplotlib.ticker import MaxNLocator

    axis.set_major_locator(MaxNLocator(integer=True))


def _log_scale(ax: Axes, which: str) -> None:
    """Log scale on the axes ``which`` ("x", "y" or "xy") with plain tick labels ("0.5", "10",
    "200"): matplotlib's default writes them as mathtext (10^1), whose parser took a third of
    the plotting time."""
    from matplotlib.ticker import LogFormatter

    for name in which:
        getattr(ax, f"set_{name}scale")("log")
        axis = getattr(ax, f"{name}axis")
        axis.set_major_formatter(LogFormatter())
        axis.set_minor_formatter(LogFormatter(labelOnlyBase=False, minor_thresholds=(1, 0.4)))


def _title(ax: Axes, text: str) -> None:
    """The axes' title at a fixed height: an automatic one measures every tick label."""
    ax.set_title(text, fontsize=TITLE_SIZE, y=1.0, pad=6)


def _note(ax: Axes, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)


def _legend(ax: Axes, **kw: Any) -> None:
    """The legend of ``ax`` (if it has labelled marks), the threshold entry last."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        order = sorted(range(len(labels)), key=lambda i: labels[i].startswith("threshold"))
        ax.legend([handles[i] for i in order], [labels[i] for i in order],
                  fontsize=LEGEND_SIZE, **kw).set_gid("legend")


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


def svg_text(fig: Figure, title: str, desc: str) -> str:
    """The figure as one SVG document with ``<title>`` and ``<desc>`` (escaped) as the first
    children of its root, and ``role="img"``."""
    import matplotlib

    buf = io.StringIO()
    with matplotlib.rc_context(_SVG_RC):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    svg = buf.getvalue()
    root = re.search(r"<svg\b[^>]*>", svg)
    if root is None:  # not what matplotlib writes
        raise ValueError("matplotlib wrote no <svg> element")
    head = root.group(0)[:-1] + ' role="img">'
    label = (f"\n <title>{escape(title, quote=False)}</title>"
             f"\n <desc>{escape(desc, quote=False)}</desc>")
    return svg[:root.start()] + head + label + svg[root.end():]


def _save(fig: Figure, out_dir: Path, name: str, title: str, desc: str) -> str:
    rel = OUTPUTS.plot_file(name)
    path = out_dir / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, svg_text(fig, title, desc))  # a symlink there is replaced
    return rel


def _threshold(records: Sequence[Mapping[str, Any]], summary: Mapping[str, Any]) -> float:
    t = summary.get("threshold_px")
    if isinstance(t, (int, float)) and math.isfinite(t):
        return float(t)
    vals = [_num(r, "threshold_px") for r in records]
    vals = [v for v in vals if math.isfinite(v)]
    return float(np.median(vals)) if vals else math.nan


def _thr_text(thr: float) -> str:
    return f"threshold {thr:.1f} px" if math.isfinite(thr) else "no threshold"


def histogram_bins(lo: float, hi: float, thr: float, n: int = HIST_BINS) -> np.ndarray:
    """``n + 1`` log-spaced edges from ``lo`` to ``hi`` (0 < lo < hi) with ``thr`` one of them
    when it lies between: with right-closed bins (``histogram_counts``) an error at or below the
    threshold is drawn left of the threshold line, an error above it right of it."""
    if not (math.isfinite(thr) and lo < thr < hi):
        return np.geomspace(lo, hi, n + 1)
    k = int(round(n * math.log(thr / lo) / math.log(hi / lo)))
    k = min(max(k, 1), n - 1)
    return np.concatenate([np.geomspace(lo, thr, k + 1), np.geomspace(thr, hi, n - k + 1)[1:]])


def histogram_counts(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Counts per bin ``(edges[i], edges[i+1]]`` (the first bin also holds ``edges[0]``);
    values outside go to the first or last bin."""
    idx = np.clip(np.searchsorted(edges, values, side="left") - 1, 0, len(edges) - 2)
    return np.bincount(idx, minlength=len(edges) - 1)


def plot_histogram(records, summary, out_dir: Path) -> str:
    thr = _threshold(records, summary)
    errs = {
        v: np.array([_num(r, "corner_error_px") for r in records if r.get("verdict") == v])
        for v in ("PASS", "FAIL")
    }
    errs = {v: e[np.isfinite(e)] for v, e in errs.items()}
    allv = np.concatenate(list(errs.values()))
    n_unv = sum(1 for r in records if r.get("verdict") == "UNVERIFIABLE")
    log = bool(len(allv))
    fig, ax = _figure((6, 3.6))
    title = f"Corner error ({n_unv} UNVERIFIABLE frames not shown)"
    if len(allv):
        lo = max(min(allv.min(), thr if math.isfinite(thr) else allv.min()), 1e-2)
        hi = max(allv.max(), thr if math.isfinite(thr) else allv.max(), lo * 10) * 1.01
        edges = histogram_bins(lo, hi, thr)
        base = np.zeros(len(edges) - 1)
        for v, e in errs.items():
            counts = histogram_counts(np.clip(e, lo, None), edges)
            nz = counts > 0
            if nz.any():
                bars = ax.bar(edges[:-1][nz], counts[nz], width=np.diff(edges)[nz],
                              bottom=base[nz], align="edge", color=VERDICT_COLOURS[v], label=v)
                for i, bar in enumerate(bars.patches):
                    bar.set_gid(f"bar-{v}-{i}")
            base = base + counts
        _log_scale(ax, "x")
    else:
        _note(ax, "no frame was measured")
    if math.isfinite(thr) and (thr > 0 or not log):
        ax.axvline(thr, color="k", ls="--", lw=1.2, label=_thr_text(thr), gid="threshold")
    ax.set_xlabel("corner error [px]" + (" (log)" if log else ""))
    ax.set_ylabel("frames")
    ax.set_ylim(bottom=0)
    _integer_axis(ax.yaxis)
    _title(ax, title)
    _legend(ax)
    desc = (f"Histogram of the corner error: {len(errs['PASS'])} PASS and {len(errs['FAIL'])} "
            f"FAIL frames measured, {_thr_text(thr)}.")
    return _save(fig, out_dir, "error_hist", title, desc)


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
    fig, ax = _figure((6.6, 3.6), right=0.67, left=0.09)  # the legend stands right of the axes
    order = np.argsort(x, kind="stable")
    ok = np.isfinite(err[order])
    ax.plot(x[order][ok], np.maximum(err[order][ok], floor), color="#90a4ae", lw=0.6, zorder=1)
    shown = {}
    for v in ("PASS", "FAIL"):
        m = (verdict == v) & np.isfinite(err)
        shown[v] = int(m.sum())
        if m.any():
            ax.scatter(x[m], np.maximum(err[m], floor), s=8, color=VERDICT_COLOURS[v], label=v,
                       zorder=2, gid=f"points-{v}")
    m = verdict == "UNVERIFIABLE"
    if m.any():
        ax.scatter(x[m], np.full(m.sum(), floor), marker="x", s=14,
                   color=VERDICT_COLOURS["UNVERIFIABLE"], label="UNVERIFIABLE (at the floor)",
                   zorder=2, gid="points-UNVERIFIABLE")
    if math.isfinite(thr) and thr > 0:
        ax.axhline(thr, color="k", ls="--", lw=1.0, label="threshold", gid="threshold")
    if log:
        _log_scale(ax, "y")
    ax.set_xlabel(xlabel)
    if xlabel == "frame index":
        _integer_axis(ax.xaxis)
    ax.set_ylabel("corner error [px]" + (" (log)" if log else ""))
    title = "Corner error along the trajectory"
    _title(ax, title)
    _legend(ax, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    desc = (f"Corner error per frame against the {xlabel}: {shown['PASS']} PASS and "
            f"{shown['FAIL']} FAIL frames, {int(m.sum())} UNVERIFIABLE frames marked at the "
            f"floor, {_thr_text(thr)}.")
    return _save(fig, out_dir, "error_time", title, desc)


def plot_raw_vs_enhanced(records, summary, out_dir: Path) -> str:
    thr = _threshold(records, summary)
    verdict = np.array([str(r.get("verdict")) for r in records])
    fig, axes = _figure((8, 3.8), ncols=2)
    counts = []
    for ax, key, label, log in (
        (axes[0], "corner_error_px", "corner error [px]", True),
        (axes[1], "inlier_ratio", "inlier ratio", False),
    ):
        raw = np.array([_num(r, f"{key}_raw") for r in records])
        enh = np.array([_num(r, f"{key}_enhanced") for r in records])
        ok = np.isfinite(raw) & np.isfinite(enh)
        if log:
            ok &= (raw > 0) & (enh > 0)
        counts.append(f"{int(ok.sum())} frames with both {label}s")
        first = ax is axes[0]  # the legend is drawn once, in the first axes
        for v, col in VERDICT_COLOURS.items():
            m = ok & (verdict == v)
            if m.any():
                ax.scatter(raw[m], enh[m], s=8, color=col, label=v if first else None,
                           gid=f"points-{v}" if first else f"points-{v}-{key}")
        if ok.any():
            lo, hi = min(raw[ok].min(), enh[ok].min()), max(raw[ok].max(), enh[ok].max())
            ax.plot([lo, hi], [lo, hi], color="k", lw=0.8, ls=":")
        elif first:  # no frame has both a raw and an enhanced value (raw matching failed)
            _note(ax, "no frame measured on both paths")
        if log and (ok.any() or (math.isfinite(thr) and thr > 0)):
            _log_scale(ax, "xy")
            if math.isfinite(thr) and thr > 0:
                ax.axvline(thr, color="k", ls="--", lw=0.8, gid="threshold")
                ax.axhline(thr, color="k", ls="--", lw=0.8, gid="threshold-enhanced")
        ax.set_xlabel(f"raw {label}")
        ax.set_ylabel(f"enhanced {label}")
        _title(ax, f"{label}: raw vs enhanced ({int(ok.sum())} frames)")
    _legend(axes[0])
    desc = (f"Each frame's raw against its enhanced value: {counts[0]}, {counts[1]}; "
            f"{_thr_text(thr)}.")
    return _save(fig, out_dir, "raw_vs_enhanced", "Raw vs enhanced path", desc)


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
    if np.isfinite(lo).any():
        ax.fill_between(x, np.where(np.isfinite(lo), lo, eff), eff, color="#90caf9", alpha=0.5,
                        label="lower bound .. estimate", gid="band")
    ax.plot(x, eff, color="#1565c0", lw=1.2, marker="o", ms=3, label="drift effect",
            gid="points-drift")
    if math.isfinite(thr):
        ax.axhline(thr, color="k", ls="--", lw=1.0, label=_thr_text(thr), gid="threshold")
    ax.set_xlabel("frame index")
    _integer_axis(ax.xaxis)
    ax.set_ylabel("drift effect [px]")
    ax.set_ylim(bottom=0)
    title = "Drift along the trajectory"
    _title(ax, title)
    _legend(ax)
    desc = (f"Drift effect of {len(per)} frames against the frame index, up to "
            f"{float(np.max(eff)):.1f} px; {_thr_text(thr)}.")
    return _save(fig, out_dir, "drift", title, desc)


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
    fig, ax = _figure((6, 3.8), left=0.13)
    ax.plot(xy[:, 0], xy[:, 1], color="#cfd8dc", lw=0.6, zorder=1)
    n = {}
    for verdict in ("PASS", "UNVERIFIABLE", "FAIL"):  # FAIL drawn last, on top
        m = verdicts_a == verdict
        n[verdict] = int(m.sum())
        if m.any():
            ax.scatter(xy[m, 0], xy[m, 1], s=10, color=VERDICT_COLOURS[verdict], label=verdict,
                       zorder=3 if verdict == "FAIL" else 2, gid=f"points-{verdict}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("1st principal axis [world units]")
    ax.set_ylabel("2nd principal axis")
    title = "Camera centres, top view (plane of largest spread)"
    _title(ax, title)
    _legend(ax)
    desc = (f"Camera centres seen from above: {n['PASS']} PASS, {n['FAIL']} FAIL and "
            f"{n['UNVERIFIABLE']} UNVERIFIABLE frames, joined in trajectory order.")
    return _save(fig, out_dir, "top_view", title, desc)


def write_plots(
    records: Sequence[Mapping[str, Any]], summary: Mapping[str, Any], out_dir: str | Path
) -> list[dict[str, str]]:
    """Write every applicable plot; returns [{name, title, path}] (paths relative to out_dir)."""
    out_dir = Path(out_dir)
    plots: list[dict[str, str]] = []
    specs: list[tuple[str, str, Callable[[Any, Any, Path], str | None]]] = [
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
    # older versions)
    stale = set(OUTPUTS.plot_files()) - {p["path"] for p in plots}
    for rel in stale:
        (out_dir / rel).unlink(missing_ok=True)
    logger.debug("wrote %d plots", len(plots))
    return plots
