"""Builders for the stability suite: procedural meshes, render-as-photo frames, clean checks.

Every case measures frames with the runner's stage 1 (``FrameChecker.measure``) and judges them
with stage 2 (``apply_verdicts``), exactly as ``pgt-check`` does, and then asserts that the
record is *clean*: no ``internal_error`` (an exception that the runner had to swallow) and no
NaN / inf in any float field that goes to frames.csv (None is the documented "not measured").
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.geometry.transforms import make_rigid
from pgt_check.measure import FrameChecker
from pgt_check.render import MeshData, make_renderer, mesh_from_trimesh
from pgt_check.types import Camera, Frame
from pgt_check.verdict import apply_verdicts

#: small working camera used by most cases (fast on two busy cores)
CAM = Camera.pinhole(240, 180, 200.0, 200.0, 119.5, 89.5)


def look_at(eye: Sequence[float], target: Sequence[float], up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """world_from_cam (OpenCV axes) for a camera at ``eye`` looking at ``target``."""
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking along up: any perpendicular will do
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_rigid(np.stack([x, y, z], axis=1), eye)


def noise_texture(seed: int, size: int = 256, cells: int = 24) -> np.ndarray:
    """(size, size, 3) uint8 blobby colour noise with sharp detail: SIFT finds plenty in it."""
    import cv2

    rng = np.random.default_rng(seed)
    coarse = rng.uniform(0, 255, (cells, cells, 3)).astype(np.float32)
    img = cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
    fine = rng.uniform(-60, 60, (size // 4, size // 4, 3)).astype(np.float32)
    img = img + cv2.resize(fine, (size, size), interpolation=cv2.INTER_NEAREST)
    return np.clip(img, 0, 255).astype(np.uint8)


def checker_texture(size: int = 256, squares: int = 8) -> np.ndarray:
    """A perfectly periodic black/white checker (repetitive: every corner looks the same)."""
    k = size // squares
    board = (np.indices((squares, squares)).sum(axis=0) % 2).astype(np.uint8) * 255
    img = np.kron(board, np.ones((k, k), dtype=np.uint8))
    return np.repeat(img[:, :, None], 3, axis=2)


def _quad(corners: np.ndarray, image: np.ndarray | None, colour=(180, 180, 180)):
    """A trimesh quad (corners tl, tr, br, bl seen from the front), textured or plain."""
    import trimesh
    from PIL import Image

    faces = [[0, 1, 2], [0, 2, 3]]
    if image is None:
        tm = trimesh.Trimesh(np.asarray(corners, float), faces, process=False)
        tm.visual.vertex_colors = np.array([[*colour, 255]] * 4, dtype=np.uint8)
        return tm
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=float)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.fromarray(image))
    return trimesh.Trimesh(
        np.asarray(corners, float),
        faces,
        process=False,
        visual=trimesh.visual.TextureVisuals(uv=uv, material=material),
    )


def plane_mesh(image: np.ndarray | None, half: float = 2.0, z: float = 0.0) -> MeshData:
    """A 2*half square in the plane z (world), textured with ``image`` (None: plain grey)."""
    c = np.array([[-half, half, z], [half, half, z], [half, -half, z], [-half, -half, z]])
    return mesh_from_trimesh(_quad(c, image))


def box_room_mesh(
    size: float = 4.0, textured: bool = True, seed: int = 0, texture: np.ndarray | None = None
) -> MeshData:
    """The six inner faces of a size^3 room centred at the origin (z up), one texture each."""
    import trimesh

    h = size / 2
    p = {
        (sx, sy, sz): np.array([sx * h, sy * h, sz * h])
        for sx in (-1, 1)
        for sy in (-1, 1)
        for sz in (-1, 1)
    }
    walls = [  # tl, tr, br, bl as seen from inside
        [p[-1, 1, 1], p[1, 1, 1], p[1, 1, -1], p[-1, 1, -1]],  # +y wall
        [p[1, -1, 1], p[-1, -1, 1], p[-1, -1, -1], p[1, -1, -1]],  # -y wall
        [p[1, 1, 1], p[1, -1, 1], p[1, -1, -1], p[1, 1, -1]],  # +x wall
        [p[-1, -1, 1], p[-1, 1, 1], p[-1, 1, -1], p[-1, -1, -1]],  # -x wall
        [p[-1, -1, -1], p[-1, 1, -1], p[1, 1, -1], p[1, -1, -1]],  # floor
        [p[-1, 1, 1], p[-1, -1, 1], p[1, -1, 1], p[1, 1, 1]],  # ceiling
    ]
    parts = []
    for i, w in enumerate(walls):
        if not textured:
            parts.append(_quad(np.array(w), None))
        else:
            parts.append(
                _quad(np.array(w), noise_texture(seed + i) if texture is None else texture)
            )
    return mesh_from_trimesh(trimesh.Scene(parts))


def box_mesh(centre, size: float, textured: bool = True, seed: int = 0) -> list:
    """Outer faces of a cube (trimesh parts), for strongly 3-D scenes."""
    c = np.asarray(centre, dtype=float)
    h = size / 2
    corners = {
        (sx, sy, sz): c + [sx * h, sy * h, sz * h]
        for sx in (-1, 1)
        for sy in (-1, 1)
        for sz in (-1, 1)
    }
    q = corners
    faces = [
        [q[-1, -1, 1], q[1, -1, 1], q[1, -1, -1], q[-1, -1, -1]],  # -y face
        [q[1, -1, 1], q[1, 1, 1], q[1, 1, -1], q[1, -1, -1]],  # +x face
        [q[1, 1, 1], q[-1, 1, 1], q[-1, 1, -1], q[1, 1, -1]],  # +y face
        [q[-1, 1, 1], q[-1, -1, 1], q[-1, -1, -1], q[-1, 1, -1]],  # -x face
        [q[-1, 1, 1], q[1, 1, 1], q[1, -1, 1], q[-1, -1, 1]],  # top
    ]
    return [
        _quad(np.array(f), noise_texture(seed + i) if textured else None)
        for i, f in enumerate(faces)
    ]


def write_photo(path: Path, rgb: np.ndarray, grayscale: bool = False) -> Path:
    """Write a float RGB [0, 1] image as PNG (8-bit; single channel if ``grayscale``)."""
    import cv2

    img = (np.clip(rgb, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
    if grayscale:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), img)
    return path


def degrade(
    rgb: np.ndarray, gain: float = 1.0, gamma: float = 1.0, noise: float = 0.0, seed: int = 0
) -> np.ndarray:
    """Exposure (gain), gamma and Gaussian noise applied to a render, clipped to [0, 1]."""
    rng = np.random.default_rng(seed)
    img = np.clip(rgb * gain, 0.0, 1.0) ** gamma
    if noise:
        img = img + rng.normal(0.0, noise, img.shape)
    return np.clip(img, 0.0, 1.0).astype(np.float32)


class Scene:
    """A mesh plus a renderer for making "photos" and checking frames against it."""

    def __init__(self, mesh: MeshData, tmp_path: Path) -> None:
        self.mesh = mesh
        self.tmp_path = tmp_path
        self.renderer = make_renderer(mesh)
        self._n = 0

    def render(self, camera: Camera, world_from_cam: np.ndarray):
        return self.renderer.render(camera, world_from_cam)

    def frame(
        self,
        camera: Camera,
        true_pose: np.ndarray,
        stored_pose: np.ndarray | None = None,
        photo: Callable[[np.ndarray], np.ndarray] | None = None,
        grayscale: bool = False,
        frame_id: str | None = None,
    ) -> Frame:
        """A frame whose photo is the render at ``true_pose`` (optionally transformed by
        ``photo``) and whose stored pose is ``stored_pose`` (default: the true one)."""
        rgb = self.render(camera, true_pose).rgb
        if photo is not None:
            rgb = photo(rgb)
        self._n += 1
        fid = frame_id or f"f{self._n:03d}"
        path = write_photo(self.tmp_path / "photos" / f"{fid}.png", rgb, grayscale)
        pose = true_pose if stored_pose is None else stored_pose
        return Frame(fid, camera, pose, image_path=path.name, image_file=path)

    def check(self, frames: Sequence[Frame], **config: Any) -> list[dict[str, Any]]:
        """Stage 1 + 2 on ``frames``; every record is asserted clean."""
        return check_with_mesh(self.mesh, frames, **config)

    def close(self) -> None:
        self.renderer.close()


def check_with_mesh(mesh: MeshData, frames: Sequence[Frame], **config: Any) -> list[dict]:
    config.setdefault("pose", {"enabled": False})
    cfg = RunConfig.from_dict({"input": {"trajectory": "memory", "mesh": "memory"}, **config})
    checker = FrameChecker(cfg)
    checker._mesh = mesh  # in-memory mesh: FrameChecker would otherwise load input.mesh
    try:
        recs = [checker.measure(f) for f in frames]
    finally:
        checker.close()
    out = apply_verdicts(recs, cfg)
    for r in out:
        assert_clean(r)
    return out


def assert_clean(rec: dict[str, Any]) -> None:
    """No swallowed exception, no NaN/inf in any float field, a verdict from the closed set."""
    assert rec["error"] != "internal_error", rec["error_detail"]
    assert rec["verdict"] in ("PASS", "FAIL", "UNVERIFIABLE")
    for key, value in rec.items():
        if isinstance(value, float):
            assert math.isfinite(value), f"{rec['frame_id']}: {key} = {value}"
        if key == "photo_from_render" and value is not None:
            assert np.all(np.isfinite(np.asarray(value))), rec["frame_id"]
    if rec["verdict"] == "UNVERIFIABLE":
        assert rec["reason"], f"{rec['frame_id']}: UNVERIFIABLE without a reason"
    if rec["verdict"] == "PASS":
        assert rec["corner_error_px"] is not None and rec["corner_error_px"] <= rec["threshold_px"]
