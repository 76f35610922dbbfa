"""Speed of the shipped MaRINeR (frozen matcher + fusion decoder) on this machine's CPU.

Usage: python benchmarks/mariner_speed_frozen.py [--checkpoint PATH] [--sizes 213x160,320x240]
       [--batches 1,8] [--repeats 3] [--threads 2]

Per size and batch: one warm-up, then ``repeats`` timed ``Enhancer.enhance`` calls on random
images (render and reference of the same size; the speed does not depend on the content);
reported per frame (call time / batch). Plus the split of one batch-1 call into the frozen VGG
(both images), the patch matching, the transfer and the fusion decoder. Writes
``reports/mariner_speed.md`` + ``.json``; the spec network's figures stay in
``reports/mariner_speed_spec.md`` (``benchmarks/mariner_speed.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import torch
from _common import REPORTS, command_line, machine

from mariner_core.enhancer import DEFAULT_CHECKPOINT, Enhancer
from mariner_core.frozen import _pad_to


def _time(fn, repeats: int) -> dict[str, float]:
    fn()  # warm-up
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return {"median": statistics.median(ts), "min": min(ts), "max": max(ts)}


def _split_one_call(model, size: str, w: int, h: int) -> dict:
    """Seconds of one batch-1 call split into VGG, matching, transfer and fusion decoder."""
    x, r = torch.rand(1, 3, h, w), torch.rand(1, 3, h, w)
    with torch.inference_mode():
        xp, _ = _pad_to(x, 4)
        rp, _ = _pad_to(r, 4)
        t0 = time.perf_counter()
        f_r = model.vgg(rp)
        t1 = time.perf_counter()
        sc, ix = model.match(xp, rp, f_r)  # includes the render's VGG pass
        t2 = time.perf_counter()
        model.transfer(rp, ix, xp.shape[-2:])
        t3 = time.perf_counter()
        prep = model.prepare(x, r, reference_features=f_r)
        t4 = time.perf_counter()
        model.fuse(prep)
        t5 = time.perf_counter()
    return {"size": size, "VGG (reference)": t1 - t0, "VGG (render) + match": t2 - t1,
            "transfer": t3 - t2, "fusion decoder": t5 - t4}


def _report_lines(a: argparse.Namespace, meta: dict, rows: list[dict],
                  splits: list[dict]) -> list[str]:
    """The Markdown report: seconds per frame per size and batch, then the call's split."""
    return [
        "# MaRINeR speed (shipped `cpu-frozen` model, CPU)",
        "",
        f"Command: `{command_line()}`  ",
        f"Machine: {machine()}; torch {torch.__version__}, {a.threads} threads  ",
        f"Checkpoint: `{Path(a.checkpoint).name}` (step {meta.get('step')})",
        "",
        "Per frame = call time / batch; median of "
        f"{a.repeats} calls after one warm-up [min-max]. 213x160 is the validator's working "
        "size (short side 160).",
        "",
        "| size | batch | s per frame | load avg |",
        "|---|---|---|---|",
        *[f"| {r['size']} | {r['batch']} | {r['median']:.3f} [{r['min']:.3f}-{r['max']:.3f}] "
          f"| {r['load']:.1f} |" for r in rows],
        "",
        "Split of one batch-1 call (s):",
        "",
        "| size | " + " | ".join(k for k in splits[0] if k != "size") + " |",
        "|---|" + "---|" * (len(splits[0]) - 1),
        *["| " + s["size"] + " | " + " | ".join(f"{v:.3f}" for k, v in s.items() if k != "size")
          + " |" for s in splits],
        "",
        "The spec network (`gpu` config, learned encoder and matching) is timed in "
        "`mariner_speed_spec.md`.",
        "",
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--checkpoint", default=str(DEFAULT_CHECKPOINT))
    p.add_argument("--sizes", default="213x160,320x240")
    p.add_argument("--batches", default="1,8")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, default=REPORTS / "mariner_speed.md")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    enh = Enhancer.from_pretrained(a.checkpoint)
    model = enh.model
    rows, splits = [], []
    for size in a.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        for b in (int(v) for v in a.batches.split(",")):
            x, r = torch.rand(b, 3, h, w), torch.rand(b, 3, h, w)
            t = _time(lambda x=x, r=r: enh.enhance(x, r), a.repeats)
            rows.append({"size": size, "batch": b, **{k: v / b for k, v in t.items()},
                         "load": os.getloadavg()[0]})
            print(json.dumps(rows[-1]), flush=True)
        splits.append(_split_one_call(model, size, w, h))
    meta = torch.load(a.checkpoint, map_location="cpu", weights_only=True)["meta"]
    a.out.with_suffix(".json").write_text(json.dumps({"rows": rows, "splits": splits}, indent=1))
    a.out.write_text("\n".join(_report_lines(a, meta, rows, splits)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
