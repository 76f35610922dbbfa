"""Absolute evidence on colourless meshes (issue #13, item 5): learned matchers vs the edge path.

A colourless mesh renders as shaded geometry, which SIFT barely matches to a photo. This
measures, on shaded renders, the raw path of every feature matcher in the registry (SIFT,
DISK+LightGlue, ALIKED+LightGlue, XFeat, XFeat+LighterGlue; enhancement and edges off) and, as
the comparison, the geometric-edge path alone (SIFT raw + ``edges.mode = always``, enhancement
off). Datasets: the Sceaux castle (colourless MVS mesh) and 7-Scenes redkitchen rendered with
``render.shading = shaded`` (the vertex colours ignored). Cases: the given poses and a copy
with independent errors on 40 % of the frames (1-4 deg, 2-8 % of the scene depth; the
``per-frame`` case of ``shared_errors.py``).

Per method x dataset: the share of frames the path verifies (PASS or FAIL, i.e. a homography
with enough inliers; ``verdict.decide.path_outcome``), median inliers, PASS share on the given
poses, per-frame ROC-AUC on the perturbed copy (score = the path's corner error, unverifiable =
+inf), absolute 2D-3D evidence points per frame (``FrameMeasurement.evidence``) and the
median seconds per frame (``FrameChecker.measure`` after one warm-up frame). Measurements are
cached under /tmp/pgt-check-colourless-cache; ``--from-json`` only rewrites the reports, and
``--findings FILE`` adds hand-written text (kept in the .json). DISK+LightGlue is measured on
every 2nd frame by default (``--stride``): ~10 s/frame on 2 shared CPU cores.
Writes reports/colourless_evidence.md, .json and .png.

    python benchmarks/colourless_evidence.py [--frames 20] [--datasets castle,7s-colourless]
        [--methods sift,edges,xfeat,...]
"""

from __future__ import annotations

import argparse
import json
import time
import traceback
from pathlib import Path

import numpy as np
import shared_errors
from _common import REPORTS, command_line, machine, md_table
from shared_errors import cases, datasets, scene_depth

from pgt_check.config import RunConfig
from pgt_check.types import Trajectory
from pgt_check.verdict.decide import path_outcome
from pgt_check.verdict.judgement import Verdict
from pgt_eval import roc_auc

CACHE = Path("/tmp/pgt-check-colourless-cache")

#: method label -> (config overrides, path judged); enhancement is off for all of them
METHODS: dict[str, tuple[dict, str]] = {
    "edges": ({"match": {"method": "sift"}, "edges": {"mode": "always"}}, "edges"),
    "sift": ({"match": {"method": "sift"}, "edges": {"mode": "never"}}, "raw"),
    "xfeat": ({"match": {"method": "xfeat"}, "edges": {"mode": "never"}}, "raw"),
    "aliked-lightglue": (
        {"match": {"method": "aliked-lightglue"}, "edges": {"mode": "never"}}, "raw"),
    "xfeat-lighterglue": (
        {"match": {"method": "xfeat-lighterglue"}, "edges": {"mode": "never"}}, "raw"),
    "disk-lightglue": ({"match": {"method": "disk-lightglue"}, "edges": {"mode": "never"}}, "raw"),
}
LABELS = {"edges": "edge path (SIFT raw + edges always)"}
BASE = {"enhance": {"mode": "never"}}
CASES = ("given", "per-frame")


def load_error(method: str) -> str | None:
    """Build the matcher once (offline weights); the error text if it cannot be built."""
    from pgt_check.match import make_matcher

    try:
        make_matcher(method, max_keypoints=RunConfig().match.max_keypoints)
    except Exception as err:  # recorded in the report, the other methods go on
        return f"{type(err).__name__}: {err}".strip()
    return None


def measure(traj, mesh, cfgd: dict, key: str):
    """``shared_errors.measure`` with this benchmark's cache folder."""
    shared_errors.CACHE = CACHE
    return shared_errors.measure(traj, mesh, cfgd, key)


def summarise(ms, cfg: RunConfig, path: str, labels: set[str] | None) -> dict:
    outs = [path_outcome(m, getattr(m, path), cfg.verdict) for m in ms]
    verdicts = [v for v, _ in outs]
    ok = np.array([v is not Verdict.UNVERIFIABLE for v in verdicts])
    paths = [getattr(m, path) for m in ms]
    inl = [p.n_inliers if p is not None else 0 for p in paths]
    err = np.array(
        [
            p.corner_error_px if o and p.corner_error_px is not None else np.inf
            for p, o in zip(paths, ok, strict=True)
        ],
        float,
    )
    totals = [m.timings.total for m in ms if m.timings.total is not None]
    out = {
        "frames": len(ms),
        "verifiable": float(ok.mean()),
        "pass": float(np.mean([v is Verdict.PASS for v in verdicts])),
        "fail": float(np.mean([v is Verdict.FAIL for v in verdicts])),
        "median_inliers": float(np.median(inl)),
        #: over the verifiable frames: on the given poses, how precisely the path aligns
        "median_corner_err": float(np.median(err[ok])) if ok.any() else None,
        "threshold_px": cfg.verdict.threshold_for(ms[0].width, ms[0].height) if ms else None,
        "median_evidence": float(np.median([len(m.evidence or ()) for m in ms])),
        "median_s_frame": float(np.median(totals)) if totals else None,
        "errors": sorted({m.error_detail.splitlines()[-1] for m in ms if m.error_detail})[:3],
        "reasons": _count(r or "ok" for _, r in outs),
    }
    if labels is not None:
        lab = np.array([m.frame_id in labels for m in ms])
        try:
            out["auc"] = roc_auc(err, lab)
        except ValueError:  # a subsample (--stride) with only good or only bad frames
            out["auc"] = None
        flagged = np.array([v is not Verdict.PASS for v in verdicts])
        out["flagged_bad"] = f"{int((flagged & lab).sum())}/{int(lab.sum())}"
        out["flagged_good"] = f"{int((flagged & ~lab).sum())}/{int((~lab).sum())}"
    return out


def _count(items) -> dict[str, int]:
    d: dict[str, int] = {}
    for x in items:
        x = x.split(" ")[0]  # "corner_error 12.3 px > ..." -> "corner_error"
        d[x] = d.get(x, 0) + 1
    return d


def run(args: argparse.Namespace) -> dict:
    methods = args.methods.split(",")
    unknown = set(methods) - set(METHODS)
    if unknown:
        raise SystemExit(f"unknown methods {sorted(unknown)}; choose from {list(METHODS)}")
    if "edges" in methods:  # first: its given-pose run fixes the scene depth of the perturbation
        methods = ["edges", *[m for m in methods if m != "edges"]]
    results: dict = {"methods": {}, "datasets": {}}
    sets = datasets(args.datasets.split(","), args.frames)
    strides = {k: int(v) for k, v in (x.split(":") for x in args.stride.split(",") if x)}
    for method in methods:
        err = None if METHODS[method][1] == "edges" else load_error(METHODS[method][0]["match"]["method"])
        results["methods"][method] = {"label": LABELS.get(method, method), "load_error": err,
                                      "stride": strides.get(method, 1)}
        if err:
            print(method, "load error:", err, flush=True)
    prepared = {}
    for name, (traj, mesh, cfgd) in sets.items():
        # only the rendering setting of the dataset is used (verdict settings are not needed:
        # each path is judged alone with the default thresholds, calibration kept)
        base = {**BASE, **({"render": cfgd["render"]} if "render" in cfgd else {})}
        _, ms_e, _ = measure(traj, mesh, {**base, **METHODS["edges"][0]},
                             f"{name}-n{args.frames}-given-edges")
        depth = scene_depth(ms_e)  # the edge path's evidence: the same perturbation for all
        prepared[name] = (mesh, base, cases(traj, depth))
        results["datasets"][name] = {"frames": len(traj.frames), "depth": depth,
                                     "config": base, "rows": {}}
    for method in methods:  # slowest last: a cut-short run still has the fast ones
        if results["methods"][method]["load_error"]:
            continue
        over, path = METHODS[method]
        k = strides.get(method, 1)
        for name, (mesh, base, all_cases) in prepared.items():
            row: dict = {}
            for case in CASES:
                t, truth = all_cases[case]
                if k > 1:  # a very slow matcher: every k-th frame only (labels by frame id)
                    t = Trajectory(tuple(t.frames[::k]), t.source, t.format)
                t0 = time.perf_counter()
                key = f"{name}-n{args.frames}-{case}-{method}" + (f"-every{k}" if k > 1 else "")
                try:
                    cfg, ms, tpf = measure(t, mesh, {**base, **over}, key)
                except Exception as exc:  # recorded, the other methods go on
                    row[case] = {"error": f"{type(exc).__name__}: {exc}"}
                    traceback.print_exc()
                    continue
                s = summarise(ms, cfg, path, truth.get("labels"))
                s["mean_s_frame"] = tpf
                row[case] = s
                print(name, method, case, json.dumps(s), f"({time.perf_counter() - t0:.0f} s)",
                      flush=True)
            results["datasets"][name]["rows"][method] = row
            write_reports(results)
    return results


def _f(x, spec=".2f") -> str:
    return "" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def _pct(x) -> str:
    return "" if x is None else f"{x:.0%}"


def _report_intro(results: dict) -> list[str]:
    """The report's title, command, machine and how to read the tables."""
    return [
        "# Absolute evidence on colourless meshes: learned matchers vs the edge path\n",
        f"Command: `{results['command']}`\n",
        f"Machine: {results['machine']}. The 2 cores were shared with another job: absolute "
        "times are pessimistic; compare within this table. torch CPU, default working size "
        "(longest side 640 px), `max_keypoints` 4096.\n",
        "Each method's raw path on the shaded render (enhancement off, edges off), and the "
        "geometric-edge path alone (SIFT raw + `edges.mode = always`, enhancement off), judged "
        "by `path_outcome` with the default verdict settings (per-frame threshold 2 % of the "
        "diagonal; calibration not removed). Verifiable = PASS or FAIL (a homography with "
        "enough inliers). AUC = per-frame ROC-AUC on the perturbed copy (40 % of the frames "
        "moved by 1-4 deg and 2-8 % of the scene depth; score = the path's corner error, "
        "unverifiable = +inf, i.e. counted as flagged). Evidence = absolute 2D-3D points per "
        "frame (median, given poses; the edge row also holds SIFT's raw inliers). s/frame = "
        "median of `FrameChecker.measure` per frame (render, match, homography, PnP, edges).\n",
    ]


def _dataset_section(name: str, ds: dict, results: dict) -> list[str]:
    """Report lines of one dataset: the per-method table and the path outcomes."""
    lines: list[str] = []
    thr = next((r["given"].get("threshold_px") for r in ds["rows"].values()
                if r.get("given", {}).get("threshold_px")), None)
    lines.append(f"\n## {name} ({ds['frames']} frames, median depth {ds['depth']:.3g}, "
                 f"per-frame threshold {_f(thr, '.1f')} px, "
                 f"config `{json.dumps(ds['config'])}`)\n")
    rows = []
    for method, row in ds["rows"].items():
        g, p = row.get("given", {}), row.get("per-frame", {})
        rows.append([
            results["methods"][method]["label"],
            f"{g.get('frames', '')}+{p.get('frames', '')}",
            _pct(g.get("verifiable")),
            _pct(p.get("verifiable")),
            _f(g.get("median_inliers"), ".0f"),
            _f(g.get("median_corner_err"), ".1f"),
            _pct(g.get("pass")),
            _f(p.get("auc")),
            p.get("flagged_bad", ""),
            p.get("flagged_good", ""),
            _f(g.get("median_evidence"), ".0f"),
            _f(g.get("median_s_frame")),
            g.get("error") or p.get("error") or "; ".join(g.get("errors", [])),
        ])
    lines.append(md_table(
        ["method", "frames (given+perturbed)", "verifiable (given)", "verifiable (perturbed)", "median inliers (given)",
         "median corner error px (given)", "PASS (given)", "per-frame AUC", "perturbed: bad flagged", "good flagged",
         "evidence pts/frame", "s/frame", "errors"],
        rows,
    ))
    lines.append("\nReasons on the given poses (path outcome):\n")
    lines.append(md_table(
        ["method", "outcomes"],
        [[results["methods"][m]["label"],
          ", ".join(f"{k} {v}" for k, v in r.get("given", {}).get("reasons", {}).items())]
         for m, r in ds["rows"].items()],
    ))
    return lines


def write_reports(results: dict) -> None:
    results["command"] = results.get("command") or command_line()
    results["machine"] = results.get("machine") or machine()
    REPORTS.mkdir(exist_ok=True)
    (REPORTS / "colourless_evidence.json").write_text(json.dumps(results, indent=1, default=str))
    lines = _report_intro(results)
    for name, ds in results["datasets"].items():
        lines += _dataset_section(name, ds, results)
    failed = {m: d["load_error"] for m, d in results["methods"].items() if d["load_error"]}
    if failed:
        lines.append("\n## Matchers that did not load\n")
        lines += [f"- {m}: `{e}`" for m, e in failed.items()]
    if results.get("findings"):
        lines.append("\n## What the numbers say\n")
        lines.append(results["findings"])
    lines.append("\n![verifiable share, PASS share and AUC vs seconds per frame](colourless_evidence.png)\n")
    (REPORTS / "colourless_evidence.md").write_text("\n".join(lines) + "\n")
    plot(results)


def plot(results: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    markers = dict(zip(METHODS, "s o ^ v D P".split(), strict=True))
    colours = dict(zip(results["datasets"], ["tab:blue", "tab:orange", "tab:green"], strict=False))
    for name, ds in results["datasets"].items():
        for method, row in ds["rows"].items():
            g, p = row.get("given", {}), row.get("per-frame", {})
            t = g.get("median_s_frame")
            if t is None:
                continue
            for ax, y in ((axes[0], g.get("verifiable")), (axes[1], g.get("pass")),
                          (axes[2], p.get("auc"))):
                if y is None:
                    continue
                ax.scatter(t, y, marker=markers.get(method, "o"), color=colours[name], s=60,
                           label=f"{name}: {method}")
                ax.annotate(method, (t, y), fontsize=7, xytext=(4, 3),
                            textcoords="offset points")
    for ax, title in ((axes[0], "share of frames verifiable (given poses)"),
                      (axes[1], "PASS share on the given (good) poses"),
                      (axes[2], "per-frame ROC-AUC (perturbed copy)")):
        ax.set_xscale("log")
        ax.set_xlabel("median seconds per frame (2 shared CPU cores)")
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=n) for n, c in colours.items()]
    axes[0].legend(handles=handles, fontsize=8, loc="center right")
    fig.suptitle("Colourless meshes (shaded renders): raw path per matcher vs the edge path",
                 fontsize=11)
    fig.tight_layout()
    fig.savefig(REPORTS / "colourless_evidence.png", dpi=110)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=20, help="7-Scenes frames (subsampled)")
    p.add_argument("--datasets", default="castle,7s-colourless")
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--stride", default="disk-lightglue:2",
                   help="method:k,... measure only every k-th frame of a very slow matcher")
    p.add_argument("--findings", type=Path, help="Markdown file: the 'what the numbers say' text")
    p.add_argument("--from-json", action="store_true",
                   help="only rewrite the reports from reports/colourless_evidence.json")
    args = p.parse_args()
    if args.from_json:
        results = json.loads((REPORTS / "colourless_evidence.json").read_text())
    else:
        results = run(args)
    if args.findings:
        results["findings"] = args.findings.read_text().strip()
    write_reports(results)


if __name__ == "__main__":
    main()
