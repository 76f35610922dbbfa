"""Reference selection: for each frame, the nearest *other* frame whose photo can lend appearance.

Distance between frames a and b (smaller is better):
    d = |c_a - c_b| / translation_scale + angle(R_a, R_b) / rotation_scale_deg
        (+ |t_a - t_b| / time_scale_s where both frames have timestamps and time_scale_s is set)
with limits ``max_translation``, ``max_rotation_deg`` and ``min_frame_gap`` (frames closer than
this many trajectory positions are skipped: at video rates the adjacent photo is almost the
frame's own photo, and an enhancer that copies it would hide the frame's pose error).
The frame's own photo is used only with ``mode="self"`` (an upper bound for evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pgt_check.config import ReferenceConfig
from pgt_check.types import Frame


@dataclass(frozen=True)
class ReferenceChoice:
    """The chosen references of one frame, best first (empty with a reason if none)."""

    frame_ids: tuple[str, ...]
    reason: str  # "" when a reference was found, else why not
    distance_t: float | None = None  # of the best reference
    distance_rot_deg: float | None = None

    @property
    def frame_id(self) -> str | None:
        return self.frame_ids[0] if self.frame_ids else None


def _angles_deg(rotations: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Geodesic angles (deg) between each of (N, 3, 3) rotations and r (3, 3)."""
    rel = np.einsum("nji,jk->nik", rotations, r)  # R_n^T r
    c = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(c))


def select_references(
    frames: list[Frame] | tuple[Frame, ...], config: ReferenceConfig = ReferenceConfig()
) -> dict[str, ReferenceChoice]:
    """Pick a reference for every frame; returns frame_id -> ReferenceChoice.

    Vectorised over the trajectory per frame (O(N^2) in total: fine to ~10^4 frames; larger
    trajectories should be split into chunks).
    """
    n = len(frames)
    out: dict[str, ReferenceChoice] = {}
    if config.mode == "none":
        return {f.frame_id: ReferenceChoice((), "reference_disabled") for f in frames}
    if config.mode == "self":
        return {f.frame_id: ReferenceChoice((f.frame_id,), "", 0.0, 0.0) for f in frames}
    if n == 0:
        return out
    centres = np.array([f.world_from_cam[:3, 3] for f in frames])
    rotations = np.array([f.world_from_cam[:3, :3] for f in frames])
    has_image = np.array([f.image_file is not None for f in frames])
    stamps = np.array([np.nan if f.timestamp is None else float(f.timestamp) for f in frames])
    t_scale = config.translation_scale
    if t_scale is None:
        extent = float(np.linalg.norm(centres.max(0) - centres.min(0))) if n > 1 else 0.0
        t_scale = max(0.1 * extent, 1e-9)
    idx = np.arange(n)
    for i, f in enumerate(frames):
        dt = np.linalg.norm(centres - centres[i], axis=1)
        dr = _angles_deg(rotations, rotations[i])
        cost = dt / t_scale + dr / config.rotation_scale_deg
        if config.time_scale_s is not None and np.isfinite(stamps[i]):
            dtime = np.abs(stamps - stamps[i])
            cost = cost + np.where(np.isfinite(dtime), dtime / config.time_scale_s, 0.0)
        ok = has_image & (np.abs(idx - i) >= max(1, config.min_frame_gap))
        ok &= dr <= config.max_rotation_deg
        if config.max_translation is not None:
            ok &= dt <= config.max_translation
        if not ok.any():
            out[f.frame_id] = ReferenceChoice((), "no_reference_within_limits")
            continue
        cand = np.flatnonzero(ok)
        best = cand[np.argsort(cost[cand], kind="stable")[: max(1, config.count)]]
        j = int(best[0])
        out[f.frame_id] = ReferenceChoice(
            tuple(frames[int(k)].frame_id for k in best), "", float(dt[j]), float(dr[j])
        )
    return out
