"""Render speed of the moderngl and pyrender backends (ms/frame) and how closely they agree.

Scenes: the committed sample scene (textured GLB, 320x240 camera) and, when ../shared/data
exists, the 7-Scenes redkitchen TSDF mesh (vertex colours, 640x480 camera). Each scene's camera
is scaled to 320 and 640 px wide. Per backend: start-up (renderer construction + first frame:
context, upload, shader compile), then ``--frames`` timed renders cycling through the
trajectory (after 2 untimed warm-up frames); median and min-max ms/frame. Agreement with
moderngl on the same frames: coverage masks, median relative depth difference, median colour
difference. Writes ``reports/renderer_speed.md``, ``.json`` and ``.png``.

    python benchmarks/renderer_speed.py [--frames 20] [--sizes 320,640] [--no-shared]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import time
from pathlib import Path

import numpy as np

from benchmarks._common import REPO, REPORTS, command_line, machine, md_table

BACKENDS = ("moderngl", "pyrender")


def scenes(use_shared: bool) -> list[tuple[str, Path, Path]]:
    """(name, mesh, trajectory) of each available scene."""
    out = [
        (
            "sample (textured GLB)",
            REPO / "sample_data/scene/mesh.glb",
            REPO / "sample_data/scene/trajectories.txt",
        )
    ]
    shared = Path(os.environ.get("PGT_SHARED_DATA", REPO.parent / "shared" / "data"))
    kitchen = shared / "7scenes_redkitchen"
    if use_shared and (kitchen / "mesh.ply").is_file():
        out.append(
            (
                "7-Scenes redkitchen (vertex colours)",
                kitchen / "mesh.ply",
                kitchen / "trajectories.txt",
            )
        )
    elif use_shared:
        logging.warning("shared data not found at %s: sample scene only", shared)
    return out


def bench_backend(backend: str, mesh, frames, scale: float, n: int) -> dict:
    from pgt_check.render import make_renderer

    t0 = time.perf_counter()
    renderer = make_renderer(mesh, backend=backend)
    f0 = frames[0]
    renderer.render(f0.camera.scaled(scale), f0.world_from_cam)
    startup = time.perf_counter() - t0
    try:
        for f in frames[1:3]:  # warm-up
            renderer.render(f.camera.scaled(scale), f.world_from_cam)
        times, renders = [], []
        for i in range(n):
            f = frames[i % len(frames)]
            cam = f.camera.scaled(scale)
            t = time.perf_counter()
            r = renderer.render(cam, f.world_from_cam)
            times.append(time.perf_counter() - t)
            if i < len(frames):
                renders.append(r)
    finally:
        renderer.close()
    return {
        "startup_s": startup,
        "ms": [1000 * t for t in times],
        "renders": renders,
        "size": f"{renders[0].rgb.shape[1]}x{renders[0].rgb.shape[0]}",
    }


def agreement(ref: list, other: list) -> dict[str, float]:
    cov, depth, colour = [], [], []
    for a, b in zip(ref, other, strict=True):
        both = a.coverage & b.coverage
        cov.append(float((a.coverage == b.coverage).mean()))
        if both.any():
            depth.append(float(np.median(np.abs(a.depth[both] - b.depth[both]) / a.depth[both])))
            colour.append(float(np.median(np.abs(a.rgb[both] - b.rgb[both]))))
    return {
        "coverage_agree_min": min(cov),
        "depth_rel_median": statistics.median(depth) if depth else float("nan"),
        "colour_median": statistics.median(colour) if colour else float("nan"),
    }


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = sorted(
        {(r["scene"], r["size"]) for r in results}, key=lambda k: (k[0], int(k[1].split("x")[0]))
    )
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(8, 4))
    for i, backend in enumerate(BACKENDS):
        med, lo, hi = [], [], []
        for scene, size in labels:
            r = next(
                r
                for r in results
                if r["scene"] == scene and r["size"] == size and r["backend"] == backend
            )
            med.append(r["ms_median"])
            lo.append(r["ms_median"] - r["ms_min"])
            hi.append(r["ms_max"] - r["ms_median"])
        ax.bar(x + (i - 0.5) * 0.38, med, 0.38, yerr=[lo, hi], capsize=3, label=backend)
    ax.set_xticks(x, [f"{s.split(' (')[0]}\n{size}" for s, size in labels])
    ax.set_ylabel("ms / frame (median, min-max)")
    ax.set_title("Render time per frame (CPU llvmpipe, EGL)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _bench_scenes(args: argparse.Namespace, widths: list[int]) -> tuple[list[dict], list[dict]]:
    """Every scene x width x backend timed -> (result rows, loaded meshes)."""
    from pgt_check.io import read_trajectory
    from pgt_check.render import load_mesh

    results = []
    meshes = []
    for name, mesh_path, traj_path in scenes(not args.no_shared):
        t = time.perf_counter()
        mesh = load_mesh(mesh_path)
        load_s = time.perf_counter() - t
        frames = read_trajectory(traj_path).frames
        meshes.append(
            {"scene": name, "faces": mesh.num_faces, "shading": mesh.shading, "load_s": load_s}
        )
        for width in widths:
            scale = width / frames[0].camera.width
            runs = {b: bench_backend(b, mesh, frames, scale, args.frames) for b in BACKENDS}
            for b, run in runs.items():
                ms = run["ms"]
                row = {
                    "scene": name,
                    "size": run["size"],
                    "backend": b,
                    "startup_s": run["startup_s"],
                    "ms_median": statistics.median(ms),
                    "ms_min": min(ms),
                    "ms_max": max(ms),
                    **agreement(runs["moderngl"]["renders"], run["renders"]),
                }
                results.append(row)
                print(
                    f"{name} {run['size']} {b}: {row['ms_median']:.1f} ms/frame, "
                    f"start-up {row['startup_s']:.2f} s",
                    flush=True,
                )
    return results, meshes


def _results_table(results: list[dict]) -> str:
    """The Markdown table of the timings and the agreement with moderngl."""
    rows = [
        [
            r["scene"],
            r["size"],
            r["backend"],
            f"{r['ms_median']:.1f}",
            f"{r['ms_min']:.1f}-{r['ms_max']:.1f}",
            f"{r['startup_s']:.2f}",
            f"{100 * r['coverage_agree_min']:.2f}",
            f"{r['depth_rel_median']:.1e}",
            f"{r['colour_median']:.4f}",
        ]
        for r in results
    ]
    return md_table(
        [
            "scene",
            "size",
            "backend",
            "median ms/frame",
            "range ms",
            "start-up s",
            "coverage agree % (min)",
            "depth rel. diff (median)",
            "colour diff (median)",
        ],
        rows,
    )


def _report_text(args: argparse.Namespace, results: list[dict], meshes: list[dict],
                 versions: dict[str, str], load_start, load_end, png: Path) -> str:
    """The Markdown report."""
    table = _results_table(results)
    mesh_lines = "\n".join(
        f"- {m['scene']}: {m['faces']} faces, shading `{m['shading']}`, loaded in {m['load_s']:.2f} s"
        for m in meshes
    )
    return f"""# Renderer speed: moderngl vs pyrender

- Machine: {machine()}; Mesa llvmpipe (CPU) through EGL; moderngl {versions["moderngl"]},
  pyrender {versions["pyrender"]}, PyOpenGL {versions["PyOpenGL"]}.
- Load average (1/5/15 min) at start {load_start[0]:.2f}/{load_start[1]:.2f}/{load_start[2]:.2f},
  at end {load_end[0]:.2f}/{load_end[1]:.2f}/{load_end[2]:.2f}: the machine is shared with other
  jobs, so absolute times are noisy; compare the backends within one row pair.
- Command: `{command_line()}`
- {args.frames} timed frames per backend and size (2 untimed warm-up frames first), cycling
  through the trajectory; the camera is scaled to each width. Start-up = renderer construction
  + first frame (GL context, mesh upload, shader compile). Both backends run with their
  defaults (pyrender: MSAA off, near_ratio 1e-3, 8-bit colour read-back).
- Agreement columns compare each backend's renders with moderngl's on the same frames
  (moderngl rows compare with themselves: 100 %, 0).
{mesh_lines}

{table}

![ms per frame]({png.name})
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20, help="timed frames per backend and size")
    ap.add_argument("--sizes", default="320,640", help="image widths in px")
    ap.add_argument("--no-shared", action="store_true", help="sample scene only")
    ap.add_argument("--out", type=Path, default=REPORTS / "renderer_speed.md")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    widths = [int(w) for w in args.sizes.split(",")]
    load_start = os.getloadavg()

    results, meshes = _bench_scenes(args, widths)
    load_end = os.getloadavg()

    from importlib import metadata

    versions = {p: metadata.version(p) for p in ("moderngl", "pyrender", "PyOpenGL")}
    out: Path = args.out
    png = out.with_suffix(".png")
    plot(results, png)
    out.with_suffix(".json").write_text(
        json.dumps({"meshes": meshes, "results": results, "versions": versions}, indent=1) + "\n"
    )
    text = _report_text(args, results, meshes, versions, load_start, load_end, png)
    out.write_text(text)
    print(f"wrote {out}, {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
