"""Training smoke tests on tiny synthetic inputs: loss decreases, GAN phase runs, resume works."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from mariner_core.config import MarinerConfig
from mariner_core.data import FrameCache, SamplerConfig
from mariner_core.enhancer import load_checkpoint
from mariner_core.losses import PerceptualLoss
from mariner_core.train import TrainConfig, cosine_lr, load_run_config, train

TINY = MarinerConfig(channels=8, encoder_blocks=(1, 1, 1), decoder_blocks=(1, 1, 1), iterations=1)
SAMPLER = SamplerConfig(
    crop=32, ref_min_size=64, ref_max_size=64, ref_jitter=4, min_gap=2, max_gap=6
)


def _cache(n: int = 24, h: int = 64, w: int = 80) -> FrameCache:
    """Smooth random 'photos'; renders are a darker, colour-shifted copy (learnable mapping)."""
    rng = np.random.default_rng(0)
    base = rng.random((n, h // 8, w // 8, 3))
    photo = np.kron(base, np.ones((1, 8, 8, 1)))
    render = np.clip(photo * 0.5 + np.array([0.2, 0.0, 0.1]), 0, 1)
    u8 = lambda a: (a * 255).round().astype(np.uint8)  # noqa: E731
    return FrameCache(
        t=np.arange(n, dtype=float), images={"photo": u8(photo), "render": u8(render)}
    )


def _cfg(**kw) -> TrainConfig:
    base = dict(
        batch_size=2,
        steps=30,
        lr=2e-3,
        train_iterations=1,
        lambda_per=0.0,
        gan_start=None,
        val_fraction=0.25,
        split_gap=6,
        val_offset=3,
        val_frames=2,
        val_every_minutes=1e9,
        ckpt_every_minutes=1e9,
        log_every=1,
        num_threads=1,
        device="cpu",
        seed=0,
    )
    base.update(kw)
    return TrainConfig(**base)


def _losses(run) -> list[float]:
    with (run / "log.csv").open() as f:
        return [float(r["loss"]) for r in csv.DictReader(f) if r["loss"]]


def test_loss_decreases_and_checkpoints_load(tmp_path) -> None:
    run = tmp_path / "run"
    summary = train(TINY, SAMPLER, _cfg(), _cache(), run, progress=False)
    assert summary["steps"] == 30
    losses = _losses(run)
    assert np.mean(losses[-5:]) < 0.7 * np.mean(losses[:5])
    model = load_checkpoint(run / "best.pt")  # strict load of the best-validation checkpoint
    assert model.cfg == TINY
    assert (run / "last.pt").is_file() and json.loads((run / "summary.json").read_text())


def test_gan_phase_and_perceptual_run(tmp_path) -> None:
    run = tmp_path / "gan"
    cfg = _cfg(steps=3, gan_start=0.0, lambda_adv=1e-3, lambda_per=0.1)
    train(TINY, SAMPLER, cfg, _cache(), run, progress=False, perceptual=PerceptualLoss())
    with (run / "log.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["loss"]]
    assert all(np.isfinite(float(r["g_adv"])) and np.isfinite(float(r["d_loss"])) for r in rows)
    assert all(float(r["perceptual"]) > 0 for r in rows)


def test_resume_continues_from_last(tmp_path) -> None:
    run = tmp_path / "resume"
    train(TINY, SAMPLER, _cfg(steps=3), _cache(), run, progress=False)
    st = torch.load(run / "last.pt", weights_only=True)
    assert st["step"] == 3
    summary = train(TINY, SAMPLER, _cfg(steps=5), _cache(), run, resume=True, progress=False)
    assert summary["steps"] == 5 and summary["samples"] == 10
    assert [int(r["step"]) for r in csv.DictReader((run / "log.csv").open()) if r["loss"]] == [
        1,
        2,
        3,
        4,
        5,
    ]


def test_max_minutes_stops(tmp_path) -> None:
    summary = train(
        TINY, SAMPLER, _cfg(steps=1000), _cache(), tmp_path / "t", max_minutes=0.0, progress=False
    )
    assert summary["steps"] == 0


def test_packaged_configs_and_schedule() -> None:
    for name in ("cpu-small", "gpu"):
        model_cfg, sampler_cfg, cfg = load_run_config(name)
        assert sampler_cfg.crop % model_cfg.render_multiple == 0
        assert sampler_cfg.ref_min_size >= model_cfg.min_reference_size
        assert sampler_cfg.min_gap >= 10
    assert load_run_config("gpu")[0] == MarinerConfig(iterations=2)
    assert cosine_lr(0.0, 1e-4, 0.0) == pytest.approx(1e-4)
    assert cosine_lr(1.0, 1e-4, 0.0) == pytest.approx(0.0)
    with pytest.raises(ValueError):
        load_run_config("no-such-config")
