"""Frame-cache builder for enhancer training (renders once, plain npz, no pairing baked in)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pgt_check.enhance.training_data import (
    VARIANTS,
    build_frame_cache,
    fixed_offset_pairs,
    working_size,
)


def test_working_size_keeps_aspect() -> None:
    assert working_size(640, 480, 160) == (213, 160)
    assert working_size(1416, 1064, 160) == (213, 160)
    assert working_size(480, 640, 160) == (160, 213)


def test_fixed_offset_pairs_never_self_and_exact_offset() -> None:
    pairs = fixed_offset_pairs(10, 4)
    assert [i for i, _ in pairs] == list(range(10))
    assert all(abs(i - j) == 4 for i, j in pairs)
    with pytest.raises(ValueError):
        fixed_offset_pairs(5, 5)


def test_build_frame_cache_sample_scene(sample_scene, tmp_path) -> None:
    pytest.importorskip("moderngl")
    out = tmp_path / "cache"
    index_path = build_frame_cache(
        sample_scene / "trajectories.txt",
        sample_scene / "mesh.glb",
        out,
        short_side=48,
        max_frames=3,
        decimate_fraction=0.3,
    )
    index = json.loads(index_path.read_text())
    assert [r["t"] for r in index["frames"]] == sorted(r["t"] for r in index["frames"])
    assert len(index["frames"]) == 3
    for r in index["frames"]:
        with np.load(out / r["file"]) as d:
            assert set(d.files) == set(VARIANTS)
            shapes = {d[k].shape for k in VARIANTS}
            assert shapes == {(r["height"], r["width"], 3)}
            assert min(r["height"], r["width"]) == 48
            assert all(d[k].dtype == np.uint8 for k in VARIANTS)
            assert d["render"].max() > 0  # the mesh is visible
            # the colourless render is grey shading: channels equal
            c = d["render_colourless"].astype(int)
            assert np.abs(c[..., 0] - c[..., 1]).max() <= 1
    # cached: a second call reuses the files (no re-render)
    mtime = (out / "frame_000000.npz").stat().st_mtime_ns
    build_frame_cache(
        sample_scene / "trajectories.txt",
        sample_scene / "mesh.glb",
        out,
        short_side=48,
        max_frames=3,
    )
    assert (out / "frame_000000.npz").stat().st_mtime_ns == mtime
