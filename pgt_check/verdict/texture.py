"""Run-level check: mesh colours against mesh geometry (``shared_errors.texture``)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.calibration import camera_matrix
from pgt_check.verdict.shared_results import TextureCheck
from pgt_check.verdict.status import FINDING, INCONCLUSIVE, NOT_CHECKED, PASSED

#: renders whose colours come from the mesh (their feature matches are texture evidence)
COLOURED_SHADINGS = ("vertex", "texture")
#: evidence sources that see the mesh's geometry only
GEOMETRIC_SOURCES = ("edges",)


def texture_entry(measurements: Sequence[FrameMeasurement], threshold: float) -> TextureCheck | None:
    """Mesh colours against mesh geometry: where the raw matches of a coloured render place the
    photos against where the geometric edges do, shared by the frames. A ``finding`` (lower
    bound above ``threshold``) means the colours sit off the geometry in every photo alike:
    the mesh was likely coloured with these poses (or with a camera offset), so texture
    matches cannot show a calibration error that the geometry shows. Informational: it does
    not change verdicts. Not checked (``no_geometric_evidence``) where coloured renders gave
    texture matches but no frame has geometric-edge evidence: a shared error the mesh colours
    carry would then go unseen, which the entry says. None when no frame has texture matches."""
    from pgt_check.geometry.shared_errors.texture import FramePoints, texture_offset

    frames = []
    n_texture = 0
    for m in measurements:
        if m.evidence is None or m.shading not in COLOURED_SHADINGS or m.intrinsics is None:
            continue
        parts = m.evidence.by_source()
        geo = [parts[s] for s in GEOMETRIC_SOURCES if s in parts]
        n_texture += "raw" in parts
        if "raw" not in parts or not geo:
            continue
        frames.append(
            FramePoints(
                camera_matrix(m.intrinsics),
                *parts["raw"],
                np.concatenate([g[0] for g in geo]),
                np.concatenate([g[1] for g in geo]),
            )
        )
    if not frames:
        return None if not n_texture else TextureCheck(
            NOT_CHECKED, "no_geometric_evidence", 0,
            f"mesh colours vs geometry not checked: {n_texture} frames have texture matches "
            "and none has geometric-edge evidence; a shared error that the mesh colours carry "
            "(a mesh coloured with these poses) is invisible to texture matches (--edges "
            "always checks it)",
        )
    est = texture_offset(frames)
    if not est.success:
        return TextureCheck(
            NOT_CHECKED, est.reason, est.n_frames,
            "mesh colours vs geometry not checked: too few frames with both texture matches "
            "and geometric edges",
        )
    lo, hi = est.effect_px_ci
    status = FINDING if lo > threshold else PASSED if hi <= threshold else INCONCLUSIVE
    dx, dy = est.offset_px
    what = (
        "the mesh colours sit off its geometry in every photo alike: the mesh was likely "
        "coloured with these poses (or with a camera offset), so texture matches cannot show "
        "a calibration error that the geometry shows (judge calibration on geometry: "
        "--shading shaded)"
        if status == FINDING
        else "mesh colours agree with its geometry"
        if status == PASSED
        else "mesh colours vs geometry: not clear"
    )
    return TextureCheck(
        status, "", est.n_frames,
        f"{what}: texture matches place the photos ({dx:+.1f}, {dy:+.1f}) px from the geometric "
        f"edges ({est.effect_px:.1f} px, 95 % {lo:.1f}-{hi:.1f}) over {est.n_frames} frames",
        (dx, dy), est.effect_px, (lo, hi),
    )
