from __future__ import annotations

import numpy as np
import pytest
import torch

from mariner_core.config import MarinerConfig
from mariner_core.enhancer import DEFAULT_CHECKPOINT, Enhancer, save_checkpoint
from mariner_core.model import Mariner

SMALL = MarinerConfig(channels=8, encoder_blocks=(1, 1, 1), decoder_blocks=(1, 1, 1))


@pytest.fixture()
def ckpt(tmp_path):
    torch.manual_seed(1)
    m = Mariner(SMALL)
    with torch.no_grad():  # make SAM residuals non-trivial
        for p in m.parameters():
            p.add_(0.01 * torch.randn_like(p))
    return m, save_checkpoint(m, tmp_path / "m.pt", extra={"steps": 3})


def test_round_trip(ckpt):
    m, path = ckpt
    enh = Enhancer.from_pretrained(path)
    assert not enh.model.training
    assert enh.model.cfg == SMALL
    for a, b in zip(m.state_dict().values(), enh.model.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b)
    x, r = torch.rand(1, 3, 40, 50), torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        want = m.eval()(x, r)[-1].clamp(0, 1)
    torch.testing.assert_close(enh.enhance(x, r), want)


def test_fp16_storage(tmp_path, ckpt):
    m, _ = ckpt
    path = save_checkpoint(m, tmp_path / "h.pt", fp16=True)
    sd = torch.load(path, weights_only=True)["state_dict"]
    assert all(v.dtype == torch.float16 for v in sd.values())
    enh = Enhancer.from_pretrained(path)
    for a, b in zip(m.state_dict().values(), enh.model.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, atol=2e-3, rtol=2e-3)


def test_missing_default_checkpoint():
    if DEFAULT_CHECKPOINT.exists():
        pytest.skip("default checkpoint is shipped")
    with pytest.raises(FileNotFoundError, match="mariner.pt"):
        Enhancer.from_pretrained()


def test_bad_checkpoints(tmp_path, ckpt):
    m, path = ckpt
    raw = torch.load(path, weights_only=True)
    torch.save({"state_dict": raw["state_dict"]}, tmp_path / "a.pt")
    with pytest.raises(ValueError, match="not a MaRINeR checkpoint"):
        Enhancer.from_pretrained(tmp_path / "a.pt")
    raw2 = dict(raw, config=dict(raw["config"], channels=16))
    torch.save(raw2, tmp_path / "b.pt")
    with pytest.raises(RuntimeError):  # strict load: shapes differ from the stored config
        Enhancer.from_pretrained(tmp_path / "b.pt")
    raw3 = dict(raw, config=dict(raw["config"], bogus=1))
    torch.save(raw3, tmp_path / "c.pt")
    with pytest.raises(ValueError, match="unknown MarinerConfig key"):
        Enhancer.from_pretrained(tmp_path / "c.pt")


def test_numpy_and_torch_layouts_deterministic(ckpt):
    _, path = ckpt
    enh = Enhancer.from_pretrained(path)
    rng = np.random.default_rng(0)
    img = rng.random((45, 38, 3), dtype=np.float32)
    ref = rng.random((70, 64, 3), dtype=np.float32)
    out = enh.enhance(img, ref)
    assert isinstance(out, np.ndarray) and out.shape == img.shape and out.dtype == np.float32
    assert out.min() >= 0 and out.max() <= 1
    np.testing.assert_array_equal(out, enh.enhance(img, ref))  # deterministic
    batch = enh.enhance(np.stack([img, img]), ref)  # one reference broadcast over the batch
    assert batch.shape == (2, 45, 38, 3)
    np.testing.assert_allclose(batch[1], out, atol=1e-5)
    t = enh.enhance(torch.from_numpy(img).permute(2, 0, 1), torch.from_numpy(ref).permute(2, 0, 1))
    assert isinstance(t, torch.Tensor) and t.shape == (3, 45, 38)
    np.testing.assert_allclose(t.permute(1, 2, 0).numpy(), out, atol=1e-5)


def test_enhance_working(ckpt):
    _, path = ckpt
    enh = Enhancer.from_pretrained(path)
    img = np.random.default_rng(0).random((200, 300, 3), dtype=np.float32)
    res = enh.enhance_working(img, img, short_side=64, iterations=1)
    assert res.image.shape == (64, 96, 3)
    assert res.scale_x == pytest.approx(300 / 96) and res.scale_y == pytest.approx(200 / 64)


@pytest.mark.parametrize(
    ("render", "ref", "msg"),
    [
        (np.zeros((40, 40, 3), np.uint8), np.zeros((64, 64, 3), np.float32), "float32"),
        (np.zeros((40, 40, 4), np.float32), np.zeros((64, 64, 3), np.float32), "expected"),
        (np.full((40, 40, 3), np.nan, np.float32), np.zeros((64, 64, 3), np.float32), "NaN"),
        (np.zeros((40, 40, 3), np.float32), np.zeros((30, 64, 3), np.float32), "at least 60"),
        (torch.zeros(1, 3, 40, 40, dtype=torch.int64), torch.zeros(1, 3, 64, 64), "floating"),
        ([[0.0]], np.zeros((64, 64, 3), np.float32), "numpy array or torch tensor"),
    ],
)
def test_bad_inputs(ckpt, render, ref, msg):
    enh = Enhancer(ckpt[0])
    with pytest.raises(ValueError, match=msg):
        enh.enhance(render, ref)


def test_fp16_requires_cuda(ckpt):
    if torch.cuda.is_available():
        pytest.skip("CUDA present")
    with pytest.raises(ValueError, match="CUDA"):
        Enhancer(ckpt[0], device="cpu", fp16=True)


def test_native_size_is_bounded_before_any_work():
    """The frozen matcher's global matching grows with the product of the image areas: a
    castle-sized pair (1416x1064) is refused at once with a message naming enhance_working,
    while the working size runs."""
    import time

    from mariner_core.frozen import FrozenMariner, FrozenMarinerConfig

    enh = Enhancer(FrozenMariner(FrozenMarinerConfig(channels=4, blocks=(1, 1, 1))))
    big = np.zeros((1064, 1416, 3), np.float32)
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="enhance_working"):
        enh.enhance(big, big)
    assert time.perf_counter() - t0 < 2.0
    out = enh.enhance_working(big, big, short_side=64)
    assert out.image.shape[:2] == (64, 85)
    # the bound is a setting: None lifts it, and a small bound refuses a small pair
    assert Enhancer(enh.model, max_match_pairs=None).max_match_pairs is None
    with pytest.raises(ValueError, match="max_match_pairs"):
        Enhancer(enh.model, max_match_pairs=10).enhance(big[:64, :64], big[:64, :64])
