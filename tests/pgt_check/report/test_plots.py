"""Report plots: what each figure shows, integer axes for counts, no stale files, hostile rows."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from report_testdata import judged, shared_errors_summary, synthetic_measurements

from pgt_check.report import plots

NS = "{http://www.w3.org/2000/svg}"


def _svg(out, rel) -> ET.Element:
    return ET.parse(out / rel).getroot()


def _texts(root, cls) -> list[str]:
    return [t.text or "" for t in root.iter(f"{NS}text") if t.get("class") == cls]


def _number(s: str) -> float:
    return float(s.replace("e", "E"))


def test_frame_count_axes_have_integer_ticks(tmp_path, config):
    recs = judged(synthetic_measurements(8, hostile=False), config)
    for r in recs:
        r["timestamp"] = None  # ordered by frame index
    hist = _svg(tmp_path, plots.plot_histogram(recs, {}, tmp_path))
    along = _svg(tmp_path, plots.plot_error_along_trajectory(recs, {}, tmp_path))
    drift = _svg(tmp_path, plots.plot_drift(recs, {"shared_errors": shared_errors_summary(8)},
                                            tmp_path))
    for root, cls in ((hist, "ytick"), (along, "xtick"), (drift, "xtick")):
        ticks = [_number(t) for t in _texts(root, cls)]
        assert len(ticks) >= 2 and all(t.is_integer() for t in ticks), (cls, ticks)
    assert _texts(along, "xlabel") == ["frame index"]
    assert plots.plot_drift(recs, {}, tmp_path) is None


def test_figures_show_every_measured_frame_by_verdict(tmp_path, config):
    recs = judged(synthetic_measurements(30, enhanced=True, hostile=False), config)
    written = {p["name"]: p["path"] for p in plots.write_plots(recs, {}, tmp_path)}
    assert set(written) == {"error_hist", "error_time", "raw_vs_enhanced", "top_view"}
    for rel in written.values():
        assert rel.endswith(".svg") and (tmp_path / rel).is_file()
    measured = [r for r in recs if r.get("verdict") in ("PASS", "FAIL")
                and math.isfinite(plots._num(r, "corner_error_px"))]
    along = _svg(tmp_path, written["error_time"])
    colours = {v: c for v, c in plots.VERDICT_COLOURS.items()}
    dots = [c.get("fill") for c in along.iter(f"{NS}circle")]
    for v in ("PASS", "FAIL"):  # one dot per frame, + one legend sample when present
        n = sum(r["verdict"] == v for r in measured)
        assert dots.count(colours[v]) == n + (n > 0)
    hist = _svg(tmp_path, written["error_hist"])
    legend = _texts(hist, "legend")
    assert legend[:2] == ["PASS", "FAIL"] and legend[2].startswith("threshold")


def test_no_measured_frame_says_so(tmp_path, config):
    recs = judged(synthetic_measurements(5, hostile=False), config)
    for r in recs:
        r["verdict"], r["corner_error_px"] = "UNVERIFIABLE", None
    root = _svg(tmp_path, plots.plot_histogram(recs, {}, tmp_path))
    assert "no frame was measured" in [t.text for t in root.iter(f"{NS}text")]


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


def test_hostile_rows_give_valid_figures(tmp_path, config):
    recs = judged(synthetic_measurements(40, enhanced=True, hostile=True), config)
    recs[0]["center"] = ["x", None, 1]
    recs[1]["timestamp"] = float("inf")
    recs[2]["corner_error_px"] = -3.0
    summary = {"threshold_px": float("nan"), "shared_errors": shared_errors_summary(40)}
    for p in plots.write_plots(recs, summary, tmp_path):
        _svg(tmp_path, p["path"])  # parses
