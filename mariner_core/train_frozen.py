"""Train the ``cpu-frozen`` MaRINeR (:mod:`mariner_core.frozen`) on two CPU cores.

Two steps, both resumable, both reading a frame cache (``mariner_core.data``):

1. ``cache`` (``mariner_core.frozen_cache``): for every training frame and render variant,
   ``pairs`` references drawn 10-60 frames away; the frozen matching
   (``FrozenMariner.prepare``) of each triple is stored once
   (uint8 images, float16 similarity maps at 1/4 resolution) in ``OUT/triples.npy`` +
   ``OUT/scores.npy``. Validation triples (the pool's last 15 %, reference ``val_offset`` frames
   away, coloured and colourless, and the same frames with Ref = target) go to ``OUT/val_*.npy``.
2. ``train``: random crops of cached triples; only the fusion U-Net learns (L1 + perceptual
   loss); validation PSNR-Y on whole images every few minutes; the best checkpoint is kept
   (``best.pt``, loadable by ``Enhancer.from_pretrained``), ``last.pt`` holds the optimiser for
   ``--resume``; ``log.csv`` is the learning curve.

    python -m mariner_core.train_frozen cache --data FRAME_CACHE --out RUN [--pairs 2]
    python -m mariner_core.train_frozen train --out RUN --max-minutes 90 [--resume | --init W]
"""

from __future__ import annotations

import argparse
import csv
import json
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from .augment import recolour as _recolour
from .augment import reshade_render as _reshade_render
from .frozen import FrozenMariner, FrozenMarinerConfig
from .frozen_cache import build_triples, layout
from .metrics import psnr_y
from .train_config import cosine_lr
from .warm_start import initial_model

logger = logging.getLogger(__name__)

__all__ = ["TrainSettings", "build_triples", "train"]


@dataclass(frozen=True)
class TrainSettings:
    crop: int = 96
    batch_size: int = 12
    lr: float = 5e-4
    lr_min: float = 2e-5
    lambda_per: float = 0.01
    val_every_minutes: float = 8.0
    ckpt_every_minutes: float = 3.0
    threads: int = 2
    seed: int = 0
    #: share of training crops whose reference and target get one random colour change
    colour_aug: float = 0.0
    channels: int = 24
    blocks: tuple[int, int, int] = (1, 2, 3)
    #: decoder output = base + confidence * correction (``FrozenMarinerConfig.gated``)
    gated: bool = False
    #: share of training crops whose render alone gets a random exposure / shading change
    render_aug: float = 0.0


def _batch_inputs(
    imgs: np.ndarray, scores: np.ndarray, k: int, idx: np.ndarray, crop: int | None,
    rng: np.random.Generator | None, colour_aug: float = 0.0, render_aug: float = 0.0,
) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
    lay = layout(k)
    x = torch.from_numpy(np.ascontiguousarray(imgs[idx])).float().div_(255.0)
    sc = torch.from_numpy(np.ascontiguousarray(scores[idx])).float()
    h, w = x.shape[-2:]
    sc = FrozenMariner.upsample_scores(sc, (h, w))
    if crop is not None and rng is not None:
        ys = rng.integers(0, h - crop + 1, size=len(idx))
        xs = rng.integers(0, w - crop + 1, size=len(idx))
        flips = rng.random(len(idx)) < 0.5
        xc, scc = [], []
        for b in range(len(idx)):
            a = x[b, :, ys[b] : ys[b] + crop, xs[b] : xs[b] + crop]
            s = sc[b, :, ys[b] : ys[b] + crop, xs[b] : xs[b] + crop]
            if flips[b]:
                a, s = a.flip(-1), s.flip(-1)
            xc.append(a)
            scc.append(s)
        x, sc = torch.stack(xc), torch.stack(scc)
    prep = {key: x[:, sl] for key, sl in lay.items() if key != "target"}
    prep["score"] = sc
    target = x[:, lay["target"]]
    if colour_aug > 0 and rng is not None:
        target = _recolour(prep, target, colour_aug, rng)
    if render_aug > 0 and rng is not None:
        _reshade_render(prep, render_aug, rng)
    return prep, target


@torch.no_grad()
def _validate(model: FrozenMariner, imgs, scores, k: int, jobs: list) -> dict[str, float]:
    model.eval()
    groups: dict[str, list[float]] = {}
    for n in range(0, len(jobs), 8):
        idx = np.arange(n, min(n + 8, len(jobs)))
        prep, tgt = _batch_inputs(imgs, scores, k, idx, None, None)
        y = model.fuse(prep).clamp(0, 1)
        p = psnr_y(y, tgt).tolist()
        pr = psnr_y(prep["render"], tgt).tolist()
        pb = psnr_y(model.base(prep).clamp(0, 1), tgt).tolist()
        for m, (pv, prv, pbv) in enumerate(zip(p, pr, pb, strict=True)):
            _, _, v, kind = jobs[idx[m]]
            key = f"{'colourless' if 'colourless' in v else 'coloured'}_{kind}"
            groups.setdefault(key, []).append(pv)
            groups.setdefault(key + "_raw", []).append(prv)
            groups.setdefault(key + "_base", []).append(pbv)
    model.train()
    return {g: float(np.mean(v)) for g, v in groups.items()}


@dataclass
class _Scene:
    """The cached triples of one training cache (one scene), training arrays in memory."""

    name: str
    imgs: np.ndarray
    scores: np.ndarray
    v_imgs: np.ndarray
    v_scores: np.ndarray
    val_jobs: list


def _load_triples(cache: Path, settings: TrainSettings) -> tuple[FrozenMarinerConfig, _Scene]:
    """(model config, scene) of the triple cache ``cache``; the training arrays are read into
    memory (~0.2-3 GB)."""
    meta = json.loads((cache / "triples.json").read_text())
    # the decoder's size does not change the cached matching: it may differ from the cache's
    cfg = FrozenMarinerConfig.from_dict(
        {**meta["config"], "channels": settings.channels, "blocks": list(settings.blocks),
         "gated": settings.gated}
    )
    n_done = json.loads((cache / "train_done.json").read_text())["n"]
    imgs = np.load(cache / "train_images.npy", mmap_mode="r")
    scores = np.load(cache / "train_scores.npy", mmap_mode="r")
    scene = _Scene(
        name=cache.name, imgs=np.ascontiguousarray(imgs[:n_done]),
        scores=np.ascontiguousarray(scores[:n_done]),
        v_imgs=np.load(cache / "val_images.npy"), v_scores=np.load(cache / "val_scores.npy"),
        val_jobs=meta["val_jobs"],
    )
    if n_done == 0:
        raise ValueError(f"{cache}: no cached training triples yet")
    return cfg, scene


def _resume(
    last: Path, model: FrozenMariner, opt: torch.optim.Optimizer, settings: TrainSettings,
) -> tuple[dict, np.random.Generator]:
    """Load ``last.pt`` into the model and optimiser -> (training state, batch generator)."""
    ck = torch.load(last, weights_only=False)
    model.load_state_dict(ck["model"])
    opt.load_state_dict(ck["opt"])
    state = ck["state"]
    rng = np.random.default_rng(settings.seed + state["step"])
    logger.info("resumed at step %d (%.1f min)", state["step"], state["elapsed"] / 60)
    return state, rng


VAL_GROUPS = ("coloured_offset", "colourless_offset", "coloured_ref_target",
              "colourless_ref_target")


def _open_log(out: Path, resume: bool, scenes: list[str]) -> tuple[Any, csv.DictWriter]:
    """``log.csv``: appended to when resuming an existing one, else written anew with a header.

    With several scenes the un-prefixed validation columns are means over scenes and every
    scene has its own ``SCENE/group`` columns (the learning curve per scene)."""
    log_path = out / "log.csv"
    new_log = not (resume and log_path.is_file())
    log_file = log_path.open("w" if new_log else "a", newline="")
    groups = [g + sfx for g in VAL_GROUPS for sfx in ("", "_base")] + [
        "coloured_offset_raw", "colourless_offset_raw"]
    fieldnames = ["step", "minutes", "samples", "lr", "loss", "l1", "per", "val_mean", *groups]
    if len(scenes) > 1:
        fieldnames += [f"{sc}/{g}" for sc in scenes for g in (*groups, "val_mean")]
    writer = csv.DictWriter(log_file, fieldnames=fieldnames, extrasaction="ignore")
    if new_log:
        writer.writeheader()
    return log_file, writer


def _scene_mean(res: dict[str, float]) -> float:
    """Checkpoint criterion of one scene: mean PSNR-Y over its far-reference groups."""
    vals = [res[g] for g in ("coloured_offset", "colourless_offset") if g in res]
    return float(np.mean(vals)) if vals else float("nan")


@dataclass
class _Session:
    """What a training run's validation, checkpoints and steps share."""

    out: Path
    settings: TrainSettings
    model: FrozenMariner
    opt: torch.optim.Optimizer
    state: dict
    log_file: Any
    writer: csv.DictWriter
    t_start: float
    acc: dict[str, list[float]]
    scenes: list[_Scene]
    k: int

    def save_last(self) -> None:
        """Write ``last.pt`` (model, optimiser, state) through a temporary file."""
        last = self.out / "last.pt"
        self.state["elapsed"] = time.perf_counter() - self.t_start
        torch.save({"model": self.model.state_dict(), "opt": self.opt.state_dict(),
                    "state": self.state}, last.with_suffix(".tmp"))
        last.with_suffix(".tmp").replace(last)

    def validate(self) -> tuple[dict[str, float], float]:
        """(log columns, checkpoint criterion): per scene, and the means over scenes. The
        criterion is the mean over scenes, so a large scene cannot outvote a small one."""
        per_scene = {sc.name: _validate(self.model, sc.v_imgs, sc.v_scores, self.k, sc.val_jobs)
                     for sc in self.scenes}
        if len(self.scenes) == 1:
            res = next(iter(per_scene.values()))
            return dict(res), _scene_mean(res)
        cols: dict[str, float] = {}
        keys = sorted({kk for r in per_scene.values() for kk in r})
        for kk in keys:
            cols[kk] = float(np.mean([r[kk] for r in per_scene.values() if kk in r]))
        for name, r in per_scene.items():
            cols.update({f"{name}/{kk}": v for kk, v in r.items()})
            cols[f"{name}/val_mean"] = _scene_mean(r)
        crit = float(np.nanmean([_scene_mean(r) for r in per_scene.values()]))
        return cols, crit

    def run_val(self) -> None:
        """Validate, log a row (with the mean training losses since the last one) and keep
        ``best.pt`` when the criterion improved."""
        from .enhancer import save_checkpoint

        state, acc = self.state, self.acc
        res, mean = self.validate()
        minutes = round((time.perf_counter() - self.t_start) / 60, 2)
        row = {"step": state["step"], "minutes": minutes,
               "samples": state["samples"], "val_mean": round(mean, 3),
               **{kk: round(v, 3) for kk, v in res.items()}}
        for kk in ("loss", "l1", "per"):
            if acc[kk]:
                row[kk] = round(float(np.mean(acc[kk])), 5)
            acc[kk] = []
        row["lr"] = self.opt.param_groups[0]["lr"]
        self.writer.writerow(row)
        self.log_file.flush()
        logger.info("val %s", {kk: v for kk, v in row.items() if "/" not in kk})
        if mean > state["best"]:
            state["best"] = mean
            save_checkpoint(self.model, self.out / "best.pt", fp16=True, extra={
                "step": state["step"], "samples": state["samples"],
                "minutes": row["minutes"], "val": {kk: float(v) for kk, v in res.items()},
                "settings": asdict(self.settings),
                "scenes": [sc.name for sc in self.scenes],
            })

    def step(self, per, rng: np.random.Generator) -> None:
        """One optimiser step on a batch of random crops, its samples spread evenly over the
        scenes; its losses go to ``acc``."""
        settings, state, acc = self.settings, self.state, self.acc
        which = rng.integers(0, len(self.scenes), size=settings.batch_size)
        preps, tgts = [], []
        for s_i, sc in enumerate(self.scenes):
            m = int((which == s_i).sum())
            if m == 0:
                continue
            idx = rng.integers(0, len(sc.imgs), size=m)
            prep, tgt = _batch_inputs(sc.imgs, sc.scores, self.k, idx, settings.crop, rng,
                                      settings.colour_aug, settings.render_aug)
            preps.append(prep)
            tgts.append(tgt)
        prep = {kk: torch.cat([p[kk] for p in preps]) for kk in preps[0]}
        tgt = torch.cat(tgts)
        y = self.model.fuse(prep)
        l1 = (y - tgt).abs().mean()
        lp = per(y, tgt) if settings.lambda_per > 0 else torch.zeros(())
        loss = l1 + settings.lambda_per * lp
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        state["step"] += 1
        state["samples"] += settings.batch_size
        acc["loss"].append(float(loss.detach()))
        acc["l1"].append(float(l1.detach()))
        acc["per"].append(float(lp.detach()))


def train(
    out: str | Path, max_minutes: float, settings: TrainSettings, resume: bool,
    init: str | Path | None = None, caches: list[str | Path] | None = None,
) -> Path:
    """Train the fusion decoder on cached triples; returns the path of ``best.pt``.

    ``caches``: triple caches (``cache`` step outputs, one per scene) to train on together;
    default: ``out`` itself. ``init``: start from these weights (e.g. the shipped checkpoint,
    whose decoder size must match ``settings``) instead of a zero-initialised head; ignored
    when resuming ``last.pt``.
    """
    from .losses import PerceptualLoss

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(settings.threads)
    torch.manual_seed(settings.seed)
    loaded = [_load_triples(Path(c), settings) for c in (caches or [out])]
    cfg = loaded[0][0]
    if any(c.to_dict() != cfg.to_dict() for c, _ in loaded):
        raise ValueError("the triple caches were matched with different configs")
    scenes = [sc for _, sc in loaded]
    if len({sc.name for sc in scenes}) != len(scenes):
        raise ValueError(f"triple cache folder names must differ: {[sc.name for sc in scenes]}")
    model = initial_model(cfg, out, init, resume)
    params = [p for n, p in model.named_parameters() if not n.startswith("vgg.")]
    opt = torch.optim.Adam(params, lr=settings.lr)
    per = PerceptualLoss.pretrained(("relu1_2", "relu2_2"))
    rng = np.random.default_rng(settings.seed)
    state = {"step": 0, "elapsed": 0.0, "best": -1e9, "samples": 0}
    last = out / "last.pt"
    if resume and last.is_file():
        state, rng = _resume(last, model, opt, settings)
    log_file, writer = _open_log(out, resume, [sc.name for sc in scenes])
    budget = max_minutes * 60.0
    t_start = time.perf_counter() - state["elapsed"]
    t_val = t_ckpt = time.perf_counter()
    acc: dict[str, list[float]] = {"loss": [], "l1": [], "per": []}
    logger.info("training %d parameters on %s triples", model.num_trainable(),
                {sc.name: len(sc.imgs) for sc in scenes})
    run = _Session(out, settings, model, opt, state, log_file, writer, t_start, acc, scenes,
                   cfg.top_k)

    if state["step"] == 0:
        run.run_val()
    while time.perf_counter() - t_start < budget:
        prog = (time.perf_counter() - t_start) / budget
        lr = cosine_lr(prog, settings.lr, settings.lr_min)
        for g in opt.param_groups:
            g["lr"] = lr
        run.step(per, rng)
        now = time.perf_counter()
        if now - t_val > settings.val_every_minutes * 60:
            run.run_val()
            t_val = time.perf_counter()
        if now - t_ckpt > settings.ckpt_every_minutes * 60:
            run.save_last()
            t_ckpt = now
    run.run_val()
    run.save_last()
    log_file.close()
    return out / "best.pt"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("cache")
    c.add_argument("--data", required=True)
    c.add_argument("--out", required=True)
    c.add_argument("--pairs", type=int, default=2)
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--min-gap", type=float, default=10.0,
                   help="nearest reference, in frame-time units (t) of the cache")
    c.add_argument("--max-gap", type=float, default=60.0, help="farthest reference (t units)")
    c.add_argument("--self-share", type=float, default=0.0,
                   help="share of triples whose reference is the frame's own photo")
    c.add_argument("--exclude-mod", type=int, default=None,
                   help="frames with t %% N == 0 are held out (never a target or reference)")
    c.add_argument("--val-offset", type=float, default=20.0)
    c.add_argument("--val-every", type=int, default=4)
    t = sub.add_parser("train")
    t.add_argument("--out", required=True)
    t.add_argument("--max-minutes", type=float, required=True)
    t.add_argument("--resume", action="store_true")
    t.add_argument("--init", default=None, help="start from these weights (e.g. the shipped "
                   "mariner_core/weights/mariner.pt)")
    t.add_argument("--crop", type=int, default=TrainSettings.crop)
    t.add_argument("--batch-size", type=int, default=TrainSettings.batch_size)
    t.add_argument("--lr", type=float, default=TrainSettings.lr)
    t.add_argument("--lambda-per", type=float, default=TrainSettings.lambda_per)
    t.add_argument("--threads", type=int, default=TrainSettings.threads)
    t.add_argument("--channels", type=int, default=TrainSettings.channels)
    t.add_argument("--colour-aug", type=float, default=TrainSettings.colour_aug,
                   help="share of crops whose reference and target change colour together")
    t.add_argument("--render-aug", type=float, default=TrainSettings.render_aug,
                   help="share of crops whose render alone changes exposure / shading")
    t.add_argument("--gated", action="store_true",
                   help="decoder output = base + confidence * correction")
    t.add_argument("--caches", default=None,
                   help="comma-separated triple caches (one per scene) to train on together; "
                   "default: --out")
    t.add_argument("--val-every-minutes", type=float, default=TrainSettings.val_every_minutes)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    if args.cmd == "cache":
        build_triples(args.data, args.out, pairs=args.pairs, seed=args.seed,
                      min_gap=args.min_gap, max_gap=args.max_gap, self_share=args.self_share,
                      exclude_mod=args.exclude_mod, val_offset=args.val_offset,
                      val_every=args.val_every)
        return 0
    settings = TrainSettings(crop=args.crop, batch_size=args.batch_size, lr=args.lr,
                             lambda_per=args.lambda_per, threads=args.threads,
                             channels=args.channels, colour_aug=args.colour_aug,
                             render_aug=args.render_aug, gated=args.gated,
                             val_every_minutes=args.val_every_minutes)
    caches = [c for c in args.caches.split(",") if c] if args.caches else None
    train(args.out, args.max_minutes, settings, args.resume, init=args.init, caches=caches)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
