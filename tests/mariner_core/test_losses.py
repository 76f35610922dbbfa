from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from mariner_core.losses import (
    Discriminator,
    PerceptualLoss,
    discriminator_loss,
    generator_adversarial_loss,
    l1_loss,
    refinement_loss,
)


def test_l1():
    a, b = torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), 0.5)
    assert l1_loss(a, b).item() == pytest.approx(0.5)


def test_perceptual_random_weights_and_grad():
    loss = PerceptualLoss()
    x = torch.rand(1, 3, 16, 16, requires_grad=True)
    y = torch.rand(1, 3, 16, 16)
    assert loss(y, y).item() == 0
    v = loss(x, y)
    v.backward()
    assert v.item() > 0 and x.grad.abs().sum() > 0
    assert all(p.grad is None for p in loss.parameters())


def test_perceptual_pretrained(converted_weights):
    loss = PerceptualLoss.pretrained()
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 3, 32, 32, generator=g)
    near = (x + 0.02 * torch.randn(x.shape, generator=g)).clamp(0, 1)
    far = torch.rand(1, 3, 32, 32, generator=g)
    assert 0 < loss(near, x).item() < loss(far, x).item()
    # relu1_1 of the converted VGG16 is a plain conv: check the layer maps weights correctly
    w = loss.vgg.convs[0].weight
    assert w.shape == (64, 3, 3, 3) and w.abs().sum() > 0


def test_ragan_losses_match_formula():
    real, fake = torch.tensor([[1.0], [2.0]]), torch.tensor([[0.5], [-1.0]])
    d_r, d_f = real - fake.mean(), fake - real.mean()
    bce = F.binary_cross_entropy_with_logits
    want_d = 0.5 * (bce(d_r, torch.ones_like(d_r)) + bce(d_f, torch.zeros_like(d_f)))
    want_g = 0.5 * (bce(d_r, torch.zeros_like(d_r)) + bce(d_f, torch.ones_like(d_f)))
    torch.testing.assert_close(discriminator_loss(real, fake), want_d)
    torch.testing.assert_close(generator_adversarial_loss(real, fake), want_g)


def test_discriminator_shapes():
    d = Discriminator(input_size=64)
    assert d(torch.rand(2, 3, 64, 64)).shape == (2, 1)
    with pytest.raises(ValueError, match="expects"):
        d(torch.rand(2, 3, 32, 32))
    d160 = Discriminator()
    assert d160.classifier[0].in_features == 512 * 5 * 5


def test_refinement_loss_sums_iterations():
    gt = torch.zeros(1, 3, 8, 8)
    ys = [torch.full_like(gt, 0.2), torch.full_like(gt, 0.1)]
    assert refinement_loss(ys, gt, None).item() == pytest.approx(0.3)
