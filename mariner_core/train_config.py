"""Settings of a MaRINeR training run and the learning-rate schedule both trainers share.

A run config is JSON: ``{"model": {MarinerConfig fields}, "sampler": {SamplerConfig fields},
"train": {TrainConfig fields}}``; unknown keys and sections raise. ``cpu-small`` and ``gpu`` are
packaged under ``mariner_core/configs``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from .config import MarinerConfig
from .data import SamplerConfig

__all__ = ["TrainConfig", "cosine_lr", "load_run_config"]


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings."""

    batch_size: int = 9
    steps: int = 100_000
    lr: float = 1e-4
    lr_min: float = 0.0
    time_schedule: bool = False
    train_iterations: int = 2
    lambda_rec: float = 1.0
    lambda_per: float = 0.1
    lambda_adv: float = 0.001
    gan_start: float | None = 0.75
    disc_lr: float = 1e-4
    val_fraction: float = 0.15
    split_gap: float = 60.0
    val_offset: float = 20.0
    val_frames: int = 16
    val_iterations: int = 1
    val_every_minutes: float = 5.0
    ckpt_every_minutes: float = 3.0
    log_every: int = 10
    seed: int = 42
    num_threads: int = 0
    device: str = "auto"
    pretrained_perceptual: bool = True


def _from_dict(cls: type, data: dict[str, Any]) -> Any:
    allowed = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - allowed)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} key(s) {unknown} (allowed: {sorted(allowed)})")
    if cls is SamplerConfig and "ref_resize" in data:
        data = {**data, "ref_resize": tuple(data["ref_resize"])}
    return cls(**data)


def load_run_config(name_or_path: str) -> tuple[MarinerConfig, SamplerConfig, TrainConfig]:
    """A packaged config name (``cpu-small``, ``gpu``) or a JSON file path."""
    p = Path(name_or_path)
    if p.suffix == ".json" or p.is_file():
        raw = json.loads(p.read_text())
    else:
        res = resources.files("mariner_core") / "configs" / f"{name_or_path}.json"
        if not res.is_file():
            raise ValueError(f"unknown config {name_or_path!r} (packaged: cpu-small, gpu)")
        raw = json.loads(res.read_text())
    unknown = sorted(set(raw) - {"model", "sampler", "train", "comment"})
    if unknown:
        raise ValueError(f"unknown config section(s) {unknown}")
    return (
        MarinerConfig.from_dict(raw.get("model", {})),
        _from_dict(SamplerConfig, raw.get("sampler", {})),
        _from_dict(TrainConfig, raw.get("train", {})),
    )


def cosine_lr(progress: float, lr: float, lr_min: float) -> float:
    """Cosine annealing from ``lr`` (progress 0) to ``lr_min`` (progress 1)."""
    p = min(max(progress, 0.0), 1.0)
    return lr_min + 0.5 * (lr - lr_min) * (1.0 + math.cos(math.pi * p))
