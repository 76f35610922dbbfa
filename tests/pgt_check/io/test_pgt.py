from __future__ import annotations

import logging
from pathlib import Path

import pytest
from numpy.testing import assert_allclose

from pgt_check.errors import FormatError, InputError
from pgt_check.geometry.transforms import invert_rigid, rotmat_to_quat
from pgt_check.io import read_trajectory
from pgt_check.io.pgt import read_pgt
from pgt_check.types import Camera


def pgt_row(name: str, cam_from_world, f: float = 525.0) -> str:
    q = rotmat_to_quat(cam_from_world[:3, :3])
    t = cam_from_world[:3, 3]
    return " ".join([name, *(repr(float(v)) for v in (*q, *t)), repr(f)])


def test_read(tmp_path: Path, random_rigid, make_image) -> None:
    poses = [random_rigid() for _ in range(3)]
    names = [f"seq-01/frame-{i:06d}.color.png" for i in range(3)]
    for name in names:
        make_image(tmp_path / name, 64, 48)
    path = tmp_path / "pgt.txt"
    path.write_text(
        "\n".join(
            pgt_row(n, p, 500.0 + i) for i, (n, p) in enumerate(zip(names, poses, strict=True))
        )
        + "\n"
    )
    traj = read_trajectory(path)
    assert traj.format == "pgt"
    assert [f.frame_id for f in traj] == names
    for i, (frame, cam_from_world) in enumerate(zip(traj, poses, strict=True)):
        # the file stores cam_from_world: the reader inverts it
        assert_allclose(frame.world_from_cam, invert_rigid(cam_from_world), atol=1e-12)
        assert frame.image_file == tmp_path / names[i]
        # principal point at the image centre: COLMAP (32, 24) -> OpenCV (31.5, 23.5)
        assert frame.camera == Camera("SIMPLE_PINHOLE", 64, 48, (500.0 + i, 31.5, 23.5))


def test_images_option_and_missing_images(tmp_path: Path, random_rigid, make_image, caplog) -> None:
    make_image(tmp_path / "imgs" / "a.png", 40, 30)
    path = tmp_path / "poses" / "pgt.txt"
    path.parent.mkdir()
    path.write_text(
        pgt_row("a.png", random_rigid()) + "\n" + pgt_row("b.png", random_rigid()) + "\n"
    )
    with caplog.at_level(logging.WARNING, logger="pgt_check.io.pgt"):
        traj = read_pgt(path, images=tmp_path / "imgs")
    # b.png is missing: kept with the size all found images share, reported once
    assert [(f.frame_id, f.camera.width, f.camera.height) for f in traj] == [
        ("a.png", 40, 30),
        ("b.png", 40, 30),
    ]
    assert any("1 image(s) not found" in r.getMessage() for r in caplog.records)
    with pytest.raises(InputError, match="none of its 2 images found"):
        read_pgt(path)


def test_missing_images_with_differing_sizes_are_kept(
    tmp_path: Path, random_rigid, make_image
) -> None:
    # issue #25: a pose is never dropped; its frame is UNVERIFIABLE image_missing downstream
    make_image(tmp_path / "a.png", 40, 30)
    make_image(tmp_path / "b.png", 20, 10)
    make_image(tmp_path / "d.png", 20, 10)
    path = tmp_path / "pgt.txt"
    path.write_text(
        "\n".join(pgt_row(n, random_rigid()) for n in ("a.png", "b.png", "c.png", "d.png"))
        + "\n"
    )
    frames = read_pgt(path).by_id()
    assert list(frames) == ["a.png", "b.png", "c.png", "d.png"]
    assert (frames["c.png"].camera.width, frames["c.png"].camera.height) == (20, 10)


BAD = {
    "columns": ("a.png 1 0 0 0 0 0 0\n", 1, "expected 9 fields"),
    "number": ("# c\na.png 1 0 0 0 0 zero 0 525\n", 2, "expected a number for ty"),
    "quaternion": ("a.png 0.5 0 0 0 0 0 0 525\n", 1, "unit quaternion"),
    "focal": ("a.png 1 0 0 0 0 0 0 -5\n", 1, "positive focal length"),
    "duplicate": ("a.png 1 0 0 0 0 0 0 5\n\na.png 1 0 0 0 0 0 0 5\n", 3, "unique image names"),
    "empty": ("", 1, "at least one data row"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_malformed(tmp_path: Path, case: str, check_error, make_image) -> None:
    content, line, fragment = BAD[case]
    make_image(tmp_path / "a.png")
    path = tmp_path / "pgt.txt"
    path.write_text(content)
    with pytest.raises(FormatError) as info:
        read_pgt(path)
    check_error(info.value, path, line, fragment)
