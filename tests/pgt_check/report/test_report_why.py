"""The report shows why: raw-vs-enhanced table and marker, columns, shared errors, plot files."""

from __future__ import annotations

import json
import math

from report_testdata import (
    check_report,
    judged,
    parse_report,
    shared_errors_summary,
    strip_tags,
    synthetic_measurements,
    with_verdict_columns,
)

from pgt_check.report.html import build_report, page_context, table_columns
from pgt_check.report.outputs import build_summary, write_outputs
from pgt_check.report.paths import disagreement, path_comparison


def _rows(data):
    keys = [c["key"] for c in data["columns"]]
    return [dict(zip(keys, r, strict=True)) for r in data["rows"]]


def test_raw_vs_enhanced_in_summary_and_report(tmp_path, config):
    recs = judged(synthetic_measurements(40, enhanced=True), config)
    summary = write_outputs(tmp_path, recs, config)
    comp = json.loads((tmp_path / "summary.json").read_text())["raw_vs_enhanced"]
    assert comp == summary["raw_vs_enhanced"]
    enh = [r for r in recs if r["n_matches_enhanced"] is not None]
    assert 0 < comp["enhanced"]["frames_ran"] == len(enh) < comp["raw"]["frames_ran"]
    errs = sorted(r["corner_error_px_enhanced"] for r in enh
                  if r["corner_error_px_enhanced"] is not None)
    mid = len(errs) // 2
    med = errs[mid] if len(errs) % 2 else (errs[mid - 1] + errs[mid]) / 2
    assert math.isclose(comp["enhanced"]["median_corner_error_px"], med)
    decided = comp["raw"]["frames_decided"] + comp["enhanced"]["frames_decided"]
    assert decided == sum(1 for r in recs if r["verdict_path"])
    page, data = parse_report(tmp_path / "report.html")
    text = strip_tags((tmp_path / "report.html").read_text(encoding="utf-8"))
    assert "Raw vs enhanced" in text and "median inlier ratio" in text
    assert f"{comp['enhanced']['median_corner_error_px']:.2f}" in text
    # the marker: raw and enhanced both verifiable, one PASS and one FAIL
    rows = _rows(data)
    for r, rec in zip(rows, recs, strict=True):
        both = {rec["raw_verdict"], rec["enhanced_verdict"]}
        want = None if not both <= {"PASS", "FAIL"} else len(both) == 2
        assert r["disagree"] == want
    assert comp["frames_disagree"] == sum(1 for r in rows if r["disagree"])
    check_report(tmp_path, recs)


def test_comparison_names_the_enhancer(tmp_path, config):
    """The raw-vs-enhanced table says which enhancer made the enhanced path (MaRINeR or
    reprojection), read from the run's settings."""
    import dataclasses

    recs = judged(synthetic_measurements(20, enhanced=True), config)
    for method in ("mariner", "reproject"):
        cfg = dataclasses.replace(
            config, enhance=dataclasses.replace(config.enhance, method=method)
        )
        out = tmp_path / method
        write_outputs(out, recs, cfg)
        text = strip_tags((out / "report.html").read_text(encoding="utf-8"))
        assert f"enhanced ({method})" in text
        other = "reproject" if method == "mariner" else "mariner"
        assert f"enhanced ({other})" not in text


def test_no_enhanced_path_no_comparison_no_empty_plot(tmp_path, config):
    recs = judged(synthetic_measurements(30, enhanced=True), config)
    for r in recs:  # enhancement decided never to run
        for k in ("corner_error_px_enhanced", "n_matches_enhanced", "n_inliers_enhanced",
                  "inlier_ratio_enhanced"):
            r[k] = None
    write_outputs(tmp_path, recs, config)
    page, data = parse_report(tmp_path / "report.html")
    assert "assets/plot_raw_vs_enhanced.svg" not in page.refs
    keys = [c["key"] for c in data["columns"]]
    assert "disagree" not in keys and "corner_error_px_enhanced" not in keys
    assert "raw-vs-enhanced" not in page.text_by_id


def test_given_disagree_evidence_and_drift_columns(tmp_path, config):
    recs = with_verdict_columns(judged(synthetic_measurements(24, enhanced=True), config))
    summary = build_summary(recs, config)
    build_report(tmp_path, recs, summary)
    _, data = parse_report(tmp_path / "report.html")
    cols = {c["key"]: c for c in data["columns"]}
    assert {"evidence", "drift_px", "disagree", "raw_verdict", "enhanced_verdict"} <= set(cols)
    assert not cols["evidence"]["hidden"] and cols["raw_verdict"]["hidden"]
    rows = _rows(data)
    assert [r["disagree"] for r in rows] == [i % 5 == 1 for i in range(24)]
    assert rows[2]["evidence"] == "relative+registration"
    assert disagreement({"raw_verdict": "PASS", "enhanced_verdict": "FAIL"}) is True
    assert disagreement({"corner_error_px_raw": 1.0, "threshold_px": 5.0}) is None


def test_columns_have_clear_names_and_few_are_shown(config):
    recs = judged(synthetic_measurements(10, enhanced=True), config)
    cols = table_columns(recs)
    labels = [c["label"] for c in cols]
    assert len(labels) == len(set(labels))
    assert "time" not in labels and "timestamp" in labels and "frame run time [s]" in labels
    shown = [c for c in cols if not c["hidden"]]
    assert len(shown) <= 16 < len(cols)
    assert {"shift_dx_px_raw", "shift_dy_px_raw"} <= {c["key"] for c in cols}


def test_shared_errors_section_and_drift_plot(tmp_path, config):
    recs = judged(synthetic_measurements(40), config)
    summary = build_summary(recs, config)
    summary["shared_errors"] = shared_errors_summary(40)
    build_report(tmp_path, recs, summary)
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    page, _ = parse_report(tmp_path / "report.html")
    assert "shared-errors" in page.text_by_id
    text = strip_tags(html)
    assert "Registration, drift and calibration" in text
    for s in ("passed", "inconclusive", "failed", "finding", "not_checked"):
        assert f'class="status st-{s}"' in html
    assert "0.040 [0.010, 0.090]" in text  # angle with its interval
    assert "1.0040 [0.9700, 1.0300]" in text  # scale
    assert "calibration (camera cam0)" in text
    assert "&lt;b&gt;cam1&lt;/b&gt;" in html and "<b>cam1</b>" not in html  # escaped
    assert "assets/plot_drift.svg" in page.refs and (tmp_path / "assets/plot_drift.svg").is_file()
    # without shared errors: no section, and the stale drift plot is gone
    del summary["shared_errors"]
    build_report(tmp_path, recs, summary)
    page, _ = parse_report(tmp_path / "report.html")
    assert "shared-errors" not in page.text_by_id
    assert not (tmp_path / "assets/plot_drift.svg").exists()


def test_page_context_without_comparison_in_summary(config):
    recs = judged(synthetic_measurements(12, enhanced=True), config)
    summary = build_summary(recs, config)
    del summary["raw_vs_enhanced"]  # an older summary.json: computed from the rows
    ctx = page_context(recs, summary, {}, [])
    assert ctx["comparison"] and ctx["comparison"][0][0] == "frames matched"
    assert ctx["comparison"][0][1] == str(path_comparison(recs)["raw"]["frames_ran"])
