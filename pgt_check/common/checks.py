"""Argument checks with no dependency inside the package (imported by ``types`` and ``geometry``)."""

from __future__ import annotations

import numpy as np


def check_shape(name: str, array: np.ndarray, shape: tuple[int | None, ...]) -> None:
    """Raise ``ValueError`` unless ``array.shape`` matches ``shape`` (None = any size)."""
    if array.ndim != len(shape) or any(
        want is not None and have != want for have, want in zip(array.shape, shape, strict=False)
    ):
        pretty = "x".join("N" if s is None else str(s) for s in shape)
        raise ValueError(f"{name}: expected shape ({pretty}), got {tuple(array.shape)}")
