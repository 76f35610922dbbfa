"""Synthetic judged records and report-reading helpers for the report tests (and tests/browser)."""

from __future__ import annotations

import csv
import json
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure import (
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    PathMeasurement,
    Timings,
)
from pgt_check.report.outputs import FRAME_COLUMNS

XSD = Path(__file__).parent / "fixtures" / "junit.xsd"
HOSTILE_NAME = "<img src=x onerror=alert(1)>.jpg"
SCRIPT_BREAKER = "</script><script>alert(2)</script><!--"


def synthetic_measurements(
    n: int = 60, seed: int = 0, enhanced: bool = False, hostile: bool = True
) -> list[dict[str, Any]]:
    """Flat stage-1 records (the layout of frames.csv; ``from_flat`` types them) with a mix of good, bad and failed frames."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        t = i / max(n - 1, 1)
        err = float(rng.lognormal(mean=1.0, sigma=0.6))
        if i % 11 == 5:
            err *= 12.0  # a bad pose
        rec: dict[str, Any] = {
            "frame_id": f"frame-{i:06d}",
            "timestamp": float(i * 10),
            "image_path": f"images/frame-{i:06d}.color.jpg",
            "width": 640,
            "height": 480,
            "error": "",
            "error_detail": "",
            "coverage": float(rng.uniform(0.4, 1.0)),
            "shading": "vertex",
            "n_kpts_render": 900,
            "n_kpts_photo": 1000,
            "n_matches": int(rng.integers(80, 400)),
            "n_inliers": 0,
            "inlier_ratio": 0.0,
            "homography_reason": "",
            "corner_error_px": err,
            "shift_dx_px": float(rng.normal(0, 2)),
            "shift_dy_px": float(rng.normal(0, 2)),
            "zoom": float(1 + rng.normal(0, 0.005)),
            "photo_from_render": np.eye(3).tolist(),
            "match_width": 640,
            "match_height": 480,
            "t_load_s": 0.01,
            "t_render_s": 0.02,
            "t_match_s": float(rng.uniform(0.05, 0.2)),
            "t_homography_s": 0.003,
            "time_s": float(rng.uniform(0.1, 0.3)),
            "center": [float(np.cos(6 * t)), float(np.sin(6 * t)), float(0.05 * rng.normal())],
        }
        rec["n_inliers"] = int(rec["n_matches"] * rng.uniform(0.3, 0.9))
        rec["inlier_ratio"] = rec["n_inliers"] / rec["n_matches"]
        if i % 13 == 7:
            rec.update(
                error="image_missing",
                corner_error_px=None,
                shift_dx_px=None,
                shift_dy_px=None,
                zoom=None,
                n_matches=0,
                n_inliers=0,
                inlier_ratio=0.0,
            )
        if i % 17 == 3:
            rec.update(
                homography_reason="too_few_matches",
                corner_error_px=None,
                n_inliers=4,
                shift_dx_px=None,
                shift_dy_px=None,
                zoom=None,
            )
        if i == 9:
            rec.update(
                error="internal_error",
                corner_error_px=None,
                error_detail='Traceback:\n  File "/home/alice/secret/pgt_check/runner.py", '
                "line 3, in measure\nValueError: boom",
            )
        if enhanced:
            rec["enhanced"] = bool(i % 2)
            rec["corner_error_px_raw"] = None if rec["corner_error_px"] is None else err * 1.3
            rec["corner_error_px_enhanced"] = rec["corner_error_px"]
            rec["inlier_ratio_raw"] = rec["inlier_ratio"] * 0.7
            rec["inlier_ratio_enhanced"] = rec["inlier_ratio"]
            rec["n_inliers_raw"] = int(rec["n_inliers"] * 0.7)
            rec["n_inliers_enhanced"] = rec["n_inliers"]
            rec["enhanced_why"] = "low inlier ratio" if i % 2 else ""
            rec["reference_id"] = f"frame-{max(i - 1, 0):06d}"
        out.append(rec)
    if hostile and n >= 3:
        out[1]["image_path"] = HOSTILE_NAME
        out[1]["frame_id"] = HOSTILE_NAME
        out[2]["image_path"] = "images/" + SCRIPT_BREAKER + ".jpg"
        out[2]["frame_id"] = "x" + SCRIPT_BREAKER
        out[4]["image_path"] = "/home/alice/secret/data/frame-000004.color.jpg"
    return out


def _path(rec: dict[str, Any], kind: str, suffix: str) -> PathMeasurement:
    """One path of a flat synthetic record (keys with ``suffix``; the unsuffixed keys hold the
    deciding path)."""
    err = rec.get(f"corner_error_px{suffix}")
    failed = rec.get("homography_reason") and not suffix or err is None
    return PathMeasurement(
        kind=kind, method="render" if kind == "raw" else "reproject",
        evidence=Evidence.ABSOLUTE if kind == "raw" else Evidence.RELATIVE,
        n_kpts_render=rec.get("n_kpts_render") or 0, n_kpts_photo=rec.get("n_kpts_photo") or 0,
        n_matches=rec.get(f"n_matches{suffix}") or rec.get("n_matches") or 0,
        n_inliers=rec.get(f"n_inliers{suffix}") or 0,
        inlier_ratio=rec.get(f"inlier_ratio{suffix}") or 0.0,
        reason=(rec.get("homography_reason") or "too_few_matches") if failed else "",
        photo_from_render=None if failed else tuple(map(tuple, np.eye(3))),
        corner_error_px=None if failed else err,
        shift_dx_px=None if failed else rec.get("shift_dx_px"),
        shift_dy_px=None if failed else rec.get("shift_dy_px"),
        zoom=None if failed else rec.get("zoom"),
        reference_id=rec.get("reference_id") if kind == "enhanced" else None,
    )


def from_flat(rec: dict[str, Any]) -> FrameMeasurement:
    """A FrameMeasurement from a flat synthetic record (the layout of frames.csv)."""
    base = FrameMeasurement(
        frame_id=rec["frame_id"], timestamp=rec["timestamp"], image_path=rec["image_path"],
        width=rec["width"], height=rec["height"], center=tuple(rec["center"]),
        error=MeasureReason(rec.get("error") or ""), error_detail=rec.get("error_detail") or "",
        coverage=rec.get("coverage"), shading=rec.get("shading"),
        match_width=rec.get("match_width"), match_height=rec.get("match_height"),
        timings=Timings(load=rec.get("t_load_s"), render=rec.get("t_render_s"),
                        match=rec.get("t_match_s"), homography=rec.get("t_homography_s"),
                        total=rec.get("time_s")),
    )
    if base.error is not MeasureReason.NONE:
        return base
    if "corner_error_px_raw" not in rec:  # raw path only
        return replace(base, raw=_path(rec, "raw", ""), verdict_path="raw")
    raw = replace(_path(rec, "raw", "_raw"), n_inliers=rec.get("n_inliers_raw") or 0)
    enh = _path(rec, "enhanced", "_enhanced") if rec.get("enhanced") else None
    return replace(
        base, raw=raw, enhanced=enh, enhance_ran=bool(rec.get("enhanced")),
        enhance_why=EnhanceWhy.RAW_FEW_INLIERS if rec.get("enhanced") else EnhanceWhy.RAW_DECISIVE,
        verdict_path="enhanced" if enh is not None else "raw",
    )


def judged(records: list[dict[str, Any]], config: RunConfig | None = None) -> list[dict[str, Any]]:
    from pgt_check.verdict import apply_verdicts

    ms = [r if isinstance(r, FrameMeasurement) else from_flat(r) for r in records]
    return apply_verdicts(ms, config or RunConfig())


class PageParser(HTMLParser):
    """Collects src/href references, script blocks by id, and element text by id."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.refs: list[str] = []
        self.scripts: dict[str, str] = {}
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self._script_id: str | None = None
        self._buf: list[str] = []
        self.text_by_id: dict[str, str] = {}
        self._id_stack: list[str | None] = []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.tags.append((tag, a))
        for key in ("src", "href"):
            if a.get(key):
                self.refs.append(str(a[key]))
        if tag == "script":
            self._script_id = a.get("id") or f"script{len(self.scripts)}"
            self._buf = []
        if a.get("id") and tag != "script":
            self.text_by_id.setdefault(str(a["id"]), "")
        self._id_stack.append(a.get("id"))

    def handle_endtag(self, tag):
        if tag == "script" and self._script_id is not None:
            self.scripts[self._script_id] = "".join(self._buf)
            self._script_id = None
        if self._id_stack:
            self._id_stack.pop()

    def handle_data(self, data):
        if self._script_id is not None:
            self._buf.append(data)
        elif self._id_stack and self._id_stack[-1]:
            self.text_by_id[self._id_stack[-1]] = self.text_by_id.get(self._id_stack[-1], "") + data


def parse_report(path: Path) -> tuple[PageParser, dict[str, Any]]:
    p = PageParser()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    data = json.loads(p.scripts["pgt-data"])
    return p, data


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def shared_data_dir() -> Path:
    default = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"
    return Path(os.environ.get("PGT_SHARED_DATA", default)).resolve()


def strip_tags(html: str) -> str:
    return re.sub(r"<[^>]*>", "", html)


def validate(text: str) -> None:
    """Validate against fixtures/junit.xsd with xmlschema; a structural check if it is absent."""
    try:
        import xmlschema
    except ImportError:
        xmlschema = None
    if xmlschema is not None:
        xmlschema.XMLSchema(str(XSD)).validate(text)
        return
    root = ET.fromstring(text)  # pragma: no cover - fallback without xmlschema
    assert root.tag == "testsuites"
    for suite in root.iter("testsuite"):
        for attr in ("name", "tests", "failures", "errors", "skipped", "time"):
            assert attr in suite.attrib
        for case in suite.iter("testcase"):
            assert {"name", "classname", "time"} <= set(case.attrib)


def check_report(out: Path, records: list[dict]) -> dict:
    """The report checks of the issue: all frames, numbers equal to frames.csv, assets exist."""
    page, data = parse_report(out / "report.html")
    cols = [c["key"] for c in data["columns"]]
    rows = [dict(zip(cols, row, strict=True)) for row in data["rows"]]
    csv_rows = read_csv(out / "frames.csv")
    assert [r["frame_id"] for r in rows] == [r["frame_id"] for r in records]
    assert [r["frame_id"] for r in csv_rows] == [r["frame_id"] for r in records]
    for row, crow in zip(rows, csv_rows, strict=True):
        for key in cols:
            if key not in FRAME_COLUMNS or key == "image_path":
                continue
            v, c = row[key], crow[key]
            if c == "":
                assert v in (None, ""), (key, v)
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                assert v == float(c), (key, v, c)
            else:
                assert str(v) == c, (key, v, c)
    # every referenced file exists (page links, plots, detail images)
    # records.jsonl is the run's store (written by the runner, not by write_outputs)
    refs = [r for r in page.refs if not r.startswith(("#", "data:")) and r != "records.jsonl"]
    refs += [p for kinds in data["assets"].values() for p in kinds.values()]
    assert refs
    for ref in refs:
        assert not ref.startswith(("http:", "https:", "//", "/")), ref
        assert (out / ref).is_file(), ref
    # no network assets at all
    for tag, attrs in page.tags:
        for key in ("src", "href"):
            assert not str(attrs.get(key) or "").startswith(("http", "//")), (tag, attrs)
    # summary numbers equal summary.json
    summary = json.loads((out / "summary.json").read_text())
    for v in ("PASS", "FAIL", "UNVERIFIABLE"):
        assert page.text_by_id[f"count-{v}"].strip() == str(summary["counts"][v])
    assert page.text_by_id["count-total"].strip() == str(len(records))
    return data


def shared_errors_summary(n_frames: int = 40, seed: int = 0) -> dict[str, Any]:
    """A ``summary["shared_errors"]`` as the run-level checks write it: registration passed,
    similarity inconclusive, drift failed with a per-frame curve, calibration per camera."""
    rng = np.random.default_rng(seed)
    effect = np.cumsum(rng.uniform(0.0, 1.0, n_frames))
    return {
        "registration": {
            "status": "passed", "message": "registration within 0.1 deg / 0.5 % of depth",
            "angle_deg": 0.04, "angle_deg_ci": [0.01, 0.09], "translation": 0.0021,
            "translation_rel_depth": 0.001, "effect_px": 0.8, "effect_px_ci": [0.3, 1.4],
        },
        "similarity": {"status": "inconclusive", "message": "too few frames for a scale",
                       "scale": 1.004, "scale_ci": [0.97, 1.03]},
        "drift": {
            "status": "failed", "message": "poses drift by 12 px over the trajectory",
            "effect_px": float(effect[-1]),
            "per_frame": [
                {"frame_id": f"frame-{i:06d}", "index": i, "effect_px": float(e),
                 "lo_px": float(e) * 0.7}
                for i, e in enumerate(effect)
            ],
        },
        "calibration": {
            "cam0": {"status": "finding", "message": "principal point off by (4.7, 0.6) px",
                     "effect_px": 4.7},
            "<b>cam1</b>": {"status": "not_checked", "message": "no frames"},
        },
    }


def with_verdict_columns(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Judged rows with the new per-frame columns of the lead's verdict work: ``evidence``,
    ``raw_verdict``, ``enhanced_verdict``, ``disagree`` and ``drift_px``."""
    out = []
    for i, r in enumerate(rows):
        r = dict(r)
        thr = r.get("threshold_px") or 16.0
        raw, enh = r.get("corner_error_px_raw"), r.get("corner_error_px_enhanced")
        r["raw_verdict"] = None if raw is None else ("FAIL" if raw > thr else "PASS")
        r["enhanced_verdict"] = None if enh is None else ("FAIL" if enh > thr else "PASS")
        r["disagree"] = bool(i % 5 == 1)  # given explicitly: wins over the computed one
        r["evidence"] = ("absolute", "relative", "relative+registration", "none")[i % 4]
        r["drift_px"] = 0.1 * i
        out.append(r)
    return out
