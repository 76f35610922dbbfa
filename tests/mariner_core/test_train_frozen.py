"""The cpu-frozen trainer on a tiny synthetic frame cache: cache, train, best checkpoint, resume."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from mariner_core.enhancer import load_checkpoint
from mariner_core.frozen import FrozenMariner
from mariner_core.train_frozen import TrainSettings, build_triples, train


def _write_cache(root, n: int = 24, h: int = 48, w: int = 64) -> None:
    """Smooth random photos 10 time units apart; renders are a darker, tinted copy."""
    rng = np.random.default_rng(0)
    base = rng.random((n, h // 8, w // 8, 3))
    photo = np.kron(base, np.ones((1, 8, 8, 1)))
    render = np.clip(photo * 0.5 + np.array([0.2, 0.0, 0.1]), 0, 1)
    u8 = lambda a: (a * 255).round().astype(np.uint8)  # noqa: E731
    root.mkdir()
    frames = []
    for i in range(n):
        name = f"frame_{i:06d}.npz"
        np.savez(root / name, photo=u8(photo[i]), render=u8(render[i]),
                 render_colourless=u8(render[i].mean(-1, keepdims=True).repeat(3, -1)))
        frames.append({"frame_id": str(i), "t": 10.0 * i, "file": name})
    (root / "index.json").write_text(json.dumps({"frames": frames}))


@pytest.fixture()
def run(tmp_path, converted_weights):
    _write_cache(tmp_path / "cache")
    build_triples(tmp_path / "cache", tmp_path / "run", pairs=1)
    return tmp_path / "run"


SMALL = TrainSettings(crop=32, batch_size=2, val_every_minutes=0.02, ckpt_every_minutes=0.01,
                      threads=1, channels=4, blocks=(1, 1, 1))


def _log(run) -> list[dict]:
    with (run / "log.csv").open() as f:
        return list(csv.DictReader(f))


def test_cache_train_checkpoint_and_resume(run) -> None:
    meta = json.loads((run / "triples.json").read_text())
    n_train = json.loads((run / "train_done.json").read_text())["n"]
    assert n_train == len(meta["train_jobs"]) > 0
    # every training reference is 10-60 time units away from its frame, in the training range
    assert all(10 <= 10 * abs(i - j) <= 60 for i, j, _ in meta["train_jobs"])
    kinds = {tuple(j[2:]) for j in meta["val_jobs"]}
    assert ("render", "offset") in kinds and ("render_colourless", "ref_target") in kinds
    imgs = np.load(run / "train_images.npy", mmap_mode="r")
    assert imgs.shape[1] == 3 + 3 * 4 + 3 + 3 and imgs.shape[2:] == (48, 64)

    best = train(run, max_minutes=0.05, settings=SMALL, resume=False)
    rows = _log(run)
    assert len(rows) >= 2 and int(rows[-1]["step"]) > 0
    assert all(np.isfinite(float(r["val_mean"])) for r in rows)
    model = load_checkpoint(best)
    assert isinstance(model, FrozenMariner) and model.cfg.channels == 4
    ck = torch.load(run / "last.pt", weights_only=False)
    steps = ck["state"]["step"]
    train(run, max_minutes=0.1, settings=SMALL, resume=True)
    assert torch.load(run / "last.pt", weights_only=False)["state"]["step"] > steps


def test_init_from_weights_must_match(run, tmp_path) -> None:
    from mariner_core.enhancer import save_checkpoint
    from mariner_core.train_frozen import _validate

    best = train(run, max_minutes=0.02, settings=SMALL, resume=False)
    start = load_checkpoint(best)
    with torch.no_grad():
        start.head.bias.fill_(0.3)  # far from anything the short run could reach
    init = save_checkpoint(start, tmp_path / "init.pt")
    other = tmp_path / "other"
    other.mkdir()
    for f in run.iterdir():
        if f.suffix in (".npy", ".json"):
            (other / f.name).symlink_to(f)
    train(other, max_minutes=0.02, settings=SMALL, resume=False, init=init)
    # the first validation of the new run scores the weights it started from
    jobs = json.loads((run / "triples.json").read_text())["val_jobs"]
    res = _validate(start, np.load(run / "val_images.npy"), np.load(run / "val_scores.npy"), 4,
                    jobs)
    want = (res["coloured_offset"] + res["colourless_offset"]) / 2
    assert float(_log(other)[0]["val_mean"]) == pytest.approx(want, abs=0.01)
    assert float(_log(run)[0]["val_mean"]) > want + 1.0  # the zero-initialised start differs
    wider = TrainSettings(**{**SMALL.__dict__, "channels": 8})
    with pytest.raises(ValueError, match="config"):
        train(other, max_minutes=0.02, settings=wider, resume=False, init=init)


def test_recolour_changes_reference_and_target_together_not_render() -> None:
    """Colour augmentation: one change per sample on the warped references, the colour-transferred
    render and the target; the render is left alone; share 0 changes nothing."""
    from mariner_core.train_frozen import _recolour

    rng = np.random.default_rng(3)
    same = torch.rand(6, 3, 8, 8) * 0.9 + 0.05
    prep = {"render": same.clone(), "warped": same.repeat(1, 4, 1, 1),
            "colour": same.clone(), "score": torch.rand(6, 4, 8, 8)}
    target = _recolour(prep, same.clone(), 1.0, rng)
    assert torch.equal(prep["render"], same)
    assert (target - same).abs().mean() > 0.02  # it did change the colours
    for k in range(4):  # the same change on every warped reference, the colour input and target
        assert torch.allclose(prep["warped"][:, 3 * k : 3 * k + 3], target, atol=1e-6)
    assert torch.allclose(prep["colour"], target, atol=1e-6)
    untouched = {"warped": same.repeat(1, 4, 1, 1), "colour": same.clone()}
    assert torch.allclose(_recolour(untouched, same.clone(), 0.0, rng), same, atol=1e-6)


def test_references_at_varied_distances_and_held_out_frames(tmp_path, converted_weights) -> None:
    """Held-out frames (t % N == 0) are never a target nor a reference; some references are
    the frame itself (Ref = target), the others lie within the gaps asked for."""
    _write_cache(tmp_path / "cache", n=30)
    build_triples(tmp_path / "cache", tmp_path / "run", pairs=2, min_gap=10, max_gap=30,
                  self_share=0.3, exclude_mod=50, seed=2)
    meta = json.loads((tmp_path / "run" / "triples.json").read_text())
    jobs = [tuple(j) for j in meta["train_jobs"]] + [tuple(j[:3]) for j in meta["val_jobs"]]
    assert all(10 * i % 50 != 0 and 10 * j % 50 != 0 for i, j, _ in jobs)
    train_jobs = meta["train_jobs"]
    selfs = [1 for i, j, _ in train_jobs if i == j]
    assert 0.1 < len(selfs) / len(train_jobs) < 0.5
    assert all(10 <= 10 * abs(i - j) <= 30 for i, j, _ in train_jobs if i != j)


def test_training_on_several_scenes_logs_each_scene(tmp_path, converted_weights) -> None:
    """Two triple caches trained together: the log has each scene's own columns and their
    mean; the best checkpoint is a gated model."""
    for name in ("scene_a", "scene_b"):
        _write_cache(tmp_path / f"{name}_frames")
        build_triples(tmp_path / f"{name}_frames", tmp_path / name, pairs=1)
    gated = TrainSettings(**{**SMALL.__dict__, "gated": True, "render_aug": 0.5,
                             "colour_aug": 0.5})
    best = train(tmp_path / "both", max_minutes=0.03, settings=gated, resume=False,
                 caches=[tmp_path / "scene_a", tmp_path / "scene_b"])
    rows = _log(tmp_path / "both")
    first = rows[0]
    a, b = float(first["scene_a/val_mean"]), float(first["scene_b/val_mean"])
    assert float(first["val_mean"]) == pytest.approx((a + b) / 2, abs=0.002)
    # a new gated decoder is the matching-only base
    assert float(first["scene_a/coloured_offset"]) == pytest.approx(
        float(first["scene_a/coloured_offset_base"]), abs=1e-3)
    assert int(rows[-1]["step"]) > 0
    assert load_checkpoint(best).cfg.gated


def test_render_reshading_changes_only_the_render() -> None:
    from mariner_core.train_frozen import _reshade_render

    rng = np.random.default_rng(0)
    x = torch.rand(5, 3, 8, 8) * 0.8 + 0.1
    prep = {"render": x.clone(), "warped": x.repeat(1, 4, 1, 1), "colour": x.clone()}
    _reshade_render(prep, 1.0, rng)
    assert (prep["render"] - x).abs().mean() > 0.01
    assert torch.equal(prep["warped"], x.repeat(1, 4, 1, 1)) and torch.equal(prep["colour"], x)
    same = {"render": x.clone()}
    _reshade_render(same, 0.0, rng)
    assert torch.equal(same["render"], x)
