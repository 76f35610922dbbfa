"""Compare two pose sources for the same images (``pgt-check compare A B``).

Per frame (paired by frame id, else by image path): the rotation angle (deg) and camera-centre
distance (scene units) between the sources, and their effect in pixels: the mean distance over
the four image corners between where A sees a point at the scene depth and where B sees it
(each source with its own intrinsics, so an intrinsics difference counts too). The scene depth
is the median render depth when ``--mesh`` is given, else the median distance of the camera
centres from their centroid (a scale proxy; stated in the summary).

With ``--mesh``, the checker measures and judges every frame with both sources (as
``pgt-check`` would, enhancement references taken from the same source) and the source with
the smaller corner error is the one the image supports (a tie within ``--tie-px``, default
0.5 px). The errors compared are those of the raw path (render vs photo: absolute evidence)
when both sources have enough raw inliers (``verdict.min_inliers``), else those of each
source's deciding path (column ``basis``; an UNVERIFIABLE source has no error). The command
(``pgt_check.commands.compare``) writes ``compare.csv`` and ``compare.json`` (``--out``) and
prints a summary.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.errors import InputError
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)

COMPARE_COLUMNS = (
    "frame_id",
    "image_path",
    "drot_deg",
    "dt",
    "shift_px",
    "depth",
    "verdict_a",
    "verdict_b",
    "corner_error_px_a",
    "corner_error_px_b",
    "n_inliers_a",
    "n_inliers_b",
    "basis",
    "supported",
)


def pair_frames(a: Trajectory, b: Trajectory) -> list[tuple[Frame, Frame]]:
    """Frames of A and B that show the same image: by frame id, else by image path."""
    b_id = b.by_id()
    pairs = [(f, b_id[f.frame_id]) for f in a if f.frame_id in b_id]
    if pairs:
        return pairs
    b_path = {f.image_path: f for f in b if f.image_path}
    return [(f, b_path[f.image_path]) for f in a if f.image_path in b_path]


def _corners(camera: Camera) -> np.ndarray:
    w, h = camera.width - 1.0, camera.height - 1.0
    return np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])


def pixel_effect(fa: Frame, fb: Frame, depth: float) -> float:
    """Mean corner distance (A's pixels) between A's and B's projection of the points A's image
    corners see at ``depth`` (B's projection rescaled to A's image size)."""
    ka, kb = fa.camera.K, fb.camera.K
    uv = _corners(fa.camera)
    rays = np.linalg.solve(ka, np.c_[uv, np.ones(len(uv))].T).T  # z = 1
    pts_cam_a = rays * depth
    world = pts_cam_a @ fa.world_from_cam[:3, :3].T + fa.world_from_cam[:3, 3]
    cam_b = fb.cam_from_world
    pb = world @ cam_b[:3, :3].T + cam_b[:3, 3]
    if np.any(pb[:, 2] <= 0):
        return math.inf
    proj = (pb / pb[:, 2:3]) @ kb.T
    sx = fa.camera.width / fb.camera.width
    sy = fa.camera.height / fb.camera.height
    proj_a = np.c_[(proj[:, 0] + 0.5) * sx - 0.5, (proj[:, 1] + 0.5) * sy - 0.5]
    return float(np.mean(np.linalg.norm(proj_a - uv, axis=1)))


def scale_proxy(frames: Sequence[Frame]) -> float:
    """Median distance of the camera centres from their centroid (1.0 for one frame)."""
    c = np.array([f.center for f in frames])
    if len(c) < 2:
        return 1.0
    d = np.linalg.norm(c - c.mean(axis=0), axis=1)
    med = float(np.median(d))
    return med if med > 0 else 1.0


@dataclass(frozen=True)
class CompareResult:
    rows: list[dict[str, Any]]
    summary: dict[str, Any]


def checker_config(mesh: str, extra: dict[str, Any] | None) -> Any:
    """The config of the checker that measures both sources (ConfigError for a bad setting)."""
    from pgt_check.config import RunConfig, merge

    base = {"input": {"mesh": mesh}, "pose": {"enabled": False}}
    return RunConfig.from_dict(merge(base, extra or {}))


def _measure_source(checker: Any, traj: Trajectory, frames: Sequence[Frame]) -> list[dict]:
    """Verdict rows of ``frames`` (enhancement references from the same source)."""
    from pgt_check.measure import pick_references
    from pgt_check.verdict import apply_verdicts

    checker.references = pick_references(traj, frames, checker.config)
    return apply_verdicts([checker.measure(f) for f in frames], checker.config)


def compare_trajectories(
    a: Trajectory,
    b: Trajectory,
    mesh: str | None = None,
    *,
    tie_px: float = 0.5,
    limit: int | None = None,
    settings: dict[str, Any] | None = None,
) -> CompareResult:
    """Compare two pose sources (see the module docstring).

    ``settings``: RunConfig overrides for the checker (e.g. ``{"match": {"method": "orb"}}``,
    ``{"enhance": {"mode": "never"}}``); each source is checked as ``pgt-check`` would (its
    enhancement references come from the same source) and judged with the same verdict
    settings; the corner error of a source whose verdict is UNVERIFIABLE does not count.
    """
    from pgt_check.geometry.transforms import pose_difference

    _check_compare_args(a, b, mesh, settings)
    check_compare_options(tie_px, limit)
    all_pairs = pair_frames(a, b)
    if not all_pairs:
        raise InputError(
            f"{a.source} and {b.source} share no frame (compared by frame id, then image path)"
        )
    pairs = all_pairs[:limit] if limit is not None else all_pairs
    proxy = scale_proxy([fa for fa, _ in all_pairs])
    rows: list[dict[str, Any]] = []
    for fa, fb in pairs:
        dt, dr = pose_difference(fa.world_from_cam, fb.world_from_cam)
        rows.append({"frame_id": fa.frame_id, "image_path": fa.image_path, "drot_deg": dr,
                     "dt": dt, "depth": proxy})
    if mesh:
        mesh = str(Path(mesh))
        if not Path(mesh).is_file():
            raise InputError(f"mesh not found: {mesh}")
        from pgt_check.measure import FrameChecker

        checker = FrameChecker(checker_config(mesh, settings))
        try:
            ra = _measure_source(checker, a, [fa for fa, _ in pairs])
            rb = _measure_source(checker, b, [fb for _, fb in pairs])
            min_inl = checker.config.verdict.min_inliers
            for row, (fa, _), x, y in zip(rows, pairs, ra, rb, strict=True):
                basis, ea, eb = _errors(x, y, min_inl)
                row.update(
                    basis=basis,
                    corner_error_px_a=ea, corner_error_px_b=eb, verdict_a=x["verdict"],
                    verdict_b=y["verdict"], n_inliers_a=x.get("n_inliers"),
                    n_inliers_b=y.get("n_inliers"), supported=_winner(ea, eb, tie_px),
                    depth=_render_depth(checker, fa) or proxy,
                )
        finally:
            checker.close()
    for row, (fa, fb) in zip(rows, pairs, strict=True):
        row["shift_px"] = pixel_effect(fa, fb, row["depth"])
    res_summary = _summary(rows, a, b, mesh, proxy, tie_px)
    res_summary["n_only_a"] = len(a) - len(all_pairs)
    res_summary["n_only_b"] = len(b) - len(all_pairs)
    return CompareResult(rows, res_summary)


def _check_compare_args(a: Any, b: Any, mesh: Any, settings: Any) -> None:
    """InputError (naming the argument) for arguments of ``compare_trajectories`` of the wrong
    type, before anything is read: never a raw TypeError / AttributeError."""
    import os

    for name, traj in (("a", a), ("b", b)):
        if not isinstance(traj, Trajectory):
            raise InputError(f"compare: {name} must be a pgt_check.types.Trajectory (read one "
                             f"with pgt_check.io.read_trajectory); got {type(traj).__name__}")
    if mesh is not None and not isinstance(mesh, (str, os.PathLike)):
        raise InputError(f"compare: mesh must be a file path or None; got {type(mesh).__name__}")
    if settings is not None and not isinstance(settings, dict):
        raise InputError("compare: settings must be a dict of config settings or None; got "
                         f"{type(settings).__name__}")


def check_compare_options(tie_px: float, limit: int | None) -> None:
    """InputError for a tie width that is not a finite number >= 0 or a limit below 1."""
    from pgt_check.config.load import check_range

    try:
        check_range("--tie-px", tie_px, 0)
        if limit is not None:
            if isinstance(limit, bool) or not isinstance(limit, int):
                raise ValueError(f"--limit: expected an integer, got {limit!r}")
            check_range("--limit", limit, 1)
    except ValueError as err:
        raise InputError(str(err)) from None


def _render_depth(checker: Any, frame: Frame) -> float | None:
    """Median render depth of ``frame`` at a small size (the scale of the pixel effect)."""
    cam = frame.camera.scaled(min(1.0, 160 / max(frame.camera.width, frame.camera.height)))
    depth = checker.renderer.render(cam, frame.world_from_cam).depth
    d = depth[depth > 0]
    return float(np.median(d)) if d.size else None


def _raw_ok(r: dict[str, Any], min_inliers: int) -> bool:
    return r.get("corner_error_px_raw") is not None and (r.get("n_inliers_raw") or 0) >= min_inliers


def _errors(x: dict[str, Any], y: dict[str, Any], min_inliers: int
            ) -> tuple[str, float | None, float | None]:
    """(basis, error A, error B): the raw path (absolute evidence: mesh vs photo) when both
    sources have at least ``min_inliers`` raw inliers, else each source's deciding path (an
    UNVERIFIABLE source has no error)."""
    if _raw_ok(x, min_inliers) and _raw_ok(y, min_inliers):
        return "raw", x["corner_error_px_raw"], y["corner_error_px_raw"]
    ea = x["corner_error_px"] if x["verdict"] != "UNVERIFIABLE" else None
    eb = y["corner_error_px"] if y["verdict"] != "UNVERIFIABLE" else None
    return "verdict_path", ea, eb


def _winner(ea: float | None, eb: float | None, tie_px: float) -> str:
    if ea is None and eb is None:
        return "none"
    if eb is None:
        return "a"
    if ea is None:
        return "b"
    if abs(ea - eb) <= tie_px:
        return "tie"
    return "a" if ea < eb else "b"


def _stats(values: Sequence[float | None]) -> dict[str, Any]:
    """median / p90 / max of the measured values. A non-finite value (a NaN, or an effect
    without bound: B sees the points behind its camera) is never dropped: it is counted in
    ``n_not_finite`` and then no finite max is claimed (``max`` None, shown as inf)."""
    measured = [float(x) for x in values if x is not None]
    finite = np.array([x for x in measured if math.isfinite(x)], float)
    n_bad = len(measured) - len(finite)
    out: dict[str, Any] = {"median": None, "p90": None, "max": None, "n_not_finite": n_bad}
    if finite.size:
        out.update(median=float(np.median(finite)), p90=float(np.percentile(finite, 90)),
                   max=None if n_bad else float(finite.max()))
    return out


def _summary(rows: list[dict[str, Any]], a: Trajectory, b: Trajectory, mesh: str | None,
             proxy: float, tie_px: float) -> dict[str, Any]:
    out: dict[str, Any] = {
        "a": a.source, "b": b.source, "n_frames": len(rows),
        "n_only_a": len(a) - len(rows), "n_only_b": len(b) - len(rows),
        "drot_deg": _stats([r["drot_deg"] for r in rows]),
        "dt": _stats([r["dt"] for r in rows]),
        "shift_px": _stats([r["shift_px"] for r in rows]),
        "depth_source": "median render depth" if mesh else
        f"median camera distance from the centroid ({proxy:.4g} scene units; no mesh)",
    }
    if mesh:
        for src in ("a", "b"):
            out[f"verdicts_{src}"] = {
                v: sum(r[f"verdict_{src}"] == v for r in rows)
                for v in ("PASS", "FAIL", "UNVERIFIABLE")
            }
        wins = {k: sum(r["supported"] == k for r in rows) for k in ("a", "b", "tie", "none")}
        out["supported"] = wins
        out["tie_px"] = tie_px
        out["corner_error_px_a"] = _stats([r.get("corner_error_px_a") for r in rows])
        out["corner_error_px_b"] = _stats([r.get("corner_error_px_b") for r in rows])
    return out


def rows_csv_text(rows: Sequence[dict[str, Any]]) -> str:
    """compare.csv: cells as in frames.csv (``csv_cell``: formulas neutralised, one line per
    row); a shift without bound is written ``inf``."""
    from pgt_check.report.outputs import csv_text

    shown = [{**r, "shift_px": "inf"} if r.get("shift_px") == math.inf else r for r in rows]
    return csv_text(COMPARE_COLUMNS, shown)


def _fmt(v: Any, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def _max(stats: dict[str, Any], spec: str) -> str:
    return "inf" if stats.get("n_not_finite") else _fmt(stats["max"], spec)


def summary_lines(s: dict[str, Any]) -> list[str]:
    lines = [
        f"pgt-check compare: {s['n_frames']} frames in both sources "
        f"({s['n_only_a']} only in A, {s['n_only_b']} only in B)",
        f"pgt-check compare: rotation difference median {_fmt(s['drot_deg']['median'], '.3f')} "
        f"deg (max {_max(s['drot_deg'], '.3f')}); centre distance median "
        f"{_fmt(s['dt']['median'], '.4g')} (max {_max(s['dt'], '.4g')}) scene units; "
        f"effect in the image median {_fmt(s['shift_px']['median'], '.2f')} px "
        f"(max {_max(s['shift_px'], '.2f')})",
    ]
    if "supported" in s:
        w = s["supported"]
        ea, eb = s["corner_error_px_a"]["median"], s["corner_error_px_b"]["median"]
        lines.append(
            f"pgt-check compare: the images support A on {w['a']}, B on {w['b']} frames "
            f"({w['tie']} ties within {s['tie_px']} px, {w['none']} unmeasurable); median "
            f"corner error A {_fmt(ea, '.2f')} px, B {_fmt(eb, '.2f')} px"
        )
        for src in ("a", "b"):
            v = s[f"verdicts_{src}"]
            lines.append(f"pgt-check compare: verdicts {src.upper()}: {v['PASS']} PASS, "
                         f"{v['FAIL']} FAIL, {v['UNVERIFIABLE']} UNVERIFIABLE")
    return lines
