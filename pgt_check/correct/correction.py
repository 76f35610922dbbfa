"""One frame's pose correction as a record (``Correction``), its frames.csv columns, and the run
directory's corrections file. ``pose.refine_pose`` makes them; split out of ``pose.py`` (its
size) so that readers of a run's corrections need none of the refinement."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.output_layout import OUTPUTS

logger = logging.getLogger(__name__)


#: frames.csv / report columns added by the correction step (empty when it did not run)
CORRECTION_COLUMNS: tuple[str, ...] = (
    "corr_applied",
    "corr_drot_deg",
    "corr_dt",
    "corr_sigma_rot_deg",
    "corr_sigma_t",
    "corr_corner_error_px",
    "corr_rounds",
    "corr_start",
    "corr_reason",
)


@dataclass(frozen=True)
class Correction:
    """The corrected pose of one frame (JSON-able; poses as nested lists).

    ``drot_deg`` / ``dt``: from the checked pose to the corrected one (degrees, scene units).
    ``corner_error_px_before``: the raw corner error at the start pose of the first round;
    ``corner_error_px``: the raw corner error of the render at the last round's start pose (the
    final update after it is part of the uncertainty), or where that did not verify it, the
    corner error of the evidence that did (``verified_by``: the frame measured at the
    corrected pose). ``start``: "pnp_raw", "pnp_enhanced" (the measurement's PnP estimate and
    the path it came from) or "checked" (no estimate). ``depth``: median render depth (scene
    units), the scale for "1 % of scene depth". ``applied``: written to the corrected
    trajectory: success, verified (corner_error_px <= the frame's threshold) and
    sigma_rot_deg <= max(0.1 deg, half the correction) (else ``reason`` is "not_verified" or
    "uncertain").
    """

    frame_id: str
    success: bool
    reason: str = ""
    world_from_cam: tuple[tuple[float, ...], ...] | None = None
    drot_deg: float | None = None
    dt: float | None = None
    sigma_rot_deg: float | None = None
    sigma_t: float | None = None
    corner_error_px_before: float | None = None
    corner_error_px: float | None = None
    n_inliers: int = 0
    rounds: int = 0
    start: str = "checked"
    depth: float | None = None
    applied: bool = False
    steps: tuple[tuple[float, float], ...] = field(default_factory=tuple)
    #: the evidence that verified the corrected pose: "raw" (the last round's raw render),
    #: "edges" or "raw" again when the frame was measured at the corrected pose
    #: (``correct.frames``: a textureless photo gives the rounds' raw render too few matches
    #: for a homography), "" when nothing verified it
    verified_by: str = ""

    @property
    def pose(self) -> np.ndarray | None:
        return None if self.world_from_cam is None else np.asarray(self.world_from_cam, float)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        return {k: _clean(v) for k, v in d.items()}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Correction:
        names = {f.name for f in fields(cls)}
        d = {k: v for k, v in data.items() if k in names}
        if d.get("world_from_cam") is not None:
            d["world_from_cam"] = tuple(tuple(map(float, r)) for r in d["world_from_cam"])
        d["steps"] = tuple(tuple(s) for s in d.get("steps") or ())
        return cls(**d)

    def row(self) -> dict[str, Any]:
        """The ``CORRECTION_COLUMNS`` values of this correction."""
        return {
            "corr_applied": self.applied,
            "corr_drot_deg": self.drot_deg,
            "corr_dt": self.dt,
            "corr_sigma_rot_deg": self.sigma_rot_deg,
            "corr_sigma_t": self.sigma_t,
            "corr_corner_error_px": self.corner_error_px,
            "corr_rounds": self.rounds,
            "corr_start": self.start,
            "corr_reason": self.reason,
        }


def _clean(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


def save_corrections(
    out_dir: str | Path, corrections: Iterable[Correction], fingerprint: str = ""
) -> Path:
    path = Path(out_dir) / OUTPUTS.corrections
    doc = {"fingerprint": fingerprint, "corrections": [c.to_json() for c in corrections]}
    from pgt_check.common.files import atomic_write_text

    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path


def load_corrections(out_dir: str | Path) -> dict[str, Correction]:
    """The corrections stored in a run directory by frame id ({} if there are none)."""
    path = Path(out_dir) / OUTPUTS.corrections
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
        return {str(d["frame_id"]): Correction.from_json(d) for d in doc.get("corrections", [])}
    except (ValueError, KeyError, TypeError) as err:
        logger.warning("%s unreadable, corrections left out: %s", path, err)
        return {}
