"""Training triples: split / pairing rules, no leakage across splits, aligned crops."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mariner_core.data import (
    FrameCache,
    SamplerConfig,
    TripletSampler,
    fixed_pairs,
    load_frame_cache,
    reference_candidates,
    split_frames,
)

# the 7-Scenes training pool: frame indices 1..999 whose index mod 10 is neither 0 nor 5
POOL_T = np.array([t for t in range(1, 1000) if t % 10 not in (0, 5)], dtype=float)


def _coord_cache(t: np.ndarray, h: int = 40, w: int = 56) -> FrameCache:
    """Images encode (row, column, frame position) so crops can be traced back."""
    n = len(t)
    yy, xx = np.mgrid[0:h, 0:w]
    photo = np.zeros((n, h, w, 3), np.uint8)
    photo[..., 0] = yy
    photo[..., 1] = xx
    photo[..., 2] = np.arange(n)[:, None, None]
    render = photo.copy()
    render[..., 2] = 250  # renders differ from photos, same geometry
    dec = render.copy()
    dec[..., 2] = 200
    colourless = render.copy()
    colourless[..., 2] = 100
    return FrameCache(
        t=np.asarray(t, float),
        images={
            "photo": photo,
            "render": render,
            "render_decimated": dec,
            "render_colourless": colourless,
        },
    )


def test_split_is_contiguous_with_gap() -> None:
    train, val = split_frames(POOL_T, val_fraction=0.15, gap=60)
    assert len(val) == 120 and val[-1] == len(POOL_T) - 1
    assert np.all(np.diff(train) == 1) and np.all(np.diff(val) == 1)
    assert POOL_T[val[0]] - POOL_T[train[-1]] >= 60
    assert set(train).isdisjoint(val)


def test_reference_window_and_split_respected() -> None:
    train, val = split_frames(POOL_T, 0.15, 60)
    for i in train[::37]:
        c = reference_candidates(POOL_T, int(i), train, 10, 60)
        assert len(c) > 0 and i not in c
        d = np.abs(POOL_T[c] - POOL_T[i])
        assert d.min() >= 10 and d.max() <= 60
        assert set(c) <= set(train)  # never a validation frame
    # the adjacent frame (1 apart) is never a candidate
    assert 1 not in reference_candidates(POOL_T, 0, train, 10, 60)


def test_sampler_crops_aligned_and_no_leakage() -> None:
    t = POOL_T[:200]
    cache = _coord_cache(t)
    train, val = split_frames(t, 0.2, 60)
    cfg = SamplerConfig(crop=32, ref_min_size=32, ref_max_size=48, ref_jitter=4, p_flip=0.5)
    sampler = TripletSampler(cache, train, cfg)
    rng = np.random.default_rng(0)
    seen_variants = set()
    for _ in range(20):
        render, ref, target = sampler.batch(4, rng)
        assert render.shape == target.shape == (4, 3, 32, 32)
        assert ref.shape[0] == 4 and min(ref.shape[-2:]) >= 32
        r = (render * 255).round().numpy().astype(int)
        g = (target * 255).round().numpy().astype(int)
        f = (ref * 255).round().numpy().astype(int)
        # aligned: same pixel coordinates in render and target
        assert np.array_equal(r[:, :2], g[:, :2])
        for b in range(4):
            i = int(g[b, 2, 0, 0])
            j = int(f[b, 2, 0, 0])
            assert i in train and j in train
            assert 10 <= abs(t[j] - t[i]) <= 60
            seen_variants.add(int(r[b, 2, 0, 0]))
    assert seen_variants == {250, 200, 100}


def test_sampler_rejects_small_images() -> None:
    cache = _coord_cache(POOL_T[:50], h=40, w=40)
    with pytest.raises(ValueError):
        TripletSampler(cache, np.arange(50), SamplerConfig(crop=64))


def test_fixed_pairs_offset() -> None:
    pos = np.arange(0, 200)
    t = POOL_T
    pairs = fixed_pairs(t, pos, 20)
    assert pairs and all(i != j and j in pos for i, j in pairs)
    assert all(abs(abs(t[j] - t[i]) - 20) <= 3 for i, j in pairs)


def test_load_frame_cache_roundtrip(tmp_path) -> None:
    cache = _coord_cache(POOL_T[:3], h=8, w=10)
    recs = []
    for n in (2, 0, 1):  # written out of order; loaded sorted by t
        name = f"f{n}.npz"
        np.savez(tmp_path / name, **{k: v[n] for k, v in cache.images.items()})
        recs.append({"t": float(cache.t[n]), "file": name, "frame_id": str(n)})
    (tmp_path / "index.json").write_text(json.dumps({"frames": recs}))
    loaded = load_frame_cache(tmp_path)
    assert np.array_equal(loaded.t, cache.t)
    for k in cache.images:
        assert np.array_equal(loaded.images[k], cache.images[k])
