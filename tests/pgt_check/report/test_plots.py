"""Report plots (matplotlib, SVG): what each figure shows (one marker per frame, bars per bin,
the threshold line), integer axes for counts, accessible text, no stale files, hostile rows, the
atomic writer, no global matplotlib state changed."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import numpy as np
from report_testdata import (
    HOSTILE_NAME,
    SCRIPT_BREAKER,
    judged,
    shared_errors_summary,
    synthetic_measurements,
)

from pgt_check.report import plots

NS = "{http://www.w3.org/2000/svg}"


def _svg(out, rel) -> ET.Element:
    return ET.parse(out / rel).getroot()


def _group(root, gid) -> ET.Element | None:
    return next((g for g in root.iter(f"{NS}g") if g.get("id") == gid), None)


def _marks(root, gid) -> int:
    """Markers drawn in the group ``gid``: one <use> per point (matplotlib writes a single
    point as a <path> instead); 0 when the group is absent."""
    g = _group(root, gid)
    if g is None:
        return 0
    uses = list(g.iter(f"{NS}use"))
    if uses:
        return len(uses)
    defs = {id(p) for d in g.iter(f"{NS}defs") for p in d.iter(f"{NS}path")}
    return sum(1 for p in g.iter(f"{NS}path") if id(p) not in defs)


def _texts(el) -> list[str]:
    return ["".join(t.itertext()).strip() for t in el.iter(f"{NS}text")]


def _ticks(root, which) -> list[float]:
    """The tick labels of the x or y axis, as numbers."""
    out = []
    for g in root.iter(f"{NS}g"):
        if re.fullmatch(f"{which}tick_\\d+", g.get("id", "")):
            out += [float(t.replace("\u2212", "-")) for t in _texts(g) if t]
    return out


def _xs(path_el) -> list[float]:
    """x coordinates of an SVG path's points (matplotlib writes ``M x y L x y ... z``)."""
    nums = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", path_el.get("d", ""))]
    return nums[0::2]


def _ys(path_el) -> list[float]:
    nums = [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?", path_el.get("d", ""))]
    return nums[1::2]


def _bars(root, verdict) -> list[ET.Element]:
    return [g.find(f"{NS}path") for g in root.iter(f"{NS}g")
            if re.fullmatch(f"bar-{verdict}-\\d+", g.get("id", ""))]


def test_frame_count_axes_have_integer_ticks(tmp_path, config):
    recs = judged(synthetic_measurements(8, hostile=False), config)
    for r in recs:
        r["timestamp"] = None  # ordered by frame index
    hist = _svg(tmp_path, plots.plot_histogram(recs, {}, tmp_path))
    along = _svg(tmp_path, plots.plot_error_along_trajectory(recs, {}, tmp_path))
    drift = _svg(tmp_path, plots.plot_drift(recs, {"shared_errors": shared_errors_summary(8)},
                                            tmp_path))
    for root, which in ((hist, "y"), (along, "x"), (drift, "x")):
        ticks = _ticks(root, which)
        assert len(ticks) >= 2 and all(t.is_integer() for t in ticks), (which, ticks)
    assert "frame index" in _texts(along) and "frames" in _texts(hist)
    assert plots.plot_drift(recs, {}, tmp_path) is None


def test_histogram_bars_counts_and_threshold_line(tmp_path):
    # PASS: two frames at 1 px, one at 2 px and one exactly at the threshold; FAIL: one at 50
    recs = [{"verdict": "PASS", "corner_error_px": e} for e in (1.0, 1.0, 2.0, 4.0)]
    recs += [{"verdict": "FAIL", "corner_error_px": 50.0},
             {"verdict": "UNVERIFIABLE", "corner_error_px": None}]
    root = _svg(tmp_path, plots.plot_histogram(recs, {"threshold_px": 4.0}, tmp_path))
    pas, fail = _bars(root, "PASS"), _bars(root, "FAIL")
    assert len(pas) == 3 and len(fail) == 1  # one bar per non-empty bin
    heights = sorted(max(_ys(b)) - min(_ys(b)) for b in pas)
    assert math.isclose(heights[0], heights[1]) and math.isclose(heights[2], 2 * heights[0],
                                                                 rel_tol=1e-3)
    line = _group(root, "threshold").find(f"{NS}path")
    x_thr = _xs(line)[0]
    assert max(max(_xs(b)) for b in pas) <= x_thr + 1e-3  # the 4.0 px PASS too
    assert min(_xs(fail[0])) > x_thr
    legend = _texts(_group(root, "legend"))
    assert legend == ["PASS", "FAIL", "threshold 4.0 px"]
    assert _texts(root).count("Corner error (1 UNVERIFIABLE frames not shown)") == 1
    assert "corner error [px] (log)" in _texts(root)


def test_histogram_bins_put_the_threshold_on_an_edge():
    edges = plots.histogram_bins(0.5, 120.0, 7.3)
    assert len(edges) == plots.HIST_BINS + 1 and np.all(np.diff(edges) > 0)
    k = int(np.argmin(abs(edges - 7.3)))
    assert edges[k] == 7.3
    counts = plots.histogram_counts(np.array([7.3, 7.3000001, 0.5, 500.0]), edges)
    assert counts[k - 1] == 1 and counts[k] == 1  # at the threshold: left of it
    assert counts[0] == 1 and counts[-1] == 1 and counts.sum() == 4
    assert np.allclose(plots.histogram_bins(1.0, 10.0, 50.0), np.geomspace(1.0, 10.0, 40))


def test_figures_show_every_frame_by_verdict(tmp_path, config):
    recs = judged(synthetic_measurements(30, enhanced=True, hostile=False), config)
    written = {p["name"]: p["path"] for p in plots.write_plots(recs, {}, tmp_path)}
    assert set(written) == {"error_hist", "error_time", "raw_vs_enhanced", "top_view"}
    for rel in written.values():
        assert rel.endswith(".svg") and (tmp_path / rel).is_file()
    n = {v: sum(r["verdict"] == v for r in recs) for v in plots.VERDICT_COLOURS}
    measured = {v: sum(r["verdict"] == v and math.isfinite(plots._num(r, "corner_error_px"))
                       for r in recs) for v in ("PASS", "FAIL")}
    assert measured["PASS"] > 0 and measured["FAIL"] > 0 and n["UNVERIFIABLE"] > 0
    along = _svg(tmp_path, written["error_time"])
    for v in ("PASS", "FAIL"):
        assert _marks(along, f"points-{v}") == measured[v]
    assert _marks(along, "points-UNVERIFIABLE") == n["UNVERIFIABLE"]
    assert _group(along, "threshold") is not None
    top = _svg(tmp_path, written["top_view"])
    for v, k in n.items():
        assert _marks(top, f"points-{v}") == k
    both = sum(math.isfinite(plots._num(r, "corner_error_px_raw"))
               and math.isfinite(plots._num(r, "corner_error_px_enhanced"))
               and r["corner_error_px_raw"] > 0 and r["corner_error_px_enhanced"] > 0
               for r in recs)
    rve = _svg(tmp_path, written["raw_vs_enhanced"])
    assert sum(_marks(rve, f"points-{v}") for v in n) == both > 0
    assert f"corner error [px]: raw vs enhanced ({both} frames)" in _texts(rve)
    hist = _svg(tmp_path, written["error_hist"])
    assert len(_bars(hist, "PASS")) > 0 and len(_bars(hist, "FAIL")) > 0


def test_drift_curve_and_threshold(tmp_path):
    shared = shared_errors_summary(25)
    shared["drift"]["threshold_px"] = 6.0
    root = _svg(tmp_path, plots.plot_drift([], {"shared_errors": shared}, tmp_path))
    assert _marks(root, "points-drift") == 25
    assert _group(root, "threshold") is not None and _group(root, "band") is not None
    assert _texts(_group(root, "legend")) == ["lower bound .. estimate", "drift effect",
                                              "threshold 6.0 px"]


def test_figures_are_accessible_and_reproducible(tmp_path, config):
    recs = judged(synthetic_measurements(20, enhanced=True, hostile=False), config)
    summary = {"shared_errors": shared_errors_summary(20)}
    written = plots.write_plots(recs, summary, tmp_path)
    assert len(written) == 5
    first = {p["path"]: (tmp_path / p["path"]).read_bytes() for p in written}
    for p in written:
        root = _svg(tmp_path, p["path"])
        assert root.get("role") == "img"
        title, desc = root[0], root[1]  # the first children: what a screen reader reads
        assert title.tag == f"{NS}title" and title.text and desc.tag == f"{NS}desc"
        assert re.search(r"\d+ (PASS|frames)", desc.text)
        assert title.text in _texts(root) or p["name"] == "raw_vs_enhanced"
        assert len(_texts(root)) >= 6  # labels and ticks are text, not outlines
    assert "PASS" in _svg(tmp_path, "assets/plot_error_hist.svg")[1].text
    plots.write_plots(recs, summary, tmp_path)
    assert {k: (tmp_path / k).read_bytes() for k in first} == first  # no date, fixed ids


def test_no_measured_frame_says_so(tmp_path, config):
    recs = judged(synthetic_measurements(5, hostile=False), config)
    for r in recs:
        r["verdict"], r["corner_error_px"] = "UNVERIFIABLE", None
    root = _svg(tmp_path, plots.plot_histogram(recs, {}, tmp_path))
    assert "no frame was measured" in _texts(root)
    assert not _bars(root, "PASS") and not _bars(root, "FAIL")


def test_stale_plots_of_an_older_run_or_version_are_removed(tmp_path, config):
    assets = tmp_path / "assets"
    assets.mkdir()
    for name in ("plot_error_hist.png", "plot_drift.png", "plot_raw_vs_enhanced.svg",
                 "plot_raw_vs_enhanced.png"):
        (assets / name).write_bytes(b"old")
    recs = judged(synthetic_measurements(10, hostile=False), config)
    written = plots.write_plots(recs, {}, tmp_path)
    left = sorted(p.name for p in assets.iterdir())
    assert left == sorted(p["path"].split("/")[-1] for p in written)
    assert not any(n.endswith(".png") for n in left)


def test_a_symlink_at_a_plot_path_is_replaced_not_written_through(tmp_path, config):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    out = tmp_path / "out"
    (out / "assets").mkdir(parents=True)
    link = out / "assets" / "plot_error_hist.svg"
    link.symlink_to(victim)
    recs = judged(synthetic_measurements(6, hostile=False), config)
    plots.write_plots(recs, {}, out)
    assert victim.read_text() == "keep me"
    assert not link.is_symlink() and _svg(out, "assets/plot_error_hist.svg").tag == f"{NS}svg"


def test_hostile_rows_give_valid_figures(tmp_path, config):
    recs = judged(synthetic_measurements(40, enhanced=True, hostile=True), config)
    assert {HOSTILE_NAME, "x" + SCRIPT_BREAKER} <= {r["frame_id"] for r in recs}
    recs[0]["center"] = ["x", None, 1]
    recs[1]["timestamp"] = float("inf")
    recs[2]["corner_error_px"] = -3.0
    recs[3]["corner_error_px"] = True
    summary = {"threshold_px": float("nan"), "shared_errors": shared_errors_summary(40)}
    summary["shared_errors"]["drift"]["per_frame"][5]["frame_id"] = SCRIPT_BREAKER
    written = plots.write_plots(recs, summary, tmp_path)
    assert len(written) == 5
    for p in written:
        text = (tmp_path / p["path"]).read_text(encoding="utf-8")
        _svg(tmp_path, p["path"])  # parses
        # no frame id reaches a figure, escaped or not
        assert "alert(" not in text and "<script" not in text and "onerror" not in text


def test_matplotlib_state_of_the_caller_is_left_alone(tmp_path, config):
    import matplotlib

    backend, fonttype = matplotlib.get_backend(), matplotlib.rcParams["svg.fonttype"]
    recs = judged(synthetic_measurements(6, hostile=False), config)
    plots.write_plots(recs, {}, tmp_path)
    assert matplotlib.get_backend() == backend
    assert matplotlib.rcParams["svg.fonttype"] == fonttype
