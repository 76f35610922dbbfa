"""How a training run's model starts (``train_frozen train``): the frozen matcher's ImageNet
VGG, and ``--init`` weights where given, an ungated checkpoint opening into a gated model
(``gated_state_dict``: the shipped weights as the start of the gated all-scenes model,
reports/mariner_training.md, eighth session). Split out of ``train_frozen.py`` (its size).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import torch

from .frozen import FrozenMariner, FrozenMarinerConfig

logger = logging.getLogger(__name__)

#: gate logit of a gated model warm-started from an ungated one (sigmoid = 0.98): it starts as
#: that model, and learns where to close
OPEN_GATE_BIAS = 4.0


def gated_state_dict(ungated: FrozenMariner) -> dict[str, torch.Tensor]:
    """The weights of ``ungated`` for the gated variant of its config: the head gains a gate
    channel with zero weights and bias ``OPEN_GATE_BIAS``, so the gated model starts as
    ``base + 0.98 x`` the ungated correction (the shipped 7-Scenes weights as the start of an
    all-scenes gated model, instead of the matching-only base)."""
    if ungated.cfg.gated:
        raise ValueError("the model is gated already")
    sd = {k: v.clone() for k, v in ungated.state_dict().items()}
    w, b = sd["head.weight"], sd["head.bias"]
    sd["head.weight"] = torch.cat([w, torch.zeros_like(w[:1])], 0)
    sd["head.bias"] = torch.cat([b, torch.full_like(b[:1], OPEN_GATE_BIAS)], 0)
    return sd


def initial_model(
    cfg: FrozenMarinerConfig, out: Path, init: str | Path | None, resume: bool,
) -> FrozenMariner:
    """The model to train, in training mode: ImageNet VGG in the matcher, and the ``init``
    weights unless ``last.pt`` will be resumed."""
    from .enhancer import load_checkpoint
    from .pretrained import backbone_state_dict

    model = FrozenMariner(cfg)
    model.load_vgg(backbone_state_dict("vgg16"))
    if init is not None and not (resume and (out / "last.pt").is_file()):
        start = load_checkpoint(init)
        if not isinstance(start, FrozenMariner):
            raise ValueError(f"{init}: not a frozen-matcher checkpoint")
        if start.cfg == cfg:
            model.load_state_dict(start.state_dict(), strict=True)
        elif replace(start.cfg, gated=True) == cfg:
            model.load_state_dict(gated_state_dict(start), strict=True)
        else:
            raise ValueError(f"{init}: config {start.cfg} does not match {cfg}")
        logger.info("initialised from %s", init)
    model.train()
    return model
