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
    n = sum(v.numel() for v in enhancer.model.state_dict().values())
    assert n == sum(v.numel() for v in ckpt["state_dict"].values())
    assert all(torch.isfinite(p).all() for p in enhancer.model.parameters())


def _render_kitchen(shared_data, frame_indices, colourless: bool = False):
    from pgt_check.io import read_trajectory
    from pgt_check.render import load_mesh, make_renderer

    pytest.importorskip("moderngl")
    scene = shared_data / "7scenes_redkitchen"
    traj = read_trajectory(scene / "trajectories.txt")
    mesh = load_mesh(scene / "mesh.ply")
    renderer = make_renderer(mesh.without_colour() if colourless else mesh)
    try:
        frames = [traj.frames[i] for i in frame_indices]
        renders = [
            renderer.render(f.camera.scaled(213 / 640, 160 / 480), f.world_from_cam).rgb
            for f in frames
        ]
    finally:
        renderer.close()
    return traj, renders


def test_enhances_a_shared_frame(shared_data) -> None:
    from pgt_check.io import load_image

    traj, (render,) = _render_kitchen(shared_data, [0])
    reference = load_image(traj.frames[2].image_file)
    enhancer = Enhancer.from_pretrained()
    out = enhancer.enhance_working(render, reference, short_side=160)
    assert out.image.shape == (160, 213, 3) and out.image.dtype == np.float32
    assert np.isfinite(out.image).all() and out.image.min() >= 0 and out.image.max() <= 1
    assert out.scale_x == pytest.approx(1.0) and out.scale_y == pytest.approx(1.0)
    # it produces an image, not a blank: some structure and colour
    assert out.image.std() > 0.02


@pytest.mark.shared_data
@pytest.mark.parametrize("colourless", [False, True])
def test_shipped_model_uses_its_reference(shared_data, colourless: bool) -> None:
    """On evaluation frames no model was trained on: the frame's own photo as reference gives
    a better result than a photo 20 frames away, which beats the raw render (PSNR-Y)."""
    from mariner_core.metrics import psnr_y
    from pgt_check.io import load_image
    from pgt_check.io.images import resize_image

    idx = [5, 40, 75]
    traj, renders = _render_kitchen(shared_data, idx, colourless=colourless)
    photos = [resize_image(load_image(traj.frames[i].image_file), (213, 160), "area") for i in idx]
    far = [resize_image(load_image(traj.frames[i + 2].image_file), (213, 160), "area") for i in idx]
    enhancer = Enhancer.from_pretrained()
    r = np.stack(renders).astype(np.float32)
    p = np.stack(photos).astype(np.float32)
    with_target = enhancer.enhance(r, p)
    with_far = enhancer.enhance(r, np.stack(far).astype(np.float32))
    raw_db = float(psnr_y(r, p).mean())
    far_db = float(psnr_y(with_far, p).mean())
    target_db = float(psnr_y(with_target, p).mean())
    assert far_db > raw_db + 1.0, (raw_db, far_db, target_db)
    assert target_db > far_db + 1.0, (raw_db, far_db, target_db)
