"""Second audit (#25), memory and files, trusted summaries and readers: special files are
refused, every read is bounded before it starts, ``--calibration-from`` is validated before any
frame is measured, and the readers turn malformed files into one-line input errors."""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest

from pgt_check.errors import InputError


def _error_line(rc: int, err: str) -> str:
    assert "Traceback" not in err
    return err.strip().splitlines()[-1] if err.strip() else ""


# -- memory and files ------------------------------------------------------------------------


def test_oversized_sparse_image_is_unverifiable_not_read(scene, tmp_path, cli, base_args, case):
    """A sparse 'image' far beyond the byte bound of the pixel cap is refused before reading:
    its frame is UNVERIFIABLE pixel_cap_exceeded (not internal_error), the run goes on."""
    big = scene / "images" / "frame-000001.jpg"
    with open(big, "r+b") as fh:
        fh.truncate(100 * 1024**2)  # sparse: no disk, 100 MB declared
    rc, _, err = cli(*base_args("--max-image-pixels", "100000"))
    rows = {r["frame_id"]: r for r in csv.DictReader(open(tmp_path / "out" / "frames.csv"))}
    row = rows["1/cam0"] if "1/cam0" in rows else list(rows.values())[1]
    case("100 MB sparse image, cap 100 kpx", "UNVERIFIABLE pixel_cap_exceeded",
         f"{rc}: {row['verdict']} {row['reason']}")
    assert "Traceback" not in err
    assert row["verdict"] == "UNVERIFIABLE" and row["reason"] == "pixel_cap_exceeded"


def test_load_image_refuses_before_reading(tmp_path, monkeypatch):
    from pgt_check.errors import PixelCapError
    from pgt_check.io import images

    p = tmp_path / "big.png"
    with open(p, "wb") as fh:
        fh.truncate(3 * 1024**2)
    monkeypatch.setattr(images, "MAX_METADATA_BYTES", 0)
    monkeypatch.setattr(np, "fromfile", lambda *a, **k: pytest.fail("read whole"))
    with pytest.raises(PixelCapError, match="larger than"):
        images.load_image(p, max_pixels=1000)


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_calibration_from_special_file_exits_2(special, tmp_path, cli, base_args, case):
    if special == "fifo":
        special = str(tmp_path / "fifo")
        os.mkfifo(special)
    rc, _, err = cli(*base_args("--calibration-from", special))
    line = _error_line(rc, err)
    case(f"--calibration-from {os.path.basename(special)}", "2, not a regular file",
         f"{rc}: {line[:140]}")
    assert rc == 2 and "regular file" in line
    assert not (tmp_path / "out" / "records.jsonl").exists()  # refused before measuring


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_special_files_refused_by_every_loader(special, tmp_path):
    from pgt_check.config import load_config_file
    from pgt_check.io import read_trajectory
    from pgt_check.verdict.calibration import load_trusted_calibrations

    if special == "fifo":
        special = str(tmp_path / "fifo.json")
        os.mkfifo(special)
    for load in (load_config_file, load_trusted_calibrations,
                 lambda p: read_trajectory(p, "tum", camera="PINHOLE,64,48,50,50,32,24"),
                 lambda p: read_trajectory(p, "nerfstudio")):
        with pytest.raises(InputError):
            load(special)


def test_reads_are_bounded(tmp_path, monkeypatch):
    """A file above the bound is refused from its size (never read)."""
    from pgt_check.common import files
    from pgt_check.config import load_config_file

    p = tmp_path / "c.json"
    p.write_text("{}" + " " * 5000)
    monkeypatch.setattr(files, "MAX_SMALL_JSON_BYTES", 1000)
    from pgt_check.config import load as config_load

    monkeypatch.setattr(config_load, "MAX_SMALL_JSON_BYTES", 1000)
    with pytest.raises(InputError, match="read at most"):
        load_config_file(p)


# -- --calibration-from, validated up front ---------------------------------------------------

_GOOD = {"rotation": np.eye(3).tolist(), "focal_scale": 1.0, "translation": [0, 0, 0]}


@pytest.mark.parametrize("name,summary", [
    ("string table", {"shared_errors": {"calibration": "oops"}}),
    ("string entry", {"shared_errors": {"calibration": {"cam": "oops"}}}),
    ("2x2 rotation", {"shared_errors": {"calibration": {"cam": {**_GOOD,
                                                                 "rotation": [[1, 0], [0, 1]]}}}}),
    ("string focal", {"shared_errors": {"calibration": {"cam": {**_GOOD, "focal_scale": "1"}}}}),
    ("NaN focal", {"shared_errors": {"calibration": {"cam": {**_GOOD,
                                                             "focal_scale": float("nan")}}}}),
    ("NaN rotation", {"shared_errors": {"calibration": {"cam": {
        **_GOOD, "rotation": [[float("nan")] * 3] * 3}}}}),
    ("not a rotation", {"shared_errors": {"calibration": {"cam": {
        **_GOOD, "rotation": (2 * np.eye(3)).tolist()}}}}),
    ("no estimate", {"shared_errors": {"calibration": {"cam": {"status": "not_checked"}}}}),
    ("a list", [1, 2]),
])
def test_malformed_trusted_summary_exits_2_before_measuring(name, summary, tmp_path, cli,
                                                            base_args, case):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(summary))
    rc, _, err = cli(*base_args("--calibration-from", str(path)))
    line = _error_line(rc, err)
    case(f"--calibration-from: {name}", "2 before measuring", f"{rc}: {line[:140]}")
    assert rc == 2 and line.startswith("pgt-check: error: ") and str(path) in line
    assert err.count("\n") == 1
    assert not (tmp_path / "out" / "records.jsonl").exists()


def test_calibration_from_missing_file_exits_2_before_measuring(tmp_path, cli, base_args,
                                                                case):
    rc, _, err = cli(*base_args("--calibration-from", str(tmp_path / "typo.json")))
    line = _error_line(rc, err)
    case("--calibration-from typo.json (missing)", "2 before any frame is measured",
         f"{rc}: {line.replace(str(tmp_path), '<tmp>')[-90:]}; records.jsonl "
         f"{'written' if (tmp_path / 'out' / 'records.jsonl').exists() else 'not written'}")
    assert rc == 2 and "not found" in line
    assert not (tmp_path / "out" / "records.jsonl").exists()


def test_calibration_from_wrong_camera_exits_2_before_measuring(tmp_path, cli, base_args):
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"shared_errors": {"calibration": {"a": _GOOD, "b": _GOOD}}}))
    rc, _, err = cli(*base_args("--calibration-from", str(path)))
    assert rc == 2 and "no calibration estimate for camera" in _error_line(rc, err)
    assert not (tmp_path / "out" / "records.jsonl").exists()


# -- readers -----------------------------------------------------------------------------------


def _colmap(tmp_path, images_txt: str):
    d = tmp_path / "model"
    d.mkdir()
    (d / "cameras.txt").write_text("1 PINHOLE 64 48 50 50 32 24\n")
    (d / "images.txt").write_text(images_txt)
    (d / "points3D.txt").write_text("")
    return d


@pytest.mark.parametrize("name,images_txt,match", [
    ("missing camera id", "1 1 0 0 0 0 0 0 7 a.png\n\n", "camera"),
    ("zero quaternion", "1 0 0 0 0 0 0 0 1 a.png\n\n", "unit quaternion"),
    ("quaternion norm 2", "1 2 0 0 0 0 0 0 1 a.png\n\n", "unit quaternion"),
])
def test_colmap_malformed_images(name, images_txt, match, tmp_path, case):
    from pgt_check.io import read_trajectory

    d = _colmap(tmp_path, images_txt)
    with pytest.raises(InputError, match=match) as info:
        read_trajectory(d)
    case(f"COLMAP: {name}", "InputError", str(info.value)[:140])


def test_colmap_slightly_off_quaternion_is_normalised(tmp_path):
    from pgt_check.io import read_trajectory

    d = _colmap(tmp_path, "1 1.00001 0 0 0 0 0 0 1 a.png\n\n")
    traj = read_trajectory(d)
    r = traj.frames[0].world_from_cam[:3, :3]
    assert np.allclose(r @ r.T, np.eye(3))


def _transforms(tmp_path, data) -> str:
    p = tmp_path / "transforms.json"
    p.write_text(data if isinstance(data, str) else json.dumps(data))
    return str(p)


_FRAME = {"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}


@pytest.mark.parametrize("angle", [0, -0.1, 3.2, 1e-320])
def test_nerfstudio_bad_camera_angle(angle, tmp_path, case):
    from pgt_check.io import read_trajectory

    p = _transforms(tmp_path, {"w": 64, "h": 48, "camera_angle_x": angle, "frames": [_FRAME]})
    with pytest.raises(InputError, match="camera") as info:
        read_trajectory(p)
    case(f"nerfstudio camera_angle_x: {angle}", "InputError (CLI: 2)",
         f"{type(info.value).__name__}: "
         f"{str(info.value).replace(str(tmp_path), '<tmp>')[-110:]}")


def test_nerfstudio_deep_json(tmp_path, case):
    from pgt_check.io import read_trajectory

    p = _transforms(tmp_path, "[" * 100000 + "]" * 100000)
    with pytest.raises(InputError, match="nested too deeply") as info:
        read_trajectory(p, "nerfstudio")
    case("nerfstudio transforms.json nested 100,000 deep", "InputError (CLI: 2)",
         f"{type(info.value).__name__}: "
         f"{str(info.value).replace(str(tmp_path), '<tmp>')[-90:]}")
    with pytest.raises(InputError):
        read_trajectory(p)  # format detection reads it too


def test_json_with_bom_is_accepted(tmp_path, case):
    """Text formats accept a UTF-8 BOM; JSON (transforms, configs, summaries) does too."""
    from pgt_check.config import load_config_file
    from pgt_check.io import read_trajectory
    from pgt_check.verdict.calibration import load_trusted_calibrations

    data = {"w": 64, "h": 48, "fl_x": 50, "frames": [_FRAME]}
    p = tmp_path / "transforms.json"
    p.write_bytes(b"\xef\xbb\xbf" + json.dumps(data).encode())
    assert len(read_trajectory(p)) == 1
    c = tmp_path / "c.json"
    c.write_bytes(b"\xef\xbb\xbf" + b'{"limit": 1}')
    assert load_config_file(c) == {"limit": 1}
    s = tmp_path / "s.json"
    s.write_bytes(b"\xef\xbb\xbf" + json.dumps(
        {"shared_errors": {"calibration": {"cam": _GOOD}}}).encode())
    assert set(load_trusted_calibrations(str(s))) == {"cam"}
    case("UTF-8 BOM in transforms.json, a config file, a trusted summary", "accepted",
         "all three read (1 frame, {'limit': 1}, camera 'cam')")


def test_deep_config_is_an_input_error(tmp_path, cli, base_args):
    c = tmp_path / "c.json"
    c.write_text("[" * 100000 + "]" * 100000)
    rc, _, err = cli(*base_args("--config", str(c)))
    assert rc == 2 and "nested too deeply" in _error_line(rc, err)


def test_colmap_image_name_not_utf8(tmp_path):
    from pgt_check.io import read_trajectory

    d = _colmap(tmp_path, "x")
    (d / "images.txt").write_bytes(b"1 1 0 0 0 0 0 0 1 \x80a.png\n\n")
    with pytest.raises(InputError, match="UTF-8"):
        read_trajectory(d)
