"""Training augmentations of the ``cpu-frozen`` trainer (``mariner_core.train_frozen``): colour
changes that force the decoder to read the photo's appearance from its reference, not from the
render. Both act in place on a batch of prepared inputs (``FrozenMariner.prepare`` keys)."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["recolour", "reshade_render"]


def recolour(
    prep: dict[str, torch.Tensor], target: torch.Tensor, share: float, rng: np.random.Generator,
) -> torch.Tensor:
    """Give the reference-derived inputs and the target one random colour change per sample.

    Why: a decoder trained on one scene learns that scene's colours and brightness from the
    render (the castle, unseen, scored below the untrained matching, ``reports/mariner_quality.md``).
    When the photo's colours change with the reference's and not with the render, the only way
    to predict them is to read them from the reference. Per-channel gain and a shared gamma, so
    the colour-transferred render (per-channel mean / std moved to the reference's) follows
    approximately. The render itself is left as it is. Modifies ``prep`` in place; returns the
    changed target.
    """
    n = target.shape[0]
    on = torch.from_numpy(rng.random(n) < share)
    gain = torch.from_numpy(np.exp(rng.uniform(-0.35, 0.35, (n, 1, 1, 1))
                                   + rng.uniform(-0.2, 0.2, (n, 3, 1, 1)))).float()
    gamma = torch.from_numpy(np.exp(rng.uniform(-0.35, 0.35, (n, 1, 1, 1)))).float()
    gain = torch.where(on[:, None, None, None], gain, torch.ones_like(gain))
    gamma = torch.where(on[:, None, None, None], gamma, torch.ones_like(gamma))

    def change(x: torch.Tensor) -> torch.Tensor:
        c = x.shape[1]
        y = x.reshape(n, c // 3, 3, *x.shape[-2:])
        y = (gain[:, None] * y.clamp_min(1e-4) ** gamma[:, None]).clamp(0, 1)
        return y.reshape(x.shape)

    prep["warped"] = change(prep["warped"])
    prep["colour"] = change(prep["colour"])
    return change(target)


def reshade_render(
    prep: dict[str, torch.Tensor], share: float, rng: np.random.Generator,
) -> None:
    """Change the exposure and shading of the render alone (gain, gamma, a linear brightness
    ramp) on a random ``share`` of samples, in place.

    Why: on a new scene the render's brightness says nothing reliable about the photo's (mesh
    colours are averaged over views, shading is synthetic); the photo's appearance must come
    from the reference. The target and the reference-derived inputs are left as they are.
    """
    r = prep["render"]
    n, _, h, w = r.shape
    on = torch.from_numpy(rng.random(n) < share)[:, None, None, None]
    gain = torch.from_numpy(np.exp(rng.uniform(-0.5, 0.5, (n, 1, 1, 1)))).float()
    gamma = torch.from_numpy(np.exp(rng.uniform(-0.4, 0.4, (n, 1, 1, 1)))).float()
    ang = rng.uniform(0, 2 * np.pi, n)
    amp = rng.uniform(0, 0.3, n)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    ramp = torch.stack([1 + a * (np.cos(t) * xx + np.sin(t) * yy) for a, t in zip(amp, ang,
                                                                                 strict=True)])
    changed = (gain * r.clamp_min(1e-4) ** gamma * ramp[:, None].float()).clamp(0, 1)
    prep["render"] = torch.where(on, changed, r)
