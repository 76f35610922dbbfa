"""Speed benchmark of the MaRINeR generator (random weights; speed does not depend on them).

Usage: python benchmarks/mariner_speed.py [--sizes 160x160,320x240,640x480] [--iters 1,2,3,4]
       [--repeats 3] [--out reports/mariner_speed_spec.md]

Each size runs in a fresh subprocess (so ru_maxrss is that size's peak RSS); per config: one
warm-up call, then ``repeats`` timed calls of ``Mariner.forward`` under ``inference_mode``
(batch 1, render and reference of the same size); the median and min/max are reported, plus an
encoder / MEM (match, transfer) / decoder split of one iteration. Writes markdown + JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

PAPER_MS = {1: 49.2, 2: 66.3, 3: 88.7, 4: 110.5}


def run_size(w: int, h: int, iters: list[int], repeats: int, threads: int) -> dict:
    import torch

    from mariner_core.model import Mariner, pad_reference, pad_render

    torch.set_num_threads(threads)
    torch.manual_seed(0)
    model = Mariner().eval()
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    x, r = torch.rand(1, 3, h, w), torch.rand(1, 3, h, w)
    out: dict = {"size": f"{w}x{h}", "ms": {}, "rss_before_kib": rss0}
    with torch.inference_mode():
        model(x, r, iterations=1)  # warm-up
        for k in iters:
            ts = []
            for _ in range(repeats):
                t = time.perf_counter()
                model(x, r, iterations=k)
                ts.append(1e3 * (time.perf_counter() - t))
            out["ms"][k] = {"median": statistics.median(ts), "min": min(ts), "max": max(ts)}
        # split of one iteration, on the padded inputs the forward uses
        x, _ = pad_render(x, model.cfg.render_multiple)
        r = pad_reference(r, model.cfg.reference_multiple)
        t0 = time.perf_counter()
        fi, fr = model.encoder(x), model.encoder(r)
        t1 = time.perf_counter()
        m = model.mem.match(fi[2], fr[2])
        t2 = time.perf_counter()
        warped, _ = model.mem(fi, fr)
        t3 = time.perf_counter()
        model.decoder(fi[2], warped)
        t4 = time.perf_counter()
        del m
    out["split_ms"] = {
        "encoder(I and R)": 1e3 * (t1 - t0),
        "MEM match": 1e3 * (t2 - t1),
        "MEM match+transfer": 1e3 * (t3 - t2),
        "decoder": 1e3 * (t4 - t3),
    }
    out["peak_rss_kib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return out


def _run_sizes(a: argparse.Namespace) -> list[dict]:
    """Each size measured in a fresh subprocess (its own peak RSS); results printed as JSON."""
    results = []
    for size in a.sizes.split(","):
        load = os.getloadavg()
        cmd = [sys.executable, __file__, "--_child", size, "--iters", a.iters,
               "--repeats", str(a.repeats), "--threads", str(a.threads)]  # fmt: skip
        res = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
        res["loadavg_before"] = load
        results.append(res)
        print(json.dumps(res), flush=True)
    return results


def _report_lines(
    a: argparse.Namespace, iters: list[int], meta: dict, results: list[dict]
) -> list[str]:
    """The Markdown report: times per size and iteration count, then the one-iteration split."""
    commit = meta["commit"]
    lines = [
        "# MaRINeR generator speed",
        "",
        f"`python benchmarks/mariner_speed.py` at commit {commit}; torch {meta['torch']}, "
        f"CPU ({meta['cpu_count']} cores, torch threads = {a.threads}); batch 1, render and "
        f"reference of the same size, random weights, `inference_mode`, median of {a.repeats} "
        "after one warm-up (min-max in brackets). No GPU was available in this session.",
        "",
        "| size | " + " | ".join(f"{k} it (ms)" for k in iters) + " | peak RSS (MiB) | load avg |",
        "|---|" + "---|" * len(iters) + "---|---|",
    ]
    for r in results:
        cells = [
            f"{r['ms'][str(k)]['median']:.0f} [{r['ms'][str(k)]['min']:.0f}-"
            f"{r['ms'][str(k)]['max']:.0f}]"
            for k in iters
        ]
        lines.append(
            f"| {r['size']} | " + " | ".join(cells)
            + f" | {r['peak_rss_kib'] / 1024:.0f} | {r['loadavg_before'][0]:.1f} |"
        )  # fmt: skip
    lines.append(
        "| paper (hardware/resolution not stated) | "
        + " | ".join(f"{PAPER_MS[k]}" for k in iters if k in PAPER_MS)
        + " | | |"
    )
    lines += ["", "One-iteration split (ms):", "", "| size | " + " | ".join(results[0]["split_ms"]) + " |",
              "|---|" + "---|" * len(results[0]["split_ms"])]  # fmt: skip
    for r in results:
        lines.append(
            f"| {r['size']} | " + " | ".join(f"{v:.0f}" for v in r["split_ms"].values()) + " |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--sizes", default="160x160,320x240,640x480")
    p.add_argument("--iters", default="1,2,3,4")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--out", type=Path, default=Path("reports/mariner_speed_spec.md"))
    p.add_argument("--_child", default=None, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    iters = [int(v) for v in a.iters.split(",")]
    if a._child:
        w, h = (int(v) for v in a._child.split("x"))
        print(json.dumps(run_size(w, h, iters, a.repeats, a.threads)))
        return 0
    import torch

    results = _run_sizes(a)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()  # fmt: skip
    meta = {
        "commit": commit,
        "torch": torch.__version__,
        "python": platform.python_version(),
        "cpu": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "threads": a.threads,
        "repeats": a.repeats,
        "device": "cpu (no GPU available in this session)",
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results}, indent=2))
    lines = _report_lines(a, iters, meta, results)
    a.out.write_text("\n".join(lines) + "\n")
    print(a.out.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
