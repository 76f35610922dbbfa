"""MaRINeR per scene and leave-one-scene-out: does the enhancer generalize to scenes it never saw?

On the evaluation split of every shared scene (``shared/data/README.md``, "Training pools and
evaluation splits"; never trained on), PSNR-Y / SSIM-Y / LPIPS(alex) at working size (short side
160) against the frame's own photo, for coloured and colourless renders:

* raw render; the reference photo copied; the matching-only base (``FrozenMariner.base``: the
  similarity-weighted mean of the transferred reference patches, no trained weights);
* every model given with ``--model NAME=PATH`` (e.g. the all-scenes model, the shipped weights);
* the model trained *without* this scene (``--loso SCENE=PATH``), the leave-one-scene-out row;
* each model with the scene check (``mariner_core.scene_check``: decoder or matching-only base,
  chosen on the scene's own photos, near references, as a run makes it): scored on up to 12
  other frames of the scene (``bm_*``: its training pool, which a left-out model never saw;
  7-Scenes: evaluation frames not evaluated here); on the castle, whose every frame is
  evaluated, cross-fitted: each half of the frames gets the choice made on the other half;
* references near and far (below), and the frame's own photo (Ref = target, upper bound).

References are never the frame's own photo except in the Ref = target rows: 7-Scenes: other
evaluation frames 20 / 60 original frames away; ``bm_*``: training-pool photos 2 / 5 capture
positions away; castle: the neighbouring photo / 3 photos away.

Frame caches (``python -m pgt_check.enhance.training_data``, one per scene, folder names
``fc_<scene>``; 7-Scenes: ``fc_redkitchen_eval``) are read from ``--caches``.

    python benchmarks/mariner_scenes.py --caches DIR --model all-scenes=RUN/best.pt \
        --model shipped=mariner_core/weights/mariner.pt --loso bm_virgin_child=RUN2/best.pt

Writes ``reports/mariner_scenes.md`` and ``reports/mariner_scenes.json``.
"""

from __future__ import annotations

import argparse
import json
import logging
import time
from pathlib import Path

import numpy as np
import torch
from _common import REPORTS, command_line, machine
from mariner_quality import Scorer

from mariner_core.data import FrameCache, load_frame_cache, to_tensor
from mariner_core.enhancer import load_checkpoint
from mariner_core.frozen import FrozenMariner
from mariner_core.metrics import psnr_y
from mariner_core.scene_check import PSNR_CAP_DB, SceneCheck, decide_output

logger = logging.getLogger("mariner_scenes")

#: frames the scene check scores per scene (as ``enhance.scene_check_frames``)
CHECK_FRAMES = 12

#: scene -> (frame-cache folder, near, far reference offset in t units, held-out rule)
SCENES = {
    "redkitchen": ("fc_redkitchen_eval", 20.0, 60.0),
    "bm_asclepius": ("fc_bm_asclepius", 2.0, 5.0),
    "bm_mictlantecuhli": ("fc_bm_mictlantecuhli", 2.0, 5.0),
    "bm_virgin_child": ("fc_bm_virgin_child", 2.0, 5.0),
    "sceaux_castle": ("fc_sceaux_castle", 1.0, 3.0),
}


def eval_plan(cache: FrameCache, scene: str, every: int) -> tuple[list[int], dict[str, list[int]]]:
    """(evaluation positions, {"near": refs, "far": refs, "check": frames, "check_ref": refs}):
    the evaluation split of ``scene`` and a reference for each frame at the scene's near / far
    offset (the nearest frame to ``t +- offset`` that is allowed as a reference: never the frame
    itself), and the scene check's frames with their near references."""
    t = cache.t
    if scene.startswith("bm_"):
        ev = np.flatnonzero(np.round(t).astype(int) % 10 == 0)
        allowed = np.flatnonzero(np.round(t).astype(int) % 10 != 0)  # the training pool
    else:
        ev = np.arange(len(t))
        allowed = np.arange(len(t))
    ev = ev[::every]
    # the scene check's frames: up to CHECK_FRAMES others of the scene (bm_*: the training pool,
    # which a left-out model never saw), spread along it; none where every frame is evaluated
    rest = np.setdiff1d(allowed, ev)
    if len(rest) > CHECK_FRAMES:
        rest = rest[np.unique(np.round(np.linspace(0, len(rest) - 1, CHECK_FRAMES)).astype(int))]
    _, near, far = SCENES[scene]
    refs: dict[str, list[int]] = {"check": [int(i) for i in rest]}
    for name, off, which in (("near", near, ev), ("far", far, ev), ("check_ref", near, rest)):
        chosen = []
        for i in which:
            cand = allowed[allowed != i]
            fwd = cand[np.argmin(np.abs(t[cand] - (t[i] + off)))]
            bwd = cand[np.argmin(np.abs(t[cand] - (t[i] - off)))]
            chosen.append(int(fwd if abs(t[fwd] - t[i] - off) <= abs(t[bwd] - t[i] + off)
                              else bwd))
        refs[name] = chosen
    return [int(i) for i in ev], refs


@torch.no_grad()
def score_scene(
    scorer: Scorer, models: dict[str, FrozenMariner], loso: FrozenMariner | None,
    cache: FrameCache, scene: str, every: int, coloured_mesh: bool,
) -> None:
    ev, refs = eval_plan(cache, scene, every)
    photos = to_tensor(cache.images["photo"][ev])
    base_model = next(iter(models.values()))
    variants = {"coloured": "render", "colourless": "render_colourless"}
    if not coloured_mesh:  # the castle's mesh has no colour: its "render" is the shaded one
        variants = {"colourless": "render"}
    all_models = dict(models)
    if loso is not None:
        all_models["left-out model"] = loso
    for vname, key in variants.items():
        prefix = f"{scene} | {vname}"
        renders = to_tensor(cache.images[key][ev])
        scorer.add(f"{prefix} | raw render", renders, photos)
        for rname, ref_idx in (("near", refs["near"]), ("far", refs["far"]), ("target", ev)):
            ref = to_tensor(cache.images["photo"][ref_idx])
            if rname != "target":
                scorer.add(f"{prefix} | reference copied ({rname})", ref, photos)
            t0 = time.perf_counter()
            preps = [base_model.prepare(renders[b : b + 1], ref[b : b + 1])
                     for b in range(len(ev))]
            h, w = renders.shape[-2:]
            base = torch.cat([base_model.base(p)[..., :h, :w] for p in preps])
            scorer.add(f"{prefix} | matching-only base ({rname})", base, photos)
            for name, m in all_models.items():
                y = torch.cat([m.fuse(p)[..., :h, :w] for p in preps])
                scorer.add(f"{prefix} | {name} ({rname})", y, photos)
                if rname != "near":
                    continue
                if refs["check"]:
                    chk = scene_check_on(m, base_model, cache, key, refs)
                    checked, how = (y if chk.output == "model" else base), [chk.to_dict()]
                else:
                    checked, how = cross_fitted_check(y, base, photos)
                scorer.add(f"{prefix} | {name} + scene check ({rname})", checked, photos)
                CHECKS[f"{prefix} | {name}"] = how
            logger.info("%s %s: %d frames in %.1f s", prefix, rname, len(ev),
                        time.perf_counter() - t0)


#: "scene | render | model" -> the scene check's choice on each half (``cross_fitted_check``)
CHECKS: dict[str, list[dict]] = {}


@torch.no_grad()
def scene_check_on(model: FrozenMariner, base_model: FrozenMariner, cache: FrameCache, key: str,
                   refs: dict[str, list[int]]) -> SceneCheck:
    """The scene check as a run makes it, on the scene's check frames (never the evaluated
    ones) with their near references."""
    renders = to_tensor(cache.images[key][refs["check"]])
    photos = to_tensor(cache.images["photo"][refs["check"]])
    ref = to_tensor(cache.images["photo"][refs["check_ref"]])
    h, w = renders.shape[-2:]
    m_db, b_db = [], []
    for b in range(len(renders)):
        p = base_model.prepare(renders[b : b + 1], ref[b : b + 1])
        for out, fn in ((m_db, model.fuse), (b_db, base_model.base)):
            out.append(min(float(psnr_y(fn(p)[..., :h, :w].clamp(0, 1), photos[b : b + 1])[0]),
                           PSNR_CAP_DB))
    return decide_output(m_db, b_db)


def cross_fitted_check(
    model_out: torch.Tensor, base: torch.Tensor, photos: torch.Tensor
) -> tuple[torch.Tensor, list[dict]]:
    """The scene check (``mariner_core.scene_check``) as a run would apply it, scored without
    choosing on the frames it is scored on: the frames are split in two halves (alternate
    frames); each half gets the output the check chooses from the *other* half's triples.
    Returns (the chosen output per frame, each half's ``SceneCheck.to_dict()``)."""
    cap = lambda t: psnr_y(t.clamp(0, 1), photos).clamp(max=PSNR_CAP_DB).tolist()  # noqa: E731
    m_db, b_db = cap(model_out), cap(base)
    out = base.clone()
    how = []
    idx = np.arange(len(photos))
    for half in (0, 1):
        score_on, apply_to = idx[idx % 2 != half], idx[idx % 2 == half]
        chk = decide_output([m_db[i] for i in score_on], [b_db[i] for i in score_on])
        if chk.output == "model":
            out[apply_to] = model_out[apply_to]
        how.append(chk.to_dict())
    return out, how


def verdict_rows(table: dict, scenes: list[str], model: str) -> list[list[object]]:
    """Per scene and render kind: the done-when criteria for ``model`` (the left-out model
    where there is one, else ``model``) with the scene check, as a run applies it; the
    decoder alone beside it."""
    rows = []
    for prefix in sorted({k.rsplit(" | ", 1)[0] for k in table}):
        scene = prefix.split(" | ")[0]
        if scene not in scenes:
            continue
        who = "left-out model" if f"{prefix} | left-out model (near)" in table else model
        if f"{prefix} | {who} (near)" not in table:
            continue
        g = lambda row, p=prefix: table[f"{p} | {row}"]["psnr_y"]  # noqa: E731
        raw, base, alone = g("raw render"), g("matching-only base (near)"), g(f"{who} (near)")
        near = g(f"{who} + scene check (near)")
        far, tgt = g(f"{who} (far)"), g(f"{who} (target)")
        need = 2.0 if prefix.endswith("| coloured") else 7.0
        chosen = "/".join(c["output"] for c in CHECKS.get(f"{prefix} | {who}", []))
        rows.append([prefix, who, round(raw, 2), round(base, 2), round(alone, 2),
                     f"{near:.2f} ({chosen})",
                     f"{near - raw:+.2f} ({'ok' if near - raw >= need else f'< +{need:g}'})",
                     f"{near - base:+.2f} ({'ok' if near >= base - 0.05 else 'below'})",
                     f"{tgt:.2f} > {far:.2f} > {raw:.2f}: "
                     f"{'yes' if tgt > far > raw else 'no'}"])
    return rows


def main(argv: list[str] | None = None) -> int:
    from _common import md_table

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--caches", type=Path, required=True)
    p.add_argument("--model", action="append", default=[], help="NAME=PATH (first: main)")
    p.add_argument("--loso", action="append", default=[], help="SCENE=PATH trained without it")
    p.add_argument("--scenes", default=",".join(SCENES))
    p.add_argument("--every", type=int, default=1, help="every Nth evaluation frame")
    p.add_argument("--rk-every", type=int, default=4, help="every Nth 7-Scenes evaluation frame")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=REPORTS / "mariner_scenes")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    torch.set_num_threads(a.threads)
    models = {n: load_checkpoint(path).eval() for n, path in (s.split("=", 1) for s in a.model)}
    loso = {n: load_checkpoint(path).eval() for n, path in (s.split("=", 1) for s in a.loso)}
    if not models or not all(isinstance(m, FrozenMariner) for m in [*models.values(),
                                                                     *loso.values()]):
        p.error("give at least one --model; all must be frozen-matcher checkpoints")
    scorer = Scorer()
    scenes = [s for s in a.scenes.split(",") if s]
    t0 = time.perf_counter()
    for scene in scenes:
        folder = a.caches / SCENES[scene][0]
        index = json.loads((folder / "index.json").read_text())
        cache = load_frame_cache(folder)
        every = a.rk_every if scene == "redkitchen" else a.every
        score_scene(scorer, models, loso.get(scene), cache, scene, every,
                    bool(index.get("mesh_coloured", True)))
    table = scorer.table()
    main_name = next(iter(models))
    out = {"command": command_line(), "machine": machine(), "models": a.model, "loso": a.loso,
           "minutes": round((time.perf_counter() - t0) / 60, 1), "table": table,
           "scene_checks": CHECKS}
    a.out.with_suffix(".json").write_text(json.dumps(out, indent=1))
    lines = [
        "# MaRINeR per scene and leave-one-scene-out",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}; {out['minutes']} min.",
        "",
        "Evaluation splits only (never trained on); PSNR-Y / SSIM-Y / LPIPS at working size "
        "(short side 160) against the frame's own photo. Models: "
        + "; ".join(f"`{s}`" for s in a.model)
        + ("; left-out models: " + "; ".join(f"`{s}`" for s in a.loso) if a.loso else "")
        + ".",
        "",
        "## Done-when criteria (near reference; the left-out model where there is one)",
        "",
        "The model column is the decoder alone; 'with scene check' is what a run gets: the "
        "output the scene check chose (in brackets) from 12 other frames of the scene (bm_*: "
        "the training pool, never seen by the left-out model; 7-Scenes: evaluation frames not "
        "scored here), on the castle cross-fitted (each half of the frames gets the choice "
        "made on the other half); the gains are those of the checked output.",
        "",
        md_table(["scene | render", "model", "raw", "base", "decoder alone", "with scene check",
                  "gain over raw", "vs base", "Ref = target > far > raw"],
                 verdict_rows(table, scenes, main_name)),
        "",
        "## All rows",
        "",
    ]
    for prefix in dict.fromkeys(k.rsplit(" | ", 1)[0] for k in table):
        lines += [f"### {prefix}", "", md_table(
            ["row", "PSNR-Y", "SSIM-Y", "LPIPS", "n"],
            [[k.rsplit(" | ", 1)[1], round(v["psnr_y"], 2), round(v["ssim_y"], 3),
              round(v["lpips"], 3), v["n"]] for k, v in table.items()
             if k.rsplit(" | ", 1)[0] == prefix]), ""]
    a.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(a.out.with_suffix(".md"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
