"""The scene check: the decoder is kept only where the scene's own photos show it beats the
matching-only base (issue 37, item 3)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from mariner_core.enhancer import Enhancer
from mariner_core.frozen import FrozenMariner, FrozenMarinerConfig
from mariner_core.scene_check import MIN_TRIPLES, decide_output, scene_check, triple_scores

SMALL = FrozenMarinerConfig(top_k=2, channels=4, blocks=(1, 1, 1), patch_size=3, gated=True)


def _textured(h: int, w: int, seed: int) -> np.ndarray:
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(1, 3, h // 8, w // 8, generator=g)
    x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)
    return x[0].permute(1, 2, 0).numpy().astype(np.float32)


def test_a_clear_gain_keeps_the_decoder() -> None:
    rng = np.random.default_rng(0)
    base = rng.uniform(12, 20, 10)
    out = decide_output(base + 1.0 + rng.normal(0, 0.2, 10), base)
    assert out.output == "model" and out.p_value < 0.05 and out.gain_db > 0.5
    assert "beats" in out.reason


@pytest.mark.parametrize("shift", [-1.0, 0.0, 0.05])
def test_no_significant_gain_falls_back_to_the_base(shift: float) -> None:
    rng = np.random.default_rng(1)
    base = rng.uniform(12, 20, 10)
    out = decide_output(base + shift + rng.normal(0, 1.0, 10), base)
    assert out.output == "base" and out.p_value >= 0.05


def test_too_few_triples_cannot_prefer_the_decoder() -> None:
    base = np.arange(MIN_TRIPLES - 1, dtype=float) + 10
    out = decide_output(base + 5.0, base)
    assert out.output == "base" and out.n == MIN_TRIPLES - 1 and "below" in out.reason
    # with MIN_TRIPLES all-positive differences the test can reach significance
    base = np.arange(MIN_TRIPLES, dtype=float) + 10
    assert decide_output(base + 5.0, base).output == "model"


def test_bad_inputs_are_errors() -> None:
    with pytest.raises(ValueError, match="length"):
        decide_output([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="finite"):
        decide_output([float("nan")] * 6, [1.0] * 6)
    with pytest.raises(ValueError, match="alpha"):
        decide_output([1.0] * 6, [1.0] * 6, alpha=1.5)


def test_base_output_is_the_matching_only_base() -> None:
    model = FrozenMariner(SMALL).eval()
    enh = Enhancer(model)
    r, ref = _textured(48, 64, 0), _textured(48, 64, 1)
    got = enh.enhance(r, ref, output="base")
    x = torch.from_numpy(r).permute(2, 0, 1)[None]
    y = torch.from_numpy(ref).permute(2, 0, 1)[None]
    with torch.no_grad():
        want = model.base(model.prepare(x, y))[..., :48, :64].clamp(0, 1)
    np.testing.assert_allclose(got, want[0].permute(1, 2, 0).numpy(), atol=1e-5)
    with pytest.raises(ValueError, match="output"):
        enh.enhance(r, ref, output="decoder")


def test_a_decoder_that_damages_the_scene_is_replaced_by_the_base() -> None:
    """A decoder whose correction brightens everything (as an unlike scene's render can make
    a decoder do) scores below the base on every triple: the scene gets the base."""
    model = FrozenMariner(SMALL).eval()
    with torch.no_grad():
        model.head.bias[:3] = 0.6  # correction +0.6 everywhere
        model.head.bias[3] = 4.0  # confident
    enh = Enhancer(model)
    triples = []
    for k in range(6):
        photo = _textured(48, 64, 10 + k)
        render = np.clip(photo * 0.5 + 0.1, 0, 1).astype(np.float32)  # an unlit render
        triples.append((render, _textured(48, 64, 20 + k) * 0.3 + photo * 0.7, photo))
    m_db, b_db = triple_scores(enh, *triples[0], short_side=48)
    assert m_db < b_db
    out = scene_check(enh, triples, short_side=48)
    assert out.output == "base" and out.n == 6 and out.gain_db < 0
    assert out.model_db < out.base_db
