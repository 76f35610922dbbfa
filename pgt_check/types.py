"""Value types shared by every pipeline step.

Conventions (one for the whole package, converted at the reader edge):

* Poses are ``world_from_cam``: 4x4 float64 rigid transforms, OpenCV camera axes
  (x right, y down, z forward), ``X_world = world_from_cam @ X_cam``.
* Pixels follow OpenCV: the centre of the top-left pixel is (0, 0). COLMAP / LaMAR files put it
  at (0.5, 0.5); their readers subtract 0.5 from cx, cy.
* Images are HxWx3 RGB float32 in [0, 1].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pgt_check.common.checks import check_shape

__all__ = [
    "CAMERA_MODELS",
    "FISHEYE_MODELS",
    "OPENCV_MODELS",
    "Camera",
    "Frame",
    "Trajectory",
    "check_shape",
]

# COLMAP camera models we accept, with their parameter names (COLMAP order): every model of
# pycolmap with a focal length and a principal point (EQUIRECTANGULAR, spherical, is left out).
CAMERA_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k1"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "FOV": ("fx", "fy", "cx", "cy", "omega"),
    "THIN_PRISM_FISHEYE": (
        "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1"
    ),  # fmt: skip
    "RAD_TAN_THIN_PRISM_FISHEYE": (
        "fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1",
        "s0", "s1", "s2", "s3",
    ),  # fmt: skip
    "SIMPLE_DIVISION": ("f", "cx", "cy", "k1"),
    "DIVISION": ("fx", "fy", "cx", "cy", "k1"),
    "SIMPLE_FISHEYE": ("f", "cx", "cy"),
    "FISHEYE": ("fx", "fy", "cx", "cy"),
    "EUCM": ("fx", "fy", "cx", "cy", "alpha", "beta"),
}

#: models whose distortion OpenCV's ``cv2.undistort`` models (``Camera.dist_coeffs``)
OPENCV_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
#: fisheye projections: distorted relative to a pinhole even with every coefficient zero
FISHEYE_MODELS = (
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "OPENCV_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "SIMPLE_FISHEYE",
    "FISHEYE",
)
#: parameters that do not distort when the others are zero (EUCM with alpha = 0 is a pinhole)
_NEUTRAL_PARAMS = {"EUCM": ("beta",)}
_PINHOLE_NAMES = ("f", "fx", "fy", "cx", "cy")


#: COLMAP pixel coordinate = OpenCV pixel coordinate + COLMAP_PIXEL_OFFSET
COLMAP_PIXEL_OFFSET = 0.5

_PRINCIPAL = ("cx", "cy")


def _shift_principal(model: str, params: Sequence[float], delta: float) -> tuple[float, ...]:
    if model not in CAMERA_MODELS:
        raise ValueError(f"unknown camera model {model!r} (allowed: {', '.join(CAMERA_MODELS)})")
    names = CAMERA_MODELS[model]
    if len(params) != len(names):
        raise ValueError(
            f"camera model {model} takes {len(names)} parameters ({', '.join(names)}), "
            f"got {len(params)}"
        )
    return tuple(
        float(p) + delta if n in _PRINCIPAL else float(p) for n, p in zip(names, params, strict=True)
    )


def colmap_to_opencv_params(model: str, params: Sequence[float]) -> tuple[float, ...]:
    """COLMAP-order parameters in COLMAP pixel convention -> OpenCV convention (cx, cy - 0.5)."""
    return _shift_principal(model, params, -COLMAP_PIXEL_OFFSET)


def opencv_to_colmap_params(model: str, params: Sequence[float]) -> tuple[float, ...]:
    """COLMAP-order parameters in OpenCV pixel convention -> COLMAP convention (cx, cy + 0.5)."""
    return _shift_principal(model, params, COLMAP_PIXEL_OFFSET)


@dataclass(frozen=True)
class Camera:
    """A camera in OpenCV pixel convention (top-left pixel centre at (0, 0)).

    ``model`` is a COLMAP model name; ``params`` are in COLMAP order but with the principal
    point already converted to OpenCV convention (readers of COLMAP/LaMAR files subtract 0.5).
    """

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def __post_init__(self) -> None:
        if self.model not in CAMERA_MODELS:
            raise ValueError(
                f"unknown camera model {self.model!r} (allowed: {', '.join(CAMERA_MODELS)})"
            )
        names = CAMERA_MODELS[self.model]
        if len(self.params) != len(names):
            raise ValueError(
                f"camera model {self.model} takes {len(names)} parameters "
                f"({', '.join(names)}), got {len(self.params)}"
            )
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"camera size must be positive, got {self.width}x{self.height}")
        if not all(np.isfinite(p) for p in self.params):
            raise ValueError(f"camera parameters must be finite, got {self.params}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "params", tuple(float(p) for p in self.params))
        fx, fy = self.focal
        if fx <= 0 or fy <= 0:
            raise ValueError(f"focal length must be positive, got fx={fx}, fy={fy}")

    @classmethod
    def pinhole(cls, width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> Camera:
        """A PINHOLE camera from OpenCV-convention intrinsics."""
        return cls("PINHOLE", width, height, (fx, fy, cx, cy))

    @property
    def _named(self) -> dict[str, float]:
        return dict(zip(CAMERA_MODELS[self.model], self.params, strict=False))

    @property
    def focal(self) -> tuple[float, float]:
        p = self._named
        return (p["f"], p["f"]) if "f" in p else (p["fx"], p["fy"])

    @property
    def principal_point(self) -> tuple[float, float]:
        p = self._named
        return p["cx"], p["cy"]

    @property
    def K(self) -> np.ndarray:  # noqa: N802 (standard name)
        """(3, 3) float64 intrinsic matrix, OpenCV pixel convention."""
        fx, fy = self.focal
        cx, cy = self.principal_point
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV distortion coefficients (k1, k2, p1, p2[, k3, k4, k5, k6]); zeros if none.

        Only for ``OPENCV_MODELS``; other models raise ValueError (undistort them with
        ``pgt_check.io.camera.undistort_to_pinhole``).
        """
        p = self._named
        if self.model not in OPENCV_MODELS:
            raise ValueError(
                f"camera model {self.model} has no OpenCV distortion coefficients; "
                "use pgt_check.io.camera.undistort_to_pinhole"
            )
        if self.model == "FULL_OPENCV":
            return np.array([p[k] for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")])
        return np.array([p.get("k1", 0.0), p.get("k2", 0.0), p.get("p1", 0.0), p.get("p2", 0.0)])

    @property
    def is_distorted(self) -> bool:
        """False only for a pinhole projection (fisheye models are distorted with zero k)."""
        if self.model in FISHEYE_MODELS:
            return True
        neutral = (*_PINHOLE_NAMES, *_NEUTRAL_PARAMS.get(self.model, ()))
        return any(v != 0.0 for k, v in self._named.items() if k not in neutral)

    @property
    def diagonal(self) -> float:
        return float(np.hypot(self.width, self.height))

    def as_pinhole(self) -> Camera:
        """The same camera with distortion dropped (the model the renderer uses)."""
        fx, fy = self.focal
        cx, cy = self.principal_point
        return Camera.pinhole(self.width, self.height, fx, fy, cx, cy)

    def scaled(self, sx: float, sy: float | None = None) -> Camera:
        """The camera for an image resized by (sx, sy): pixel centres map as (x+.5)*s-.5."""
        sy = sx if sy is None else sy
        fx, fy = self.focal
        cx, cy = self.principal_point
        width = max(1, round(self.width * sx))
        height = max(1, round(self.height * sy))
        return Camera.pinhole(width, height, fx * sx, fy * sy, (cx + 0.5) * sx - 0.5,
                              (cy + 0.5) * sy - 0.5)

    def to_colmap_params(self) -> tuple[float, ...]:
        """Parameters in COLMAP convention (principal point + 0.5), for writers."""
        return opencv_to_colmap_params(self.model, self.params)


@dataclass(frozen=True, eq=False)
class Frame:
    """One captured image with its pose to check.

    ``image_path`` is the path exactly as written in the input file (reported verbatim);
    ``image_file`` is the resolved path used to read it (None if the input named no image).
    """

    frame_id: str
    camera: Camera
    world_from_cam: np.ndarray
    image_path: str = ""
    image_file: Path | None = None
    timestamp: float | None = None

    def __post_init__(self) -> None:
        m = np.asarray(self.world_from_cam, dtype=np.float64)
        check_shape(f"frame {self.frame_id}: world_from_cam", m, (4, 4))
        if not np.all(np.isfinite(m)):
            raise ValueError(f"frame {self.frame_id}: world_from_cam is not finite")
        if not np.allclose(m[3], [0, 0, 0, 1]):
            raise ValueError(f"frame {self.frame_id}: world_from_cam last row must be 0 0 0 1")
        r = m[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-5) or np.linalg.det(r) < 0:
            raise ValueError(f"frame {self.frame_id}: world_from_cam rotation is not a rotation")
        m = m.copy()
        m.setflags(write=False)
        object.__setattr__(self, "world_from_cam", m)

    @property
    def cam_from_world(self) -> np.ndarray:
        r, c = self.world_from_cam[:3, :3], self.world_from_cam[:3, 3]
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = r.T, -r.T @ c
        return out

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return self.world_from_cam[:3, 3].copy()

    def with_pose(self, world_from_cam: np.ndarray) -> Frame:
        return replace(self, world_from_cam=world_from_cam)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """An ordered list of frames read from one pose file."""

    frames: tuple[Frame, ...]
    source: str = ""
    format: str = ""
    metadata: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "frames", tuple(self.frames))
        seen: set[str] = set()
        for f in self.frames:
            if f.frame_id in seen:
                raise ValueError(f"duplicate frame id {f.frame_id!r} in {self.source}")
            seen.add(f.frame_id)

    def __len__(self) -> int:
        return len(self.frames)

    def __iter__(self):
        return iter(self.frames)

    def __getitem__(self, i: int) -> Frame:
        return self.frames[i]

    def by_id(self) -> dict[str, Frame]:
        return {f.frame_id: f for f in self.frames}
