"""Result types of the edge evidence: render edges, photo edges (with their chamfer maps),
matches and the alignment."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from pgt_check.geometry.edges.config import EdgeAlignConfig, EdgeReason
from pgt_check.geometry.edges.distance import distance_with_labels, row_major_index


@dataclass(frozen=True, eq=False)
class RenderEdges:
    """Geometric edge points of a render.

    points: (N, 2) float64 pixel coordinates (x, y) on the edge (midpoints between the two pixels
    of an occlusion / border pair; pixel centres for creases). normals: (N, 2) float64 unit edge
    normal (direction across the edge, sign arbitrary). depth: (N,) float64 metric depth of the
    surface the edge belongs to (the near side for occlusions). kind: (N,) uint8, KIND_*.
    n_detected: number of points before subsampling. camera_K: the render's intrinsics (lets
    ``align_edges`` start from the camera rotation that explains the best shift).
    """

    points: np.ndarray
    normals: np.ndarray
    depth: np.ndarray
    kind: np.ndarray
    width: int
    height: int
    n_detected: int
    camera_K: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @property
    def angles(self) -> np.ndarray:
        """(N,) normal orientation in [0, pi)."""
        return np.mod(np.arctan2(self.normals[:, 1], self.normals[:, 0]), np.pi)


@dataclass(frozen=True, eq=False)
class PhotoEdges:
    """Edges of a photo and the maps for (oriented) chamfer matching.

    magnitude: (H, W) float32 gradient magnitude (grey levels 0-255 per pixel, Sobel / 8);
    grad_x, grad_y: (H, W) float32 Sobel derivatives of the blurred grey image (x 8);
    ``orientation`` (computed on first use): gradient (edge normal) direction in [0, pi).
    edges: (H, W) bool Canny edges.
    points: (E, 2) float64 sub-pixel edge positions (x, y); normals: (E, 2) unit edge normals;
    pixels: (E, 2) int32 (x, y) of the Canny pixel; bins: (E,) orientation bin.
    oriented_dist: (B, H, W) float32 distance to the nearest edge whose orientation bin is within
    +-1 of b (inf if there is none); oriented_labels: (B, H, W) int32 OpenCV label of that edge
    pixel, resolved by ``compatible_nearest`` / ``oriented_nearest``; label_edges: per bin, edge
    index of each label - 1. ``dist`` / ``nearest`` (unoriented) are computed on first use.
    """

    magnitude: np.ndarray
    grad_x: np.ndarray
    grad_y: np.ndarray
    edges: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    pixels: np.ndarray
    bins: np.ndarray
    oriented_dist: np.ndarray
    oriented_labels: np.ndarray
    label_edges: tuple[np.ndarray, ...]
    thresholds: tuple[float, float]

    @property
    def width(self) -> int:
        return int(self.edges.shape[1])

    @property
    def height(self) -> int:
        return int(self.edges.shape[0])

    @property
    def n_bins(self) -> int:
        return int(self.oriented_dist.shape[0])

    def __len__(self) -> int:
        return len(self.points)

    @cached_property
    def orientation(self) -> np.ndarray:
        """(H, W) float32 gradient (edge normal) direction in [0, pi)."""
        return np.mod(np.arctan2(self.grad_y, self.grad_x), np.pi).astype(np.float32)

    @cached_property
    def _label_lut(self) -> tuple[np.ndarray, np.ndarray]:
        sizes = [len(x) for x in self.label_edges]
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        lut = np.concatenate([*self.label_edges, np.zeros(0, np.int32)]).astype(np.int32)
        return lut, offsets

    def compatible_nearest(
        self, bins: np.ndarray, x: np.ndarray, y: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(distance, edge index) of the nearest edge compatible with orientation ``bins`` at
        integer pixels (x, y) (all (N,), inside the image); index -1 where there is none."""
        d = self.oriented_dist[bins, y, x]
        lab = self.oriented_labels[bins, y, x].astype(np.int64)
        lut, offsets = self._label_lut
        ok = (lab > 0) & np.isfinite(d)
        e = np.full(len(d), -1, dtype=np.int64)
        e[ok] = lut[offsets[bins[ok]] + lab[ok] - 1]
        return d, e

    @cached_property
    def oriented_nearest(self) -> np.ndarray:
        """(B, H, W) int32 index into ``points`` of the nearest compatible edge (-1: none)."""
        out = np.full(self.oriented_labels.shape, -1, dtype=np.int32)
        for b, edges_b in enumerate(self.label_edges):
            if len(edges_b):
                lab = self.oriented_labels[b]
                out[b] = np.where(lab > 0, edges_b[np.maximum(lab, 1) - 1], -1)
        return out

    @cached_property
    def _unoriented(self) -> tuple[np.ndarray, np.ndarray]:
        dist, labels, order = distance_with_labels(self.edges)
        if not len(order):
            return dist, np.full(dist.shape, -1, dtype=np.int32)
        edge_of = np.searchsorted(row_major_index(self.pixels, self.width), order)
        return dist, np.where(labels > 0, edge_of[np.maximum(labels, 1) - 1], -1).astype(np.int32)

    @property
    def dist(self) -> np.ndarray:
        """(H, W) float32 distance (px) to the nearest edge pixel, any orientation."""
        return self._unoriented[0]

    @property
    def nearest(self) -> np.ndarray:
        """(H, W) int32 index into ``points`` of the nearest edge (-1 if there is none)."""
        return self._unoriented[1]


@dataclass(frozen=True, eq=False)
class EdgeProblem:
    """One alignment's fixed inputs, handed together through the search, the refinement and
    the evaluation: the render's edges, the photo's edges, the render edges' orientation bins
    (``search.bins_of``: (N,) int64 into the photo's oriented distance maps), the chamfer
    truncation ``tau`` (px) and the settings."""

    render: RenderEdges
    photo: PhotoEdges
    bins: np.ndarray
    tau: float
    config: EdgeAlignConfig

    def with_config(self, config: EdgeAlignConfig) -> EdgeProblem:
        return replace(self, config=config)

    def part(self, keep: np.ndarray) -> EdgeProblem:
        """The problem on the render edges ``keep`` selects (a bool mask or indices)."""
        re = self.render
        render = replace(
            re, points=re.points[keep], normals=re.normals[keep], depth=re.depth[keep],
            kind=re.kind[keep],
        )  # fmt: skip
        return replace(self, render=render, bins=self.bins[keep])


@dataclass(frozen=True, eq=False)
class EdgeMatches:
    """Render edge points matched to photo edges after alignment (for 2D-3D evidence).

    render_points: (M, 2) render pixels; depth: (M,) their render depth (lift with K^-1);
    photo_points: (M, 2) the aligned point ``photo_from_render @ p`` moved onto the matched
    photo edge line (foot of the perpendicular): the photo observation, exact across the edge
    and only as good as the homography along it; photo_normals: (M, 2) the photo edge normal, for
    point-to-line residuals; residuals: (M,) signed point-to-line distance (px) before the move.
    """

    render_points: np.ndarray
    photo_points: np.ndarray
    photo_normals: np.ndarray
    depth: np.ndarray
    residuals: np.ndarray

    def __len__(self) -> int:
        return len(self.render_points)


def _no_matches() -> EdgeMatches:
    z2 = np.zeros((0, 2))
    return EdgeMatches(z2, z2.copy(), z2.copy(), np.zeros(0), np.zeros(0))


@dataclass(frozen=True, eq=False)
class EdgeAlignment:
    """Result of ``align_edges``.

    ``photo_from_render`` / ``corner_error`` are the measured alignment whenever one was computed
    (also when ``success`` is False for "ambiguous" or "low_support", for diagnostics); they are
    None / inf when nothing could be computed. Callers must check ``success``.
    shift: (dx, dy) best integer-grid shift of the search; second_shift / second_score: the
    separated runner-up (None if there is none); baseline_score: median score over all searched
    shifts; ambiguity: (second_score - baseline) / (score - baseline), 0 if there is no runner-up.
    support: share of render edge points within tau of a compatible photo edge after alignment;
    support_identity: the same at the identity. residual_px: median |point-to-line| distance of
    the matched points. timings: seconds per step. p_value: the best shift's significance
    against the frame's own wrong alignments (``search.null_p_value``; 1 = not tested), over
    ``n_null`` null cells.
    """

    success: bool
    reason: EdgeReason | None
    photo_from_render: np.ndarray | None
    corner_error: float
    support: float
    support_identity: float
    residual_px: float
    n_edges: int
    n_photo_edges: int
    score: float
    baseline_score: float
    shift: tuple[float, float] | None
    second_shift: tuple[float, float] | None
    second_score: float
    ambiguity: float
    ambiguous: bool
    tau_px: float
    model: str
    matches: EdgeMatches = field(default_factory=_no_matches)
    timings: dict[str, float] = field(default_factory=dict)
    p_value: float = 1.0
    n_null: int = 0
