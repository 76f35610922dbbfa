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

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pgt_check.config import ReferenceConfig
from pgt_check.geometry.transforms import rotmat_to_quat
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


#: slack of the KD-tree bound for rounding (the angle from arccos near 0 is the least exact)
_BOUND_MARGIN = 1e-6


def select_references(
    frames: list[Frame] | tuple[Frame, ...],
    config: ReferenceConfig = ReferenceConfig(),
    only: Iterable[str] | None = None,
    eligible: Iterable[str] | None = None,
) -> dict[str, ReferenceChoice]:
    """Pick a reference for every frame (or for the frame ids in ``only``: the checked ones;
    any frame of ``frames`` may serve, or only those in ``eligible``: e.g. the frames whose
    own absolute evidence passed, so that a wrong neighbour's photo, painted onto the wrong
    surfaces, never decides a correct frame); returns frame_id -> ReferenceChoice. Trajectory
    positions (``min_frame_gap``) are those in ``frames`` either way.

    Near-linear: each frame scores only its nearest frames in a KD-tree over
    ``(c / translation_scale, q * 360 / (pi * rotation_scale_deg))`` (q the unit quaternion,
    both signs), whose Euclidean distance is a lower bound of the cost (``2 sin(a/4) <= a/2``
    for the chordal quaternion distance; the time term is >= 0). The neighbourhood is doubled
    until every frame left out is farther than the chosen ones' cost allows, so the choices
    are those of scoring every frame: same cost, limits and tie-break (lower trajectory
    position first).
    """
    n = len(frames)
    wanted = None if only is None else set(only)
    todo = [(i, f) for i, f in enumerate(frames) if wanted is None or f.frame_id in wanted]
    out: dict[str, ReferenceChoice] = {}
    if config.mode == "none":
        return {f.frame_id: ReferenceChoice((), "reference_disabled") for _, f in todo}
    if config.mode == "self":
        return {f.frame_id: ReferenceChoice((f.frame_id,), "", 0.0, 0.0) for _, f in todo}
    if n == 0:
        return out
    ix = _pose_index(frames, config, None if eligible is None else set(eligible))
    count = max(1, config.count)
    gap = max(1, config.min_frame_gap)
    for i, f in todo:
        near, best, dt, dr = _nearest(ix, i, config, count, gap)
        if not len(best):
            out[f.frame_id] = ReferenceChoice((), "no_reference_within_limits")
            continue
        j = int(best[0])
        out[f.frame_id] = ReferenceChoice(
            tuple(frames[int(near[m])].frame_id for m in best), "", float(dt[j]), float(dr[j])
        )
    return out


@dataclass(frozen=True)
class _PoseIndex:
    """The frames' poses as the search needs them, in trajectory order."""

    centres: np.ndarray  # (N, 3)
    rotations: np.ndarray  # (N, 3, 3)
    has_image: np.ndarray  # (N,) bool
    stamps: np.ndarray  # (N,) s, NaN where unknown
    t_scale: float  # translation_scale, or 10 % of the trajectory's extent
    q_scale: float  # quaternion coordinate per unit of rotation cost
    embedded: np.ndarray  # (N, 7) (c / t_scale, q * q_scale)
    tree: Any  # cKDTree over ``embedded`` and its flipped quaternions (2N points)


def _pose_index(
    frames: Sequence[Frame], config: ReferenceConfig, eligible: set[str] | None = None
) -> _PoseIndex:
    """The KD-tree and pose arrays of ``frames`` (at least one); a frame outside ``eligible``
    (when given) counts as one without a photo: it cannot serve."""
    from scipy.spatial import cKDTree

    n = len(frames)
    centres = np.array([f.world_from_cam[:3, 3] for f in frames])
    rotations = np.array([f.world_from_cam[:3, :3] for f in frames])
    has_image = np.array([
        f.image_file is not None and (eligible is None or f.frame_id in eligible) for f in frames
    ])
    stamps = np.array([np.nan if f.timestamp is None else float(f.timestamp) for f in frames])
    t_scale = config.translation_scale
    if t_scale is None:
        extent = float(np.linalg.norm(centres.max(0) - centres.min(0))) if n > 1 else 0.0
        t_scale = max(0.1 * extent, 1e-9)
    quats = np.array([rotmat_to_quat(r) for r in rotations])
    q_scale = 360.0 / (np.pi * config.rotation_scale_deg)
    embedded = np.hstack([centres / t_scale, quats * q_scale])
    flipped = np.hstack([centres / t_scale, -quats * q_scale])
    tree = cKDTree(np.vstack([embedded, flipped]))  # q and -q: the same rotation
    return _PoseIndex(centres, rotations, has_image, stamps, t_scale, q_scale, embedded, tree)


def _nearest(
    ix: _PoseIndex, i: int, config: ReferenceConfig, count: int, gap: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(near, best, dt, dr) of frame ``i``: the frames scored (positions), the ``count`` best
    within the limits (indices into near, best first) and the translation / rotation (deg)
    to each of near; the neighbourhood doubles until no frame left out could score better."""
    n = len(ix.centres)
    k = min(2 * n, max(32, 8 * count + 4 * gap))
    while True:
        dist, found = ix.tree.query(ix.embedded[i], k=k)
        dist, found = np.atleast_1d(dist), np.atleast_1d(found)
        near = np.unique(found[np.isfinite(dist)] % n)
        dt, dr, cost, ok = _scores(ix, i, near, config, gap)
        cand = np.flatnonzero(ok)
        best = cand[np.argsort(cost[cand], kind="stable")[:count]]
        reach = float(np.max(dist)) if len(dist) else 0.0  # every frame left out: >= reach
        if (
            k >= 2 * n
            or (len(best) == count and reach > float(cost[best[-1]]) + _BOUND_MARGIN)
            or (config.max_translation is not None
                and reach > config.max_translation / ix.t_scale + ix.q_scale * 2.0)
        ):
            return near, best, dt, dr
        k = min(2 * n, 2 * k)


def _scores(
    ix: _PoseIndex, i: int, near: np.ndarray, config: ReferenceConfig, gap: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(dt, dr, cost, ok) of the frames ``near`` as references of frame ``i``: translation,
    rotation (deg), cost (module docstring) and whether they are within the limits."""
    dt = np.linalg.norm(ix.centres[near] - ix.centres[i], axis=1)
    dr = _angles_deg(ix.rotations[near], ix.rotations[i])
    cost = dt / ix.t_scale + dr / config.rotation_scale_deg
    if config.time_scale_s is not None and np.isfinite(ix.stamps[i]):
        dtime = np.abs(ix.stamps[near] - ix.stamps[i])
        cost = cost + np.where(np.isfinite(dtime), dtime / config.time_scale_s, 0.0)
    ok = ix.has_image[near] & (np.abs(near - i) >= gap)
    ok &= dr <= config.max_rotation_deg
    if config.max_translation is not None:
        ok &= dt <= config.max_translation
    return dt, dr, cost, ok
