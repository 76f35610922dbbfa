"""kornia LoFTR with user-supplied weights (none are bundled; nothing is downloaded).

``make_matcher("loftr", weights="PATH")`` (CLI: ``--loftr-weights PATH``) loads a LoFTR checkpoint,
either the released Lightning ``.ckpt`` (its ``state_dict`` entry, ``matcher.`` prefix) or a plain
state dict of ``kornia.feature.LoFTR``, strictly, with ``weights_only=True``.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.errors import ConfigError
from pgt_check.match import _torch
from pgt_check.match.base import Matches

logger = logging.getLogger(__name__)

NO_WEIGHTS_MESSAGE = (
    "no LoFTR weights are bundled with pgt-check: pass a LoFTR checkpoint with "
    "--loftr-weights PATH (Python: make_matcher('loftr', weights=PATH))"
)


def loftr_state_dict(raw: dict[str, Any]) -> dict[str, Any]:
    """The network weights of a LoFTR checkpoint: ``raw["state_dict"]`` if present, else ``raw``.

    The ``matcher.`` prefix of the released checkpoints is stripped.
    """
    sd = raw.get("state_dict", raw) if isinstance(raw, dict) else raw
    if not isinstance(sd, dict):
        raise ValueError("a LoFTR checkpoint must be a state dict or hold one under 'state_dict'")
    return {(k[len("matcher.") :] if k.startswith("matcher.") else k): v for k, v in sd.items()}


@dataclass
class LoFTRMatcher(_torch.PicklesWithoutModels):
    """Detector-free LoFTR matching (kornia ``LoFTR``) with weights from ``weights``.

    weights: path to the checkpoint (required); temp_bug_fix: the positional-encoding variant
    (True for ``loftr_indoor_ds_new.ckpt``, False for the other released checkpoints);
    max_keypoints: keep at most this many matches, highest confidence first; device: "cpu" |
    "cuda"; num_threads: fix torch's CPU threads. Images are converted to grey and not resized
    (kornia's LoFTR takes any size). Coordinates are shifted by -0.5 from LoFTR's frame (pixel
    centre at +0.5) to the OpenCV convention. ``mask0`` drops matches whose image0 point lies
    outside it. ``n_kpts0`` / ``n_kpts1`` are the number of coarse matches before the mask.
    """

    _model_attrs = ("_model",)  # dropped when pickled (see PicklesWithoutModels)
    weights: str | Path | None = None
    temp_bug_fix: bool = False
    max_keypoints: int = 2048
    device: str = "cpu"
    num_threads: int | None = None
    _model: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.weights is None or str(self.weights) == "":
            raise ConfigError(NO_WEIGHTS_MESSAGE)
        if self.max_keypoints < 1:
            raise ValueError(f"max_keypoints must be >= 1, got {self.max_keypoints}")
        self.name = "loftr"
        self.weights = Path(self.weights)
        if not self.weights.is_file():
            raise ConfigError(f"LoFTR weights not found: {self.weights}")
        _torch.require_torch_kornia()
        self.device = _torch.resolve_device(self.device)

    def _load(self) -> Any:
        if self._model is None:
            _, kf = _torch.require_torch_kornia()
            from kornia.feature.loftr.loftr import default_cfg

            _torch.set_threads(self.num_threads)
            cfg = copy.deepcopy(default_cfg)
            cfg["coarse"]["temp_bug_fix"] = self.temp_bug_fix  # type: ignore[index]
            model = kf.LoFTR(pretrained=None, config=cfg)
            assert self.weights is not None  # resolved in __post_init__
            sd = loftr_state_dict(_torch.load_weights(self.weights))
            _torch.load_strict(model, sd, str(self.weights))
            self._model = model.to(self.device)
            logger.debug("loaded LoFTR weights from %s", self.weights)
        return self._model

    def match(
        self, image0: np.ndarray, image1: np.ndarray, mask0: np.ndarray | None = None
    ) -> Matches:
        """Match image0 (render) to image1 (photo); both (H, W, 3) RGB float32 in [0, 1]."""
        torch = _torch.require("torch")
        im0, im1, m0 = _torch.check_pair(image0, image1, mask0)
        model = self._load()
        with torch.inference_mode():
            out = model(
                {
                    "image0": _torch.image_to_tensor(im0, self.device, gray=True),
                    "image1": _torch.image_to_tensor(im1, self.device, gray=True),
                }
            )
        k0 = out["keypoints0"].double().cpu().numpy().reshape(-1, 2) - 0.5
        k1 = out["keypoints1"].double().cpu().numpy().reshape(-1, 2) - 0.5
        conf = out["confidence"].double().cpu().numpy().reshape(-1)
        n = len(k0)
        keep = np.isfinite(k0).all(1) & np.isfinite(k1).all(1) & np.isfinite(conf)
        if m0 is not None:
            keep &= _torch.keypoints_in_mask(k0, m0)
        k0, k1, conf = k0[keep], k1[keep], conf[keep]
        if len(conf) > self.max_keypoints:
            order = np.argsort(-conf, kind="stable")[: self.max_keypoints]
            k0, k1, conf = k0[order], k1[order], conf[order]
        return Matches(k0, k1, conf, n, n)
