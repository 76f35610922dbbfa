"""Error against run time over matcher x enhancement x MaRINeR iterations x working resolution.

Each grid point checks the same frames twice, once at the given pose and once with an injected
error (rotation 1-4 deg about a random axis + translation 5-20 cm, 2-5 % of the path span on the
castle), so every frame is both a negative and a positive. Per point: median / p90 seconds per
frame end to end and split by stage; detection ROC-AUC (corner error vs injected label);
median corner error on the given poses; median relative error of the PnP rotation estimate on
the injected frames. The grid is one-factor-at-a-time around base points (a full product is
days of CPU here). Marks the Pareto front (time vs 1 - AUC) and writes
reports/error_vs_runtime.md + reports/error_vs_runtime.png (+ .json).

Usage: python benchmarks/error_vs_runtime.py [--frames7 12] [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np
from _common import REPORTS, command_line, machine, md_table, shared_data

from pgt_check.config import RunConfig, merge
from pgt_check.io import read_trajectory
from pgt_check.measure import FrameChecker, pick_references
from pgt_check.threads import run_threads
from pgt_check.types import Trajectory
from pgt_eval import perturb_trajectory, roc_auc

STAGES = ("t_load_s", "t_render_s", "t_enhance_s", "t_match_s", "t_homography_s", "t_pose_s",
          "t_edges_s")


def grid(has_weights: bool, quick: bool) -> list[tuple[str, dict]]:
    pts: list[tuple[str, dict]] = []
    matchers = ["sift", "orb", "akaze", "xfeat"] + ([] if quick else ["aliked-lightglue",
                                                                       "disk-lightglue"])
    for m in matchers:
        pts.append((f"{m} / never / 640", {"match": {"method": m, "resize_max": 640},
                                             "enhance": {"mode": "never"}}))
    for m in ("sift", "xfeat"):
        for mode in ("auto", "always"):
            pts.append((f"{m} / {mode} reproject / 640",
                        {"match": {"method": m, "resize_max": 640},
                         "enhance": {"mode": mode, "method": "reproject"}}))
    if has_weights:
        for it in (1, 2, 3, 4) if not quick else (1, 2):
            pts.append((f"sift / always mariner it{it} / 640",
                        {"match": {"resize_max": 640},
                         "enhance": {"mode": "always", "method": "mariner", "iterations": it}}))
        pts.append(("sift / auto mariner it2 / 640",
                    {"match": {"resize_max": 640},
                     "enhance": {"mode": "auto", "method": "mariner", "iterations": 2}}))
        for ss in (240, 320):
            pts.append((f"sift / always mariner it2 short{ss} / 640",
                        {"match": {"resize_max": 640},
                         "enhance": {"mode": "always", "method": "mariner", "iterations": 2,
                                     "short_side": ss}}))
    for res in (320, 480, 960):
        pts.append((f"sift / never / {res}",
                    {"match": {"resize_max": res}, "enhance": {"mode": "never"}}))
        pts.append((f"sift / auto reproject / {res}",
                    {"match": {"resize_max": res}, "enhance": {"mode": "auto", "method": "reproject"}}))
    return pts


def datasets(data: Path, n7: int):
    k = data / "7scenes_redkitchen"
    t7 = read_trajectory(k / "trajectories.txt")
    step = max(1, len(t7) // n7)
    t7 = Trajectory(t7.frames[::step][:n7], t7.source, t7.format)
    c = data / "sceaux_castle"
    tc = read_trajectory(c / "trajectories.txt")
    cc = np.array([f.center for f in tc])
    span = float(np.linalg.norm(cc.max(0) - cc.min(0)))
    return [("7scenes", t7, k / "mesh.ply", (0.05, 0.20), {"verdict": {"threshold_px": 20.0}}),
            ("castle", tc, c / "mesh.ply", (0.02 * span, 0.05 * span), {})]


def run_point(traj, bad, mesh, base, point):
    cfg = RunConfig.from_dict(merge(merge({"input": {"trajectory": traj.source, "mesh": str(mesh)}},
                                          base), point))
    recs = []
    with run_threads(cfg.threads):  # OpenCV / BLAS threads as a run sets them
        for t in (traj, bad):
            checker = FrameChecker(cfg, pick_references(t, t.frames, cfg))
            checker.measure(t.frames[0])  # warm-up: GL context, model load
            recs.append([checker.measure(f).row() for f in t.frames])
            checker.close()
    return recs


def _summarise_point(dname: str, label: str, good: list, pert: list, inj: dict) -> dict:
    """One grid point's result: times, detection AUC, given-pose error and PnP error."""
    allr = good + pert
    times = [r["time_s"] for r in allr if r.get("time_s") is not None]
    err = np.array([math.inf if r["corner_error_px"] is None else r["corner_error_px"]
                    for r in allr])
    labels = np.array([False] * len(good) + [True] * len(pert))
    auc = roc_auc(err, labels)
    ge = [r["corner_error_px"] for r in good if r["corner_error_px"] is not None]
    rel = [abs(r["pose_drot_deg"] - inj[r["frame_id"]].rotation_deg)
           / inj[r["frame_id"]].rotation_deg for r in pert if r.get("pose_drot_deg") is not None]
    stages = {s: float(np.median([r.get(s) or 0.0 for r in allr])) for s in STAGES}
    return {"dataset": dname, "point": label, "auc": auc,
            "median_s": float(np.median(times)), "p90_s": float(np.percentile(times, 90)),
            "given_error_median": float(np.median(ge)) if ge else None,
            "given_verifiable": len(ge) / len(good),
            "pnp_rot_rel_err_median": float(np.median(rel)) if rel else None,
            "stages": stages}


def _run_grid(args: argparse.Namespace, data: Path, has_w: bool) -> list[dict]:
    """Every dataset x grid point measured at the given and the perturbed poses."""
    results = []
    for dname, traj, mesh, trans, base in datasets(data, args.frames7):
        bad, injected = perturb_trajectory(traj, 1.0, (1.0, 4.0), trans, seed=5)
        inj = {p.frame_id: p for p in injected}
        for label, point in grid(has_w, args.quick):
            if args.only and args.only not in label:
                continue
            good, pert = run_point(traj, bad, mesh, base, point)
            res = _summarise_point(dname, label, good, pert, inj)
            results.append(res)
            print(json.dumps(res), flush=True)
    return results


def _mark_pareto(results: list[dict]) -> None:
    """Pareto front per dataset: no other point is both faster and more accurate."""
    for d in {r["dataset"] for r in results}:
        pts = [r for r in results if r["dataset"] == d]
        for r in pts:
            r["pareto"] = not any(
                (o["median_s"] <= r["median_s"] and o["auc"] >= r["auc"])
                and (o["median_s"] < r["median_s"] or o["auc"] > r["auc"]) for o in pts)


def _plot(results: list[dict]) -> None:
    """AUC against median seconds per frame, one panel per dataset (Pareto front in red)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dsets = sorted({r["dataset"] for r in results})
    fig, axes = plt.subplots(1, len(dsets), figsize=(6.5 * len(dsets), 5))
    for ax, d in zip(np.atleast_1d(axes), dsets, strict=False):
        pts = sorted([r for r in results if r["dataset"] == d], key=lambda r: r["median_s"])
        for r in pts:
            ax.scatter(r["median_s"], r["auc"], c="tab:red" if r["pareto"] else "tab:gray", s=25)
            ax.annotate(r["point"], (r["median_s"], r["auc"]), fontsize=6, alpha=0.8)
        front = [r for r in pts if r["pareto"]]
        ax.plot([r["median_s"] for r in front], [r["auc"] for r in front], "r-", lw=1)
        ax.set_xscale("log")
        ax.set_xlabel("median seconds per frame (log)")
        ax.set_ylabel("detection ROC-AUC")
        ax.set_title(f"{d}: error vs run time (red = Pareto front)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    REPORTS.mkdir(exist_ok=True)
    fig.savefig(REPORTS / "error_vs_runtime.png", dpi=110)


def _write_report(results: list[dict], t_start: float) -> None:
    """Write reports/error_vs_runtime.md and .json and print the Markdown."""
    rows = [[r["dataset"], r["point"], r["median_s"], r["p90_s"], r["auc"],
             "-" if r["given_error_median"] is None else f"{r['given_error_median']:.2f}",
             f"{r['given_verifiable']:.2f}",
             "-" if r["pnp_rot_rel_err_median"] is None else f"{r['pnp_rot_rel_err_median']:.2f}",
             " / ".join(f"{1000 * r['stages'].get(s, 0.0):.0f}" for s in STAGES),
             "**yes**" if r["pareto"] else ""] for r in results]
    text = "\n".join([
        "# Error against run time",
        "",
        f"Machine: {machine()}; torch threads = 2, OpenCV / BLAS threads as a run sets them "
        f"(`threads`, default 1); load average at the end "
        f"{' / '.join(f'{x:.1f}' for x in os.getloadavg())} (1 / 5 / 15 min: other jobs on "
        f"the cores make the times pessimistic). Command: `{command_line()}`. "
        f"Total {time.perf_counter() - t_start:.0f} s.",
        "",
        "Grid points are `matcher / enhancement / longest side used for matching`, each with "
        "the rest of the defaults (the geometric-edge path on auto at its own size, as a run "
        "does; the default run is `sift / auto reproject / 320`). Each frame is "
        "checked at its given pose and with an injected error (every frame both a negative and "
        "a positive). AUC: ROC-AUC of the corner error against the injected label "
        "(unverifiable = flagged). Given error: median corner error on the given poses "
        "(verifiable frames; share verifiable beside it). PnP: median relative error of the "
        "estimated rotation correction on injected frames. Stage ms: load / render / enhance / "
        "match / homography / PnP / edges (medians).",
        "",
        "![error vs runtime](error_vs_runtime.png)",
        "",
        md_table(["dataset", "point", "median s", "p90 s", "AUC", "given err px", "verifiable",
                  "PnP rot rel err", "stage ms", "Pareto"], rows),
        "",
    ])
    (REPORTS / "error_vs_runtime.md").write_text(text)
    (REPORTS / "error_vs_runtime.json").write_text(json.dumps(results, indent=2))
    print(text)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames7", type=int, default=12)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", default=None, help="run only grid points containing this text")
    ap.add_argument("--append", action="store_true",
                    help="merge with reports/error_vs_runtime.json (replacing equal points)")
    args = ap.parse_args()
    data = shared_data()
    has_w = (Path(__file__).resolve().parents[1] / "mariner_core/weights/mariner.pt").is_file()
    t_start = time.perf_counter()
    results = _run_grid(args, data, has_w)
    if args.append and (REPORTS / "error_vs_runtime.json").is_file():
        old = json.loads((REPORTS / "error_vs_runtime.json").read_text())
        new_keys = {(r["dataset"], r["point"]) for r in results}
        results = [r for r in old if (r["dataset"], r["point"]) not in new_keys] + results
    _mark_pareto(results)
    _plot(results)
    _write_report(results, t_start)


if __name__ == "__main__":
    main()
