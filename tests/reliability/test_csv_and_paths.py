"""Class 8: frames.csv cells that a spreadsheet would run as formulas are neutralised (text
only; numbers stay numbers), and image paths outside the dataset folder are recorded and shown
in the report (read, not refused)."""

from __future__ import annotations

import csv
import json
import shutil

from pgt_check.report.outputs import _csv_value


def test_formula_cells_neutralised(scene, cli, base_args, tmp_path, case):
    images = scene / "images.txt"
    lines = images.read_text().splitlines()
    old = lines[1].split(",")[2].strip()
    shutil.copy(scene / old, scene / "=HYPERLINK(x).jpg")  # a file name starting with '='
    lines[1] = lines[1].replace(old, "=HYPERLINK(x).jpg")
    images.write_text("\n".join(lines) + "\n")
    rc, _, _ = cli(*base_args())
    assert rc == 0
    rows = list(csv.DictReader((tmp_path / "out" / "frames.csv").open()))
    case("image file '=HYPERLINK(x).jpg' in frames.csv", "cell '=HYPERLINK(x).jpg",
         f"{rc}: cell {rows[0]['image_path']!r}")
    assert rows[0]["image_path"] == "'=HYPERLINK(x).jpg"
    assert _csv_value("=HYPERLINK(1)") == "'=HYPERLINK(1)"
    assert _csv_value("@SUM(A1)") == "'@SUM(A1)" and _csv_value("+1") == "'+1"
    assert _csv_value("\tx") == "'\tx" and _csv_value("-x") == "'-x"
    assert _csv_value(-3.5) == "-3.5" and _csv_value(-2) == -2  # numbers stay numbers
    case("text cell '=HYPERLINK(1)' / number -3.5 in frames.csv", "'=HYPERLINK(1) / -3.5",
         f"{_csv_value('=HYPERLINK(1)')} / {_csv_value(-3.5)}")


def test_frame_id_formula_in_csv(scene, cli, base_args, tmp_path, case):
    # LaMAR frame ids come from "timestamp/sensor"; a sensor id starting with '=' reaches the id
    for name in ("trajectories.txt", "images.txt", "sensors.txt"):
        p = scene / name
        p.write_text(p.read_text().replace("cam0", "=cam0"))
    rc, _, _ = cli(*base_args())
    text = (tmp_path / "out" / "frames.csv").read_text()
    rows = list(csv.DictReader(text.splitlines()))
    case("sensor id '=cam0' (frame ids start with '=')", "cells start with '",
         f"{rc}: frame_id cell {rows[0]['frame_id']!r}")
    assert all(not r["frame_id"].startswith("=") for r in rows)


def test_images_outside_dataset_recorded_and_shown(scene, cli, base_args, tmp_path, case):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    images = scene / "images.txt"
    lines = images.read_text().splitlines()
    old = lines[1].split(",")[2].strip()
    shutil.copy(scene / old, elsewhere / "f0.jpg")
    lines[1] = lines[1].replace(old, "../elsewhere/f0.jpg")
    images.write_text("\n".join(lines) + "\n")
    rc, _, _ = cli(*base_args())
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    html = (tmp_path / "out" / "report.html").read_text()
    case("image path ../elsewhere/f0.jpg", "read (not refused), listed + report warning",
         f"{rc}: {summary.get('images_outside_dataset')}")
    assert rc == 0  # read, not refused
    assert summary["images_outside_dataset"] == {"count": 1, "examples": ["../elsewhere/f0.jpg"]}
    assert "outside the dataset folder" in html
