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
import time
from pathlib import Path
from typing import Any

from tqdm import tqdm

from .config import MarinerConfig
from .data import FrameCache, SamplerConfig
from .losses import PerceptualLoss
from .train_config import TrainConfig, cosine_lr, load_run_config
from .trainer import LOG_FIELDS, Trainer

logger = logging.getLogger(__name__)

__all__ = ["TrainConfig", "cosine_lr", "load_run_config", "main", "train"]


def _open_log(out: Path, resume: bool) -> tuple[Any, csv.DictWriter]:
    """``log.csv``: appended to on resume, else started with a header."""
    log_path = out / "log.csv"
    new_log = not log_path.is_file() or not resume
    log_file = log_path.open("w" if new_log else "a", newline="")
    writer = csv.DictWriter(log_file, fieldnames=LOG_FIELDS)
    if new_log:
        writer.writeheader()
    return log_file, writer


def _run_loop(
    tr: Trainer,
    total_steps: int,
    max_minutes: float | None,
    writer: csv.DictWriter,
    log_file: Any,
    bar: Any,
) -> None:
    """Steps until ``total_steps`` or the time budget; periodic log rows, validation, last.pt."""
    cfg, s = tr.cfg, tr.state
    t_ckpt = t_val = tr.t_start
    acc: dict[str, list[float]] = {}
    budget_s = None if max_minutes is None else max_minutes * 60.0
    while s.step < total_steps:
        if budget_s is not None and tr.elapsed() >= budget_s:
            logger.info("time budget of %.1f min reached at step %d", max_minutes, s.step)
            break
        prog = s.step / max(1, total_steps)
        if cfg.time_schedule and budget_s is not None:
            prog = max(prog, tr.elapsed() / budget_s)
        lr = cosine_lr(prog, cfg.lr, cfg.lr_min)
        for k, v in tr.step(prog, lr).items():
            acc.setdefault(k, []).append(v)
        bar.update(1)
        if s.step % cfg.log_every == 0 or s.step == total_steps:
            row, mean_loss = tr.loss_row(acc, lr)
            writer.writerow(row)
            log_file.flush()
            bar.set_postfix(loss=f"{mean_loss:.4f}", lr=f"{lr:.1e}")
            acc.clear()
        now = time.perf_counter()
        if now - t_val >= cfg.val_every_minutes * 60:
            tr.validate(writer, log_file)
            t_val = time.perf_counter()
        if now - t_ckpt >= cfg.ckpt_every_minutes * 60:
            tr.save_last()
            t_ckpt = time.perf_counter()


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
    tr = Trainer(model_cfg, sampler_cfg, cfg, data, out, perceptual)
    if resume:
        tr.resume()
    log_file, writer = _open_log(out, resume)
    tr.t_start = time.perf_counter()
    bar = tqdm(total=total_steps, initial=tr.state.step, disable=not progress, desc="train")
    try:
        _run_loop(tr, total_steps, max_minutes, writer, log_file, bar)
        tr.validate(writer, log_file)
        tr.save_last()
    finally:
        bar.close()
        log_file.close()
    s = tr.state
    summary = {
        "steps": s.step,
        "samples": s.samples,
        "elapsed_s": tr.elapsed(),
        "best_val_psnr": s.best,
    }
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
