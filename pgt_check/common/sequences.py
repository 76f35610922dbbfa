"""Picking from sequences, with no dependency inside the package."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np

T = TypeVar("T")


def evenly_spaced(items: Sequence[T], n: int) -> list[T]:
    """Up to ``n`` of ``items``, evenly spaced over them in order (the first and the last
    included); all of them when there are at most ``n``, none for ``n <= 0``."""
    if n <= 0:
        return []
    if len(items) <= n:
        return list(items)
    return [items[i] for i in np.linspace(0, len(items) - 1, n).round().astype(int)]
