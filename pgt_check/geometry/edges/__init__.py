"""Geometry-edge evidence: align the render's geometric edges with the photo's edges.

On textureless scenes feature matching finds nothing, yet silhouettes and creases of the mesh
line up with the photo's edges when the pose is right. This module estimates the 2D motion
``photo_from_render`` (3x3, render pixels -> photo pixels, OpenCV pixel convention) that aligns
them, and scores it like the feature path (corner error, support, ambiguity).

```python
re = geometric_edges(render.depth, camera.K)        # silhouettes + creases, from depth only
pe = photo_edges(photo_rgb)                          # Canny + orientation + distance transforms
al = align_edges(re, pe)                             # EdgeAlignment(success, reason, ...)
al.corner_error, al.support, al.ambiguous, al.matches.render_points, al.matches.depth
```

Steps of ``align_edges``:

(a) exhaustive search over integer 2D shifts (+-``search_radius`` x image diagonal, coarse grid
    of ~0.5 % of the diagonal, then 1 px) of an oriented, truncated chamfer score: the mean of
    ``1 - min(d, tau) / tau`` over the render edge points, d = distance to the nearest photo edge
    whose orientation is within one bin (22.5 deg) of the point's. The best score farther than
    3 tau from the best one (a second peak: repeated structure; or a ridge: parallel edges only)
    gives the ambiguity, normalised by the median score of all shifts.
(b) refinement from the best shift as a translation or as the camera rotation that produces
    it (``rotation_homography``, which carries the keystone of a real rotation), whichever
    puts more edges exactly on photo edges, and, with ``tile_grid`` (off by default), from the
    affine map fitting the best shifts of 3 x 3 image tiles near it (``tiles.tile_start``:
    zoom and perspective larger than tau; the lower robust cost wins). Each start: re-search of the
    shift at a narrow truncation, then point-to-line iterative closest edge (oriented
    correspondences from per-bin distance transforms with labels, Tukey IRLS, Levenberg
    damping) from shift through similarity and affine to ``model``, then ``model`` with the
    Tukey scale annealed from tau to ``final_scale`` x tau. With ``tile_grid``, where the
    shift search reads the result as ambiguous, the ambiguity is judged again around the
    refined alignment (a zoom spreads the shift scores over several peaks).
    With ``select_model`` (the run setting ``edges.select_model`` turns it on where the fixed
    model's alignment does not pass) the model is not fixed: each model from shift up to
    ``model`` is refined on the edges of two opposite image quadrants and tested on the other
    two (``align.select_model``); the lowest held-out robust cost wins (issue #29: on a
    TSDF-fused scan a fixed homography bends to the rounded silhouettes and clutter).

Pure numpy / OpenCV / scipy. Modules: ``config`` (settings, kinds, reasons), ``results``
(result types), ``distance`` (labelled distance transforms), ``render``
(``geometric_edges``), ``photo`` (``photo_edges``), ``search`` (shift search, ambiguity), ``tiles``
(the tile-shift start), ``refine`` (start matrices, polish, robust refinement), ``align``
(``align_edges``).
"""

from __future__ import annotations

from pgt_check.geometry.edges.align import align_edges, auto_tau
from pgt_check.geometry.edges.config import (
    DECISIONS,
    KIND_BORDER,
    KIND_CREASE,
    KIND_OCCLUSION,
    MODELS,
    EdgeAlignConfig,
    EdgeReason,
    PhotoEdgeConfig,
    RenderEdgeConfig,
)
from pgt_check.geometry.edges.photo import photo_edges
from pgt_check.geometry.edges.refine import rotation_homography, translation_matrix
from pgt_check.geometry.edges.render import geometric_edges
from pgt_check.geometry.edges.results import (
    EdgeAlignment,
    EdgeMatches,
    EdgeProblem,
    PhotoEdges,
    RenderEdges,
)

__all__ = [
    "KIND_BORDER",
    "KIND_CREASE",
    "KIND_OCCLUSION",
    "DECISIONS",
    "MODELS",
    "EdgeAlignConfig",
    "EdgeAlignment",
    "EdgeMatches",
    "EdgeProblem",
    "EdgeReason",
    "PhotoEdgeConfig",
    "PhotoEdges",
    "RenderEdgeConfig",
    "RenderEdges",
    "align_edges",
    "auto_tau",
    "geometric_edges",
    "photo_edges",
    "rotation_homography",
    "translation_matrix",
]
