"""Growth of a run with the trajectory length and with the mesh size (issue #28 item 4).

Two curves, each measured on whole ``pgt-check`` processes or fresh subprocesses, so imports,
allocator and GL driver are counted as a user pays them::

    PGT_SHARED_DATA=../shared/data python benchmarks/scaling_growth.py frames
    PGT_SHARED_DATA=../shared/data python benchmarks/scaling_growth.py mesh

``frames``: long LaMAR trajectories generated from the 100 shared 7-Scenes frames (frame k uses
photo ``k mod 100`` at that photo's pose plus a small deterministic jitter, 1 mm / 0.05 deg per
repetition, so every pose is distinct; the images folder is a symlink to the shared one, never a
copy). Per length N it runs the CLI twice in a subprocess: ``--limit 1`` (setup: time from the
process start to the first stored record, polled on ``records.jsonl``) and ``--limit W``
(per-frame cost over the first W frames: the steady rate between the first and the last stored
record, and the median of the records' own ``timings.total``). Everything else is the default
configuration. The run-level stage (verdicts, outputs) is timed separately in-process on
``K`` copies of the stored measurements of one real run (``--outputs``).

``mesh``: the shared 7-Scenes mesh (150,000 faces) subdivided (trimesh ``remesh.subdivide``:
all faces, then a subset, so the counts land on 1.5 M and 15 M; vertex colours interpolated) and
written as binary PLY under ``--work``. Per size, in a fresh subprocess: the memory estimate of
``pgt_check.render.memory`` from the PLY header, ``load_mesh`` time, renderer build + first render
(upload), then the median of ``--renders`` renders at the shared poses (640x480, the default
moderngl backend), and the process's peak RSS (``ru_maxrss``) before and after.

Writes ``reports/scaling_growth.json`` (merged per curve) and the PNG plots; the Markdown
tables go into ``reports/scaling.md`` by hand from the printed tables. Not a test: nothing here
asserts a time.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _common import REPO, REPORTS, command_line, machine, md_table, shared_data

JSON_OUT = REPORTS / "scaling_growth.json"


# -- generated long trajectories --------------------------------------------------------------
def make_long_trajectory(src: Path, out: Path, n: int) -> Path:
    """A LaMAR trajectory of ``n`` poses in ``out`` that reuses the photos of ``src`` (see the
    module docstring); returns the trajectories.txt path."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from pgt_check.io import read_trajectory
    from pgt_check.io.lamar import write_lamar
    from pgt_check.types import Frame, Trajectory

    base = read_trajectory(src / "trajectories.txt", "lamar", images=src / "images.txt",
                           sensors=src / "sensors.txt")
    out.mkdir(parents=True, exist_ok=True)
    link = out / "images"
    if not link.exists():
        link.symlink_to(src / "images", target_is_directory=True)
    rng = np.random.default_rng(0)
    frames = []
    for k in range(n):
        f = base.frames[k % len(base.frames)]
        rep = k // len(base.frames)
        pose = np.array(f.world_from_cam, dtype=np.float64)
        if rep:
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            pose[:3, :3] = Rotation.from_rotvec(np.deg2rad(0.05) * axis).as_matrix() @ pose[:3, :3]
            pose[:3, 3] += 0.001 * rng.normal(size=3)
        frames.append(Frame(f"{k:06d}", f.camera, pose, image_path=f.image_path,
                            image_file=out / f.image_path, timestamp=float(k)))
    write_lamar(Trajectory(tuple(frames), str(out), "lamar"), out)
    return out / "trajectories.txt"


def _children_cpu() -> float:
    """User + system CPU seconds of the finished child processes (all their threads)."""
    import resource

    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def timed_cli(argv: list[str], out: Path, poll_s: float = 0.01) -> dict:
    """Run the CLI in a subprocess; times (from the process start) of every new line of
    ``out/records.jsonl`` and of the process end, plus the records' ``timings.total``."""
    import shutil

    shutil.rmtree(out, ignore_errors=True)  # a stale records.jsonl would be polled as new
    records = out / "records.jsonl"
    cmd = [sys.executable, "-m", "pgt_check", *argv, "--out", str(out), "--overwrite", "-q",
           "--report-details", "0"]
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    stamps: list[float] = []
    seen = 0
    while proc.poll() is None:
        if records.is_file():
            n = records.read_bytes().count(b"\n")
            if n > seen:
                stamps += [time.perf_counter() - t0] * (n - seen)
                seen = n
        time.sleep(poll_s)
    wall = time.perf_counter() - t0
    cpu = _children_cpu() - cpu0
    err = proc.stderr.read() if proc.stderr else ""
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"pgt-check exited {proc.returncode}: {err.strip()[-500:]}")
    recs = [json.loads(ln) for ln in records.read_text().splitlines() if ln.strip()]
    n = len(recs)
    stamps += [wall] * (n - seen)  # lines written after the last poll
    totals = [r["timings"]["total"] for r in recs if (r.get("timings") or {}).get("total")]
    steady = (stamps[-1] - stamps[0]) / (n - 1) if n > 1 else None
    return {"frames": n, "wall_s": wall, "cpu_s": cpu, "first_record_s": stamps[0] if stamps else None,
            "after_last_record_s": wall - stamps[-1] if stamps else None,
            "steady_s_per_frame": steady,
            "median_frame_total_s": statistics.median(totals) if totals else None}


def frames_curve(args) -> dict:
    src = shared_data() / "7scenes_redkitchen"
    rows = []
    for n in args.lengths:
        scene = args.work / f"traj_{n}"
        t = time.perf_counter()
        traj = make_long_trajectory(src, scene, n)
        gen_s = time.perf_counter() - t
        common = [str(traj), "--mesh", str(src / "mesh.ply"), "--format", "lamar"]
        setup = timed_cli([*common, "--limit", "1"], args.work / f"out_{n}_1")
        row = {"n_poses": n, "generate_s": gen_s, "setup": setup}
        if n in args.window_lengths:
            row["window"] = timed_cli([*common, "--limit", str(args.window)],
                                      args.work / f"out_{n}_w")
        if "window" in row and row["window"]["frames"] > 1:
            # CPU of the extra frames: the window run minus the --limit 1 run, per extra frame
            row["cpu_s_per_extra_frame"] = (row["window"]["cpu_s"] - setup["cpu_s"]) / (
                row["window"]["frames"] - setup["frames"])
        rows.append(row)
        w = row.get("window") or {}
        print(f"N={n}: first record {setup['first_record_s']:.1f} s, --limit 1 wall "
              f"{setup['wall_s']:.1f} s; window {w.get('frames', '-')} frames: steady "
              f"{w.get('steady_s_per_frame') or float('nan'):.2f} s/frame, median frame total "
              f"{w.get('median_frame_total_s') or float('nan'):.2f} s, CPU "
              f"{row.get('cpu_s_per_extra_frame', float('nan')):.2f} s/extra frame; --limit 1 "
              f"CPU {setup['cpu_s']:.1f} s; load {os.getloadavg()[0]:.1f}", flush=True)
    return {"frames": rows, "window": args.window}


def setup_split(args) -> dict:
    """In-process CPU seconds of the pose-dependent setup steps of a ``--limit 1`` run on the
    generated trajectories: reading the trajectory, the input checks, reference selection."""
    from pgt_check import runner
    from pgt_check.config import RunConfig
    from pgt_check.measure import pick_references

    src = shared_data() / "7scenes_redkitchen"
    rows = []
    for n in args.lengths:
        traj_path = make_long_trajectory(src, args.work / f"traj_{n}", n)
        cfg = RunConfig.from_dict({"input": {"trajectory": str(traj_path), "format": "lamar",
                                             "mesh": str(src / "mesh.ply")},
                                   "limit": 1, "out": str(args.work / "split_out")})
        t0 = time.process_time()
        traj = runner.load_trajectory(cfg)
        t1 = time.process_time()
        frames = list(traj.frames)[:1]
        runner.check_side_inputs(cfg, frames)
        t2 = time.process_time()
        pick_references(traj, frames, cfg)
        t3 = time.process_time()
        rows.append({"n_poses": n, "read_s": t1 - t0, "side_inputs_s": t2 - t1,
                     "references_s": t3 - t2})
        print(f"N={n}: read {t1 - t0:.2f} s, input checks {t2 - t1:.2f} s, references "
              f"{t3 - t2:.2f} s (CPU)", flush=True)
    return {"setup_split": rows}


# -- the run-level stage on many frames --------------------------------------------------------
def outputs_curve(args) -> dict:
    """judge_run + write_outputs on K copies of a real run's stored measurements."""
    import dataclasses

    from pgt_check.config import RunConfig
    from pgt_check.measure import FrameMeasurement
    from pgt_check.report.outputs import write_outputs
    from pgt_check.verdict import judge_run

    src = args.work / f"out_{args.window_lengths[0]}_w" / "records.jsonl"
    base = [FrameMeasurement.from_json(json.loads(ln)) for ln in src.read_text().splitlines()]
    data = shared_data() / "7scenes_redkitchen"
    rows = []
    for k in args.output_sizes:
        ms = [dataclasses.replace(base[i % len(base)], frame_id=f"{i:06d}") for i in range(k)]
        out = args.work / f"outputs_{k}"
        config = RunConfig.from_dict({"input": {"trajectory": str(data / "trajectories.txt"),
                                                "mesh": str(data / "mesh.ply")},
                                      "out": str(out), "report_details": 0})
        out.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        judged = judge_run(ms, config)
        t_judge = time.perf_counter() - t
        t = time.perf_counter()
        write_outputs(out, judged.rows(), config, extra=judged.summary_extra())
        t_out = time.perf_counter() - t
        rows.append({"frames": k, "judge_s": t_judge, "outputs_s": t_out})
        print(f"K={k}: judge_run {t_judge:.2f} s, write_outputs {t_out:.2f} s", flush=True)
        _merge("outputs", {"outputs": rows, "source": str(src)})  # kept if a later K is stopped
    return {"outputs": rows, "source": str(src)}


def _merge(key: str, value: dict) -> None:
    doc = json.loads(JSON_OUT.read_text()) if JSON_OUT.is_file() else {}
    doc[key] = value
    JSON_OUT.write_text(json.dumps(doc, indent=2) + "\n")


# -- meshes of growing size ---------------------------------------------------------------------
def subdivided_mesh(src: Path, out: Path, faces: int) -> Path:
    """``src`` subdivided to exactly ``faces`` faces (each subdivided face becomes 4: all faces
    while that stays below the target, then the first ``(target - F) / 3``), as binary PLY with
    vertex colours. T-junctions where a subdivided face meets an undivided one are left."""
    import numpy as np
    import trimesh
    from trimesh import remesh

    if out.is_file():
        return out
    m = trimesh.load(str(src), process=False)
    v = np.asarray(m.vertices, np.float64)
    f = np.asarray(m.faces, np.int64)
    col = np.asarray(m.visual.vertex_colors, np.float64)
    while len(f) < faces:
        grow = faces - len(f)
        index = None if 3 * len(f) <= grow else np.arange(grow // 3)
        v, f, attrs = remesh.subdivide(v, f, face_index=index,
                                       vertex_attributes={"color": col})
        col = attrs["color"]
    mesh = trimesh.Trimesh(v, f, vertex_colors=np.round(col).astype(np.uint8), process=False)
    out.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(str(out))
    return out


MESH_PROBE = r"""
import json, resource, sys, time
import numpy as np
def rss(): return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
path, n_renders = sys.argv[1], int(sys.argv[2])
from pgt_check.io import read_trajectory
from pgt_check.render import load_mesh, make_renderer
from pgt_check.render.memory import estimate_run_memory, read_mesh_counts
src = sys.argv[3]
traj = read_trajectory(src + "/trajectories.txt", "lamar", images=src + "/images.txt",
                       sensors=src + "/sensors.txt")
cam = traj.frames[0].camera
counts = read_mesh_counts(path)
est = estimate_run_memory(counts, cam.width, cam.height)
import trimesh, moderngl  # imported before the timed load
base = rss()
t = time.perf_counter(); mesh = load_mesh(path); load_s = time.perf_counter() - t
after_load = rss()
r = make_renderer(mesh)
t = time.perf_counter(); r.render(cam, traj.frames[0].world_from_cam); first_s = time.perf_counter() - t
times = []
for f in traj.frames[1:1 + n_renders]:
    t = time.perf_counter(); out = r.render(f.camera, f.world_from_cam); times.append(time.perf_counter() - t)
peak = rss()
print(json.dumps({"faces": int(mesh.num_faces), "vertices": int(len(mesh.vertices)),
  "header_faces": counts.n_faces, "estimate_bytes": est, "load_s": load_s,
  "first_render_s": first_s, "render_s": sorted(times)[len(times) // 2], "render_all_s": times,
  "rss_base_bytes": base, "rss_after_load_bytes": after_load, "rss_peak_bytes": peak,
  "coverage_last": float(out.coverage.mean()) if hasattr(out.coverage, "mean") else None}))
"""


def mesh_curve(args) -> dict:
    src = shared_data() / "7scenes_redkitchen"
    rows = []
    for faces in args.faces:
        path = src / "mesh.ply" if faces == 150_000 else args.work / f"mesh_{faces}.ply"
        t = time.perf_counter()
        if faces != 150_000:
            subdivided_mesh(src / "mesh.ply", path, faces)
        make_s = time.perf_counter() - t
        res = subprocess.run([sys.executable, "-c", MESH_PROBE, str(path), str(args.renders),
                              str(src)], cwd=REPO, capture_output=True, text=True)
        if res.returncode:
            print(f"{faces} faces: probe failed: {res.stderr.strip()[-800:]}", flush=True)
            rows.append({"faces": faces, "error": res.stderr.strip()[-800:]})
            continue
        row = json.loads(res.stdout.strip().splitlines()[-1])
        row.update(file_bytes=path.stat().st_size, make_s=make_s)
        rows.append(row)
        gib = 2**30
        print(f"{faces} faces ({row['file_bytes'] / 2**20:.0f} MiB PLY): load {row['load_s']:.2f} s, "
              f"first render {row['first_render_s']:.2f} s, render median {row['render_s']:.3f} s, "
              f"peak RSS {row['rss_peak_bytes'] / gib:.2f} GiB (estimate "
              f"{row['estimate_bytes'] / gib:.2f} GiB)", flush=True)
    return {"mesh": rows, "renders": args.renders}


# -- plots and tables ---------------------------------------------------------------------------
def plot(doc: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if doc.get("frames"):
        rows = doc["frames"]["frames"]
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
        n = [r["n_poses"] for r in rows]
        ax[0].plot(n, [r["setup"]["first_record_s"] for r in rows], "o-", label="to first record")
        ax[0].plot(n, [r["setup"]["wall_s"] for r in rows], "s--", label="--limit 1, whole run")
        ax[0].plot(n, [r["setup"]["cpu_s"] for r in rows], "^:", label="--limit 1, CPU s")
        ax[0].plot([10000, 20000], [22, 79], "kx", ms=9,
                   label="before (quadratic references, issue #28)")
        ax[0].set(xscale="log", xlabel="poses in the trajectory", ylabel="seconds",
                  title="setup (--limit 1)")
        ax[0].legend()
        win = [r for r in rows if r.get("window")]
        ax[1].plot([r["n_poses"] for r in win],
                   [r["window"]["steady_s_per_frame"] for r in win], "o-", label="steady s/frame")
        ax[1].plot([r["n_poses"] for r in win],
                   [r["window"]["median_frame_total_s"] for r in win], "s--",
                   label="median frame total")
        ax[1].plot([r["n_poses"] for r in win], [r["cpu_s_per_extra_frame"] for r in win],
                   "^:", label="CPU s per extra frame")
        ax[1].set(xscale="log", xlabel="poses in the trajectory", ylabel="seconds per frame",
                  title=f"per frame (first {doc['frames']['window']} frames)", ylim=(0, None))
        ax[1].legend()
        fig.tight_layout()
        fig.savefig(REPORTS / "scaling_frames.png", dpi=110)
        plt.close(fig)
    if doc.get("mesh"):
        rows = [r for r in doc["mesh"]["mesh"] if "error" not in r]
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
        f = [r["faces"] for r in rows]
        ax[0].plot(f, [r["render_s"] for r in rows], "o-", label="render (median)")
        ax[0].plot(f, [r["load_s"] for r in rows], "s--", label="load_mesh")
        ax[0].plot(f, [r["first_render_s"] for r in rows], "^:", label="first render (upload)")
        ax[0].set(xscale="log", yscale="log", xlabel="faces", ylabel="seconds",
                  title="time vs mesh size")
        ax[0].legend()
        gib = 2**30
        ax[1].plot(f, [r["rss_peak_bytes"] / gib for r in rows], "o-", label="peak RSS")
        ax[1].plot(f, [r["estimate_bytes"] / gib for r in rows], "s--", label="pre-check estimate")
        ax[1].set(xscale="log", yscale="log", xlabel="faces", ylabel="GiB",
                  title="memory vs mesh size")
        ax[1].legend()
        fig.tight_layout()
        fig.savefig(REPORTS / "scaling_mesh.png", dpi=110)
        plt.close(fig)


def tables(doc: dict) -> str:
    parts = []
    if doc.get("frames"):
        rows = []
        for r in doc["frames"]["frames"]:
            w = r.get("window") or {}
            rows.append([r["n_poses"], f"{r['setup']['first_record_s']:.1f}",
                         f"{r['setup']['wall_s']:.1f}",
                         f"{w['steady_s_per_frame']:.2f}" if w else "-",
                         f"{w['median_frame_total_s']:.2f}" if w else "-"])
        parts.append(md_table(["poses", "first record s (--limit 1)", "--limit 1 wall s",
                               f"steady s/frame (first {doc['frames']['window']})",
                               "median frame total s"], rows))
    if doc.get("setup"):
        parts.append(md_table(["poses", "read trajectory s", "input checks s", "references s"],
                              [[r["n_poses"], f"{r['read_s']:.2f}", f"{r['side_inputs_s']:.2f}",
                                f"{r['references_s']:.2f}"] for r in doc["setup"]["setup_split"]]))
    if doc.get("outputs"):
        parts.append(md_table(["frames", "judge_run s", "write_outputs s"],
                              [[r["frames"], f"{r['judge_s']:.2f}", f"{r['outputs_s']:.2f}"]
                               for r in doc["outputs"]["outputs"]]))
    if doc.get("mesh"):
        gib = 2**30
        rows = [[r["faces"], r.get("vertices", "-"), f"{r['file_bytes'] / 2**20:.0f}",
                 f"{r['load_s']:.2f}", f"{r['first_render_s']:.2f}", f"{r['render_s'] * 1e3:.0f}",
                 f"{r['rss_peak_bytes'] / gib:.2f}", f"{r['estimate_bytes'] / gib:.2f}"]
                for r in doc["mesh"]["mesh"] if "error" not in r]
        parts.append(md_table(["faces", "vertices", "PLY MiB", "load s", "first render s",
                               "render ms (median)", "peak RSS GiB", "estimate GiB"], rows))
    return "\n\n".join(parts)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("curve", choices=["frames", "setup", "outputs", "mesh", "plot"])
    p.add_argument("--work", type=Path, default=Path("/tmp/pgt_scaling_growth"),
                   help="generated trajectories, meshes and run outputs (outside the repo)")
    p.add_argument("--lengths", type=int, nargs="+", default=[100, 1000, 10000, 20000])
    p.add_argument("--window-lengths", type=int, nargs="+", default=[100, 1000, 10000])
    p.add_argument("--window", type=int, default=20, help="frames measured per window run")
    p.add_argument("--output-sizes", type=int, nargs="+", default=[100, 1000, 10000])
    p.add_argument("--faces", type=int, nargs="+", default=[150_000, 1_500_000, 15_000_000])
    p.add_argument("--renders", type=int, default=5)
    args = p.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    doc = json.loads(JSON_OUT.read_text()) if JSON_OUT.is_file() else {}
    if args.curve == "frames":
        doc["frames"] = frames_curve(args)
    elif args.curve == "setup":
        doc["setup"] = setup_split(args)
    elif args.curve == "outputs":
        doc["outputs"] = outputs_curve(args)
    elif args.curve == "mesh":
        doc["mesh"] = mesh_curve(args)
    if args.curve != "plot":
        doc.setdefault("commands", {})[args.curve] = command_line()
        doc.setdefault("machine", {})[args.curve] = machine()
        doc.setdefault("load_average", {})[args.curve] = os.getloadavg()
        JSON_OUT.write_text(json.dumps(doc, indent=2) + "\n")
    plot(doc)
    print(tables(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
