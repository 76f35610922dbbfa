"""``OutputLayout``: one place names every output of a run; the marker, the ownership check and
the input-vs-output check read it."""

from __future__ import annotations

import ast
import re
from dataclasses import FrozenInstanceError
from pathlib import Path

import pytest

from pgt_check.output_layout import OUTPUTS, OutputLayout

PKG = Path(__file__).resolve().parents[2] / "pgt_check"


def test_marker_covers_report_correction_and_probes_in_a_fixed_order():
    marked = OUTPUTS.marked_files()
    assert marked[:7] == ("frames.csv", "config.json", "summary.json", "report.html",
                          "junit.xml", "assets/index.json", "calibrated_sensors.txt")
    assert "assets/plot_drift.svg" in marked and "assets/plot_drift.png" in marked
    assert marked[-4:] == tuple(f"calibrated/{n}" for n in OUTPUTS.calibrated_files)
    for name in ("corrections.json", "corrected_trajectory.txt", "bad_frames.txt",
                 "registration_refined.json", "registered_trajectory.txt",
                 "separation_probes.json"):
        assert name in marked
    # the store and the marker itself are never listed by the marker
    assert not {OUTPUTS.records, OUTPUTS.run, OUTPUTS.completion_marker} & set(marked)
    assert len(set(marked)) == len(marked)


def test_report_files_are_what_pgt_check_report_rewrites():
    report = OUTPUTS.report_files()
    assert set(report) <= set(OUTPUTS.marked_files())
    assert OUTPUTS.corrections not in report and OUTPUTS.summary_json in report


def test_top_level_names_every_file_and_folder_once():
    top = OUTPUTS.top_level()
    assert list(top) == sorted(set(top))
    assert {"assets", "calibrated", "records.jsonl", "run.json", "outputs.complete.json",
            "separation_probes.json"} <= set(top)
    assert all("/" not in n for n in top)
    assert OUTPUTS.paths("/o") == [Path("/o") / n for n in top]


def test_layout_is_frozen():
    with pytest.raises(FrozenInstanceError):
        OUTPUTS.frames_csv = "x.csv"  # type: ignore[misc]
    assert OutputLayout() == OUTPUTS


def test_no_module_spells_an_output_name_of_its_own():
    """Writers read names from the layout: no other module of the package holds one of its
    file names as a string literal (log and help texts aside, which are not paths)."""
    names = {OUTPUTS.frames_csv, OUTPUTS.summary_json, OUTPUTS.corrections,
             OUTPUTS.corrected_trajectory, OUTPUTS.bad_frames, OUTPUTS.registration_refined,
             OUTPUTS.separation_probes, OUTPUTS.calibrated_sensors, OUTPUTS.records,
             OUTPUTS.completion_marker, OUTPUTS.report_html, OUTPUTS.junit_xml}
    bad = []
    for path in PKG.rglob("*.py"):
        if path.name == "output_layout.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Assign | ast.AnnAssign) and isinstance(
                getattr(node, "value", None), ast.Constant
            ):
                if node.value.value in names:  # type: ignore[union-attr]
                    bad.append(f"{path.relative_to(PKG)}:{node.lineno}")
            if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div):
                right = node.right
                if isinstance(right, ast.Constant) and right.value in names:
                    bad.append(f"{path.relative_to(PKG)}:{node.lineno}")
    assert not bad, bad
    assert re.fullmatch(r"[\w.]+", OUTPUTS.completion_marker)


def test_the_other_commands_outputs_are_named_here_too():
    from pgt_check.output_layout import COMPARE_OUTPUTS, ENHANCE_OUTPUTS

    assert [p.name for p in COMPARE_OUTPUTS.paths("/o")] == ["compare.csv", "compare.json"]
    assert [p.name for p in ENHANCE_OUTPUTS.paths("/o")] == [
        "images", "references.csv", "metrics.csv", "metrics.md"]
