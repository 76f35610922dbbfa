"""The interface every enhancement method implements, and the kind of evidence it gives."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

from pgt_check.render.base import Render, Renderer
from pgt_check.types import Camera


class Evidence(str, Enum):
    """What a comparison with the photo depends on.

    ABSOLUTE: only the mesh and this frame's own pose (the raw render; an enhancement that takes
    appearance from a reference and places it by image content). RELATIVE: also a reference
    photo placed by the reference's own pose (reprojection): errors the frame and its reference
    share (registration, drift, calibration) cancel. See README "What a verdict proves".
    """

    ABSOLUTE = "absolute"
    RELATIVE = "relative"


@dataclass(frozen=True, eq=False)
class View:
    """A render with the working camera and the pose it was made with."""

    render: Render
    camera: Camera
    world_from_cam: np.ndarray


@dataclass(frozen=True, eq=False)
class ReferenceView:
    """A reference photo at working scale with its (pinhole) camera and pose."""

    frame_id: str
    photo: np.ndarray  # (h, w, 3) float32 RGB [0, 1]
    camera: Camera
    world_from_cam: np.ndarray


@dataclass(frozen=True, eq=False)
class EnhancedImage:
    """image: (h, w, 3) float32 RGB at the render's size; filled: (h, w) bool, where the
    reference contributed (all True for methods that change every pixel)."""

    image: np.ndarray
    filled: np.ndarray


class Enhancer(Protocol):
    """An enhancement method: the render of ``view`` given the appearance of ``reference``."""

    name: str
    evidence: Evidence
    #: the enhanced image carries detail only up to this short side (px; None: the render's
    #: own): the enhanced path matches it at that size (``measure.steps.match_path``)
    detail_short_side: int | None

    def enhance(
        self, view: View, reference: ReferenceView, renderer: Renderer
    ) -> EnhancedImage: ...
