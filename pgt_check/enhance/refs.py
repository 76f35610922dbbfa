"""Reference photos chosen with what the run knows.

For ``pgt-check enhance``: find the renders, give each the pose of the model image it is named
like (or of a ``--render-poses`` entry), and pick the nearest training photo by pose (never the
render's own view unless asked).

For a check run (``verified_references``): after the main pass has judged every frame, the
frames whose enhanced path leaned on a reference frame whose own absolute evidence did not pass
get references among those whose evidence did (``absolute_passes``). A wrong neighbour's photo
paints its texture onto the wrong surfaces: the enhanced path of a correct frame then finds too
few matches or a large error, and with 40 % wrong frames most frames have a wrong neighbour
(issue 38)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.errors import InputError
from pgt_check.types import Frame, Trajectory

logger = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


@dataclass(frozen=True)
class RenderItem:
    """One render file with the pose it was made at and its chosen reference (None: skipped)."""

    name: str  # file name without extension
    file: Path
    frame: Frame | None
    reference: Frame | None = None
    reference_dt: float | None = None
    reference_drot_deg: float | None = None
    status: str = "ok"


def find_renders(folder: str | Path) -> list[Path]:
    """The image files directly inside ``folder``, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"renders folder not found: {folder}")
    files = sorted(p for p in folder.iterdir()
                   if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputError(f"{folder}: no .png/.jpg renders in this folder")
    return files


def _keys(frame: Frame) -> list[str]:
    """Names a render may carry to take this frame's pose: the image's file name without its
    extension, or the frame id."""
    keys = [Path(frame.image_path).stem] if frame.image_path else []
    return list(dict.fromkeys([*keys, frame.frame_id]))


def frame_index(frames: Sequence[Frame]) -> dict[str, Frame]:
    """name -> frame for every key of ``_keys``; a key two frames share is left out."""
    index: dict[str, Frame] = {}
    clash: set[str] = set()
    for f in frames:
        for k in _keys(f):
            if k in index and index[k] is not f:
                clash.add(k)
            index.setdefault(k, f)
    for k in clash:
        del index[k]
    return index


def _angles_deg(rotations: np.ndarray, r: np.ndarray) -> np.ndarray:
    rel = np.einsum("nji,jk->nik", rotations, r)
    c = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(c))


def nearest_references(
    items: Sequence[RenderItem],
    training: Sequence[Frame],
    *,
    translation_scale: float | None = None,
    rotation_scale_deg: float = 10.0,
    max_rotation_deg: float = 45.0,
    max_translation: float | None = None,
    allow_same_view: bool = False,
) -> list[RenderItem]:
    """Each posed render with its nearest training photo (the validator's distance, see the
    module docstring). A training frame named like the render or at the render's own pose
    (1e-6 of the translation scale, 1e-3 deg) is the view's ground truth and is excluded unless
    ``allow_same_view`` (an upper bound: the enhancer then sees the answer)."""
    from dataclasses import replace

    if not training:
        raise InputError("the model has no frame whose photo exists (nothing to take "
                         "appearance from; check --images)")
    centres = np.array([f.world_from_cam[:3, 3] for f in training])
    rotations = np.array([f.world_from_cam[:3, :3] for f in training])
    if translation_scale is None:
        extent = float(np.linalg.norm(centres.max(0) - centres.min(0)))
        translation_scale = max(0.1 * extent, 1e-9)
    out = []
    for it in items:
        if it.frame is None:
            out.append(it)
            continue
        names = set(_keys(it.frame)) | {it.name}
        dt = np.linalg.norm(centres - it.frame.world_from_cam[:3, 3], axis=1)
        dr = _angles_deg(rotations, it.frame.world_from_cam[:3, :3])
        cost = dt / translation_scale + dr / rotation_scale_deg
        ok = dr <= max_rotation_deg
        if not allow_same_view:
            ok &= ~np.array([bool(names & set(_keys(f))) for f in training])
            ok &= ~((dt <= 1e-6 * translation_scale) & (dr <= 1e-3))
        if max_translation is not None:
            ok &= dt <= max_translation
        if not ok.any():
            out.append(replace(it, status="no_reference_within_limits"))
            continue
        cand = np.flatnonzero(ok)
        j = int(cand[np.argmin(cost[cand])])
        out.append(replace(it, reference=training[j], reference_dt=float(dt[j]),
                           reference_drot_deg=float(dr[j])))
    return out


def pose_renders(files: Sequence[Path], poses: Trajectory) -> list[RenderItem]:
    """Each render file with the frame of ``poses`` it is named like (None: no such frame)."""
    index = frame_index(poses.frames)
    items = [RenderItem(p.stem, p, index.get(p.stem), status="ok" if p.stem in index
                        else "no_pose") for p in files]
    for it in items:
        if it.frame is None:
            logger.warning("%s: no pose named %r in %s; skipped", it.file, it.name, poses.source)
    if not any(it.frame for it in items):
        examples = ", ".join(sorted(index)[:3])
        raise InputError(
            f"no render in {files[0].parent} is named like a posed image of {poses.source} "
            f"(render names: {', '.join(p.stem for p in files[:3])}; pose names: {examples})"
        )
    return items


def absolute_passes(result: Any) -> set[str]:
    """Frame ids whose own absolute evidence passed in a judged run (a ``RunResult``): the
    verdict PASS rests on absolute evidence, the raw path alone says PASS, or the frame's own
    absolute evidence alone does (``Judgement.own_verdict``) whatever the run-level checks made
    of its verdict: under a failed registration check every verdict is FAIL, yet a reference
    right up to that shared error is what a relative path needs (frame and reference carry it
    alike). Without that, the reference pass of such a run took every reference away (colourless
    7-Scenes with the defaults: reports/scenes_loso_colourless.md, colourless6 and 7). Never a
    frame the run-level checks left out (its absolute evidence disagrees with the shared
    model)."""
    left_out = result.shared.left_out if result.shared is not None else frozenset()
    out = set()
    for fr in result.frames:
        j = fr.judgement
        own = (j.verdict.value == "PASS" and j.evidence == "absolute") or \
            j.raw_verdict == "PASS" or j.own_verdict == "PASS"
        if own and fr.frame_id not in left_out:
            out.add(fr.frame_id)
    return out


def verified_references(
    trajectory: Trajectory, result: Any, config: Any
) -> dict[str, tuple[Frame, ...]]:
    """Frame id -> new references (best first; empty: none within the limits) for every frame
    of the judged run ``result`` whose enhanced path ran on a reference outside
    ``absolute_passes`` and which did not PASS on absolute evidence; the new ones are chosen
    among ``absolute_passes`` (``select_references(eligible=...)``, the run's reference
    settings). Frames whose choice does not change are left out; so is everything when the
    enhanced path is off or its references are the frame's own photo."""
    from pgt_check.enhance.reference import select_references

    ref_cfg = config.enhance.reference
    if config.enhance.mode == "never" or ref_cfg.mode != "nearest":
        return {}
    eligible = absolute_passes(result)
    todo = []
    for fr in result.frames:
        m, j = fr.measurement, fr.judgement
        if not m.enhance_ran or (j.verdict.value == "PASS" and j.evidence == "absolute"):
            continue
        used = {p.reference_id for p in (m.enhanced, *m.enhanced_alternatives)
                if p is not None and p.reference_id}
        if used - eligible:
            todo.append(fr.frame_id)
    if not todo:
        return {}
    by_id = trajectory.by_id()
    before = select_references(trajectory.frames, ref_cfg, only=todo)
    after = select_references(trajectory.frames, ref_cfg, only=todo, eligible=eligible)
    return {
        fid: tuple(by_id[i] for i in after[fid].frame_ids)
        for fid in todo
        if after[fid].frame_ids != before[fid].frame_ids
    }
