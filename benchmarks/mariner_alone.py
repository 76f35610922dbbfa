"""Issue #38 item 5 on every shared scene: MaRINeR evidence alone on colourless renders.

The issue's protocol (``--enhance-method mariner --enhance always --edges never``, the mesh
rendered without its colours, 40 frames of which 40 % carry their own errors with wrong
neighbours, 7-Scenes with ``--remove-calibration``) measured the enhanced path alone deciding
4 of 24 correct 7-Scenes frames PASS at per-frame AUC 0.47. What it asks: the verdict must not
rest on a path that cannot tell right from wrong on the run (``verdict.separation``: each path
probed at poses moved by known amounts; a path that does not rank its given poses lowest
decides no frame, UNVERIFIABLE ``path_cannot_separate``).

Per scene (``scenes_loso``'s scenes and frame choice, colourless copies), judged as a run
judges (``shared_errors.as_run``: the reference pass and the separation probes):

* the enhanced path's own separating power on the wrong frames: its per-frame ROC-AUC (the
  enhanced corner error, no homography = worst), and the separation check's verdict on it
  (status, p-value);
* verdicts of the correct and the wrong frames (PASS / FAIL / UNVERIFIABLE; how many
  UNVERIFIABLE ``path_cannot_separate``), and the PASS among wrong frames whose injected
  error's image effect is above the threshold (must be none).

A path the check lets decide must separate (AUC well above 0.5); a path that cannot separate
must decide no frame. Measurements are cached (``shared_errors.measure``, keys
``item5-<scene>-<case>``). Writes reports/mariner_alone.md and .json.

    python benchmarks/mariner_alone.py [--frames 40] [--scene 7scenes_redkitchen ...]
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter

import numpy as np
import scenes_loso
from _common import REPORTS, command_line, machine, md_table
from shared_errors import as_run, measure, scene_depth

#: the issue's settings (item 5), on top of the colourless rendering
PROTOCOL = {"render": {"shading": "shaded"}, "enhance": {"mode": "always", "method": "mariner"},
            "edges": {"mode": "never"}}


def judged_rows(traj, mesh, cfgd: dict, key: str):
    """The run's rows and its separation summary for ``traj`` measured with ``cfgd``."""
    from pgt_check.verdict import judge_run

    cfg, ms, tpf = measure(traj, mesh, cfgd, key)
    jc = scenes_loso._cfg(mesh, cfgd)
    r_ms, probes = as_run(traj, ms, jc, key)
    j = judge_run(r_ms, jc, probes)
    sep = j.separation.summary() if j.separation is not None and j.separation.paths else {}
    return j.rows(), sep, tpf, ms


def injected_effect_px(m, given: np.ndarray, bad: np.ndarray, depth: float) -> float:
    """The image effect of a frame's injected error: ``scenes_loso.image_shift`` between the
    given and the injected pose over a 5 x 5 grid of image points lifted at the scene's median
    depth with the given pose (the colourless renders leave too few evidence points to use the
    frame's own)."""
    from pgt_check.geometry.transforms import apply_rigid
    from pgt_check.verdict.calibration import camera_matrix

    k = camera_matrix(m.intrinsics)
    u, v = np.meshgrid(np.linspace(0, m.width - 1, 5), np.linspace(0, m.height - 1, 5))
    rays = np.linalg.solve(k, np.vstack([u.ravel(), v.ravel(), np.ones(u.size)])).T
    world = apply_rigid(np.asarray(given, np.float64), rays * depth)
    return scenes_loso.image_shift(given, bad, world, k)


def run_scene(name: str, n: int) -> dict:
    from pgt_eval import perturb_runs, roc_auc

    scenes_loso.SHADING = "shaded"
    traj, mesh, _ = scenes_loso.load_scene(name, n)
    cfgd = json.loads(json.dumps(PROTOCOL))
    if name.startswith("7scenes"):
        cfgd["run_checks"] = {"remove_calibration": True}
    t0 = time.perf_counter()
    g_rows, _, _, g_ms = judged_rows(traj, mesh, cfgd, f"item5-{name}-n{n}-given")
    depth = scene_depth(g_ms)  # the errors' scale, as scenes_loso's
    if not np.isfinite(depth):  # no evidence on the colourless renders: the coloured run's
        scenes_loso.SHADING = None
        t30, _, _ = scenes_loso.load_scene(name, 30)
        depth = scene_depth(measure(t30, mesh, {}, f"{scenes_loso._prefix(name)}-given")[1])
        scenes_loso.SHADING = "shaded"
    bad, inj = perturb_runs(traj, 0.4, (0.5, 4.0), (0.01 * depth, 0.08 * depth), seed=3)
    wrong = {p.frame_id for p in inj}
    rows, sep, tpf, _ = judged_rows(bad, mesh, cfgd, f"item5-{name}-n{n}-per-frame")
    g_by, b_by = traj.by_id(), bad.by_id()
    effect = {m.frame_id: injected_effect_px(m, g_by[m.frame_id].world_from_cam,
                                             b_by[m.frame_id].world_from_cam, depth)
              for m in g_ms if m.frame_id in wrong and m.intrinsics is not None}
    thr = {r["frame_id"]: r.get("threshold_px") for r in rows}
    labels = np.array([r["frame_id"] in wrong for r in rows])
    enh = np.array([np.inf if r.get("corner_error_px_enhanced") is None
                    else r["corner_error_px_enhanced"] for r in rows])
    head = np.array([np.inf if r.get("corner_error_px") is None else r["corner_error_px"]
                     for r in rows])
    enh_sep = sep.get("paths", {}).get("enhanced", {}) if sep else {}

    def verdicts(mask) -> dict:
        sel = [r for r, m in zip(rows, mask, strict=True) if m]
        return {"n": len(sel), **Counter(r["verdict"] for r in sel),
                "cannot_separate": sum(str(r.get("reason", "")).startswith("path_cannot_separate")
                                       for r in sel)}

    return {
        "scene": name, "frames": len(rows), "wrong": int(labels.sum()),
        "enhanced_auc": roc_auc(enh, labels) if 0 < labels.sum() < len(labels) else None,
        "headline_auc": roc_auc(head, labels) if 0 < labels.sum() < len(labels) else None,
        "separation": {k: enh_sep.get(k) for k in ("status", "p_value", "n_frames", "n_higher")},
        "barred": sep.get("barred", []) if sep else [],
        "correct": verdicts(~labels), "wrong_frames": verdicts(labels),
        # the wrong frames that PASS: their injected error's image effect against the threshold
        # (a PASS of an injection below the threshold is right)
        "wrong_pass": [{"frame_id": r["frame_id"], "effect_px": effect.get(r["frame_id"]),
                        "threshold_px": thr.get(r["frame_id"])}
                       for r in rows if r["frame_id"] in wrong and r["verdict"] == "PASS"],
        "given": {"n": len(g_rows), **Counter(r["verdict"] for r in g_rows)},
        "s_per_frame": tpf, "seconds": time.perf_counter() - t0,
    }


def _v(d: dict) -> str:
    parts = [f"{d.get(k, 0)} {k}" for k in ("PASS", "FAIL", "UNVERIFIABLE")]
    extra = f" ({d['cannot_separate']} path_cannot_separate)" if d.get("cannot_separate") else ""
    return f"{', '.join(parts)} of {d['n']}{extra}"


def _wrong_pass(rows: list | None) -> str:
    if rows is None:
        return "(not measured)"
    if not rows:
        return "none"
    return ", ".join(f"{r['frame_id']}: {r['effect_px']:.1f} / {r['threshold_px']:.1f}"
                     if r.get("effect_px") is not None and r.get("threshold_px") is not None
                     else str(r["frame_id"]) for r in rows)


def write_report(doc: dict) -> None:
    rows = []
    for r in doc["scenes"].values():
        s = r["separation"]
        rows.append([
            r["scene"], f"{r['frames']} ({r['wrong']} wrong)",
            "-" if r["enhanced_auc"] is None else f"{r['enhanced_auc']:.2f}",
            f"{s.get('status') or 'not probed'}"
            + ("" if s.get("p_value") is None else f" (p {s['p_value']:.3f})"),
            _v(r["correct"]), _v(r["wrong_frames"]), _wrong_pass(r.get("wrong_pass")),
            _v(r["given"]), f"{r['s_per_frame']:.2f}",
        ])
    head = ["scene", "frames", "enhanced path AUC (its own separating power)",
            "separation check on the enhanced path", "correct frames", "wrong frames",
            "wrong frames that PASS: injected image effect / threshold (px)", "given run",
            "s/frame"]
    text = [
        "# MaRINeR evidence alone on colourless renders, every shared scene (issue #38, item 5)",
        "",
        (__doc__ or "").split("\n\n")[1].replace("\n", " "),
        "",
        f"Command: `{doc['command']}`  ",
        f"Machine: {doc['machine']}",
        "",
        md_table(head, rows),
        "",
        "Reading: where the AUC is near 0.5 the path cannot tell right from wrong and the check "
        "must bar it (its frames UNVERIFIABLE `path_cannot_separate`); where it passes the check, "
        "its AUC must be well above 0.5 and the wrong frames must not PASS.",
    ]
    text += ["", *doc.get("notes", [])]
    (REPORTS / "mariner_alone.md").write_text("\n".join(text) + "\n")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--scene", action="append", default=None,
                   choices=scenes_loso.SCENES + tuple(scenes_loso.HELD_OUT))
    args = p.parse_args()
    path = REPORTS / "mariner_alone.json"
    doc = json.loads(path.read_text()) if path.is_file() else {"scenes": {}}
    doc.update(command=command_line(), machine=machine())
    for name in args.scene or scenes_loso.SCENES:
        res = run_scene(name, args.frames)
        print(json.dumps(res, default=str), flush=True)
        doc["scenes"][name] = res
        path.write_text(json.dumps(doc, indent=1, default=str))
        write_report(doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
