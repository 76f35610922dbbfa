"""Adapter from the validator to ``mariner_core.Enhancer`` (torch imported only when built)."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

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
    def name(self) -> str:
        return "mariner"

    def enhance(self, render: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """render: (h, w, 3) float32 RGB [0, 1]; reference: (hr, wr, 3). Returns (h, w, 3)."""
        import cv2

        enh = self._load()
        res = enh.enhance_working(render, reference, short_side=self.short_side,
                                  iterations=self.iterations)
        img = np.asarray(res.image, dtype=np.float32)
        h, w = render.shape[:2]
        if img.shape[:2] != (h, w):
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_CUBIC)
        return np.clip(img, 0.0, 1.0)
