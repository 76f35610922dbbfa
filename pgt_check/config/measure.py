"""The measuring sections of the run configuration (input, render, match, homography, enhance,
edges, pose): frozen dataclasses checked on construction. A change to any of them invalidates
stored per-frame measurements (``run_config.MEASUREMENT_SECTIONS``); the judging sections are
in ``judge``. Split out of ``run_config.py`` (its size), which composes them into ``RunConfig``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from pgt_check.config.load import check_name as _check_name
from pgt_check.config.load import check_range as _check_range
from pgt_check.errors import ConfigError

#: upper bounds of the size options (beyond them a run would allocate without bound or hang):
#: keypoints per image, image sides in px, edge tiles per side, RANSAC iterations
MAX_KEYPOINTS = 1_000_000
MAX_IMAGE_SIDE = 65_536
MAX_TILE_GRID = 16
MAX_ITERATIONS = 10_000_000


@dataclass(frozen=True)
class HomographyConfig:
    """Robust estimation settings (pixels are those of the images that were matched)."""

    ransac_threshold_px: float = 3.0
    confidence: float = 0.9999
    max_iters: int = 10000
    min_matches: int = 12
    min_inliers: int = 12
    max_condition: float = 1e7
    #: the warped image may not shrink or grow by more than this factor in area
    max_area_ratio: float = 16.0

    def __post_init__(self) -> None:
        _check_range("homography.ransac_threshold_px", self.ransac_threshold_px, 0, lo_open=True)
        _check_range("homography.confidence", self.confidence, 0, 1, lo_open=True, hi_open=True)
        _check_range("homography.max_iters", self.max_iters, 1, MAX_ITERATIONS)
        _check_range("homography.min_matches", self.min_matches, 4)
        _check_range("homography.min_inliers", self.min_inliers, 4)
        _check_range("homography.max_condition", self.max_condition, 1)
        _check_range("homography.max_area_ratio", self.max_area_ratio, 1)


@dataclass(frozen=True)
class ReferenceConfig:
    mode: Literal["nearest", "self", "none"] = "nearest"
    #: scene units that count as much as ``rotation_scale_deg`` degrees; None = 10 % of the
    #: trajectory's extent (scale-free default)
    translation_scale: float | None = None
    rotation_scale_deg: float = 10.0
    time_scale_s: float | None = None
    #: hard limits; None = no limit on translation (rotation is always limited)
    max_translation: float | None = None
    max_rotation_deg: float = 45.0
    min_frame_gap: int = 1
    #: references tried per frame, best first, until one gives a clear PASS (aligned, enough
    #: inliers, below the auto band); the enhanced result with the most homography inliers is
    #: kept (a reference whose own pose is wrong paints texture on the wrong surfaces, which
    #: costs inliers and moves the result off, so a second reference guards against one bad
    #: neighbour)
    count: int = 2

    def __post_init__(self) -> None:
        r = "enhance.reference."
        _check_range(r + "translation_scale", self.translation_scale, 0, lo_open=True)
        _check_range(r + "rotation_scale_deg", self.rotation_scale_deg, 0, lo_open=True)
        _check_range(r + "time_scale_s", self.time_scale_s, 0, lo_open=True)
        _check_range(r + "max_translation", self.max_translation, 0)
        _check_range(r + "max_rotation_deg", self.max_rotation_deg, 0, 180)
        _check_range(r + "min_frame_gap", self.min_frame_gap, 0)
        _check_range(r + "count", self.count, 1, 1000)


@dataclass(frozen=True)
class InputConfig:
    trajectory: str = ""
    #: "auto" or a name of ``pgt_check.io.FORMATS``
    format: str = "auto"
    images: str | None = None
    camera: str | None = None
    sensors: str | None = None
    #: nerfstudio: dataparser_transforms.json whose transform and scale are undone
    dataparser_transforms: str | None = None
    mesh: str = ""
    #: images whose header declares more pixels are not decoded (per-frame reason
    #: ``pixel_cap_exceeded``); bounds a worker's memory. None = no cap
    max_image_pixels: int | None = 100_000_000

    def __post_init__(self) -> None:
        from pgt_check.registry import FORMATS

        _check_name("input", "format", self.format, ("auto", *FORMATS))
        _check_range("input.max_image_pixels", self.max_image_pixels, 1, 2**31 - 1)


@dataclass(frozen=True)
class RenderConfig:
    #: a name of ``pgt_check.render.BACKENDS``
    backend: str = "moderngl"
    #: "auto" picks texture > vertex colours > shaded geometry from what the mesh has
    shading: Literal["auto", "vertex", "texture", "shaded"] = "auto"

    def __post_init__(self) -> None:
        from pgt_check.registry import RENDER_BACKENDS

        _check_name("render", "backend", self.backend, RENDER_BACKENDS)


@dataclass(frozen=True)
class MatchConfig:
    method: str = "sift"
    max_keypoints: int = 4096
    #: longest image side used for matching (render is made at that size); None = original.
    #: 320: the error-vs-runtime Pareto point (reports/error_vs_runtime.md); the geometric
    #: edges work at their own, larger size (``edges.resize_max``)
    resize_max: int | None = 320
    #: LoFTR checkpoint (no LoFTR weights are bundled); only for method "loftr"
    loftr_weights: str | None = None

    def __post_init__(self) -> None:
        from pgt_check.registry import MATCHERS

        _check_name("match", "method", self.method, MATCHERS)
        _check_range("match.max_keypoints", self.max_keypoints, 1, MAX_KEYPOINTS)
        if self.resize_max == 0:  # 0 = the original size (documented CLI meaning)
            object.__setattr__(self, "resize_max", None)
        _check_range("match.resize_max", self.resize_max, 16, MAX_IMAGE_SIDE)


@dataclass(frozen=True)
class EnhanceConfig:
    """The enhanced path (render enhanced with a reference photo, matched again).

    mode: "never" (raw only), "always", or "auto": enhance only frames whose raw result is not
    decisive: the raw homography failed, it has fewer than ``auto_min_inliers`` inliers, or its
    corner error lies within ``auto_margin`` x threshold of the threshold.
    method: "mariner" (the learned MaRINeR core) or "reproject" (classical: the reference photo
    projected through the mesh into the render's view).
    """

    mode: Literal["never", "auto", "always"] = "auto"
    #: default "reproject": no torch, and ahead of the shipped (CPU-trained) MaRINeR weights on
    #: colourless meshes; MaRINeR's evidence is absolute (reports/raw_vs_enhanced.md)
    method: str = "reproject"
    weights: str | None = None
    iterations: int | None = None
    short_side: int = 160
    device: str = "cpu"
    auto_min_inliers: int = 40
    auto_margin: float = 0.5
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    #: MaRINeR only: "model" (the trained decoder's output), "base" (the matching-only base, no
    #: trained weights) or "auto": the scene check decides per run from a few of the run's own
    #: frames (``stages.scene_check``; the decoder is kept only where it is significantly better
    #: on them: a decoder can damage scenes unlike its training data, reports/mariner_scenes.md)
    output: Literal["auto", "model", "base"] = "auto"
    #: frames the scene check scores (spread along the trajectory); below 5 it cannot prefer
    #: the decoder
    scene_check_frames: int = 12

    def __post_init__(self) -> None:
        from pgt_check.registry import ENHANCERS

        _check_name("enhance", "method", self.method, ENHANCERS)
        _check_range("enhance.scene_check_frames", self.scene_check_frames, 1, 1000)
        _check_range("enhance.iterations", self.iterations, 1, 1000)
        _check_range("enhance.short_side", self.short_side, 16, MAX_IMAGE_SIDE)
        _check_range("enhance.auto_min_inliers", self.auto_min_inliers, 0)
        _check_range("enhance.auto_margin", self.auto_margin, 0)


@dataclass(frozen=True)
class EdgeConfig:
    """The geometric-edge path: the render's silhouettes and creases (from its depth) aligned
    with the photo's edges (absolute evidence that needs no texture; ``geometry.edges``).

    mode: "auto" runs it where the raw feature path is not decisive (as ``enhance.auto``),
    "always", or "never". model: the 2D motion fitted ("homography" or "similarity").
    """

    mode: Literal["never", "auto", "always"] = "auto"
    model: Literal["homography", "similarity"] = "homography"
    #: mesh borders (holes, scan limits) count as edges
    include_borders: bool = True
    #: longest image side of the edge path; where it is larger than ``match.resize_max`` the
    #: frame is rendered again at this size for the edges: edges localise to about a working
    #: pixel, so on large photos the finer size resolves a shared error of a few pixels
    #: (reports/shared_errors.md). None / 0 = the original size
    resize_max: int | None = 1024
    #: on renders without colours (``shaded``: colourless meshes) the edge path runs first and
    #: a clear edge PASS leaves out the raw and enhanced paths, which rarely find a homography
    #: on shading (reports/colourless_evidence.md)
    lead_on_shaded: bool = True
    #: the refinement also starts from the affine map of the best shifts of tile_grid x
    #: tile_grid image tiles (0 = off; 3 = on): a motion no single shift fits (a zoom) is then
    #: aligned, which helps the pooled registration tell a translation from a rotation. Off by
    #: default: on near, cluttered views it fits clutter on some correct frames, and it costs
    #: time (reports/shared_errors_tiles.md)
    tile_grid: int = 0
    #: how an edge alignment is accepted: "significance" (its score against the frame's own
    #: wrong alignments, false-accept rate about ``alpha`` whatever the scene), "support" (the
    #: rule before issue #29: a fixed share of render edges on photo edges) or "either" (one of
    #: the two; the default: a TSDF scan's correct alignments often lack the support, a
    #: cluttered near view's the significance); reports/edge_evidence.md has them side by side
    decision: Literal["either", "significance", "support"] = "either"
    alpha: float = 0.01
    #: the frame's edges choose the motion model (shift, similarity, affine, up to ``model``)
    #: by spatial cross-validation instead of fitting ``model`` (for TSDF scans, where a fixed
    #: homography bends to shrunk silhouettes and clutter): "always", "never", or "fallback"
    #: (the default): only where the fixed model's alignment does not pass (refused, or its
    #: corner error above the frame's threshold). The fixed alignment's points stay the
    #: run-level evidence wherever it was accepted: the simpler models' points bias the pooled
    #: registration fit. ``true`` / ``false`` mean always / never (reports/edge_evidence.md)
    select_model: Literal["never", "fallback", "always"] | bool = "fallback"

    def __post_init__(self) -> None:
        _check_range("edges.alpha", self.alpha, 0, 0.5, lo_open=True)
        if self.resize_max == 0:
            object.__setattr__(self, "resize_max", None)
        _check_range("edges.resize_max", self.resize_max, 16, MAX_IMAGE_SIDE)
        _check_range("edges.tile_grid", self.tile_grid, 0, MAX_TILE_GRID)
        if isinstance(self.select_model, bool):
            object.__setattr__(self, "select_model", "always" if self.select_model else "never")
        elif self.select_model not in ("never", "fallback", "always"):
            raise ConfigError(
                f"edges.select_model: {self.select_model!r} is not one of never, fallback, "
                "always (or true / false)"
            )


@dataclass(frozen=True)
class PoseConfig:
    """The PnP pose-error estimate from the render depth (pycolmap)."""

    enabled: bool = True
    max_error_px: float = 4.0
    min_inliers: int = 12

    def __post_init__(self) -> None:
        _check_range("pose.max_error_px", self.max_error_px, 0, lo_open=True)
        _check_range("pose.min_inliers", self.min_inliers, 4)
