"""Scene check: does the trained decoder improve on the matching-only base *on this scene*?

A decoder trained on a few scenes can damage renders unlike its training renders (issue 37: on
the Sceaux castle, a scene no model saw, the decoder scores 10.8-13.2 dB PSNR-Y where the
matching-only base scores 17.5), and its learned confidence gate was learned on the same
scenes, so it cannot see this. The scene check decides from the scene itself, at test time:
for a few (render, reference photo, the frame's own photo) triples of the run to be enhanced
it scores both outputs of one matching against the frame's own photo, and keeps the decoder
only where it is **significantly** better than the base (one-sided Wilcoxon signed-rank test
of the paired PSNR-Y differences at ``alpha``); otherwise, and with too few triples to reach
significance, the output is the base. So on a new scene the output is the matching-only base
unless the scene's own photos show the decoder helps: nothing is fitted to a scene.

The frame's own photo is a fair target here although the same photo is later compared with
the enhanced render: the check chooses one of two outputs for the whole run (one bit), with
the same reference for both; it never picks per frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["MIN_TRIPLES", "PSNR_CAP_DB", "SceneCheck", "decide_output", "scene_check", "triple_scores"]

#: the fewest triples for which a one-sided signed-rank test can reach p < 0.05 (5 all-positive
#: differences give p = 1/32); below it the check cannot prefer the decoder
MIN_TRIPLES = 5

#: PSNR-Y of an output identical to its target (8-bit: any real difference scores below it)
PSNR_CAP_DB = 100.0


@dataclass(frozen=True)
class SceneCheck:
    """The outcome of the scene check: which output the scene gets and the evidence.

    output: "model" or "base"; n: triples scored; model_db / base_db: mean PSNR-Y of each
    output against the frames' own photos; gain_db: median paired difference (model - base);
    p_value: one-sided signed-rank p of "the model is better" (1.0 with too few triples);
    reason: one sentence for logs and reports.
    """

    output: str
    n: int
    model_db: float
    base_db: float
    gain_db: float
    p_value: float
    alpha: float
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return {k: (round(v, 4) if isinstance(v, float) and math.isfinite(v) else v)
                for k, v in asdict(self).items()}


def decide_output(
    model_db: Sequence[float], base_db: Sequence[float], alpha: float = 0.05
) -> SceneCheck:
    """The scene's output from paired PSNR-Y scores (dB) of the decoder and the base.

    The decoder is kept when the one-sided Wilcoxon signed-rank test says its scores are higher
    at level ``alpha`` (and the median difference is positive); otherwise the base. Raises
    ValueError on unequal lengths, non-finite scores or ``alpha`` outside (0, 1).
    """
    m = np.asarray(model_db, np.float64).reshape(-1)
    b = np.asarray(base_db, np.float64).reshape(-1)
    if m.shape != b.shape:
        raise ValueError(f"model_db and base_db differ in length: {m.shape} vs {b.shape}")
    if not (np.isfinite(m).all() and np.isfinite(b).all()):
        raise ValueError("scene check scores must be finite")
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    n = int(m.size)
    d = m - b
    gain = float(np.median(d)) if n else 0.0
    means = (float(m.mean()) if n else math.nan, float(b.mean()) if n else math.nan)
    if n < MIN_TRIPLES:
        return SceneCheck("base", n, *means, gain, 1.0, alpha,
                          f"{n} triples: below the {MIN_TRIPLES} a significant gain needs; "
                          "the matching-only base is used")
    if not np.any(d != 0.0):
        p = 1.0
    else:
        from scipy.stats import wilcoxon

        p = float(wilcoxon(d, alternative="greater", zero_method="zsplit").pvalue)
    if p < alpha and gain > 0.0:
        return SceneCheck("model", n, *means, gain, p, alpha,
                          f"the decoder beats the matching-only base on this scene's own photos "
                          f"by {gain:+.2f} dB (median of {n}, p = {p:.3g} < {alpha:g})")
    return SceneCheck("base", n, *means, gain, p, alpha,
                      f"the decoder is not significantly better than the matching-only base "
                      f"on this scene's own photos ({gain:+.2f} dB median of {n}, p = {p:.3g}): "
                      "the base is used")


def triple_scores(
    enhancer: Any, render: Any, reference: Any, target: Any, short_side: int = 160,
    iterations: int | None = None,
) -> tuple[float, float]:
    """(model, base) PSNR-Y in dB of one triple at working size: ``render`` enhanced with
    ``reference`` by ``enhancer`` (a ``mariner_core.Enhancer`` with a frozen-matcher model),
    both outputs from one matching, against ``target`` (the render's own photo) resized to the
    same working size. Images as ``Enhancer.enhance`` takes them (one image each)."""
    import torch

    from .enhancer import _to_tensor, resize_short_side
    from .metrics import psnr_y

    x, _, _ = _to_tensor(render, "render")
    ref, _, _ = _to_tensor(reference, "reference")
    tgt, _, _ = _to_tensor(target, "target")
    if x.shape[0] != 1 or ref.shape[0] != 1 or tgt.shape[0] != 1:
        raise ValueError("triple_scores takes one render, reference and target")
    xw = resize_short_side(x.float(), short_side)
    refw = resize_short_side(ref.float(), short_side)
    tw = torch.nn.functional.interpolate(
        tgt.float(), size=tuple(xw.shape[-2:]), mode="bicubic", align_corners=False,
        antialias=True).clamp(0.0, 1.0)
    model, base = enhancer._run_outputs(xw, refw, iterations, "both")
    tw = tw.to(model.device)
    # identical images score inf: capped so that the paired test stays defined
    return (min(float(psnr_y(model, tw)[0]), PSNR_CAP_DB),
            min(float(psnr_y(base, tw)[0]), PSNR_CAP_DB))


def scene_check(
    enhancer: Any, triples: Sequence[tuple[Any, Any, Any]], short_side: int = 160,
    alpha: float = 0.05, iterations: int | None = None,
) -> SceneCheck:
    """The scene's output (``SceneCheck``) from ``(render, reference, target)`` triples of the
    scene (see the module docstring). A model without a matching-only base (the spec network)
    always gives "model": there is nothing to fall back to."""
    from .frozen import FrozenMariner

    if not isinstance(enhancer.model, FrozenMariner):
        return SceneCheck("model", 0, math.nan, math.nan, math.nan, 1.0, alpha,
                          "the spec network has no matching-only base to fall back to")
    scores = [triple_scores(enhancer, r, f, t, short_side, iterations) for r, f, t in triples]
    return decide_output([s[0] for s in scores], [s[1] for s in scores], alpha)
