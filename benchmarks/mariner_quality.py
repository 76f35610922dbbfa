"""Image quality of the shipped MaRINeR weights: do enhanced renders look like the photos?

PSNR-Y / SSIM-Y / LPIPS(alex) against the frame's own photo at working size (short side 160),
on the 100 evaluation frames of ``7scenes_redkitchen/`` (coloured and colourless renders; these
frames are never trained on) and on all ``sceaux_castle/`` frames (a different, outdoor scene with
a colourless mesh, never trained on). Rows: raw render; the reference photo copied as-is;
a classical colour transfer (per-channel mean/std in Lab from the reference, Reinhard et al.);
MaRINeR with 1-3 refinement iterations and references at fixed offsets; MaRINeR with the target
photo itself as reference (upper bound, the paper's Ref=GT).

7-Scenes references: evaluation frames 1, 2, 4 positions away (= 10, 20, 40 original frames at
30 Hz, since that folder holds every 10th frame); castle: the neighbouring photo.

    python benchmarks/mariner_quality.py [--checkpoint PATH] [--cache DIR] [--frames N]

Writes ``reports/mariner_quality.md``, ``reports/mariner_quality.json`` and
``reports/mariner_quality_examples.png``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch
from _common import REPORTS, command_line, machine, shared_data

from mariner_core.data import FrameCache, load_frame_cache, to_tensor
from mariner_core.enhancer import DEFAULT_CHECKPOINT, load_checkpoint
from mariner_core.metrics import LPIPS, psnr_y, ssim_y
from pgt_check.enhance.training_data import build_frame_cache, fixed_offset_pairs
from pgt_check.io.images import resize_image

logger = logging.getLogger("mariner_quality")

PAPER_ROWS = [
    ("paper CAB: render", 15.60, 0.559, 0.380),
    ("paper CAB: MaRINeR (level-1 reference)", 20.03, 0.697, 0.180),
    ("paper CAB: MaRINeR (Ref = GT)", 23.89, 0.799, 0.089),
]


def colour_transfer(render: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Reinhard-style transfer: match per-channel Lab mean/std of the render's covered pixels
    to the reference's. uint8 RGB in, uint8 RGB out (background stays black)."""
    import cv2

    lab = cv2.cvtColor(render, cv2.COLOR_RGB2LAB).astype(np.float32)
    ref = cv2.cvtColor(reference, cv2.COLOR_RGB2LAB).astype(np.float32).reshape(-1, 3)
    mask = render.sum(axis=2) > 0
    src = lab[mask] if mask.any() else lab.reshape(-1, 3)
    mu_s, sd_s = src.mean(0), src.std(0) + 1e-3
    mu_r, sd_r = ref.mean(0), ref.std(0)
    out = (lab - mu_s) / sd_s * sd_r + mu_r
    out = cv2.cvtColor(np.clip(out, 0, 255).astype(np.uint8), cv2.COLOR_LAB2RGB)
    out[~mask] = 0
    return out


class Scorer:
    """Accumulates per-image PSNR-Y / SSIM-Y / LPIPS per row."""

    def __init__(self) -> None:
        self.lpips = LPIPS.pretrained("alex")
        self.rows: dict[str, list[tuple[float, float, float]]] = {}

    @torch.no_grad()
    def add(self, name: str, pred: torch.Tensor, target: torch.Tensor) -> None:
        pred = pred.clamp(0, 1)
        p = psnr_y(pred, target).tolist()
        s = ssim_y(pred, target).tolist()
        lp = self.lpips(pred.float(), target.float()).tolist()
        self.rows.setdefault(name, []).extend(zip(p, s, lp, strict=True))

    def table(self) -> dict[str, dict[str, float]]:
        return {
            k: {
                "psnr_y": float(np.mean([v[0] for v in vals])),
                "ssim_y": float(np.mean([v[1] for v in vals])),
                "lpips": float(np.mean([v[2] for v in vals])),
                "n": len(vals),
            }
            for k, vals in self.rows.items()
        }


def ensure_cache(root: Path, data: Path, name: str, variants: list[str]) -> FrameCache:
    folder = root / f"eval_{name}"
    if not (folder / "index.json").is_file():
        src = data / ("7scenes_redkitchen" if name == "redkitchen" else "sceaux_castle")
        build_frame_cache(src / "trajectories.txt", src / "mesh.ply", folder, variants=variants)
    return load_frame_cache(folder)


@torch.no_grad()
def run_model(model, render: torch.Tensor, ref: torch.Tensor, k: int, batch: int = 10):
    """-> list of K tensors (N, 3, H, W), clamped."""
    outs: list[list[torch.Tensor]] = [[] for _ in range(k)]
    for s in range(0, len(render), batch):
        ys = model(render[s : s + batch], ref[s : s + batch], iterations=k)
        for i, y in enumerate(ys):
            outs[i].append(y.clamp(0, 1))
    return [torch.cat(o) for o in outs]


def evaluate_set(
    models: dict[str, torch.nn.Module],
    scorer: Scorer,
    prefix: str,
    cache: FrameCache,
    variant: str,
    plan: list[tuple[int, int]],
    gt_k: int,
    n: int,
    examples: dict,
) -> None:
    """``plan``: (reference offset, max iterations K) pairs; ``gt_k``: K of the Ref = target rows
    (0: none). One K-iteration run scores every k <= K (the model returns all iterates); the
    frozen-matcher models run once whatever K. Baselines are scored once per offset."""
    photos = to_tensor(cache.images["photo"][:n])
    render_u8 = cache.images[variant][:n]
    renders = to_tensor(render_u8)
    scorer.add(f"{prefix} | raw render", renders, photos)
    main = next(iter(models))
    for off, max_k in plan:
        pairs = fixed_offset_pairs(len(cache), off)[:n]
        ref_idx = [j for _, j in pairs]
        refs = to_tensor(cache.images["photo"][ref_idx])
        scorer.add(f"{prefix} | reference copied (offset {off})", refs, photos)
        ct = np.stack([colour_transfer(render_u8[i], cache.images["photo"][j]) for i, j in pairs])
        scorer.add(f"{prefix} | colour transfer (offset {off})", to_tensor(ct), photos)
        for name, model in models.items():
            kk = max_k if getattr(model.cfg, "architecture", "spec") == "spec" else 1
            t0 = time.perf_counter()
            ys = run_model(model, renders, refs, kk)
            logger.info("%s %s offset %d: %d x K=%d in %.1f s", prefix, name, off, n, kk,
                        time.perf_counter() - t0)
            for k, y in enumerate(ys, start=1):
                scorer.add(f"{prefix} | {name} K={k} (offset {off})", y, photos)
            if name == main:
                examples.setdefault(prefix, {})[off] = (renders, refs, ys, photos)
    if gt_k:
        for name, model in models.items():
            ys = run_model(model, renders, photos, 1)
            scorer.add(f"{prefix} | {name} K=1 (Ref = target, upper bound)", ys[0], photos)


def save_grid(examples: dict, path: Path, picks: dict[str, list[int]], k_show: int) -> None:
    import cv2

    tiles = []
    for prefix, idxs in picks.items():
        if prefix not in examples:
            continue
        off = 2 if 2 in examples[prefix] else sorted(examples[prefix])[0]
        renders, refs, ys, photos = examples[prefix][off]
        y = ys[min(k_show, len(ys)) - 1]
        for i in [i for i in idxs if i < len(renders)] or [0]:
            row = [renders[i], refs[i], y[i], photos[i]]
            row = [(t.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8) for t in row]
            h = row[0].shape[0]
            row = [resize_image(r, (round(r.shape[1] * h / r.shape[0]), h)) for r in row]
            img = np.concatenate([np.pad(r, ((2, 2), (2, 2), (0, 0))) for r in row], axis=1)
            label = f"{prefix} #{i} ref offset {off}"
            cv2.putText(img, label, (6, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 0), 1)
            tiles.append(img)
    width = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 0), (0, width - t.shape[1]), (0, 0))) for t in tiles]
    header = np.zeros((20, width, 3), np.uint8)
    for x, text in zip(
        (8, width // 4 + 8, width // 2 + 8, 3 * width // 4 + 8),
        ("render", "reference", "enhanced", "photo (target)"),
        strict=True,
    ):
        cv2.putText(header, text, (x, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
    grid = np.concatenate([header, *tiles], axis=0)
    cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))


def model_summary(model: torch.nn.Module) -> str:
    cfg = model.cfg
    trained = sum(p.numel() for n, p in model.named_parameters() if not n.startswith("vgg."))
    if getattr(cfg, "architecture", "spec") == "spec":
        return (f"spec network, C={cfg.channels}, encoder {list(cfg.encoder_blocks)}, decoder "
                f"{list(cfg.decoder_blocks)}, global skip {cfg.global_skip}, {trained} parameters")
    return (f"frozen ImageNet VGG16 matching ({cfg.patch_size}x{cfg.patch_size} relu3_3 patches, "
            f"top {cfg.top_k}) + fusion U-Net (C={cfg.channels}, blocks {list(cfg.blocks)}), "
            f"{trained} trained parameters")


def fmt_table(table: dict[str, dict[str, float]], prefix: str) -> list[str]:
    lines = ["| row | PSNR-Y (dB) ↑ | SSIM-Y ↑ | LPIPS ↓ | n |", "|---|---|---|---|---|"]
    raw = table.get(f"{prefix} | raw render")
    for name, v in table.items():
        if not name.startswith(prefix + " |"):
            continue
        d = f" ({v['psnr_y'] - raw['psnr_y']:+.2f})" if raw and "raw" not in name else ""
        lines.append(
            f"| {name.split(' | ', 1)[1]} | {v['psnr_y']:.2f}{d} | {v['ssim_y']:.3f} | "
            f"{v['lpips']:.3f} | {v['n']} |"
        )
    return lines


def _parse_args() -> argparse.Namespace:
    """The command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--checkpoint", action="append", default=None, metavar="NAME=PATH",
        help="a model to score (repeatable; the first one is shown in the examples); default: "
        "the shipped weights",
    )
    parser.add_argument("--cache", default=str(Path.home() / ".cache/pgt_check/mariner_train"))
    parser.add_argument("--frames", type=int, default=100, help="7-Scenes frames (first N)")
    parser.add_argument("--max-k", type=int, default=3)
    parser.add_argument("--castle-frames", type=int, default=0, help="0: all")
    parser.add_argument("--k-other", type=int, default=1, help="K for offsets 10 and 40")
    parser.add_argument("--gt-k", type=int, default=2, help="K for the Ref = target rows")
    parser.add_argument("--gt-k-colourless", type=int, default=1)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", default=str(REPORTS / "mariner_quality"))
    return parser.parse_args()


def _load_models(
    specs: list[str],
) -> tuple[dict[str, torch.nn.Module], dict[str, tuple[str, dict]]]:
    """``NAME=PATH`` specs -> (name -> model in eval mode, name -> (path, training meta))."""
    models: dict[str, torch.nn.Module] = {}
    metas: dict[str, tuple[str, dict]] = {}
    for spec in specs:
        name, _, path = spec.partition("=")
        models[name] = load_checkpoint(path).eval()
        metas[name] = (path, torch.load(path, map_location="cpu", weights_only=True)["meta"])
    return models, metas


def _report_lines(
    models: dict[str, torch.nn.Module],
    metas: dict[str, tuple[str, dict]],
    table: dict[str, dict[str, float]],
    elapsed: float,
    n: int,
    nc: int,
    out: Path,
) -> list[str]:
    """The Markdown report: models, one table per evaluation set, the paper's numbers."""
    lines = [
        "# MaRINeR enhancer quality",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}  ",
        f"Evaluation time: {elapsed / 60:.1f} min",
        "",
        "Models (rows are named after them):",
        "",
        *[
            f"* **{name}**: `{path}`: {model_summary(models[name])}; training meta: step "
            f"{meta.get('step')}, samples {meta.get('samples')}"
            for name, (path, meta) in metas.items()
        ],
        "",
        "All images at working size (short side 160 px, 213x160 for both datasets); metrics "
        "against the frame's own photo: PSNR/SSIM on 8-bit BT.601 Y, LPIPS v0.1 AlexNet. "
        "Offsets are in evaluation frames: 7-Scenes offset 1 / 2 / 4 = 10 / 20 / 40 original "
        "frames (0.33 / 0.67 / 1.33 s at 30 Hz). Values in parentheses: PSNR-Y change "
        "against the raw render. K = refinement iterations.",
        "",
    ]
    for prefix, title in (
        ("7-Scenes coloured", f"## 7-Scenes redkitchen, coloured mesh renders ({n} frames)"),
        (
            "7-Scenes colourless",
            f"## 7-Scenes redkitchen, colourless (shaded) renders ({n} frames)",
        ),
        ("castle", f"## Sceaux castle, colourless mesh (cross-scene, {nc} frames)"),
    ):
        lines += [title, "", *fmt_table(table, prefix), ""]
    lines += [
        "## Paper numbers for context (CAB test set, 160x160, LaMAR; different data and model size)",
        "",
        "| row | PSNR-Y (dB) | SSIM-Y | LPIPS |",
        "|---|---|---|---|",
        *[f"| {name} | {p:.2f} | {s:.3f} | {lp:.3f} |" for name, p, s, lp in PAPER_ROWS],
        "",
        f"Examples: `{out.name}_examples.png` (columns: render, reference, {next(iter(models))}, "
        "photo).",
        "",
    ]
    return lines


def main() -> int:
    args = _parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(args.threads)
    data = shared_data()
    root = Path(args.cache)
    t_start = time.perf_counter()
    specs = args.checkpoint or [f"shipped={DEFAULT_CHECKPOINT}"]
    models, metas = _load_models(specs)
    kitchen = ensure_cache(root, data, "redkitchen", ["photo", "render", "render_colourless"])
    castle = ensure_cache(root, data, "castle", ["photo", "render"])
    scorer = Scorer()
    ex: dict = {}
    n = min(args.frames, len(kitchen))
    k, ko = args.max_k, args.k_other
    nc = min(args.castle_frames or len(castle), len(castle))
    evaluate_set(
        models,
        scorer,
        "7-Scenes coloured",
        kitchen,
        "render",
        [(1, ko), (2, k), (4, ko)],
        args.gt_k,
        n,
        ex,
    )
    evaluate_set(
        models,
        scorer,
        "7-Scenes colourless",
        kitchen,
        "render_colourless",
        [(2, ko)],
        args.gt_k_colourless,
        n,
        ex,
    )
    evaluate_set(models, scorer, "castle", castle, "render", [(1, k)], args.gt_k, nc, ex)
    table = scorer.table()
    elapsed = time.perf_counter() - t_start
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(table, indent=1))
    save_grid(
        ex,
        out.parent / (out.name + "_examples.png"),
        {"7-Scenes coloured": [5, 40, 75], "7-Scenes colourless": [20, 60], "castle": [2, 7]},
        k_show=1,
    )
    lines = _report_lines(models, metas, table, elapsed, n, nc, out)
    out.with_suffix(".md").write_text("\n".join(lines))
    logger.info("wrote %s (%.1f min)", out.with_suffix(".md"), elapsed / 60)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
