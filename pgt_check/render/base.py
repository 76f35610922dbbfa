"""The renderer interface every backend implements."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pgt_check.types import Camera

#: How the colour of a render was produced (recorded in every run):
#: "vertex" = unlit per-vertex colours, "texture" = unlit texture lookup,
#: "shaded" = colourless mesh, head-light Lambertian shading of the geometry.
SHADING_MODES = ("vertex", "texture", "shaded")


@dataclass(frozen=True, eq=False)
class Render:
    """One rendered view.

    rgb: (H, W, 3) float32 in [0, 1], RGB; background is 0.
    depth: (H, W) float32 metric camera-space z (same units as the mesh), 0 where nothing was hit.
    coverage: (H, W) bool, True where the mesh was hit.
    shading: one of SHADING_MODES.
    """

    rgb: np.ndarray
    depth: np.ndarray
    coverage: np.ndarray
    shading: str

    @classmethod
    def empty(cls, height: int, width: int, shading: str) -> Render:
        """A view in which nothing of the mesh is visible."""
        return cls(
            rgb=np.zeros((height, width, 3), dtype=np.float32),
            depth=np.zeros((height, width), dtype=np.float32),
            coverage=np.zeros((height, width), dtype=bool),
            shading=shading,
        )

    @property
    def coverage_fraction(self) -> float:
        return float(self.coverage.mean()) if self.coverage.size else 0.0


class Renderer(Protocol):
    """Renders one loaded mesh. Create inside the process that uses it (GL contexts do not fork)."""

    shading: str

    def render(self, camera: Camera, world_from_cam: np.ndarray) -> Render:
        """Render at ``world_from_cam`` (4x4 float64, OpenCV axes) with ``camera``'s pinhole model."""
        ...

    def close(self) -> None: ...
