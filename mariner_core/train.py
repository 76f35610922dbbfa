"""Train a MaRINeR generator on a frame cache (see ``mariner_core.data``).

::

    python -m mariner_core.train --config cpu-small|gpu|PATH.json --data CACHE_DIR --out RUN_DIR \
        [--resume] [--max-minutes M] [--steps N]

Config JSON: ``{"model": {MarinerConfig fields}, "sampler": {SamplerConfig fields},
"train": {TrainConfig fields}}`` (unknown keys raise). Losses (spec §6): the sum over training
iterations of ``L1 + lambda_per * VGG16 perceptual``; from ``gan_start`` (a fraction of the
schedule; ``null`` = never) the relativistic-average GAN term ``lambda_adv * L_G`` on the last
iteration is added and a VGG-style discriminator is trained alongside. Adam with a cosine
learning-rate schedule over the schedule's progress, which is ``step / steps`` or, with
``time_schedule`` and ``--max-minutes``, the larger of that and ``elapsed / max_minutes`` (so a run
on a shared, slow CPU still completes its schedule within the time budget).

Outputs in RUN_DIR: ``log.csv`` (one row per ``log_every`` steps plus validation rows),
``last.pt`` (resumable: model, discriminator, optimisers, step, elapsed time, RNG states),
``best.pt`` (best validation PSNR-Y, a plain ``save_checkpoint`` file) and ``config.json``.
Validation: fixed (frame, reference ``val_offset`` frames away) pairs of the validation range,
full frames, ``val_iterations`` iterations.
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import math
import random
import time
from dataclasses import asdict, dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from .config import MarinerConfig
from .data import (
    FrameCache,
    SamplerConfig,
    TripletSampler,
    fixed_pairs,
    load_frame_cache,
    split_frames,
    to_tensor,
)
from .enhancer import save_checkpoint
from .losses import (
    Discriminator,
    PerceptualLoss,
    discriminator_loss,
    generator_adversarial_loss,
    refinement_loss,
)
from .metrics import psnr_y
from .model import Mariner

logger = logging.getLogger(__name__)

__all__ = ["TrainConfig", "load_run_config", "main", "train"]

LOG_FIELDS = (
    "step",
    "samples",
    "elapsed_s",
    "lr",
    "loss",
    "l1",
    "perceptual",
    "g_adv",
    "d_loss",
    "val_psnr",
    "val_psnr_render",
)


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


def _seed_all(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def cosine_lr(progress: float, lr: float, lr_min: float) -> float:
    """Cosine annealing from ``lr`` (progress 0) to ``lr_min`` (progress 1)."""
    p = min(max(progress, 0.0), 1.0)
    return lr_min + 0.5 * (lr - lr_min) * (1.0 + math.cos(math.pi * p))


@torch.no_grad()
def validate(
    model: Mariner,
    cache: FrameCache,
    pairs: list[tuple[int, int]],
    iterations: int,
    device: torch.device,
) -> tuple[float, float]:
    """Mean PSNR-Y of (enhanced, raw render) vs the photo over full validation frames."""
    was_training = model.training
    model.eval()
    out, raw = [], []
    for i, j in pairs:
        x = to_tensor(cache.images["render"][i])[None].to(device)
        ref = to_tensor(cache.images["photo"][j])[None].to(device)
        tgt = to_tensor(cache.images["photo"][i])[None]
        y = model(x, ref, iterations=iterations)[-1].clamp(0, 1).cpu()
        out.append(float(psnr_y(y, tgt)[0]))
        raw.append(float(psnr_y(x.cpu(), tgt)[0]))
    model.train(was_training)
    return float(np.mean(out)) if out else float("nan"), float(np.mean(raw)) if raw else float(
        "nan"
    )


def _rng_state(rng: np.random.Generator) -> dict[str, Any]:
    return {
        "numpy": json.dumps(rng.bit_generator.state),
        "torch": torch.get_rng_state(),
    }


def train(
    model_cfg: MarinerConfig,
    sampler_cfg: SamplerConfig,
    cfg: TrainConfig,
    data: str | Path | FrameCache,
    out: str | Path,
    *,
    resume: bool = False,
    max_minutes: float | None = None,
    steps: int | None = None,
    perceptual: PerceptualLoss | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Run (or resume) training; returns a summary dict (steps, samples, elapsed, best val)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    total_steps = cfg.steps if steps is None else int(steps)
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    device = torch.device(
        ("cuda" if torch.cuda.is_available() else "cpu") if cfg.device == "auto" else cfg.device
    )
    _seed_all(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    cache = data if isinstance(data, FrameCache) else load_frame_cache(data)
    train_pos, val_pos = split_frames(cache.t, cfg.val_fraction, cfg.split_gap)
    sampler = TripletSampler(cache, train_pos, sampler_cfg)
    val_pairs = []
    if len(val_pos) > 1:
        pairs = fixed_pairs(cache.t, val_pos, cfg.val_offset)
        sel = np.linspace(0, len(pairs) - 1, min(cfg.val_frames, len(pairs))).round().astype(int)
        val_pairs = [pairs[k] for k in sorted(set(sel.tolist()))]
    logger.info(
        "frames: %d train (t %.0f..%.0f), %d val (t %.0f..%.0f), %d val pairs",
        len(train_pos),
        cache.t[train_pos[0]],
        cache.t[train_pos[-1]],
        len(val_pos),
        cache.t[val_pos[0]] if len(val_pos) else float("nan"),
        cache.t[val_pos[-1]] if len(val_pos) else float("nan"),
        len(val_pairs),
    )
    model = Mariner(model_cfg).to(device).train()
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    use_gan = cfg.gan_start is not None and cfg.lambda_adv > 0
    disc = Discriminator(input_size=sampler_cfg.crop).to(device).train() if use_gan else None
    d_opt = torch.optim.Adam(disc.parameters(), lr=cfg.disc_lr) if disc is not None else None
    if perceptual is None and cfg.lambda_per > 0:
        perceptual = PerceptualLoss.pretrained() if cfg.pretrained_perceptual else PerceptualLoss()
    if perceptual is not None:
        perceptual = perceptual.to(device)
    run_meta = {
        "model": model_cfg.to_dict(),
        "sampler": asdict(sampler_cfg),
        "train": asdict(cfg),
        "data": str(cache.root),
        "train_t": [float(cache.t[train_pos[0]]), float(cache.t[train_pos[-1]])],
        "val_t": [float(cache.t[val_pos[0]]), float(cache.t[val_pos[-1]])] if len(val_pos) else [],
    }
    (out / "config.json").write_text(json.dumps(run_meta, indent=1, default=str))

    step, samples, elapsed_before, best = 0, 0, 0.0, -float("inf")
    last_path = out / "last.pt"
    if resume and last_path.is_file():
        st = torch.load(last_path, map_location="cpu", weights_only=True)
        model.load_state_dict(st["model"], strict=True)
        opt.load_state_dict(st["opt"])
        if disc is not None and st.get("disc") is not None:
            disc.load_state_dict(st["disc"])
            d_opt.load_state_dict(st["d_opt"])
        step, samples = int(st["step"]), int(st["samples"])
        elapsed_before, best = float(st["elapsed_s"]), float(st["best"])
        rng.bit_generator.state = json.loads(st["rng"]["numpy"])
        torch.set_rng_state(st["rng"]["torch"])
        logger.info("resumed from %s at step %d (%.1f min)", last_path, step, elapsed_before / 60)

    def save_last() -> None:
        st = {
            "model": model.state_dict(),
            "opt": opt.state_dict(),
            "disc": disc.state_dict() if disc is not None else None,
            "d_opt": d_opt.state_dict() if d_opt is not None else None,
            "step": step,
            "samples": samples,
            "elapsed_s": elapsed_before + (time.perf_counter() - t_start),
            "best": best,
            "rng": _rng_state(rng),
        }
        tmp = last_path.with_suffix(".tmp")
        torch.save(st, tmp)
        tmp.replace(last_path)

    log_path = out / "log.csv"
    new_log = not log_path.is_file() or not resume
    log_file = log_path.open("w" if new_log else "a", newline="")
    writer = csv.DictWriter(log_file, fieldnames=LOG_FIELDS)
    if new_log:
        writer.writeheader()

    t_start = time.perf_counter()
    t_ckpt = t_val = t_start
    acc: dict[str, list[float]] = {}
    budget_s = None if max_minutes is None else max_minutes * 60.0
    bar = tqdm(total=total_steps, initial=step, disable=not progress, desc="train")

    def do_validate() -> None:
        nonlocal best
        if not val_pairs:
            return
        v, vr = validate(model, cache, val_pairs, cfg.val_iterations, device)
        row = {k: "" for k in LOG_FIELDS}
        row.update(step=step, samples=samples, elapsed_s=f"{elapsed():.1f}")
        row.update(val_psnr=f"{v:.3f}", val_psnr_render=f"{vr:.3f}")
        writer.writerow(row)
        log_file.flush()
        logger.info("step %d: val PSNR-Y %.2f dB (render %.2f dB)", step, v, vr)
        if v > best:
            best = v
            save_checkpoint(
                model,
                out / "best.pt",
                extra={"step": step, "samples": samples, "val_psnr_y": v, "elapsed_s": elapsed()},
            )

    def elapsed() -> float:
        return elapsed_before + time.perf_counter() - t_start

    try:
        while step < total_steps:
            if budget_s is not None and elapsed() >= budget_s:
                logger.info("time budget of %.1f min reached at step %d", max_minutes, step)
                break
            prog = step / max(1, total_steps)
            if cfg.time_schedule and budget_s is not None:
                prog = max(prog, elapsed() / budget_s)
            lr = cosine_lr(prog, cfg.lr, cfg.lr_min)
            for g in opt.param_groups:
                g["lr"] = lr
            render, ref, target = sampler.batch(cfg.batch_size, rng)
            render, ref, target = render.to(device), ref.to(device), target.to(device)
            outputs = model(render, ref, iterations=cfg.train_iterations)
            l1 = sum(float((y.detach() - target).abs().mean()) for y in outputs)
            loss = refinement_loss(outputs, target, perceptual, cfg.lambda_rec, cfg.lambda_per)
            rec = float(loss.detach())
            g_adv = d_l = float("nan")
            gan_on = use_gan and prog >= float(cfg.gan_start)
            if gan_on:
                fake = outputs[-1]
                disc.requires_grad_(False)
                g_loss = generator_adversarial_loss(disc(target).detach(), disc(fake))
                disc.requires_grad_(True)
                loss = loss + cfg.lambda_adv * g_loss
                g_adv = float(g_loss)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if gan_on:
                for g in d_opt.param_groups:
                    g["lr"] = cfg.disc_lr * lr / cfg.lr
                d_loss = discriminator_loss(disc(target), disc(outputs[-1].detach()))
                d_opt.zero_grad(set_to_none=True)
                d_loss.backward()
                d_opt.step()
                d_l = float(d_loss)
            step += 1
            samples += cfg.batch_size
            for k, v in (("loss", float(loss.detach())), ("l1", l1), ("rec", rec)):
                acc.setdefault(k, []).append(v)
            if gan_on:
                acc.setdefault("g_adv", []).append(g_adv)
                acc.setdefault("d_loss", []).append(d_l)
            bar.update(1)
            if step % cfg.log_every == 0 or step == total_steps:
                mean = {k: float(np.mean(v)) for k, v in acc.items()}
                row = {k: "" for k in LOG_FIELDS}
                per = (mean["rec"] - cfg.lambda_rec * mean["l1"]) / max(cfg.lambda_per, 1e-12)
                row.update(
                    step=step,
                    samples=samples,
                    elapsed_s=f"{elapsed():.1f}",
                    lr=f"{lr:.3e}",
                    loss=f"{mean['loss']:.5f}",
                    l1=f"{mean['l1']:.5f}",
                    perceptual=f"{per:.5f}" if perceptual is not None else "",
                    g_adv=f"{mean['g_adv']:.5f}" if "g_adv" in mean else "",
                    d_loss=f"{mean['d_loss']:.5f}" if "d_loss" in mean else "",
                )
                writer.writerow(row)
                log_file.flush()
                bar.set_postfix(loss=f"{mean['loss']:.4f}", lr=f"{lr:.1e}")
                acc.clear()
            now = time.perf_counter()
            if now - t_val >= cfg.val_every_minutes * 60:
                do_validate()
                t_val = time.perf_counter()
            if now - t_ckpt >= cfg.ckpt_every_minutes * 60:
                save_last()
                t_ckpt = time.perf_counter()
        do_validate()
        save_last()
    finally:
        bar.close()
        log_file.close()
    summary = {"steps": step, "samples": samples, "elapsed_s": elapsed(), "best_val_psnr": best}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    logger.info("done: %s", summary)
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Train a MaRINeR generator on a frame cache.")
    parser.add_argument("--config", required=True, help="cpu-small, gpu or a JSON file")
    parser.add_argument("--data", required=True, help="frame cache folder (index.json + npz)")
    parser.add_argument("--out", required=True, help="run folder (checkpoints, log.csv)")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--max-minutes", type=float, default=None)
    parser.add_argument("--steps", type=int, default=None, help="override train.steps")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    model_cfg, sampler_cfg, cfg = load_run_config(args.config)
    train(
        model_cfg,
        sampler_cfg,
        cfg,
        args.data,
        args.out,
        resume=args.resume,
        max_minutes=args.max_minutes,
        steps=args.steps,
        progress=not args.no_progress,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


def export_weights(
    run_checkpoint: str | Path,
    dst: str | Path,
    iterations: int | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Turn a run's ``last.pt`` (resumable) or ``best.pt`` into a shipped fp16 checkpoint.

    ``iterations`` overrides the stored default number of refinement iterations (it does not
    change the weights).
    """
    st = torch.load(run_checkpoint, map_location="cpu", weights_only=True)
    if "model" in st:  # resumable last.pt: the config comes from the run folder
        run_cfg = json.loads((Path(run_checkpoint).parent / "config.json").read_text())
        cfg = MarinerConfig.from_dict(run_cfg["model"])
        state, meta = (
            st["model"],
            {"step": st["step"], "samples": st["samples"], "elapsed_s": st["elapsed_s"]},
        )
    else:
        cfg = MarinerConfig.from_dict(dict(st["config"]))
        state = st["state_dict"]
        meta = {k: v for k, v in st["meta"].items() if k in ("step", "samples", "elapsed_s")}
    if iterations is not None:
        cfg = MarinerConfig.from_dict({**cfg.to_dict(), "iterations": int(iterations)})
    model = Mariner(cfg)
    model.load_state_dict(
        {k: v.float() if v.is_floating_point() else v for k, v in state.items()}, strict=True
    )
    meta.update(extra or {})
    return save_checkpoint(model, dst, extra=meta, fp16=True)
