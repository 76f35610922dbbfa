from __future__ import annotations

import pytest
import torch

from mariner_core.config import MarinerConfig
from mariner_core.model import Mariner, pad_render


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return Mariner(MarinerConfig()).eval()


def test_parameter_count(model):
    n = sum(p.numel() for p in model.parameters())
    assert n == 3_732_867
    assert abs(n - 3.73e6) / 3.73e6 < 0.03  # spec: ~3.73 M


@pytest.mark.parametrize(
    ("render_hw", "ref_hw"),
    [((64, 64), (64, 64)), ((50, 70), (60, 60)), ((33, 97), (80, 61)), ((96, 40), (64, 100))],
)
def test_output_shapes(model, render_hw, ref_hw):
    with torch.no_grad():
        ys = model(torch.rand(2, 3, *render_hw), torch.rand(2, 3, *ref_hw), iterations=2)
    assert len(ys) == 2
    assert all(y.shape == (2, 3, *render_hw) for y in ys)


def test_iterations_default_and_override(model):
    x, r = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        assert len(model(x, r)) == 2
        ys3 = model(x, r, iterations=3)
        ys1 = model(x, r, iterations=1)
    assert len(ys3) == 3
    torch.testing.assert_close(ys3[0], ys1[0])


def test_pad_render_even_split():
    x = torch.arange(5.0).view(1, 1, 1, 5).expand(1, 3, 3, 5)
    y, pads = pad_render(x, 32)
    assert y.shape[-2:] == (32, 32)
    assert pads == (13, 14, 14, 15)
    torch.testing.assert_close(y[..., 14:17, 13:18], x)


def test_gradients_reach_every_parameter():
    cfg = MarinerConfig(encoder_blocks=(1, 1, 1), decoder_blocks=(1, 1, 1), channels=16)
    m = Mariner(cfg)
    # Zero-initialised SAM gamma/beta convs block the gradient to the shared SAM conv at init;
    # perturb them so every parameter is on a live path.
    for mod in m.modules():
        if mod.__class__.__name__ == "SAM":
            torch.nn.init.normal_(mod.conv_gamma.weight, std=0.05)
            torch.nn.init.normal_(mod.conv_beta.weight, std=0.05)
    x, r, gt = torch.rand(1, 3, 32, 32), torch.rand(1, 3, 64, 64), torch.rand(1, 3, 32, 32)
    ys = m(x, r, iterations=2)
    sum((y - gt).abs().mean() for y in ys).backward()
    missing = [n for n, p in m.named_parameters() if p.grad is None or p.grad.abs().sum() == 0]
    assert not missing, missing


@pytest.mark.parametrize(
    ("render", "ref", "msg"),
    [
        (torch.zeros(1, 3, 32, 32, dtype=torch.uint8), torch.rand(1, 3, 64, 64), "floating"),
        (torch.rand(1, 4, 32, 32), torch.rand(1, 3, 64, 64), r"\(N, 3, H, W\)"),
        (torch.rand(3, 32, 32), torch.rand(1, 3, 64, 64), r"\(N, 3, H, W\)"),
        (torch.full((1, 3, 32, 32), float("nan")), torch.rand(1, 3, 64, 64), "NaN"),
        (torch.rand(1, 3, 32, 32), torch.rand(1, 3, 59, 64), "at least 60"),
        (torch.rand(2, 3, 32, 32), torch.rand(1, 3, 64, 64), "batch"),
    ],
)
def test_bad_inputs(model, render, ref, msg):
    with pytest.raises(ValueError, match=msg):
        model(render, ref)


def test_config_strict():
    with pytest.raises(ValueError, match="unknown MarinerConfig key"):
        MarinerConfig.from_dict({"chanels": 32})
    cfg = MarinerConfig(channels=8)
    assert MarinerConfig.from_dict(cfg.to_dict()) == cfg
