"""MaRINeR core: reference-based render enhancement (standalone PyTorch package).

Public API (imported lazily, so ``import mariner_core`` does not import torch):
``MarinerConfig``, ``Mariner``, ``Enhancer``, ``EnhanceResult``, ``save_checkpoint``,
``load_checkpoint``, ``scene_check`` / ``SceneCheck`` (decoder or matching-only base for a
scene, decided on the scene's own photos). Images are RGB float in [0, 1] everywhere.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "EnhanceResult",
    "Enhancer",
    "Mariner",
    "MarinerConfig",
    "SceneCheck",
    "load_checkpoint",
    "save_checkpoint",
    "scene_check",
]

_LAZY = {
    "MarinerConfig": "config",
    "Mariner": "model",
    "Enhancer": "enhancer",
    "EnhanceResult": "enhancer",
    "save_checkpoint": "enhancer",
    "load_checkpoint": "enhancer",
    "SceneCheck": "scene_check",
    "scene_check": "scene_check",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'mariner_core' has no attribute {name!r}")
