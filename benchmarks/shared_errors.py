"""Errors that neighbouring frames share (issue #13) and the geometric-edge path (issue #17).

For each dataset the given trajectory and copies with a known error are checked with the
default settings (and, where asked, with the edge path switched off):

* per-frame: 40 % of the frames with an independent error (1-4 deg, 2-8 % of the scene depth);
* moved: the whole trajectory moved by 2 deg + 4 % of the scene depth (and 1 deg alone);
* similarity: scaled by 1.03 about the camera centroid;
* drift: the last 40 % of the frames drift to 2 deg + 4 % of the depth;
* focal +2 %, principal point +5 px, a time offset of one frame.

Reported per case: the share of frames flagged (not PASS), the registration estimate against
the injected transform, drift ROC-AUC, per-frame ROC-AUC (deciding corner error, failures as
inf), the evidence kinds, and seconds per frame (measurement) and per run (run-level checks).
Writes reports/shared_errors.md and reports/edge_evidence.md (+ .json).

This file holds the command line, the cached measurement (``measure``, ``CACHE``), the runs
per dataset (``run_dataset`` and its preset, calibration-from and refinement passes) and the
report files; the datasets, injected errors and scoring are in ``shared_errors_cases.py``,
the Markdown in ``shared_errors_report.py``. The names other benchmarks import from here
(``cases``, ``datasets``, ``evaluate``, ``_subset``, ...) stay importable from here.

    python benchmarks/shared_errors.py [--frames 20] [--datasets 7s,7s-colourless,castle,boxes]
        [--edges-off] [--presets fast,balanced,accurate]
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np
from _common import REPORTS, command_line, machine
from shared_errors_cases import (
    CALIBRATION_FROM_CASES,
    PRESET_CASES,
    REMOVE_CALIBRATION,  # noqa: F401  (re-exported: edge_pipeline.py imports it from here)
    _errors_vs_given,
    _estimate_errors,
    _first_errors,
    _subset,  # noqa: F401  (re-exported: edge_pipeline.py imports it from here)
    _true_effects,
    _world_move,
    cases,
    datasets,
    evaluate,
    independent_check,
    scene_depth,
)
from shared_errors_report import _suffix, report_lines, write_edge_report

from pgt_check.config import RunConfig
from pgt_check.measure import FrameChecker, pick_references
from pgt_check.types import Trajectory
from pgt_check.verdict import judge_run

#: the measurements' cache (``measure``, ``refined_estimate``); colourless_evidence.py
#: sets ``shared_errors.CACHE`` to its own folder
CACHE = Path("/tmp/pgt-check-bench-cache")


def _sources_hash(skip: tuple[str, ...]) -> str:
    """A hash of the pgt_check sources but those under the folders ``skip``."""
    import hashlib

    import pgt_check

    h = hashlib.blake2b(digest_size=6)
    root = Path(pgt_check.__file__).parent
    for f in sorted(root.rglob("*.py")):
        if not f.relative_to(root).as_posix().startswith(skip):
            h.update(f.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=1)
def _code_version() -> str:
    """A hash of the pgt_check sources a measurement depends on (read once per process; all but
    ``JUDGING_ONLY``): a cached measurement is reused only by the code that made it (a
    measurement cached by another working tree once served a later run)."""
    return _sources_hash(JUDGING_ONLY)


#: packages that only judge stored measurements (the measurement stack - measure, render,
#: match, enhance, io, geometry - never imports them): a change there re-judges the cached
#: measurements instead of measuring again
JUDGING_ONLY = ("verdict/", "geometry/shared_errors/", "report/", "correct/", "commands/")


#: set by ``--reuse-measurements``: a key without a measurement by this code is judged on the
#: newest cached measurement of that key by any code (``_reused``), and says so
REUSE_MEASUREMENTS = False


def _cached(key: str, cfg: RunConfig) -> Path:
    """The cache file of ``key`` measured with ``cfg``'s measurement settings by this code."""
    return CACHE / f"{key}-{cfg.measurement_fingerprint()}-{_code_version()}.json"


def _reused(key: str) -> Path | None:
    """The newest cached measurement of exactly ``key`` (``key-FINGERPRINT-VERSION.json``), by
    whatever code and measurement settings made it; None when there is none."""
    files = [f for f in CACHE.glob(f"{key}-*.json") if f.name[len(key) + 1:].count("-") == 1]
    return max(files, key=lambda f: f.stat().st_mtime) if files else None


def measure(
    traj: Trajectory, mesh: Path, cfgd: dict, key: str = ""
) -> tuple[RunConfig, list, float]:
    """Measure every frame (cached under ``key``: the verdict stage can be re-run alone)."""
    from pgt_check.measure import FrameMeasurement

    cfg = RunConfig.from_dict({"input": {"trajectory": str(mesh), "mesh": str(mesh)}, **cfgd})
    path = _cached(key, cfg)
    if key and not path.is_file() and REUSE_MEASUREMENTS:
        old = _reused(key)
        if old is not None:
            print(f"{key}: judging the cached measurement {old.name} (--reuse-measurements)",
                  file=sys.stderr)
            path = old
    if key and path.is_file():
        d = json.loads(path.read_text())
        return cfg, [FrameMeasurement.from_json(m) for m in d["ms"]], d["tpf"]
    checker = FrameChecker(cfg, pick_references(traj, traj.frames, cfg))
    try:
        checker.measure(traj.frames[0])  # warm-up (GL context, shaders)
        t0 = time.perf_counter()
        ms = [checker.measure(f) for f in traj.frames]
        tpf = (time.perf_counter() - t0) / len(ms)
    finally:
        checker.close()
    if key:
        CACHE.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"ms": [m.to_json() for m in ms], "tpf": tpf}))
    return cfg, ms, tpf


@functools.lru_cache(maxsize=1)
def _all_code_version() -> str:
    """A hash of every pgt_check source (the judging code too: the reference pass chooses what
    to measure again from a judgement)."""
    return _sources_hash(())


def as_run(traj: Trajectory, ms: list, cfg: RunConfig, key: str) -> tuple[list, list]:
    """What a run does between its main pass and its verdicts (``pgt_check.runner``), on the
    main pass's measurements ``ms`` judged with ``cfg``, with the runner's own stages: the
    reference pass (``stages.remeasure.reference_stage``) and the separation probes
    (``stages.remeasure.separation_stage``). -> (measurements, probes) for
    ``judge_run(ms, cfg, probes)``; cached under ``key``, ``cfg`` (a trusted calibration file
    by its content: scenes_loso writes it to a new temporary folder each time) and the code.
    ``measure`` alone is the main pass, which scenes_loso's labels before after9 judged."""
    import hashlib
    from dataclasses import replace

    from pgt_check.measure import FrameMeasurement
    from pgt_check.stages.remeasure import reference_stage, separation_stage

    cal = cfg.run_checks.calibration_from
    ident = repr(replace(cfg, run_checks=replace(cfg.run_checks, calibration_from=None)))
    if cal:
        ident += Path(cal).read_text()
    h = hashlib.blake2b(ident.encode(), digest_size=6).hexdigest()
    out = CACHE / f"{key}-run-{h}-{_all_code_version()}"
    done = out / "reference_pass.json"
    rcfg = replace(cfg, out=str(out), executor="serial")
    if done.is_file():
        got = {m["frame_id"]: FrameMeasurement.from_json(m)
               for m in json.loads(done.read_text())}
    else:
        got = reference_stage(traj, traj.frames, ms, rcfg)[1]
        out.mkdir(parents=True, exist_ok=True)
        done.write_text(json.dumps([m.to_json() for m in got.values()]))
    ms = [got.get(m.frame_id, m) for m in ms]
    probes = separation_stage(traj, ms, rcfg, _all_code_version())
    return ms, probes


#: the rounds the refinement is measured with (``--registration-rounds``)
REFINE_ROUNDS = 8


def refined_estimate(key: str, t: Trajectory, mesh: Path, cfg: RunConfig, ms) -> dict:
    """The run's registration refinement (``pgt_check.correct.registration``, as a run with
    ``--registration-rounds 8`` does it after a failed registration check (the default defers
    it); cached under ``key``): the refined estimate replaces the row's, the first pass's is
    kept as ``*_first``."""
    from dataclasses import replace

    from pgt_check.correct.registration import (
        RefinedRegistration,
        apply_refinement,
        refine_registration,
    )

    if cfg.run_checks.refine_rounds == 0:
        cfg = replace(cfg, run_checks=replace(cfg.run_checks, refine_rounds=REFINE_ROUNDS))
    j = judge_run(ms, cfg)
    if j.shared is None:
        return {}
    path = _cached(f"{key}-refined", cfg)
    if path.is_file():
        d = json.loads(path.read_text())
        refined = None if d["refined"] is None else RefinedRegistration.from_json(d["refined"])
        secs = d["s"]
    else:
        checkers: list = []

        def measure_fn(frames, ecfg):
            if not checkers:
                checkers.append(FrameChecker(ecfg, {}))
            return [checkers[0].measure(f) for f in frames]

        t0 = time.perf_counter()
        try:
            refined = refine_registration(t.frames, ms, j.shared, cfg, measure_fn)
        finally:
            for c in checkers:
                c.close()
        secs = time.perf_counter() - t0
        CACHE.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps({"refined": None if refined is None else refined.to_json(),
                                    "s": secs}))
    if refined is None or not refined.rounds:
        return {}
    se = apply_refinement(j.shared, refined).summary()
    reg, sim = se["registration"], se["similarity"]
    first = reg["refinement"]["first_pass"]
    return {
        "reg_deg_first": first["angle_deg"],
        "reg_t_first": first["translation"],
        "reg_deg": reg["angle_deg"],
        "reg_t": reg["translation"],
        "reg_correction": reg["corrected_world_from_world"],
        "sim_scale": sim.get("scale"),
        "sim_correction": sim.get("corrected_world_from_world"),
        "refine_rounds": len(refined.rounds),
        "refine_left_px": refined.rounds[-1].effect_px,
        "refine_s": secs,
    }


def _merged(base: dict, extra: dict) -> dict:
    """``base`` with ``extra``'s sections merged in (one level deep, ``extra`` wins)."""
    out = {k: dict(v) if isinstance(v, dict) else v for k, v in base.items()}
    for k, v in extra.items():
        out[k] = {**out.get(k, {}), **v} if isinstance(v, dict) else v
    return out


def run_presets(name: str, traj: Trajectory, mesh: Path, cfgd: dict, depth: float,
                presets: list[str]) -> list[dict]:
    """The ``PRESET_CASES`` under each named preset (``pgt_check.config.PRESETS``)."""
    from pgt_check.config import PRESETS

    out = []
    all_cases = cases(traj, depth)
    for preset in presets:
        pcfg = _merged(cfgd, PRESETS[preset])
        for case in PRESET_CASES:
            t, truth = all_cases[case]
            c_cfg, c_ms, c_tpf = measure(t, mesh, pcfg, f"{name}-{case}-{preset}")
            row = evaluate(case, truth, c_ms, c_cfg)
            row.update(preset=preset, s_per_frame=c_tpf)
            out.append(row)
            print(name, preset, json.dumps(row), flush=True)
    return out


def run_calibration_from(name: str, traj: Trajectory, mesh: Path, cfgd: dict,
                         depth: float) -> list[dict]:
    """``--calibration-from``: the calibration estimated on the given poses' run (its
    summary.json), removed from each case (no new measurement; the cached ones are judged)."""
    import tempfile

    base = {k: v for k, v in cfgd.items() if k != "run_checks"}
    cfg = RunConfig.from_dict({"input": {"mesh": str(mesh)}, **base})
    _, ms, _ = measure(traj, mesh, cfgd, f"{name}-given")
    trusted = Path(tempfile.mkdtemp()) / "summary.json"
    trusted.write_text(json.dumps(judge_run(ms, cfg).summary_extra(), default=str))
    given_cfg = RunConfig.from_dict(
        {"input": {"mesh": str(mesh)}, **base, "run_checks": {"calibration_from": str(trusted)}}
    )
    # the given poses' own correction (they are pseudo ground truth too): the evidence's
    # view of the truth of a moved case is this composed with the inverse of the move
    given_c = judge_run(ms, given_cfg).shared.summary()["registration"]["corrected_world_from_world"]
    all_cases = cases(traj, depth)
    out = []
    for case in CALIBRATION_FROM_CASES:
        t, truth = all_cases[case]
        _, c_ms, c_tpf = measure(t, mesh, cfgd, f"{name}-{case}")
        vcfg = RunConfig.from_dict(
            {"input": {"mesh": str(mesh)}, **base, "run_checks": {"calibration_from": str(trusted)}}
        )
        row = evaluate(case, truth, c_ms, vcfg)
        row.update(s_per_frame=c_tpf)
        if _world_move(truth):
            row.update(refined_estimate(f"{name}-{case}-calfrom", t, mesh, vcfg, c_ms))
            row.update(_true_effects(c_ms, traj, row))
            if given_c is not None and "scale" not in truth:
                row.update(_errors_vs_given(truth, row, traj, t, np.asarray(given_c)))
        row.update(_estimate_errors(truth, row))
        row.update(_first_errors(truth, row))
        out.append(row)
        print(name, "calibration-from", json.dumps(row), flush=True)
    return out


def run_dataset(
    name: str, traj: Trajectory, mesh: Path, cfgd: dict, edges_off: bool, presets: list[str],
    depth: float | None = None,
) -> dict:
    """Every case of one dataset. ``depth``: the scene depth the perturbations scale with
    (default: the median evidence depth of the given run, which depends on the settings; pin
    it to compare two commits on the same perturbations)."""
    cfg, ms, tpf = measure(traj, mesh, cfgd, f"{name}-given")
    depth = scene_depth(ms) if depth is None else depth
    res = {"dataset": name, "frames": len(ms), "depth": depth, "s_per_frame": tpf, "rows": []}
    if cfgd.get("run_checks", {}).get("remove_calibration"):
        plain = {k: v for k, v in cfgd.items() if k != "run_checks"}
        row = evaluate(
            "given (defaults, calibration kept)",
            {},
            ms,
            RunConfig.from_dict({"input": {"mesh": str(mesh)}, **plain}),
        )
        row["s_per_frame"] = tpf
        res["rows"].append(row)
        print(name, json.dumps(row), flush=True)
    for case, (t, truth) in cases(traj, depth).items():
        c_cfg, c_ms, c_tpf = measure(t, mesh, cfgd, f"{name}-{case}")
        row = evaluate(case, truth, c_ms, c_cfg)
        if _world_move(truth):
            row.update(refined_estimate(f"{name}-{case}", t, mesh, c_cfg, c_ms))
            row.update(_true_effects(c_ms, traj, row))
        row["s_per_frame"] = c_tpf
        row["t_edges_s"] = float(np.median([m.timings.edges or 0.0 for m in c_ms]))
        row.update(_estimate_errors(truth, row))
        row.update(_first_errors(truth, row))
        res["rows"].append(row)
        print(name, json.dumps(row), flush=True)
        if edges_off and case in ("given", "per-frame", "moved 2deg+4%"):
            off = {**cfgd, "edges": {"mode": "never"}}
            o_cfg, o_ms, o_tpf = measure(t, mesh, off, f"{name}-{case}-noedges")
            row_off = evaluate(case + " (no edges)", truth, o_ms, o_cfg)
            row_off["s_per_frame"] = o_tpf
            res["rows"].append(row_off)
            print(name, json.dumps(row_off), flush=True)
    res["independent"] = independent_check(name, traj, judge_run(ms, cfg).rows())
    res["presets"] = run_presets(name, traj, mesh, cfgd, depth, presets) if presets else []
    res["calibration_from"] = (
        run_calibration_from(name, traj, mesh, cfgd, depth)
        if cfgd.get("run_checks", {}).get("remove_calibration")
        else []
    )
    return res


def write_reports(results: list[dict], args: argparse.Namespace) -> None:
    head = (
        f"Command: `{command_line()}`\n\nMachine: {machine()} (other jobs shared the cores; "
        "absolute times are pessimistic).\n"
    )
    lines = report_lines(results, args, head)
    (REPORTS / f"shared_errors{_suffix(args)}.md").write_text("\n".join(lines) + "\n")
    (REPORTS / f"shared_errors{_suffix(args)}.json").write_text(
        json.dumps(results, indent=1, default=str)
    )
    if not _suffix(args):  # the edge report compares the default runs with and without edges
        write_edge_report(results, head)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--datasets", default="castle,7s,7s-colourless")
    p.add_argument("--edges-off", action="store_true", help="also run without the edge path")
    p.add_argument("--presets", default="", help="comma-separated presets to run the key cases with")
    p.add_argument(
        "--edges-tile-grid", type=int, default=0,
        help="run everything with edges.tile_grid (reports/shared_errors_tiles.md)",
    )
    p.add_argument(
        "--depth", action="append", default=[], metavar="DATASET=DEPTH",
        help="pin a dataset's scene depth (the perturbations' scale) to compare commits",
    )
    p.add_argument(
        "--from-json",
        action="store_true",
        help="only rewrite the reports from reports/shared_errors.json",
    )
    args = p.parse_args()
    if args.from_json:
        write_reports(json.loads((REPORTS / f"shared_errors{_suffix(args)}.json").read_text()), args)
        return
    results = []
    pinned = dict(x.split("=", 1) for x in args.depth)  # --depth DATASET=DEPTH
    for name, (traj, mesh, cfgd) in datasets(args.datasets.split(","), args.frames).items():
        presets = [x for x in args.presets.split(",") if x]
        if args.edges_tile_grid:
            cfgd = {**cfgd, "edges": {"tile_grid": args.edges_tile_grid}}
            name = f"{name}+tiles"
        depth = float(pinned[name]) if name in pinned else None
        results.append(run_dataset(name, traj, mesh, cfgd, args.edges_off, presets, depth))
        write_reports(results, args)


if __name__ == "__main__":
    main()
