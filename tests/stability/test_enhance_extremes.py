"""Enhancement on extreme inputs (CPU: the fp32 path; fp16 autocast exists only on CUDA).

Expected: ``Enhancer(..., fp16=True)`` on CPU raises a clear ValueError naming CUDA; fp32
enhancement of all-black, all-white, saturated and NaN-free extreme renders/references with a
small random model returns finite images in [0, 1] of the render's shape.
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

pytestmark = pytest.mark.enhance


@pytest.fixture(scope="module")
def small_model():
    from mariner_core.config import MarinerConfig
    from mariner_core.model import Mariner

    torch.manual_seed(0)
    return Mariner(MarinerConfig(channels=8, encoder_blocks=(1, 1, 1), decoder_blocks=(1, 1, 1)))


def test_fp16_on_cpu_is_refused(small_model):
    """fp16 on CPU -> ValueError mentioning CUDA (not a silent fp32 fallback, not a crash)."""
    from mariner_core.enhancer import Enhancer

    with pytest.raises(ValueError, match="CUDA"):
        Enhancer(small_model, device="cpu", fp16=True)


def _img(kind: str, h: int = 64, w: int = 96) -> np.ndarray:
    if kind == "black":
        return np.zeros((h, w, 3), np.float32)
    if kind == "white":
        return np.ones((h, w, 3), np.float32)
    if kind == "saturated":  # pure primaries in blocks, every channel at 0 or 1
        img = np.zeros((h, w, 3), np.float32)
        for i in range(3):
            img[:, i * w // 3 : (i + 1) * w // 3, i] = 1.0
        return img
    rng = np.random.default_rng(0)  # "noise": high-contrast binary noise
    return (rng.uniform(size=(h, w, 3)) > 0.5).astype(np.float32)


@pytest.mark.parametrize(
    "render, reference",
    [
        ("black", "black"),
        ("white", "white"),
        ("saturated", "saturated"),
        ("noise", "black"),
        ("black", "white"),
    ],
)
def test_fp32_extreme_inputs_stay_finite(small_model, render, reference):
    """All-black / all-white / saturated inputs -> finite output in [0, 1], same shape."""
    from mariner_core.enhancer import Enhancer

    enh = Enhancer(small_model, device="cpu", fp16=False)
    x = _img(render)
    out = enh.enhance(x, _img(reference, 64, 80))
    assert out.shape == x.shape and out.dtype == np.float32
    assert np.isfinite(out).all()
    assert out.min() >= 0.0 and out.max() <= 1.0
