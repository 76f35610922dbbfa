from __future__ import annotations

import torch

from mariner_core.encoder import Encoder


def test_encoder_shapes_and_params():
    enc = Encoder(64, (4, 4, 4))
    f1, f2, f3 = enc(torch.rand(2, 3, 32, 48))
    assert f1.shape == (2, 64, 32, 48)
    assert f2.shape == (2, 64, 16, 24)
    assert f3.shape == (2, 64, 8, 12)
    assert sum(p.numel() for p in enc.parameters()) == 961_920  # spec: ~0.96 M


def test_encoder_shared_weights_batch_independent():
    enc = Encoder(8, (1, 1, 1))
    x = torch.rand(2, 3, 16, 16)
    a = enc(x)[2]
    b = enc(x[1:])[2]
    torch.testing.assert_close(a[1:], b)
