from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pgt_check.errors import InputError
from pgt_check.io import FORMATS, detect_format, read_trajectory

SAMPLES = {
    "trajectories.txt": ("# h\n0, cam0, 1, 0, 0, 0, 1, 2, 3\n", "lamar"),
    "gt.txt": ("# h\n1305031102.17 1 2 3 0 0 0 1\n", "tum"),
    "pgt.txt": ("seq-01/frame-000000.color.png 1 0 0 0 0 0 0 525\n", "pgt"),
    "transforms.json": (json.dumps({"frames": []}), "nerfstudio"),
    "results.txt": ("query/night/IMG_01.jpg 1 0 0 0 0.1 0.2 0.3\n", "hloc"),
}


@pytest.mark.parametrize("name", list(SAMPLES))
def test_detect_files(tmp_path: Path, name: str) -> None:
    content, expected = SAMPLES[name]
    (tmp_path / name).write_text(content)
    assert detect_format(tmp_path / name) == expected


def test_detect_directories(tmp_path: Path) -> None:
    colmap = tmp_path / "sparse"
    colmap.mkdir()
    (colmap / "cameras.txt").write_text("")
    (colmap / "images.txt").write_text("")
    assert detect_format(colmap) == "colmap"
    assert detect_format(colmap / "images.txt") == "colmap"
    (tmp_path / "lamar").mkdir()
    (tmp_path / "lamar" / "trajectories.txt").write_text("")
    assert detect_format(tmp_path / "lamar") == "lamar"
    (tmp_path / "ns").mkdir()
    (tmp_path / "ns" / "transforms.json").write_text("{}")
    assert detect_format(tmp_path / "ns") == "nerfstudio"


@pytest.mark.parametrize(
    "content",
    [
        "0 1 2 3\n",  # too few columns
        "0, cam0, 1, 0, 0\n",  # lamar-like but short
        "# only comments\n",
        "0 1 2 3 0 0 0 1\na.png 1 0 0 0 0 0 0 5\n",  # mixed rows
        "a.png 1 0 0 0 0 0 0 five\n",
    ],
)
def test_detect_unknown(tmp_path: Path, content: str) -> None:
    path = tmp_path / "mystery.txt"
    path.write_text(content)
    with pytest.raises(
        InputError, match=r"mystery.txt: cannot tell the format \(tried lamar.*tum.*pgt"
    ):
        detect_format(path)


def test_detect_other_failures(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        detect_format(tmp_path / "missing.txt")
    with pytest.raises(InputError, match="tried colmap"):
        detect_format(tmp_path)
    (tmp_path / "x.json").write_text('{"a": 1}')
    with pytest.raises(InputError, match="x.json.*tried nerfstudio"):
        detect_format(tmp_path / "x.json")


def test_read_trajectory_option_checks(tmp_path: Path) -> None:
    path = tmp_path / "trajectories.txt"
    path.write_text(SAMPLES["trajectories.txt"][0])
    with pytest.raises(InputError, match="unknown trajectory format 'kitti'"):
        read_trajectory(path, "kitti")
    with pytest.raises(InputError, match="--camera applies to TUM"):
        read_trajectory(path, camera="PINHOLE,64,48,50,50,32,24")
    gt = tmp_path / "gt.txt"
    gt.write_text(SAMPLES["gt.txt"][0])
    with pytest.raises(InputError, match="--sensors applies to LaMAR"):
        read_trajectory(gt, sensors=path)
    assert set(FORMATS) == {"lamar", "colmap", "tum", "pgt", "nerfstudio", "hloc"}


def test_import_is_light() -> None:
    """Importing pgt_check.io must not pull in OpenCV, Pillow or pycolmap."""
    code = "import sys, pgt_check.io; print(sorted(m for m in ('cv2', 'PIL', 'pycolmap', 'torch') if m in sys.modules))"
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[3],
    )
    assert out.stdout.strip() == "[]"


@pytest.mark.shared_data
@pytest.mark.parametrize(
    ("relative", "expected"),
    [
        ("7scenes_redkitchen/trajectories.txt", "lamar"),
        ("7scenes_redkitchen/trajectories_sfm.txt", "lamar"),
        ("7scenes_redkitchen/trajectory_tum.txt", "tum"),
        ("sceaux_castle/trajectories_colmap.txt", "lamar"),
    ],
)
def test_detect_real(shared_data: Path, relative: str, expected: str) -> None:
    assert detect_format(shared_data / relative) == expected
