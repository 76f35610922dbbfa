"""Settings of the edge evidence, the kinds of render edge points and the failure reasons."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

#: kinds of render edge points (``RenderEdges.kind``)
KIND_OCCLUSION = 0  # depth discontinuity between two surfaces
KIND_BORDER = 1  # mesh / background border
KIND_CREASE = 2  # normal discontinuity on one surface

#: decision rules of ``align_edges`` (``EdgeAlignConfig.decision``)
DECISIONS = ("either", "significance", "support")
MODELS = ("shift", "similarity", "affine", "homography")
#: parameters of each model (refinement needs at least 3 matches per parameter)
N_PARAMS = {"shift": 2, "similarity": 4, "affine": 6, "homography": 8}


class EdgeReason(str, Enum):
    """Why an edge alignment is not usable (machine-readable, closed set)."""

    TOO_FEW_EDGES = "too_few_edges"
    TOO_FEW_PHOTO_EDGES = "too_few_photo_edges"
    NO_OVERLAP = "no_overlap"
    LOW_SUPPORT = "low_support"
    AMBIGUOUS = "ambiguous"
    NOT_SIGNIFICANT = "not_significant"
    ILL_CONDITIONED = "ill_conditioned_homography"


@dataclass(frozen=True)
class RenderEdgeConfig:
    """Settings of ``geometric_edges`` (pixels of the render)."""

    #: occlusion edge: inverse depth mis-predicted (by planar extrapolation from both sides) by
    #: more than this fraction of the near inverse depth
    depth_jump_rel: float = 0.04
    #: crease: angle between the normals on both sides of a pixel above this (degrees)
    crease_angle_deg: float = 28.0
    #: baseline (px) of the finite differences for normals; 2 smooths faceted / noisy meshes
    normal_step_px: int = 2
    #: no creases this close (px) to an occlusion edge or the background (normals unreliable)
    crease_margin_px: int = 2
    include_borders: bool = True
    include_creases: bool = True
    #: keep at most this many points (seeded random subsample); None = all
    max_points: int | None = 4000
    seed: int = 0


@dataclass(frozen=True)
class PhotoEdgeConfig:
    """Settings of ``photo_edges``."""

    blur_sigma: float = 1.0
    #: Canny high threshold = max(this percentile of the gradient magnitude,
    #: ``median_factor`` x median, ``min_gradient`` (grey levels per pixel))
    high_percentile: float = 90.0
    median_factor: float = 3.0
    min_gradient: float = 6.0
    low_ratio: float = 0.4
    #: orientation bins over [0, pi); a render edge matches photo edges of its bin +- 1
    n_bins: int = 8


@dataclass(frozen=True)
class EdgeAlignConfig:
    """Settings of ``align_edges`` (pixels of the working images)."""

    #: chamfer truncation / inlier distance (px); None = 0.0075 x image diagonal, at least 3
    tau_px: float | None = None
    #: shift search range as a fraction of the image diagonal
    search_radius: float = 0.1
    #: coarse shift grid step (px); None = 0.005 x diagonal, at least 2
    coarse_step_px: float | None = None
    coarse_points: int = 500
    fine_points: int = 2000
    refine_points: int = 2000
    #: a shift must keep at least this share of the render edges inside the photo
    min_inside: float = 0.5
    #: the most general motion model; with ``select_model`` the frame's edges pick the model
    #: from shift up to this one by spatial cross-validation (``align.select_model``, issue #29)
    model: str = "homography"
    select_model: bool = False
    #: refinement iterations in all (split over the stages shift -> ... -> model)
    iterations: int = 30
    #: a stage stops when an update moves no image corner by more than this (px)
    converged_px: float = 0.02
    #: Levenberg damping, relative to the mean diagonal of the normal equations
    damping: float = 1e-3
    #: Tukey scale of the last refinement stage: max(min_scale_px, final_scale x tau)
    final_scale: float = 0.35
    min_scale_px: float = 1.5
    #: observability of the refined motion: a parameter direction along which a coherent misfit
    #: of 1 px of the edges would move the image corners by more than this (px) is held at its
    #: start (lines through one point leave a zoom about it free; issue #29)
    max_corner_gain: float = 20.0
    #: before refining, re-search the shift within +- this (px) at the narrow final scale
    polish_radius_px: int = 3
    #: the refinement also starts from the best shift turned by these in-plane angles (deg,
    #: about the image centre): the shift search cannot see a roll, and from the shift alone
    #: the refinement followed a castle view's roll by less than half (reports/edge_evidence.md)
    roll_starts_deg: tuple[float, ...] = (-6.0, -4.0, -2.0, 2.0, 4.0, 6.0)
    #: a third start (``tiles.tile_start``): the affine map fitting the best shifts of a
    #: tile_grid x tile_grid split of the render edges, each searched within +- tile_radius x
    #: diagonal of the global best shift (motions that vary across the image by more than the
    #: Tukey scale: zoom, perspective); 0 or 1 = off (the default; 3 = on)
    tile_grid: int = 0
    tile_radius: float = 0.03
    #: best shift farther than ``ambiguity_separation`` x tau from the best (a second peak or a
    #: ridge of parallel edges) whose score above the median shift score is at least this share
    #: of the best's -> ambiguous
    ambiguity_ratio: float = 0.85
    ambiguity_separation: float = 3.0
    min_edges: int = 50
    min_photo_edges: int = 50
    #: how a found alignment is accepted (besides not ambiguous, well conditioned):
    #: "significance": its shift score is significant at level ``alpha`` against the frame's own
    #: wrong alignments (``search.null_p_value``): the false-accept rate of a frame with no true
    #: alignment in the search range is about ``alpha`` whatever the scene; "support" (the rule
    #: before issue #29): at least ``min_support`` of the render edges lie on a photo edge;
    #: "either" (the default): one of the two suffices. A scan's rounded, incomplete edges
    #: lower the support of a correct alignment but not its standing against the frame's own
    #: chance alignments; a cluttered near view is the other way round
    #: (reports/edge_evidence.md)
    decision: str = "either"
    alpha: float = 0.01
    min_support: float = 0.3

    def __post_init__(self) -> None:
        if self.decision not in DECISIONS:
            raise ValueError(
                f"decision must be one of {', '.join(DECISIONS)}, got {self.decision!r}"
            )
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")
