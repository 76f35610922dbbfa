from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from report_testdata import (
    HOSTILE_NAME,
    SCRIPT_BREAKER,
    check_report,
    judged,
    parse_report,
    synthetic_measurements,
)

from pgt_check.commands.report import main as report_main
from pgt_check.config import RunConfig
from pgt_check.measure import FrameImages
from pgt_check.report.assets import select_detail_frames, write_frame_assets
from pgt_check.report.html import (
    build_report,
    display_path,
    redact_text,
    script_json,
    table_value,
)
from pgt_check.report.outputs import build_summary, write_outputs


def _images(seed: int) -> FrameImages:
    rng = np.random.default_rng(seed)
    photo = rng.uniform(0, 1, (240, 320, 3)).astype(np.float32)
    k = rng.uniform(0, [320, 240], (80, 2))
    return FrameImages(
        photo=photo,
        render=photo[:, ::-1].copy(),
        kpts_render=k,
        kpts_photo=k + 2,
        inliers=rng.uniform(size=80) < 0.5,
    )


def make_run(out: Path, config: RunConfig, records: list[dict], with_assets: bool = True) -> dict:
    assets = None
    if with_assets:
        by_id = {r["frame_id"]: r for r in records}
        assets = {
            fid: write_frame_assets(out, by_id[fid], _images(i))
            for i, fid in enumerate(select_detail_frames(records, n_worst=5, max_details=25))
        }
    return write_outputs(out, records, config, assets=assets)


def test_report_for_sample_data(tmp_path, config, records):
    make_run(tmp_path, config, records)
    data = check_report(tmp_path, records)
    assert data["inspect"] == [str(f) for f in select_detail_frames(records)]
    assert set(data["assets"]) <= set(data["inspect"])
    assert list(data["assets"]) == select_detail_frames(records, n_worst=5, max_details=25)
    assert (tmp_path / "junit.xml").is_file()
    assert (tmp_path / "assets" / "index.json").is_file()
    for name in ("error_hist", "error_time", "top_view"):
        assert (tmp_path / "assets" / f"plot_{name}.svg").is_file()
    assert not (tmp_path / "assets" / "plot_raw_vs_enhanced.svg").exists()
    assert "corner_error_px_raw" not in [c["key"] for c in data["columns"]]


def test_hostile_names_show_as_text(tmp_path, config, records):
    make_run(tmp_path, config, records)
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    # never raw markup: not in the table data, not in static HTML
    assert "<img src=x" not in html
    assert "onerror=alert(1)>" not in html
    assert "alert(2)</script>" not in html
    assert html.count("</script>") == 2  # the data block and the code block, nothing else
    assert html.count("<!--") == 0
    _, data = parse_report(tmp_path / "report.html")
    ids = [row[0] for row in data["rows"]]
    assert HOSTILE_NAME in ids and "x" + SCRIPT_BREAKER in ids
    paths = [row[2] for row in data["rows"]]
    assert HOSTILE_NAME in paths


def test_hostile_trajectory_name_is_escaped(tmp_path):
    config = RunConfig.from_dict({"input": {"trajectory": f"runs/{HOSTILE_NAME}", "mesh": "m.ply"}})
    recs = judged(synthetic_measurements(8), config)
    write_outputs(tmp_path, recs, config)
    html = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "<img src=x" not in html
    assert "&lt;img src=x onerror=alert(1)&gt;.jpg" in html


def test_script_json_neutralises_script_end_and_comments():
    text = script_json({"a": SCRIPT_BREAKER, "b": "x & y \u2028", "c": [1.5, None]})
    assert "</script" not in text.lower() and "<!--" not in text and "<" not in text
    assert "\u2028" not in text
    assert json.loads(text) == {"a": SCRIPT_BREAKER, "b": "x & y \u2028", "c": [1.5, None]}
    with pytest.raises(ValueError):
        script_json({"x": math.nan})


def test_table_value_matches_csv_rounding():
    assert table_value(1.23456789, "num") == 1.23457
    assert table_value(math.inf, "num") is None
    assert table_value(None, "str") is None
    assert table_value(3, "int") == 3
    assert table_value(1, "bool") is True
    assert table_value("abc", "num") is None


@pytest.mark.parametrize(
    ("path", "shown"),
    [
        ("images/a.jpg", "images/a.jpg"),
        ("/home/alice/secret/data/a.jpg", "…/data/a.jpg"),
        ("C:\\Users\\alice\\data\\a.jpg", "…/data/a.jpg"),
        ("/a.jpg", "…/a.jpg"),
        ("", ""),
    ],
)
def test_display_path(path, shown):
    assert display_path(path) == shown
    assert display_path(path, absolute_paths=True) == path


def test_redact_text_keeps_relative_paths():
    text = 'File "/home/alice/secret/x/runner.py", line 3; images/a.jpg; 1/2; http://h/p'
    out = redact_text(text)
    assert "/home/alice" not in out and "…/x/runner.py" in out
    assert "images/a.jpg" in out and "1/2" in out and "http://h/p" in out
    assert redact_text(text, absolute_paths=True) == text


def test_no_absolute_paths_unless_asked(tmp_path, config, records):
    make_run(tmp_path, config, records)
    for name in ("report.html", "junit.xml", "assets/index.json"):
        text = (tmp_path / name).read_text(encoding="utf-8")
        assert "/home/alice" not in text, name
        assert str(tmp_path) not in text, name
    data = parse_report(tmp_path / "report.html")[1]
    assert "…/data/frame-000004.color.jpg" in [row[2] for row in data["rows"]]
    # internal_error traceback is shown, redacted
    details = [e["error_detail"] for e in data["extra"].values()]
    assert any("…/pgt_check/runner.py" in d for d in details)

    abs_config = RunConfig.from_dict({**config.to_dict(), "absolute_paths": True})
    write_outputs(tmp_path, records, abs_config)
    text = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert "/home/alice/secret/data/frame-000004.color.jpg" in text


def test_enhanced_columns_and_plot_when_present(tmp_path, config):
    recs = judged(synthetic_measurements(40, enhanced=True), config)
    make_run(tmp_path, config, recs, with_assets=False)
    data = check_report(tmp_path, recs)
    keys = [c["key"] for c in data["columns"]]
    for k in ("enhanced", "corner_error_px_raw", "corner_error_px_enhanced", "reference_id"):
        assert k in keys
    assert (tmp_path / "assets" / "plot_raw_vs_enhanced.svg").is_file()
    # a later run without the enhanced path must not keep the stale plot
    recs2 = judged(synthetic_measurements(40), config)
    make_run(tmp_path, config, recs2, with_assets=False)
    assert not (tmp_path / "assets" / "plot_raw_vs_enhanced.svg").exists()
    page, _ = parse_report(tmp_path / "report.html")
    assert "assets/plot_raw_vs_enhanced.svg" not in page.refs


def _store(out: Path, config: RunConfig, flat: list[dict]) -> None:
    """records.jsonl + run.json as a run writes them (``pgt-check report`` reads them)."""
    from report_testdata import from_flat

    from pgt_check.runner import measurement_fingerprint
    from pgt_check.store import RecordStore

    ms = [from_flat(r) for r in flat]
    with RecordStore.open(out, measurement_fingerprint(config),
                          settings=config.measurement_settings(),
                          frame_ids=[m.frame_id for m in ms]) as store:
        for m in ms:
            store.append(m.to_json())


def test_report_cli_regenerates_from_records_and_keeps_assets(tmp_path, config, records, capsys):
    _store(tmp_path, config, synthetic_measurements())
    make_run(tmp_path, config, records)
    before = parse_report(tmp_path / "report.html")[1]
    (tmp_path / "report.html").unlink()
    (tmp_path / "junit.xml").unlink()
    # the synthetic run has one internal_error frame, which the gate counts unless allowed
    rc = report_main([str(tmp_path), "--threshold-px", "1000", "--max-internal-errors", "1"])
    assert rc == 0  # nothing FAILs at 1000 px: gate passes
    assert "0 FAIL" in capsys.readouterr().out
    data = check_report(tmp_path, records)
    assert data["assets"] == before["assets"]
    assert "FAIL" not in [row[3] for row in data["rows"]]
    assert (tmp_path / "junit.xml").is_file()


def test_build_report_empty_run(tmp_path):
    config = RunConfig()
    summary = build_summary([], config)
    build_report(tmp_path, [], summary)
    _, data = parse_report(tmp_path / "report.html")
    assert data["rows"] == []


def test_build_report_ignores_assets_of_unknown_frames(tmp_path, config, records):
    summary = build_summary(records, config)
    paths = write_frame_assets(tmp_path, {"frame_id": "not-a-frame"}, _images(0))
    build_report(
        tmp_path, records, summary, {"not-a-frame": paths, "frame-000005": {"photo": "nope"}}
    )
    _, data = parse_report(tmp_path / "report.html")
    assert data["assets"] == {}


@pytest.mark.slow
def test_5000_frames_stay_small(tmp_path, config):
    recs = judged(synthetic_measurements(5000, seed=3, hostile=False), config)
    make_run(tmp_path, config, recs, with_assets=False)
    html = (tmp_path / "report.html").read_bytes()
    assert len(html) < 3_000_000  # table as compact JSON, no per-frame markup
    # rows are built by the script, one page at a time (the fixed tables: summary, run-level
    # checks, accuracy, settings, timing)
    assert html.count(b"<tr") < 130
    check_report(tmp_path, recs)


def test_report_modules_import_lazily():
    import subprocess
    import sys

    code = (
        "import sys, pgt_check.report.html, pgt_check.report.plots, pgt_check.report.junit, "
        "pgt_check.report.outputs; "
        "print(sorted(m for m in ('matplotlib', 'jinja2', 'cv2') if m in sys.modules))"
    )
    import os

    repo = str(Path(__file__).resolve().parents[3])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([repo, os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.strip() == "[]"


def test_shared_error_rows_name_the_new_checks_in_order():
    """The report's run-level section: known checks first with their titles, per-camera checks
    one row per camera (calibration change), the informational mesh-colours check last among
    the known ones; numbers with their intervals."""
    from pgt_check.report.tables import shared_error_rows

    entry = {"status": "finding", "effect_px": 6.5, "effect_px_ci": [5.9, 7.0], "message": "m"}
    summary = {"shared_errors": {
        "texture": entry,
        "calibration_change": {"cam0": {"status": "failed", "effect_px": 6.4, "message": "c"}},
        "registration": {"status": "passed", "effect_px": 0.8, "message": "r"},
    }}  # fmt: skip
    rows = shared_error_rows(summary)
    assert [r["name"] for r in rows] == [
        "registration",
        "calibration change since the trusted run (camera cam0)",
        "mesh colours vs geometry",
    ]
    assert rows[1]["status_class"] == "failed"
    assert rows[2]["numbers"] == [("effect [px]", "6.50 [5.90, 7.00]")]
