"""Where a pgt-check run spends its time: a per-stage profile of whole runs (issue #28, item 1),
and the run timed against the bare render-and-match loop on the same frames.

Each case runs ``pgt-check`` (the CLI's ``main``) in a fresh process with timers wrapped
around the pipeline's functions (no change to what runs); the timers are exclusive (a render
inside the enhancement counts as render, not enhancement) and split by phase: the main pass,
the registration refinement, the per-frame corrections, the report. Then ``--pairs`` times
each case against ``benchmarks/bare_loop.py`` as whole processes, A B A B (wall and CPU from
the OS), and reports the median ratio per pair. Writes reports/pipeline_timing.{md,json}.

    python benchmarks/pipeline_timing.py [--cases 7s,7s-fast,7s-cal,7s-xfeat,castle,
        castle-xfeat,boxes] [--pairs 3]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from _common import REPO, REPORTS, command_line, machine, md_table, shared_data

#: case -> (dataset, frames, extra CLI options, what it shows)
CASES: dict[str, tuple[str, int | None, tuple[str, ...], str]] = {
    "7s": ("7scenes", 30, (), "7-Scenes, 30 frames, default (fails on its calibration offset)"),
    "7s-cal": ("7scenes", 30, ("--remove-calibration",),
               "7-Scenes, 30 frames, default + --remove-calibration (passes)"),
    "7s-fast": ("7scenes", 30, ("--preset", "fast"),
                "7-Scenes, 30 frames, --preset fast (fails on its calibration offset)"),
    "7s-xfeat": ("7scenes", 30, ("--matcher", "xfeat"),
                 "7-Scenes, 30 frames, default with --matcher xfeat (the Pareto point of "
                 "reports/error_vs_runtime.md)"),
    "castle": ("castle", None, (), "castle, 10 frames, default"),
    "castle-xfeat": ("castle", None, ("--matcher", "xfeat"),
                     "castle, 10 frames, default with --matcher xfeat"),
    "boxes": ("boxes", None, (), "generated boxes (sample_data/boxes), 24 frames, default"),
    "7s-proc": ("7scenes", 30, ("--executor", "process", "--workers", "2"),
                "7-Scenes, 30 frames, default on a pool of 2 worker processes (both cores; "
                "the per-stage timers see only the main process)"),
    "7s-refine": ("7scenes", 30, ("--registration-rounds", "8"),
                  "7-Scenes, 30 frames, default + --registration-rounds 8 (the deferred "
                  "refinement run)"),
}

#: the bare loop's working sizes: 640 px (the issue's baseline, and the default matching size
#: before issue #28) and 320 px (the default matching size since; the edge path still works at
#: 640 / 1024 px)
BARE_SIZES = (640, 320)
#: the environment of the bare loop's third variant: 640 px with one OpenCV and one BLAS
#: thread, as the run uses by default (``RunConfig.threads``)
ONE_THREAD = {"OPENCV_FOR_THREADS_NUM": "1", "OPENBLAS_NUM_THREADS": "1"}

#: stage name -> timed functions ("module:attr" or "module:Class.method")
STAGES: dict[str, tuple[str, ...]] = {
    "load trajectory": ("pgt_check.runner:load_trajectory",),
    "references + side inputs": ("pgt_check.runner:pick_references",
                                 "pgt_check.runner:check_side_inputs"),
    "setup (mesh, renderer, matcher)": ("pgt_check.runner:preflight",
                                        "pgt_check.measure.checker:build_frame_checker"),
    "hash inputs": ("pgt_check.runner:mesh_content_hash", "pgt_check.runner:frame_input_keys"),
    "load photos": ("pgt_check.io:load_image",),
    "render": ("pgt_check.render.moderngl_backend:ModernGLRenderer.render",),
    "features (per image)": ("pgt_check.match.opencv:OpenCVMatcher._detect",),
    "matching": ("pgt_check.match.opencv:OpenCVMatcher.match",),
    "homography": ("pgt_check.geometry.homography:estimate_homography",),
    "edges": ("pgt_check.measure.checker:measure_edges",),
    "enhancement": ("pgt_check.enhance.reproject:ReprojectEnhancer.enhance",),
    "PnP": ("pgt_check.geometry.pnp:estimate_pose_correction",),
    "panels": ("pgt_check.report.assets:PanelWriter.__call__",
               "pgt_check.report.assets:write_frame_assets"),
    "run-level checks + verdicts": ("pgt_check.runner:judge_run",),
    "report files (csv, json, html, plots)": ("pgt_check.report.outputs:write_outputs",),
}
#: timed functions that a process pool sends to its workers by reference: a wrapper would not
#: pickle, so they are not timed in pooled cases
PICKLED = {"pgt_check.measure.checker:build_frame_checker"}
#: phase name -> function that runs it
PHASES = {
    "main pass": "pgt_check.runner:_measure_into_store",
    "refinement": "pgt_check.correct.registration:refine_run",
    "corrections": "pgt_check.correct.frames:correct_run",
    "report": "pgt_check.runner:write_report_assets",
}
#: stages outside the phases above: setup, the run-level checks, the report files
BASE = "setup, checks, files"
PHASE_ORDER = (BASE, *PHASES)


# -- the child: one instrumented run ----------------------------------------------------------
class Timers:
    """Exclusive wall and CPU seconds (the process's, all threads) per (phase, stage): a
    timer's time is taken off its parent's. CPU seconds hold better than wall seconds on a
    loaded machine (another process's time slices do not count)."""

    def __init__(self) -> None:
        self.total: dict[tuple[str, str], float] = defaultdict(float)
        self.cpu: dict[tuple[str, str], float] = defaultdict(float)
        self.calls: dict[tuple[str, str], int] = defaultdict(int)
        self.stack: list[list] = []  # [stage, start, cpu start, child wall, child cpu]
        self.phase = [BASE]

    def wrap(self, fn, stage: str):
        def timed(*args, **kwargs):
            self.stack.append([stage, time.perf_counter(), time.process_time(), 0.0, 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                name, t0, c0, inner, inner_cpu = self.stack.pop()
                dt, dc = time.perf_counter() - t0, time.process_time() - c0
                key = (self.phase[-1], name)
                self.total[key] += dt - inner
                self.cpu[key] += dc - inner_cpu
                self.calls[key] += 1
                if self.stack:
                    self.stack[-1][3] += dt
                    self.stack[-1][4] += dc

        timed.__wrapped__ = fn
        return timed

    def phased(self, fn, phase: str):
        def run_phase(*args, **kwargs):
            self.phase.append(phase)
            try:
                return self.wrap(fn, "other")(*args, **kwargs)
            finally:
                self.phase.pop()

        return run_phase


def _patch(target: str, make) -> None:
    import importlib

    mod_name, attr = target.split(":")
    obj = importlib.import_module(mod_name)
    *owners, name = attr.split(".")
    for o in owners:
        obj = getattr(obj, o)
    setattr(obj, name, make(getattr(obj, name)))


def child(argv: list[str], out_json: str) -> None:
    t_start = time.perf_counter()
    from pgt_check.cli import main

    t_import = time.perf_counter() - t_start
    timers = Timers()
    pooled = "--executor" in argv and argv[argv.index("--executor") + 1] != "serial"
    for stage, targets in STAGES.items():
        for t in targets:
            if pooled and t in PICKLED:
                continue
            _patch(t, lambda fn, s=stage: timers.wrap(fn, s))
    for phase, t in PHASES.items():
        _patch(t, lambda fn, p=phase: timers.phased(fn, p))
    t0 = time.perf_counter()
    rc = main(argv)
    wall = time.perf_counter() - t0
    cpu = sum(getattr(resource.getrusage(who), f) for who in
              (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN) for f in ("ru_utime", "ru_stime"))
    out = Path(argv[argv.index("--out") + 1])
    summary = json.loads((out / "summary.json").read_text())
    refinement = (summary.get("shared_errors", {}).get("registration", {}) or {}).get("refinement")
    Path(out_json).write_text(json.dumps({
        "rc": rc, "import_s": t_import, "run_s": wall, "cpu_s": cpu,
        "n_frames": summary.get("n_frames"), "counts": summary.get("counts"),
        "gate": summary.get("gate", {}).get("passed"),
        "refinement": None if refinement is None else {
            "stopped": refinement.get("stopped"), "rounds": len(refinement.get("rounds", [])),
            "rounds_kept": refinement.get("rounds_kept")},
        "corrections": summary.get("corrections", {}).get("attempted"),
        "stages": [[p, s, v, timers.calls[(p, s)], timers.cpu[(p, s)]]
                   for (p, s), v in timers.total.items()],
    }))


# -- the parent -------------------------------------------------------------------------------
def _inputs(dataset: str) -> tuple[Path, Path]:
    if dataset == "boxes":
        root = REPO / "sample_data" / "boxes"
        return root / "trajectories.txt", root / "boxes.ply"
    root = shared_data() / {"7scenes": "7scenes_redkitchen", "castle": "sceaux_castle"}[dataset]
    return root / "trajectories.txt", root / "mesh.ply"


def _timed_process(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall s, CPU s of the process and its children) of one whole process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=False, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                   cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _commands(case: str, tmp: Path) -> tuple[list[str], dict[int, list[str]]]:
    """(the run's CLI arguments, the bare loop's command per working size)."""
    dataset, n, extra, _ = CASES[case]
    traj, mesh = _inputs(dataset)
    limit = ["--limit", str(n)] if n else []
    run = [str(traj), "--mesh", str(mesh), "--out", str(tmp / case), "--overwrite", "-q",
           *limit, *extra]
    bare = {size: [sys.executable, str(REPO / "benchmarks" / "bare_loop.py"), str(traj),
                   "--mesh", str(mesh), "-q", "--resize-max", str(size), *limit]
            for size in BARE_SIZES}
    return run, bare


def _load() -> str:
    la = os.getloadavg()
    return f"{la[0]:.1f} / {la[1]:.1f} / {la[2]:.1f}"


def _byte_compile() -> None:
    """Write the .pyc files of the project's packages, as an installed package has them: with
    PYTHONDONTWRITEBYTECODE set, every run would otherwise compile each module again."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", "pgt_check", "mariner_core",
                    "pgt_eval"], check=True, cwd=REPO, stdout=subprocess.DEVNULL)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--pairs", type=int, default=3, help="A B pairs per case (0 = none)")
    ap.add_argument("--child", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child[1:], args.child[0])
        return
    cases = args.cases.split(",")
    _byte_compile()
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        for case in cases:
            run, bare = _commands(case, tmp)
            js = tmp / f"{case}.json"
            load0 = _load()
            wall, cpu = _timed_process([sys.executable, __file__, "--child", str(js), *run])
            res = json.loads(js.read_text())
            res.update(process_wall_s=wall, process_cpu_s=cpu, load_before=load0,
                       load_after=_load())
            pairs = []
            for _ in range(args.pairs):
                b = _timed_process(bare[BARE_SIZES[0]])
                a = _timed_process([sys.executable, "-m", "pgt_check", *run])
                b2 = _timed_process(bare[BARE_SIZES[1]])
                b3 = _timed_process(bare[BARE_SIZES[0]], ONE_THREAD)
                pairs.append({"bare_wall_s": b[0], "bare_cpu_s": b[1], "run_wall_s": a[0],
                              "run_cpu_s": a[1], "bare2_wall_s": b2[0], "bare2_cpu_s": b2[1],
                              "bare1t_wall_s": b3[0], "bare1t_cpu_s": b3[1]})
            res["pairs"] = pairs
            res["load_after_pairs"] = _load()
            results[case] = res
            print(case, json.dumps({k: v for k, v in res.items() if k != "stages"}), flush=True)
    meta = {"machine": machine(), "command": command_line(), "cases": cases,
            "cpu_count": os.cpu_count()}
    REPORTS.mkdir(exist_ok=True)
    (REPORTS / "pipeline_timing.json").write_text(
        json.dumps({"meta": meta, "results": results}, indent=1) + "\n")
    text = render(meta, results)
    (REPORTS / "pipeline_timing.md").write_text(text)
    print(text)


def _end_to_end_rows(results: dict[str, dict]) -> list[list]:
    """One row per case: the run against the bare loop, medians over the A B pairs."""
    rows = []
    for case, r in results.items():
        pairs = r.get("pairs") or []

        def med(key: str, pairs=pairs) -> float:
            have = [p[key] for p in pairs if key in p]
            return statistics.median(have) if have else float("nan")

        def ratio(a: str, b: str, pairs=pairs) -> str:
            if not pairs or b not in pairs[0]:
                return "-"
            return f"{statistics.median(p[a] / p[b] for p in pairs):.2f}x"

        ref = r.get("refinement")
        rows.append([
            CASES[case][3], r["n_frames"], len(pairs),
            f"{med('bare_wall_s'):.1f} / {med('bare_cpu_s'):.1f}",
            f"{med('run_wall_s'):.1f} / {med('run_cpu_s'):.1f}",
            ratio("run_wall_s", "bare_wall_s"), ratio("run_cpu_s", "bare_cpu_s"),
            f"{med('bare2_cpu_s'):.1f} / {ratio('run_cpu_s', 'bare2_cpu_s')}",
            f"{med('bare1t_wall_s'):.1f} / {med('bare1t_cpu_s'):.1f} / "
            f"{ratio('run_cpu_s', 'bare1t_cpu_s')}",
            "-" if ref is None else f"{ref['rounds']} ({ref['stopped'].split(':')[0]})",
            r.get("corrections", 0), r["load_before"] + " -> " + r["load_after_pairs"],
        ])
    return rows


def _stage_section(case: str, r: dict, stage_names: list[str]) -> list[str]:
    """One case's per-stage table: CPU seconds per phase, totals, share, CPU ms per frame."""
    table: dict[str, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    walls: dict[str, float] = defaultdict(float)
    for phase, stage, secs, _, cpu in r["stages"]:
        table[stage][phase] += cpu
        walls[stage] += secs
    n = r["n_frames"] or 1
    total = sum(st[4] for st in r["stages"])
    rows = []
    for stage in stage_names:
        if stage not in table:
            continue
        vals = [table[stage].get(p, 0.0) for p in PHASE_ORDER]
        rows.append([stage, *(f"{v:.2f}" if v else "" for v in vals),
                     f"{sum(vals):.2f} / {walls[stage]:.2f}",
                     f"{100 * sum(vals) / total:.0f} %", f"{1000 * sum(vals) / n:.0f}"])
    rows.append(["**timed total**", *[""] * len(PHASE_ORDER),
                 f"{total:.2f} / {sum(walls.values()):.2f}", "100 %",
                 f"{1000 * total / n:.0f}"])
    rows.append([f"**whole process** (load {r['load_before']})",
                 *[""] * len(PHASE_ORDER),
                 f"{r['process_cpu_s']:.1f} / {r['process_wall_s']:.1f}", "", ""])
    ref = r.get("refinement")
    return [f"### {CASES[case][3]}", "",
            f"{r['n_frames']} frames, counts {r['counts']}, gate "
            f"{'passed' if r['gate'] else 'failed'}"
            + ("" if ref is None else f"; refinement: {ref['rounds']} round(s), "
               f"{ref['rounds_kept']} kept, stopped: {ref['stopped']}") + ".", "",
            md_table(["stage", *PHASE_ORDER, "CPU / wall s", "share",
                      "CPU ms per frame"], rows), ""]


def render(meta: dict, results: dict[str, dict]) -> str:
    stage_names = [*STAGES, "other"]
    lines = [
        "# Pipeline timing: the default run per stage, and against the bare loop",
        "",
        f"Machine: {meta['machine']}. Command: `{meta['command']}`.",
        "",
        "Each case is one whole `pgt-check` process with timers around the pipeline's "
        "functions (exclusive: a render inside the enhancement counts as render); 'other' is "
        "what no timer covers (per-frame bookkeeping, the record store, the refinement's "
        "pooled fits). The machine may be shared (2 cores): the load average (1 / 5 / 15 "
        "min) is given per case, and the comparison "
        "with the bare loop is paired (bare, run, bare, run ... as whole processes), so "
        "read the ratios and CPU seconds rather than single wall times. The project's "
        "sources are byte-compiled before the first case, as in an installed package (this "
        "machine sets PYTHONDONTWRITEBYTECODE; compiling every module at each start cost "
        "about 0.2 s CPU a run).",
        "",
        "## End to end, against the bare render + SIFT + homography loop",
        "",
        "`benchmarks/bare_loop.py` on the same frames (same renderer, OpenCV SIFT, ratio "
        "test, RANSAC homography) at 640 px, the issue's baseline (the run matches at 320 px "
        "and aligns edges at 640 / 1024 px), with OpenCV's default threads. Beside it, timed "
        "in the same pairs: the bare loop at 320 px, and at 640 px with one OpenCV and one "
        "BLAS thread, as the run has by default (`threads`, `pgt_check/threads.py`): one "
        "thread makes the bare loop cheaper but slower, the run cheaper and no slower. Medians "
        "over the pairs; ratio = run / bare, per pair, then the median.",
        "",
    ]
    rows = _end_to_end_rows(results)
    lines.append(md_table(["case", "frames", "pairs", "bare s (wall / CPU)", "run s (wall / CPU)",
                           "ratio wall", "ratio CPU", "bare at 320 px: CPU s / ratio CPU",
                           "bare, 1 thread: wall / CPU s / ratio CPU",
                           "refinement rounds", "corrections", "load"], rows))
    lines += ["", "## Per stage (the profiled run)", "",
              "CPU seconds of the process (all its threads) per phase, then the stage's total "
              "CPU and wall seconds, its share of the timed CPU and CPU ms per frame checked. "
              "The profiled process's own wall / CPU are in the last row.", ""]
    for case, r in results.items():
        lines += _stage_section(case, r, stage_names)
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
