"""One MaRINeR training run's state: the networks, optimisers, data, validation and bookkeeping
that ``mariner_core.train.train`` drives step by step (``Trainer``), and what ``last.pt`` carries
across a resume (``Progress``)."""

from __future__ import annotations

import csv
import json
import logging
import random
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .config import MarinerConfig
from .data import (
    FrameCache,
    SamplerConfig,
    TripletSampler,
    load_frame_cache,
    split_frames,
    spread_pairs,
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
from .train_config import TrainConfig

logger = logging.getLogger(__name__)

__all__ = ["LOG_FIELDS", "Progress", "Trainer", "validate"]

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


def _seed_all(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


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


def _resolve_device(name: str) -> torch.device:
    return torch.device(
        ("cuda" if torch.cuda.is_available() else "cpu") if name == "auto" else name
    )


def _log_split(cache: FrameCache, train_pos: np.ndarray, val_pos: np.ndarray, n_pairs: int) -> None:
    logger.info(
        "frames: %d train (t %.0f..%.0f), %d val (t %.0f..%.0f), %d val pairs",
        len(train_pos),
        cache.t[train_pos[0]],
        cache.t[train_pos[-1]],
        len(val_pos),
        cache.t[val_pos[0]] if len(val_pos) else float("nan"),
        cache.t[val_pos[-1]] if len(val_pos) else float("nan"),
        n_pairs,
    )


@dataclass
class Progress:
    """What ``last.pt`` carries across a resume."""

    step: int = 0
    samples: int = 0
    elapsed_before: float = 0.0
    best: float = -float("inf")


class Trainer:
    """One training run: the networks, optimisers, data and bookkeeping that ``train`` drives."""

    def __init__(
        self,
        model_cfg: MarinerConfig,
        sampler_cfg: SamplerConfig,
        cfg: TrainConfig,
        data: str | Path | FrameCache,
        out: Path,
        perceptual: PerceptualLoss | None,
    ) -> None:
        # the construction order fixes the RNG streams: seed, data, model, discriminator, VGG
        self.cfg, self.out = cfg, out
        if cfg.num_threads:
            torch.set_num_threads(cfg.num_threads)
        self.device = _resolve_device(cfg.device)
        _seed_all(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.cache = data if isinstance(data, FrameCache) else load_frame_cache(data)
        train_pos, val_pos = split_frames(self.cache.t, cfg.val_fraction, cfg.split_gap)
        self.sampler = TripletSampler(self.cache, train_pos, sampler_cfg)
        self.val_pairs = spread_pairs(self.cache.t, val_pos, cfg.val_offset, cfg.val_frames)
        _log_split(self.cache, train_pos, val_pos, len(self.val_pairs))
        self.model = Mariner(model_cfg).to(self.device).train()
        self.opt = torch.optim.Adam(self.model.parameters(), lr=cfg.lr)
        self.use_gan = cfg.gan_start is not None and cfg.lambda_adv > 0
        self.disc = (
            Discriminator(input_size=sampler_cfg.crop).to(self.device).train()
            if self.use_gan
            else None
        )
        self.d_opt = (
            torch.optim.Adam(self.disc.parameters(), lr=cfg.disc_lr)
            if self.disc is not None
            else None
        )
        if perceptual is None and cfg.lambda_per > 0:
            perceptual = (
                PerceptualLoss.pretrained() if cfg.pretrained_perceptual else PerceptualLoss()
            )
        self.perceptual = perceptual.to(self.device) if perceptual is not None else None
        run_meta = {
            "model": model_cfg.to_dict(),
            "sampler": asdict(sampler_cfg),
            "train": asdict(cfg),
            "data": str(self.cache.root),
            "train_t": [float(self.cache.t[train_pos[0]]), float(self.cache.t[train_pos[-1]])],
            "val_t": (
                [float(self.cache.t[val_pos[0]]), float(self.cache.t[val_pos[-1]])]
                if len(val_pos)
                else []
            ),
        }
        (out / "config.json").write_text(json.dumps(run_meta, indent=1, default=str))
        self.last_path = out / "last.pt"
        self.state = Progress()
        self.t_start = time.perf_counter()

    def elapsed(self) -> float:
        return self.state.elapsed_before + time.perf_counter() - self.t_start

    def resume(self) -> None:
        """Load ``last.pt`` (networks, optimisers, counters, RNG states) if it exists."""
        if not self.last_path.is_file():
            return
        st = torch.load(self.last_path, map_location="cpu", weights_only=True)
        self.model.load_state_dict(st["model"], strict=True)
        self.opt.load_state_dict(st["opt"])
        if self.disc is not None and st.get("disc") is not None:
            assert self.d_opt is not None  # built with the discriminator
            self.disc.load_state_dict(st["disc"])
            self.d_opt.load_state_dict(st["d_opt"])
        self.state = Progress(
            int(st["step"]), int(st["samples"]), float(st["elapsed_s"]), float(st["best"])
        )
        self.rng.bit_generator.state = json.loads(st["rng"]["numpy"])
        torch.set_rng_state(st["rng"]["torch"])
        logger.info(
            "resumed from %s at step %d (%.1f min)",
            self.last_path,
            self.state.step,
            self.state.elapsed_before / 60,
        )

    def save_last(self) -> None:
        st = {
            "model": self.model.state_dict(),
            "opt": self.opt.state_dict(),
            "disc": self.disc.state_dict() if self.disc is not None else None,
            "d_opt": self.d_opt.state_dict() if self.d_opt is not None else None,
            "step": self.state.step,
            "samples": self.state.samples,
            "elapsed_s": self.elapsed(),
            "best": self.state.best,
            "rng": _rng_state(self.rng),
        }
        tmp = self.last_path.with_suffix(".tmp")
        torch.save(st, tmp)
        tmp.replace(self.last_path)

    def validate(self, writer: csv.DictWriter, log_file: Any) -> None:
        """One validation row in the log; ``best.pt`` when PSNR-Y improves."""
        if not self.val_pairs:
            return
        s = self.state
        v, vr = validate(
            self.model, self.cache, self.val_pairs, self.cfg.val_iterations, self.device
        )
        row: dict[str, Any] = {k: "" for k in LOG_FIELDS}
        row.update(step=s.step, samples=s.samples, elapsed_s=f"{self.elapsed():.1f}")
        row.update(val_psnr=f"{v:.3f}", val_psnr_render=f"{vr:.3f}")
        writer.writerow(row)
        log_file.flush()
        logger.info("step %d: val PSNR-Y %.2f dB (render %.2f dB)", s.step, v, vr)
        if v > s.best:
            s.best = v
            save_checkpoint(
                self.model,
                self.out / "best.pt",
                extra={
                    "step": s.step,
                    "samples": s.samples,
                    "val_psnr_y": v,
                    "elapsed_s": self.elapsed(),
                },
            )

    def step(self, prog: float, lr: float) -> dict[str, float]:
        """One optimisation step at schedule progress ``prog``; returns the step's losses."""
        cfg = self.cfg
        for g in self.opt.param_groups:
            g["lr"] = lr
        render, ref, target = self.sampler.batch(cfg.batch_size, self.rng)
        render, ref, target = render.to(self.device), ref.to(self.device), target.to(self.device)
        outputs = self.model(render, ref, iterations=cfg.train_iterations)
        l1 = sum(float((y.detach() - target).abs().mean()) for y in outputs)
        loss = refinement_loss(outputs, target, self.perceptual, cfg.lambda_rec, cfg.lambda_per)
        rec = float(loss.detach())
        gan_on = self.use_gan and cfg.gan_start is not None and prog >= float(cfg.gan_start)
        losses: dict[str, float] = {}
        disc, d_opt = self.disc, self.d_opt
        if gan_on:
            assert disc is not None and d_opt is not None  # built where use_gan
            disc.requires_grad_(False)
            g_loss = generator_adversarial_loss(disc(target).detach(), disc(outputs[-1]))
            disc.requires_grad_(True)
            loss = loss + cfg.lambda_adv * g_loss
            losses["g_adv"] = float(g_loss.detach())
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        if gan_on:
            assert disc is not None and d_opt is not None
            for g in d_opt.param_groups:
                g["lr"] = cfg.disc_lr * lr / cfg.lr
            d_loss = discriminator_loss(disc(target), disc(outputs[-1].detach()))
            d_opt.zero_grad(set_to_none=True)
            d_loss.backward()
            d_opt.step()
            losses["d_loss"] = float(d_loss.detach())
        self.state.step += 1
        self.state.samples += cfg.batch_size
        return {"loss": float(loss.detach()), "l1": l1, "rec": rec, **losses}

    def loss_row(self, acc: dict[str, list[float]], lr: float) -> tuple[dict[str, Any], float]:
        """The log row of the steps accumulated in ``acc`` (means), and their mean loss."""
        cfg = self.cfg
        mean = {k: float(np.mean(v)) for k, v in acc.items()}
        row: dict[str, Any] = {k: "" for k in LOG_FIELDS}
        per = (mean["rec"] - cfg.lambda_rec * mean["l1"]) / max(cfg.lambda_per, 1e-12)
        row.update(
            step=self.state.step,
            samples=self.state.samples,
            elapsed_s=f"{self.elapsed():.1f}",
            lr=f"{lr:.3e}",
            loss=f"{mean['loss']:.5f}",
            l1=f"{mean['l1']:.5f}",
            perceptual=f"{per:.5f}" if self.perceptual is not None else "",
            g_adv=f"{mean['g_adv']:.5f}" if "g_adv" in mean else "",
            d_loss=f"{mean['d_loss']:.5f}" if "d_loss" in mean else "",
        )
        return row, mean["loss"]
