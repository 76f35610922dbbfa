"""The shipped default checkpoint: small, loads strictly, enhances a real frame sensibly."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from mariner_core.enhancer import DEFAULT_CHECKPOINT, Enhancer

MAX_BYTES = 20 * 1024 * 1024


def test_checkpoint_is_shipped_and_small() -> None:
    assert DEFAULT_CHECKPOINT.is_file(), "mariner_core/weights/mariner.pt is not shipped"
    assert DEFAULT_CHECKPOINT.stat().st_size <= MAX_BYTES
    assert (DEFAULT_CHECKPOINT.parent / "MODEL_CARD.md").is_file()


def test_checkpoint_loads_strictly_with_metadata() -> None:
    ckpt = torch.load(DEFAULT_CHECKPOINT, map_location="cpu", weights_only=True)
    assert set(ckpt) == {"config", "state_dict", "meta"}
    assert ckpt["meta"]["fp16"] is True
    enhancer = Enhancer.from_pretrained()  # load_state_dict(strict=True) inside
    n = sum(p.numel() for p in enhancer.model.parameters())
    assert n == sum(v.numel() for v in ckpt["state_dict"].values() if v.is_floating_point())
    assert all(torch.isfinite(p).all() for p in enhancer.model.parameters())


def test_enhances_a_shared_frame(shared_data) -> None:
    from pgt_check.io import load_image, read_trajectory
    from pgt_check.render import load_mesh, make_renderer

    pytest.importorskip("moderngl")
    scene = shared_data / "7scenes_redkitchen"
    traj = read_trajectory(scene / "trajectories.txt")
    frame, ref_frame = traj.frames[0], traj.frames[2]
    cam = frame.camera.scaled(213 / 640, 160 / 480)
    renderer = make_renderer(load_mesh(scene / "mesh.ply"))
    try:
        render = renderer.render(cam, frame.world_from_cam).rgb
    finally:
        renderer.close()
    reference = load_image(ref_frame.image_file)
    enhancer = Enhancer.from_pretrained()
    out = enhancer.enhance_working(render, reference, short_side=160)
    assert out.image.shape == (160, 213, 3) and out.image.dtype == np.float32
    assert np.isfinite(out.image).all() and out.image.min() >= 0 and out.image.max() <= 1
    assert out.scale_x == pytest.approx(1.0) and out.scale_y == pytest.approx(1.0)
    # it produces an image, not a blank: some structure and colour
    assert out.image.std() > 0.02
