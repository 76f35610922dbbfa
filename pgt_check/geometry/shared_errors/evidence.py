"""Evidence of one frame for the run-level shared-error estimators, and its JSON form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pgt_check.types import check_shape

#: closed set of failure reasons
REASONS = (
    "too_few_frames",
    "too_few_points",
    "too_few_inliers",
    "ill_conditioned",
)


@dataclass(frozen=True, eq=False)
class FrameEvidence:
    """Absolute evidence of one frame.

    world_from_cam: (4, 4) float64, the checked pose; K: (3, 3) photo intrinsics (OpenCV pixel
    centres); pts2d: (N, 2) photo pixels; pts3d: (N, 3) world points (lifted render keypoints).
    ``index`` is the position along the trajectory (for drift windows).
    """

    frame_id: str
    index: int
    camera_id: str
    world_from_cam: np.ndarray
    K: np.ndarray
    width: int
    height: int
    pts2d: np.ndarray
    pts3d: np.ndarray

    def __post_init__(self) -> None:
        for name, shape in (("world_from_cam", (4, 4)), ("K", (3, 3))):
            arr = np.asarray(getattr(self, name), dtype=np.float64)
            check_shape(name, arr, shape)
            object.__setattr__(self, name, arr)
        p2 = np.asarray(self.pts2d, dtype=np.float64).reshape(-1, 2)
        p3 = np.asarray(self.pts3d, dtype=np.float64).reshape(-1, 3)
        if len(p2) != len(p3):
            raise ValueError(f"pts2d has {len(p2)} rows, pts3d {len(p3)}")
        object.__setattr__(self, "pts2d", p2)
        object.__setattr__(self, "pts3d", p3)

    def to_json(self) -> dict:
        """Plain dict (pixels to 1e-3, world points to 1e-5 scene units, pose in full)."""
        return {
            "frame_id": self.frame_id,
            "index": int(self.index),
            "camera_id": self.camera_id,
            "world_from_cam": self.world_from_cam.tolist(),
            "K": np.round(self.K, 6).tolist(),
            "width": int(self.width),
            "height": int(self.height),
            "pts2d": np.round(self.pts2d, 3).tolist(),
            "pts3d": np.round(self.pts3d, 5).tolist(),
        }

    @classmethod
    def from_json(cls, d: dict) -> FrameEvidence:
        return cls(
            frame_id=str(d["frame_id"]),
            index=int(d["index"]),
            camera_id=str(d["camera_id"]),
            world_from_cam=np.asarray(d["world_from_cam"], np.float64),
            K=np.asarray(d["K"], np.float64),
            width=int(d["width"]),
            height=int(d["height"]),
            pts2d=np.asarray(d["pts2d"], np.float64).reshape(-1, 2),
            pts3d=np.asarray(d["pts3d"], np.float64).reshape(-1, 3),
        )
