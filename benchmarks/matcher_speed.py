"""Matcher speed and match counts on real 7-Scenes redkitchen photo pairs (frame n vs n + 10).

Per matcher: median (min-max) seconds per pair at the working size, median matches, and the
median share of matches consistent with a fundamental matrix (RANSAC, 1.5 px). One warm-up
pair is matched first and not timed (model loading, first-call allocation). Writes
``reports/matcher_speed.md`` and ``reports/matcher_speed.json``.

    python benchmarks/matcher_speed.py [--matchers xfeat,...] [--pairs 10] [--threads N]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from _common import REPORTS, command_line, machine, md_table, shared_data

DEFAULT = "sift,xfeat,xfeat-lighterglue,aliked-lightglue,disk-lightglue"


def load(path: Path, size: tuple[int, int]) -> np.ndarray:
    from pgt_check.errors import InputError
    from pgt_check.io.images import load_image, resize_image

    try:
        return resize_image(load_image(path), size)
    except InputError as err:
        sys.exit(str(err))


def _load_pairs(args: argparse.Namespace, size: tuple[int, ...]) -> tuple[list, list]:
    """Disjoint photo pairs of the 7-Scenes folder -> (pairs of paths, pairs of images)."""
    folder = shared_data() / "7scenes_redkitchen" / "images"
    names = sorted(p.name for p in folder.glob("frame-*.color.jpg"))
    # pair k: file 2*step*k vs file 2*step*k + step (disjoint pairs)
    idx = [(2 * args.step * k, 2 * args.step * k + args.step) for k in range(args.pairs + 1)]
    pairs = [(folder / names[a], folder / names[b]) for a, b in idx if b < len(names)]
    if len(pairs) < args.pairs + 1:
        sys.exit(f"only {len(pairs)} pairs available in {folder}")
    images = [(load(a, size), load(b, size)) for a, b in pairs]
    return pairs, images


def _time_matcher(matcher, images: list) -> tuple[list, list, list]:
    """Match every pair after the first (an untimed warm-up) -> (seconds, matches, F-inlier
    shares) per pair."""
    import cv2

    matcher.match(*images[0])  # warm-up, not timed
    times, counts, ratios = [], [], []
    for im0, im1 in images[1:]:
        t0 = time.perf_counter()
        m = matcher.match(im0, im1)
        times.append(time.perf_counter() - t0)
        counts.append(len(m))
        ratio = 0.0
        if len(m) >= 8:
            _, inl = cv2.findFundamentalMat(m.kpts0, m.kpts1, cv2.FM_RANSAC, 1.5, 0.999, 2000)
            ratio = float(inl.mean()) if inl is not None else 0.0
        ratios.append(ratio)
    return times, counts, ratios


def _write_report(args: argparse.Namespace, meta: dict, pairs: list, rows: list,
                  threads: int) -> None:
    """Write reports/matcher_speed.md."""
    table = md_table(
        ["matcher", "median s/pair", "range s", "median matches", "range", "median F-inlier share"],
        rows,
    )
    text = f"""# Matcher speed on 7-Scenes redkitchen photo pairs

- Machine: {meta["machine"]}; torch {meta["torch"]}, {threads} torch threads, CPU.
- **The machine was shared** with other jobs (a network training in the background), so the
  absolute times are pessimistic and noisy; compare matchers within this table only. Load
  average (1/5/15 min) at the end of the run: {meta["load_average_at_end"]}.
- Command: `{meta["command"]}`
- {len(pairs) - 1} pairs at {args.size} (file i vs file i + {args.step} of the folder, i.e. frame
  n vs n + {10 * args.step}; first pair = untimed
  warm-up): {", ".join(f"{a.stem.split('.')[0]}/{b.stem.split('.')[0]}" for a, b in pairs[1:])}.
- Photo vs photo (no render): timings cover matching only (detection of both images + matching),
  not rendering. `max_keypoints` 2048 for the learned matchers, defaults otherwise. F-inlier share:
  matches consistent with a fundamental matrix (OpenCV RANSAC, 1.5 px).

{table}
"""
    (REPORTS / "matcher_speed.md").write_text(text)


def main(argv: list[str] | None = None) -> int:
    from pgt_check.match import make_matcher

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--matchers", default=DEFAULT)
    ap.add_argument("--pairs", type=int, default=10)
    ap.add_argument(
        "--step",
        type=int,
        default=1,
        help="gap within a pair, in files (the folder holds every 10th frame)",
    )
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    size = tuple(int(v) for v in args.size.split("x"))
    pairs, images = _load_pairs(args, size)

    import torch

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    threads = torch.get_num_threads()
    rows, results = [], {}
    for name in args.matchers.split(","):
        options = {} if name in ("sift", "orb", "akaze") else {"max_keypoints": 2048}
        matcher = make_matcher(name, **options)
        times, counts, ratios = _time_matcher(matcher, images)
        med = statistics.median(times)
        results[name] = {"seconds": times, "matches": counts, "f_inlier_ratio": ratios}
        rows.append(
            [
                name,
                med,
                f"{min(times):.2f}-{max(times):.2f}",
                int(statistics.median(counts)),
                f"{min(counts)}-{max(counts)}",
                statistics.median(ratios),
            ]
        )
        print(f"{name}: {med:.3f} s/pair, {statistics.median(counts)} matches", flush=True)

    meta = {
        "machine": machine(),
        "torch_threads": threads,
        "torch": torch.__version__,
        "command": command_line(),
        "size": args.size,
        "load_average_at_end": os.getloadavg(),
        "pairs": [[a.name, b.name] for a, b in pairs[1:]],
    }
    REPORTS.mkdir(exist_ok=True)
    (REPORTS / "matcher_speed.json").write_text(json.dumps({**meta, "results": results}, indent=1))
    _write_report(args, meta, pairs, rows, threads)
    print(f"wrote {REPORTS / 'matcher_speed.md'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
