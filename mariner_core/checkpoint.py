"""Reading a MaRINeR checkpoint file (``{"config", "state_dict", "meta"}``, written by
``enhancer.save_checkpoint``) without building a model: the one place both loaders
(``enhancer.load_checkpoint`` for any architecture, ``FrozenMariner.from_pretrained``) read it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

CHECKPOINT_KEYS = frozenset({"config", "state_dict", "meta"})


def read_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The checkpoint's dict, loaded with ``weights_only=True``; FileNotFoundError when there is
    no file, ValueError when it is not a MaRINeR checkpoint."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MaRINeR checkpoint not found: {path}")
    ckpt = torch.load(path, map_location=map_location, weights_only=True)
    if not isinstance(ckpt, dict) or set(ckpt) != CHECKPOINT_KEYS:
        keys = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise ValueError(
            f"{path} is not a MaRINeR checkpoint: expected keys "
            f"{sorted(CHECKPOINT_KEYS)}, got {keys}"
        )
    return ckpt
