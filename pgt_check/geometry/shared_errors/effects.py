"""Pixel effects and summaries of world corrections (batched over bootstrap states)."""

from __future__ import annotations

import numpy as np

from pgt_check.geometry.shared_errors.model import _angle_deg, _bmv, _Problem, _rodrigues, _State


def _effect_points(p: _Problem, inliers: np.ndarray) -> np.ndarray:
    """Points used for a frame's pixel effect: its inliers, or all its points if < 3 inliers."""
    n_in = np.bincount(p.fidx[inliers], minlength=p.n_frames)
    return inliers | (n_in[p.fidx] < 3)


def _project_world(
    p: _Problem, q: np.ndarray, sig: np.ndarray, tau: np.ndarray, sel: np.ndarray
) -> np.ndarray:
    """(B, n, 2) pixels of the selected points under B world maps D (no calibration)."""
    f = p.fidx[sel]
    y = p.y[sel]
    xw = sig[:, None, None] * (y @ q.transpose(0, 2, 1)) + tau[:, None, :] - p.centre[f]
    pix = _bmv((p.K @ p.rt)[f], xw)
    return pix[..., :2] / pix[..., 2:3]


def _per_frame_mean(p: _Problem, sel: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(B, n) values of the selected points -> (B, F) per-frame means (NaN without points)."""
    f = p.fidx[sel]
    cnt = np.bincount(f, minlength=p.n_frames).astype(np.float64)
    m = np.zeros((len(f), p.n_frames))
    m[np.arange(len(f)), f] = 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        return (values @ m) / cnt


def _world_params(p: _Problem, st: _State, deltas: np.ndarray | None, similarity: bool):
    """(Q (B,3,3), sigma (B,), tau (B,3)) for the point estimate (B=1) or bootstrap states."""
    if deltas is None:
        return st.q[None], np.array([np.exp(st.log_sigma)]), st.tau[None]
    q = _rodrigues(deltas[:, 0:3]) @ st.q
    tau = st.tau + deltas[:, 3:6]
    ls = st.log_sigma + (deltas[:, 6] if similarity else 0.0)
    return q, np.exp(np.broadcast_to(ls, (len(deltas),))), tau


def _correction_summary(q, sig, tau):
    """Angle (deg), scale s, centroid translation t of C = D^-1 for batched world maps."""
    angle = _angle_deg(q)
    s = 1.0 / sig
    t = -np.einsum("bji,bj->bi", q, tau) * s[:, None]  # -Q^T tau / sigma
    return angle, s, t
