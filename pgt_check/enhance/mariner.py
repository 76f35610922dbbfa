"""Adapter from the validator to ``mariner_core.Enhancer`` (torch imported only when built)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.enhance.base import EnhancedImage, Evidence, ReferenceView, View
from pgt_check.errors import InputError, MissingExtraError

logger = logging.getLogger(__name__)


@dataclass
class MarinerEnhancer:
    """Enhances a render with a reference photo at the method's working scale.

    weights: checkpoint path (None = the checkpoint shipped in mariner_core); short_side: the
    working size (the method works at ~160-320 px); iterations: refinement iterations (None =
    the checkpoint's default). ``enhance`` returns the enhanced image resized back to the
    render's size, so matching and the corner error stay in the render's pixel frame.
    """

    weights: str | None = None
    device: str = "cpu"
    short_side: int = 160
    iterations: int | None = None
    threads: int | None = None
    #: "model", "base" (the matching-only base) or "auto" (not decided yet: the decoder's
    #: output until the run's scene check sets it, ``stages.scene_check``)
    output: str = "model"
    _enhancer: Any = field(default=None, init=False, repr=False)

    def _load(self):
        if self._enhancer is None:
            try:
                import torch

                from mariner_core.enhancer import Enhancer
            except ImportError as err:
                raise MissingExtraError(err.name or "torch", "enhance") from err
            if self.threads:
                torch.set_num_threads(self.threads)
            path = None if self.weights is None else Path(self.weights)
            try:
                self._enhancer = Enhancer.from_pretrained(path, device=self.device)
            except FileNotFoundError as err:
                raise InputError(f"MaRINeR weights not found: {err}") from err
        return self._enhancer

    @property
    def detail_short_side(self) -> int:
        """The enhanced image carries detail up to this short side (its working size): the
        enhanced path matches it there (``measure.steps.match_path``)."""
        return self.short_side

    name = "mariner"
    #: the reference's appearance is placed by matching image content to the render, so the
    #: result keeps the render's own geometry (this frame's pose only)
    evidence = Evidence.ABSOLUTE

    @classmethod
    def from_config(cls, config: Any) -> MarinerEnhancer:
        """From an ``EnhanceConfig`` (weights, device, short_side, iterations, output)."""
        return cls(weights=config.weights, device=config.device, short_side=config.short_side,
                   iterations=config.iterations, output=getattr(config, "output", "model"))

    def enhance_image(self, render: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """render: (h, w, 3) float32 RGB [0, 1]; reference: (hr, wr, 3). Returns (h, w, 3)."""
        from pgt_check.io.images import resize_image

        enh = self._load()
        res = enh.enhance_working(render, reference, short_side=self.short_side,
                                  iterations=self.iterations,
                                  output="base" if self.output == "base" else "model")
        img = np.asarray(res.image, dtype=np.float32)
        h, w = render.shape[:2]
        img = resize_image(img, (w, h), interpolation="cubic")
        return np.clip(img, 0.0, 1.0)

    def enhance(self, view: View, reference: ReferenceView, renderer: Any) -> EnhancedImage:
        image = self.enhance_image(view.render.rgb, reference.photo)
        return EnhancedImage(image, np.ones(image.shape[:2], bool))

    def scene_scores(
        self, render: np.ndarray, reference: np.ndarray, target: np.ndarray
    ) -> tuple[float, float] | None:
        """(decoder, matching-only base) PSNR-Y in dB of ``render`` enhanced with
        ``reference`` against ``target`` (the render's own photo) at the working size, from one
        matching (``mariner_core.scene_check.triple_scores``); None for a model without a base
        (the spec network)."""
        from mariner_core.frozen import FrozenMariner
        from mariner_core.scene_check import triple_scores

        enh = self._load()
        if not isinstance(enh.model, FrozenMariner):
            return None
        return triple_scores(enh, render, reference, target, self.short_side, self.iterations)
