"""Training triples (render, reference, target) from a frame cache of plain ``npz`` files.

The cache (written e.g. by ``pgt_check.enhance.training_data``) is a folder with ``index.json``
(``{"frames": [{"t": frame_index, "file": "frame_000000.npz", ...}, ...]}``) and one ``npz`` per
frame holding uint8 RGB images ``photo``, ``render`` and optionally ``render_decimated`` /
``render_colourless``, all the same size. This module never renders and never imports
``pgt_check``.

Rules (all in frame-index units ``t``, the frame's timestamp):

* **split**: frames sorted by ``t``; the last ``val_fraction`` form the validation range; the
  training range ends ``gap`` frames before it, so no reference window crosses the split
  (``split_frames``).
* **pairing**: the reference of a frame is another frame *of the same split* with
  ``min_gap <= |t_ref - t| <= max_gap`` (``reference_candidates``), drawn uniformly among them
  at every sample (random reference distance). Adjacent frames (a few ``t`` away) are never
  used: at 30 Hz they nearly equal the target and teach the model to copy the reference.
* **samples**: a random aligned ``crop x crop`` window of (render variant, target photo); the
  render variant is the decimated-mesh render with probability ``p_decimated``, the colourless
  render with ``p_colourless``, else the coloured render; the reference is a crop of the
  reference photo around the same window (jittered), with a per-batch size, optionally resized;
  a joint horizontal flip.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

logger = logging.getLogger(__name__)

__all__ = [
    "FrameCache",
    "SamplerConfig",
    "TripletSampler",
    "fixed_pairs",
    "load_frame_cache",
    "reference_candidates",
    "split_frames",
    "spread_pairs",
    "to_tensor",
]

RENDER_VARIANTS = ("render", "render_decimated", "render_colourless")


@dataclass
class FrameCache:
    """All frames of one cache in memory: ``images[variant]`` is (N, H, W, 3) uint8."""

    t: np.ndarray
    images: dict[str, np.ndarray]
    frame_ids: list[str] = field(default_factory=list)
    root: Path | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) of the stored images."""
        h, w = self.images["photo"].shape[1:3]
        return int(h), int(w)


def load_frame_cache(root: str | Path, variants: tuple[str, ...] | None = None) -> FrameCache:
    """Read ``index.json`` and every frame file (sorted by ``t``) into memory."""
    root = Path(root)
    index = json.loads((root / "index.json").read_text())
    records = sorted(index["frames"], key=lambda r: r["t"])
    if not records:
        raise ValueError(f"{root}: empty frame cache")
    stacks: dict[str, list[np.ndarray]] = {}
    for r in records:
        with np.load(root / r["file"]) as d:
            keys = d.files if variants is None else [k for k in ("photo", *variants) if k in d]
            for k in keys:
                stacks.setdefault(k, []).append(d[k])
    images = {k: np.stack(v) for k, v in stacks.items() if len(v) == len(records)}
    if "photo" not in images or "render" not in images:
        raise ValueError(f"{root}: frames need at least 'photo' and 'render'")
    t = np.array([float(r["t"]) for r in records])
    logger.info("loaded %d frames %s from %s", len(t), sorted(images), root)
    return FrameCache(
        t=t, images=images, frame_ids=[str(r["frame_id"]) for r in records], root=root
    )


def split_frames(
    t: np.ndarray, val_fraction: float = 0.15, gap: float = 60.0
) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous split: (train positions, validation positions) into the ``t``-sorted frames.

    Validation = the last ``ceil(val_fraction * n)`` frames; training = frames with
    ``t <= t_val_start - gap`` (frames inside the gap are unused).
    """
    t = np.asarray(t, dtype=float)
    if np.any(np.diff(t) <= 0):
        raise ValueError("frame times must be strictly increasing")
    n = len(t)
    n_val = int(np.ceil(val_fraction * n)) if val_fraction > 0 else 0
    if n_val >= n:
        raise ValueError(f"val_fraction {val_fraction} leaves no training frames")
    if n_val == 0:
        return np.arange(n), np.arange(0)
    val = np.arange(n - n_val, n)
    train = np.flatnonzero(t <= t[val[0]] - gap)
    return train, val


def reference_candidates(
    t: np.ndarray, i: int, allowed: np.ndarray, min_gap: float, max_gap: float
) -> np.ndarray:
    """Positions ``j`` in ``allowed`` (``j != i``) with ``min_gap <= |t[j] - t[i]| <= max_gap``."""
    allowed = np.asarray(allowed, dtype=int)
    d = np.abs(np.asarray(t, dtype=float)[allowed] - float(t[i]))
    return allowed[(d >= min_gap) & (d <= max_gap) & (allowed != i)]


def fixed_pairs(t: np.ndarray, positions: np.ndarray, offset: float) -> list[tuple[int, int]]:
    """(frame, reference) with the reference ``offset`` frames later (earlier at the end),
    the nearest available within ``positions``; used for deterministic validation."""
    positions = np.asarray(positions, dtype=int)
    t = np.asarray(t, dtype=float)
    out = []
    for i in positions:
        d_fwd = t[positions] - (t[i] + offset)
        d_bwd = t[positions] - (t[i] - offset)
        fwd = positions[np.argmin(np.abs(d_fwd))]
        bwd = positions[np.argmin(np.abs(d_bwd))]
        j = fwd if t[i] + offset <= t[positions[-1]] else bwd
        if j != i:
            out.append((int(i), int(j)))
    return out


def spread_pairs(
    t: np.ndarray, positions: np.ndarray, offset: float, n: int
) -> list[tuple[int, int]]:
    """At most ``n`` of the :func:`fixed_pairs`, spread evenly over ``positions``."""
    if len(positions) <= 1:
        return []
    pairs = fixed_pairs(t, positions, offset)
    sel = np.linspace(0, len(pairs) - 1, min(n, len(pairs))).round().astype(int)
    return [pairs[k] for k in sorted(set(sel.tolist()))]


@dataclass(frozen=True)
class SamplerConfig:
    """Sampling / augmentation settings (see the module docstring)."""

    crop: int = 96
    ref_min_size: int = 96
    ref_max_size: int = 160
    ref_multiple: int = 16
    ref_jitter: int = 24
    ref_resize: tuple[float, float] = (1.0, 1.0)
    min_gap: float = 10.0
    max_gap: float = 60.0
    p_decimated: float = 0.2
    p_colourless: float = 0.3
    p_flip: float = 0.5


def to_tensor(img: np.ndarray) -> torch.Tensor:
    """(…, H, W, 3) uint8 -> (…, 3, H, W) float32 in [0, 1]."""
    t = torch.from_numpy(np.ascontiguousarray(img)).float().div_(255.0)
    return t.movedim(-1, -3)


class TripletSampler:
    """Draws batches of aligned crops from the frames ``positions`` of a :class:`FrameCache`."""

    def __init__(self, cache: FrameCache, positions: np.ndarray, cfg: SamplerConfig) -> None:
        self.cache = cache
        self.cfg = cfg
        self.positions = np.asarray(positions, dtype=int)
        h, w = cache.size
        if cfg.crop > min(h, w):
            raise ValueError(f"crop {cfg.crop} exceeds the image size {h}x{w}")
        if cfg.ref_min_size > min(h, w):
            raise ValueError(f"ref_min_size {cfg.ref_min_size} exceeds the image size {h}x{w}")
        self.candidates = {
            int(i): reference_candidates(cache.t, int(i), self.positions, cfg.min_gap, cfg.max_gap)
            for i in self.positions
        }
        self.usable = np.array([i for i, c in self.candidates.items() if len(c)], dtype=int)
        if not len(self.usable):
            raise ValueError("no frame has a reference candidate in the given window")
        self.variants = [v for v in RENDER_VARIANTS if v in cache.images]

    def _variant(self, rng: np.random.Generator) -> str:
        u = rng.random()
        if u < self.cfg.p_decimated and "render_decimated" in self.cache.images:
            return "render_decimated"
        if u < self.cfg.p_decimated + self.cfg.p_colourless and (
            "render_colourless" in self.cache.images
        ):
            return "render_colourless"
        return "render"

    def draw(self, rng: np.random.Generator) -> tuple[int, int, str, int, int]:
        """One (frame, reference, variant, crop y, crop x) choice."""
        i = int(rng.choice(self.usable))
        j = int(rng.choice(self.candidates[i]))
        h, w = self.cache.size
        c = self.cfg.crop
        y = int(rng.integers(0, h - c + 1))
        x = int(rng.integers(0, w - c + 1))
        return i, j, self._variant(rng), y, x

    def batch(
        self, batch_size: int, rng: np.random.Generator
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> (render, reference, target) float tensors (B, 3, ...), one reference size per batch."""
        cfg = self.cfg
        h, w = self.cache.size
        m = cfg.ref_multiple
        lo, hi = cfg.ref_min_size, cfg.ref_max_size
        rh = min(h, int(rng.integers(lo // m, hi // m + 1)) * m)
        rw = min(w, int(rng.integers(lo // m, hi // m + 1)) * m)
        renders, refs, targets = [], [], []
        c = cfg.crop
        for _ in range(batch_size):
            i, j, variant, y, x = self.draw(rng)
            r = self.cache.images[variant][i, y : y + c, x : x + c]
            tgt = self.cache.images["photo"][i, y : y + c, x : x + c]
            cy = y + c // 2 + int(rng.integers(-cfg.ref_jitter, cfg.ref_jitter + 1))
            cx = x + c // 2 + int(rng.integers(-cfg.ref_jitter, cfg.ref_jitter + 1))
            ry = int(np.clip(cy - rh // 2, 0, h - rh))
            rx = int(np.clip(cx - rw // 2, 0, w - rw))
            ref = self.cache.images["photo"][j, ry : ry + rh, rx : rx + rw]
            if rng.random() < cfg.p_flip:
                r, tgt, ref = r[:, ::-1], tgt[:, ::-1], ref[:, ::-1]
            renders.append(r)
            targets.append(tgt)
            refs.append(ref)
        ref_t = to_tensor(np.stack(refs))
        s = float(rng.uniform(*cfg.ref_resize))
        if s != 1.0:
            size = (max(60, round(rh * s)), max(60, round(rw * s)))
            ref_t = F.interpolate(
                ref_t, size=size, mode="bilinear", align_corners=False, antialias=True
            ).clamp_(0, 1)
        return to_tensor(np.stack(renders)), ref_t, to_tensor(np.stack(targets))
