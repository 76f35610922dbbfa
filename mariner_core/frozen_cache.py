"""Step 1 of training the ``cpu-frozen`` MaRINeR (``python -m mariner_core.train_frozen
cache``): the frozen matching of every training and validation triple, computed once and stored
(uint8 images, float16 similarity maps at 1/4 resolution), resumable. The layout of a stored
triple is ``layout``; ``train_frozen`` reads them back and trains on them."""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .data import (
    RENDER_VARIANTS,
    FrameCache,
    load_frame_cache,
    reference_candidates,
    split_frames,
    to_tensor,
)
from .frozen import FrozenMariner, FrozenMarinerConfig

logger = logging.getLogger(__name__)

__all__ = ["build_triples", "layout"]


#: channel layout of one cached triple (uint8): render 3, warped 3k, colour 3, target 3
def layout(k: int) -> dict[str, slice]:
    return {
        "render": slice(0, 3),
        "warped": slice(3, 3 + 3 * k),
        "colour": slice(3 + 3 * k, 6 + 3 * k),
        "target": slice(6 + 3 * k, 9 + 3 * k),
    }


def _u8(x: torch.Tensor) -> np.ndarray:
    return (x.clamp(0, 1) * 255.0).round().to(torch.uint8).numpy()


def _prepare_one(
    model: FrozenMariner, render: np.ndarray, ref: np.ndarray, target: np.ndarray,
    ref_features: torch.Tensor | None = None,
):
    prep = model.prepare(to_tensor(render)[None], to_tensor(ref)[None], low_res_scores=True,
                         reference_features=ref_features)
    x = prep["render"]
    tgt = F.pad(to_tensor(target)[None], (0, x.shape[-1] - target.shape[1],
                                            0, x.shape[-2] - target.shape[0]), mode="replicate")
    img = torch.cat([prep["render"], prep["warped"], prep["colour"], tgt], 1)[0]
    return _u8(img), prep["score"][0].half().numpy()


def build_triples(
    data: str | Path, out: str | Path, pairs: int = 2, val_offset: float = 20.0,
    val_every: int = 4, seed: int = 0, weights: str | Path | None = None,
    min_gap: float = 10.0, max_gap: float = 60.0, self_share: float = 0.0,
    exclude_mod: int | None = None, val_fraction: float = 0.15,
) -> None:
    """Write the cached matching of training and validation triples (see module docstring).

    References are drawn ``min_gap``..``max_gap`` frames (``t`` units) away, or with
    probability ``self_share`` are the frame's own photo (Ref = target: the model must learn to
    trust an exact reference as much as to doubt a far one). Frames with ``t % exclude_mod == 0``
    (a dataset's held-out evaluation frames) are never a target nor a reference. Validation is
    the pool's last ``val_fraction``, separated from training by ``max_gap``.
    """
    from .pretrained import backbone_state_dict

    if not 0.0 <= self_share <= 1.0 or not 0 <= min_gap <= max_gap:
        raise ValueError(f"bad reference settings: self_share {self_share}, gaps "
                         f"{min_gap}..{max_gap}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cache = load_frame_cache(data)
    keep = np.ones(len(cache.t), bool)
    if exclude_mod:
        keep = np.round(cache.t).astype(int) % int(exclude_mod) != 0
    pos = np.flatnonzero(keep)
    tr, va = split_frames(cache.t[pos], val_fraction=val_fraction, gap=max_gap)
    train_pos, val_pos = pos[tr], pos[va]
    cfg = FrozenMarinerConfig()
    model = FrozenMariner(cfg).eval()
    model.load_vgg(backbone_state_dict("vgg16"))
    rng = np.random.default_rng(seed)
    variants = [v for v in RENDER_VARIANTS if v in cache.images]
    jobs: list[tuple[int, int, str]] = []
    for i in train_pos:
        cand = reference_candidates(cache.t, int(i), train_pos, min_gap, max_gap)
        for v in variants:
            for _ in range(pairs):
                if rng.random() < self_share or not len(cand):
                    jobs.append((int(i), int(i), v))
                else:
                    jobs.append((int(i), int(rng.choice(cand)), v))
    jobs = [jobs[n] for n in rng.permutation(len(jobs))]  # any prefix is a random subset
    val_jobs: list[tuple[int, int, str, str]] = []
    for i in val_pos[::val_every]:
        d = np.abs(cache.t[val_pos] - (cache.t[i] + val_offset))
        d_b = np.abs(cache.t[val_pos] - (cache.t[i] - val_offset))
        j = val_pos[np.argmin(d)] if d.min() <= d_b.min() else val_pos[np.argmin(d_b)]
        for v in ("render", "render_colourless"):
            if v in cache.images and j != i:
                val_jobs.append((int(i), int(j), v, "offset"))
        if "render_colourless" in cache.images:
            val_jobs.append((int(i), int(i), "render_colourless", "ref_target"))
        val_jobs.append((int(i), int(i), "render", "ref_target"))
    meta = {
        "data": str(data), "pairs": pairs, "val_offset": val_offset, "seed": seed,
        "min_gap": min_gap, "max_gap": max_gap, "self_share": self_share,
        "exclude_mod": exclude_mod, "config": cfg.to_dict(), "train_jobs": jobs,
        "val_jobs": [list(j) for j in val_jobs],
    }
    (out / "triples.json").write_text(json.dumps(meta))
    _write_set(model, cache, [(i, j, v) for i, j, v, _ in val_jobs], out / "val", "val")
    _write_set(model, cache, jobs, out / "train", "train")


def _write_set(model: FrozenMariner, cache: FrameCache, jobs: list, stem: Path, name: str) -> None:
    img_path = stem.with_name(stem.name + "_images.npy")
    sc_path = stem.with_name(stem.name + "_scores.npy")
    done_path = stem.with_name(stem.name + "_done.json")
    done = json.loads(done_path.read_text())["n"] if done_path.is_file() else 0
    photo_features: dict[int, torch.Tensor] = {}  # each photo's relu3_3 once (~2 MB each)

    def prepared(n: int) -> tuple[np.ndarray, np.ndarray]:
        i, j, v = jobs[n]
        if j not in photo_features:
            photo_features[j] = model.features(to_tensor(cache.images["photo"][j])[None])
        return _prepare_one(model, cache.images[v][i], cache.images["photo"][j],
                            cache.images["photo"][i], photo_features[j])

    first = prepared(done if done < len(jobs) else 0)  # the array shapes
    mode = "r+" if img_path.is_file() and done > 0 else "w+"
    imgs = np.lib.format.open_memmap(img_path, mode=mode, dtype=np.uint8,
                                     shape=(len(jobs), *first[0].shape))
    scs = np.lib.format.open_memmap(sc_path, mode=mode, dtype=np.float16,
                                    shape=(len(jobs), *first[1].shape))
    t0 = time.perf_counter()
    for n in range(done, len(jobs)):
        imgs[n], scs[n] = first if n == done else prepared(n)
        if (n + 1) % 100 == 0 or n + 1 == len(jobs):
            imgs.flush()
            scs.flush()
            done_path.write_text(json.dumps({"n": n + 1}))
            el = time.perf_counter() - t0
            logger.info("%s: %d/%d triples (%.0f s, %.2f s each)", name, n + 1, len(jobs), el,
                        el / (n + 1 - done))
    imgs.flush()
    scs.flush()
    done_path.write_text(json.dumps({"n": len(jobs)}))
