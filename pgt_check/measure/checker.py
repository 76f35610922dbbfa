"""Stage 1: measure one frame (render, match raw and enhanced, homography, PnP).

``FrameChecker.measure(frame) -> FrameMeasurement`` never raises for one bad frame: expected
problems become a ``MeasureReason``, unexpected ones ``internal_error`` (re-raised with
``fail_fast``). The checker holds the per-process resources (mesh, renderer, matcher,
enhancer); build it inside the process that uses it (GL contexts and models are not shared).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, cast

import numpy as np

from pgt_check.enhance.base import Evidence, ReferenceView, View
from pgt_check.errors import InputError, ReferenceUnreadableError
from pgt_check.measure.edge_path import EdgePath, edge_extra, edge_path, edges_lead, edges_only
from pgt_check.measure.paths import (
    FrameImages,
    PathImages,
    PathResult,
    absolute_evidence,
)
from pgt_check.measure.record import (
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    failed_measurement,
)
from pgt_check.measure.steps import (  # format_exception, pick_references: re-exported
    ENHANCE,
    INPUT_ERROR_REASONS,
    NO_ENHANCE,
    Clock,
    MeasuringConfig,
    Working,
    clear_pass,
    edges_decisive,
    enhance_decision,
    format_exception,
    match_path,
    pick_references,
    pose_estimate,
    raw_contradicts,
    replace_measurement,
)
from pgt_check.threads import limit_threads
from pgt_check.types import Camera, Frame

logger = logging.getLogger(__name__)

__all__ = [
    "FrameChecker",
    "FrameImages",
    "PathImages",
    "PathResult",
    "build_frame_checker",
    "format_exception",
    "pick_references",
]


class EnhancedPath(NamedTuple):
    """``FrameChecker._enhanced_path``: the result with the most inliers, its reference id and
    enhanced image, how many references were tried, and the other references' aligned results
    as (reference id, result): the verdict may prefer one whose reference the run vouches
    for."""

    result: PathResult | None
    reference_id: str | None
    image: np.ndarray | None
    n_tried: int
    others: list[tuple[str, PathResult]]


class Enhancement(NamedTuple):
    """``FrameChecker._enhancement``: the edge path, the enhanced path (``EnhancedPath``'s
    result, reference id and the other references' results) and the enhancement decision
    (why, detail)."""

    edges: EdgePath | None
    enhanced: PathResult | None
    reference_id: str | None
    others: list[tuple[str, PathResult]]
    why: EnhanceWhy
    detail: str


@dataclass
class FrameChecker:
    """Holds the per-process resources and measures frames (see the module docstring).

    ``references`` maps a frame id to the frames whose photos serve as enhancement references,
    best first (see ``pick_references``).
    """

    config: MeasuringConfig
    references: Mapping[str, tuple[Frame, ...]] = field(default_factory=dict)
    #: called as ``panel_sink(measurement, images)`` after each frame (images kept for it; it
    #: decides which frames get report panels, e.g. ``report.assets.PanelWriter``)
    panel_sink: Callable[[FrameMeasurement, FrameImages], Any] | None = None
    _renderer: Any = field(default=None, init=False, repr=False)
    _matcher: Any = field(default=None, init=False, repr=False)
    _mesh: Any = field(default=None, init=False, repr=False)
    _enhancer: Any = field(default=None, init=False, repr=False)

    @property
    def mesh(self) -> Any:
        if self._mesh is None:
            from pgt_check.render import load_mesh

            self._mesh = load_mesh(self.config.input.mesh, shading=self.config.render.shading)
        return self._mesh

    @property
    def renderer(self) -> Any:
        if self._renderer is None:
            from pgt_check.render import make_renderer
            from pgt_check.render.cache import CachedRenderer

            # kept renders: the references' views are mostly frames this run renders anyway
            self._renderer = CachedRenderer(
                make_renderer(self.mesh, backend=self.config.render.backend)
            )
        return self._renderer

    @property
    def matcher(self) -> Any:
        if self._matcher is None:
            from pgt_check.match import make_matcher

            m = self.config.match
            options: dict[str, Any] = {"max_keypoints": m.max_keypoints}
            if m.method == "loftr":
                options["weights"] = m.loftr_weights
            self._matcher = make_matcher(m.method, **options)
        return self._matcher

    @property
    def enhancer(self) -> Any:
        """The enhancement method of the config (built on first use: torch only for MaRINeR)."""
        if self._enhancer is None:
            from pgt_check.enhance import make_enhancer

            self._enhancer = make_enhancer(self.config.enhance)
        return self._enhancer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- one frame --------------------------------------------------------------------------
    def measure(self, frame: Frame, keep: FrameImages | None = None) -> FrameMeasurement:
        """Stage-1 measurement of one frame; expected problems become ``error`` reasons.

        If ``keep`` is given, the working-resolution images and matches are stored in it
        (for report panels); the measurement itself is the same.
        """
        t_start = time.perf_counter()
        clock = Clock()
        if keep is None and self.panel_sink is not None:
            keep = FrameImages()
        try:
            m = self._measure(frame, keep, clock)
        except InputError as err:
            reason = INPUT_ERROR_REASONS.get(type(err), MeasureReason.IMAGE_UNREADABLE)
            m = failed_measurement(frame, reason, str(err))
        except Exception as err:  # one frame must not kill the run: recorded and counted
            if self.config.fail_fast:
                raise
            logger.error("frame %s: internal error: %s", frame.frame_id, err)
            m = failed_measurement(frame, MeasureReason.INTERNAL_ERROR, format_exception(err))
        m = m.with_timings(clock.timings(time.perf_counter() - t_start))
        if self.panel_sink is not None:
            assert keep is not None  # made above for the sink
            try:
                self.panel_sink(m, keep)
            except Exception as err:  # panels are a convenience: the run goes on without them
                if self.config.fail_fast:
                    raise
                logger.warning("frame %s: report panels not written: %s", frame.frame_id, err)
        return m

    def scene_triple(self, frame: Frame) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(render, first reference's photo, the frame's own photo) at the frame's working
        size, for the enhancer's scene check (``stages.scene_check``); None when the frame has
        no readable photo, no usable reference or too little mesh in view."""
        refs = [r for r in self.references.get(frame.frame_id, ())
                if r.image_file is not None and Path(r.image_file).is_file()]
        if not refs or frame.image_file is None or not Path(frame.image_file).is_file():
            return None
        try:
            photo, _, _, _, cam_w, photo_w = self._working_photo(frame)
            render = self.renderer.render(cam_w, frame.world_from_cam)
            if render.coverage_fraction < self.config.verdict.min_coverage:
                return None
            ref = self._reference_view(frame, cam_w, refs[0])
        except InputError as err:
            logger.info("scene check: frame %s left out (%s)", frame.frame_id, err)
            return None
        return render.rgb, ref.photo, photo_w

    def _working_photo(
        self, frame: Frame
    ) -> tuple[np.ndarray, Camera, tuple[int, int], tuple[float, float], Camera, np.ndarray]:
        """(photo, camera, working size, scale, working camera, photo at working size) of a
        frame whose image exists (the matching size ``match.resize_max``)."""
        from pgt_check.io.images import resize_image
        from pgt_check.io.photo import working_scale

        photo, camera = self._load_photo(frame)
        size = working_scale(camera.width, camera.height, self.config.match.resize_max)
        scale = (size[0] / camera.width, size[1] / camera.height)
        return photo, camera, size, scale, camera.scaled(*scale), resize_image(photo, size)

    def _measure(self, frame: Frame, keep: FrameImages | None, clock: Clock) -> FrameMeasurement:
        base = failed_measurement(frame, MeasureReason.NONE)
        t = time.perf_counter()
        if frame.image_file is None or not Path(frame.image_file).is_file():
            return replace_measurement(base, error=MeasureReason.IMAGE_MISSING)
        photo, camera, size, scale, cam_w, photo_w = self._working_photo(frame)
        clock.add("load", time.perf_counter() - t)
        t = time.perf_counter()
        render = self.renderer.render(cam_w, frame.world_from_cam)
        clock.add("render", time.perf_counter() - t)
        m = replace_measurement(
            base,
            width=camera.width,
            height=camera.height,
            match_width=size[0],
            match_height=size[1],
            coverage=render.coverage_fraction,
            shading=render.shading,
            intrinsics=(*camera.focal, *camera.principal_point),
        )
        if keep is not None:
            keep.photo, keep.render = photo_w, render.rgb
        assert m.coverage is not None  # set above
        if m.coverage < self.config.verdict.min_coverage:
            return replace_measurement(m, error=MeasureReason.LOW_COVERAGE)

        ctx = Working(photo_w, camera, cam_w, size, scale, render, photo, frame.world_from_cam)
        return self._compare(frame, ctx, m, keep, clock)

    def _compare(
        self,
        frame: Frame,
        w: Working,
        m: FrameMeasurement,
        keep: FrameImages | None,
        clock: Clock,
    ) -> FrameMeasurement:
        """Raw path, then (where it is not decisive) the enhanced and geometric-edge paths. On
        renders without colours (``edges.lead_on_shaded``) the edge path comes first, and a clear
        edge PASS leaves out the raw and enhanced paths."""
        threshold = self.config.verdict.threshold_for(w.camera.width, w.camera.height)
        edges = None
        if edges_lead(self.config, w):
            edges = edge_path(self.config, self.renderer, w, None, threshold, clock)
            if edges is not None and edges_decisive(
                edges.measurement, threshold, self.config.enhance
            ):
                return edges_only(m, w, edges, threshold, self.config.enhance.mode)
        raw = match_path(
            self.matcher, self.config.homography,
            w.render.rgb, w.photo, w.render.coverage, w.size, w.scale, w.camera, clock
        )
        edges, enh, ref_id, others, why, detail = self._enhancement(
            frame, w, raw, edges, threshold, keep, clock
        )
        chosen, path_name = _chosen_path(raw, enh, edges, keep, w.scale)
        pose = None
        if chosen.success and self.config.pose.enabled:
            pose = pose_estimate(chosen, w.render.depth, w.cam_w, frame, self.config.pose, clock)
        method = self.config.enhance.method
        absolute = [(raw, "raw")]
        if enh is not None and self.enhancer.evidence is Evidence.ABSOLUTE:
            absolute.append((enh, method))
        extra = [] if edges is None else edge_extra(edges)
        return replace_measurement(
            m,
            evidence=absolute_evidence(absolute, w.render.depth, w.cam_w, w.scale, extra=extra),
            raw=raw.measurement("raw", "render", Evidence.ABSOLUTE, w.camera),
            enhanced=None
            if enh is None
            else enh.measurement("enhanced", method, self.enhancer.evidence, w.camera, ref_id),
            enhanced_alternatives=tuple(
                r.measurement("enhanced", method, self.enhancer.evidence, w.camera, rid)
                for rid, r in others
            ),
            edges=None if edges is None else edges.measurement,
            enhance_ran=why not in NO_ENHANCE,
            enhance_why=why,
            enhance_why_detail=detail,
            verdict_path=path_name,
            pose=pose,
            auto_threshold_px=threshold if self.config.enhance.mode == "auto" else None,
        )

    def _enhancement(
        self, frame: Frame, w: Working, raw: PathResult, edges: EdgePath | None,
        threshold: float, keep: FrameImages | None, clock: Clock,
    ) -> Enhancement:
        """After the raw path: the edge path (where it did not lead), the enhancement decision,
        the enhanced path."""
        why, detail = self._enhance_decision(raw, threshold)
        if edges is None:
            edges = edge_path(self.config, self.renderer, w, raw, threshold, clock)
        if (
            why in ENHANCE
            and why is not EnhanceWhy.MODE_ALWAYS
            and edges is not None
            and edges_decisive(edges.measurement, threshold, self.config.enhance)
            and not raw_contradicts(raw, threshold, self.config.enhance)
        ):
            # the geometric edges already decide with absolute evidence: leave out the
            # enhancement (colourless meshes where the edges line up clearly), unless the raw
            # render aligned and does not clearly pass (the enhanced path breaks the tie)
            why, detail = EnhanceWhy.EDGES_DECISIVE, ""
        enh = ref_id = None
        others: list[tuple[str, PathResult]] = []
        if why in ENHANCE:
            view = View(w.render, w.cam_w, frame.world_from_cam)
            enh, ref_id, enh_img, n_tried, others = self._enhanced_path(
                frame, view, w, threshold, clock
            )
            if n_tried == 0:
                why, detail = EnhanceWhy.NO_REFERENCE, ""
            if keep is not None:
                keep.enhanced = enh_img
        return Enhancement(edges, enh, ref_id, others, why, detail)

    def _load_photo(self, frame: Frame) -> tuple[np.ndarray, Camera]:
        from pgt_check.io import load_image
        from pgt_check.io.photo import prepare_photo

        return prepare_photo(
            # a frame without an image fails in load_image (the caller checks its own frame)
            load_image(cast(Path, frame.image_file),
                       max_pixels=self.config.input.max_image_pixels),
            frame.camera,
        )

    def _enhance_decision(self, raw: PathResult, threshold: float) -> tuple[EnhanceWhy, str]:
        return enhance_decision(raw, threshold, self.config.enhance)

    def _reference_view(self, frame: Frame, cam_w: Camera, ref: Frame) -> ReferenceView:
        """The reference photo at the same pixel scale as the frame's working image."""
        from pgt_check.io.images import resize_image

        try:
            ref_photo, ref_cam = self._load_photo(ref)
        except InputError as err:
            raise ReferenceUnreadableError(f"reference {ref.frame_id}: {err}") from err
        sx = cam_w.width / frame.camera.width
        ref_size = (max(1, round(ref_cam.width * sx)), max(1, round(ref_cam.height * sx)))
        ref_cam_w = ref_cam.scaled(ref_size[0] / ref_cam.width, ref_size[1] / ref_cam.height)
        return ReferenceView(
            ref.frame_id, resize_image(ref_photo, ref_size), ref_cam_w, ref.world_from_cam
        )

    def _enhanced_path(
        self, frame: Frame, view: View, w: Working, threshold: float, clock: Clock,
    ) -> EnhancedPath:
        """Enhance with each reference in turn and match again; keep the result with the most
        inliers. The references after one whose result is a clear PASS (``clear_pass``) are
        left out: another reference could only add a result the verdict does not need."""
        refs = [
            r
            for r in self.references.get(frame.frame_id, ())
            if r.image_file is not None and Path(r.image_file).is_file()
        ]
        best: PathResult | None = None
        best_id = best_img = None
        tried: list[tuple[str, PathResult]] = []
        for ref in refs:
            t = time.perf_counter()
            out = self.enhancer.enhance(
                view, self._reference_view(frame, view.camera, ref), self.renderer
            )
            clock.add("enhance", time.perf_counter() - t)
            # keypoints are detected where the mesh covers the render (the reference may
            # leave holes, which keep the render's own colour)
            res = match_path(
                self.matcher, self.config.homography, out.image, w.photo,
                view.render.coverage, w.size, w.scale, w.camera, clock,
                self.enhancer.detail_short_side,
            )
            tried.append((ref.frame_id, res))
            if best is None or res.n_inliers > best.n_inliers:
                best, best_id, best_img = res, ref.frame_id, out.image
            if clear_pass(res, threshold, self.config.enhance):
                break
        others = [(rid, r) for rid, r in tried if rid != best_id and r.success]
        return EnhancedPath(best, best_id, best_img, len(tried), others)


def _chosen_path(raw: PathResult, enh: PathResult | None, edges: EdgePath | None,
                 keep: FrameImages | None, scale: tuple[float, float]) -> tuple[PathResult, str]:
    """The deciding feature path and the verdict path's name; matches and images go to ``keep``."""
    chosen, path_name = raw, "raw"
    if enh is not None and enh.success and (not raw.success or enh.n_inliers >= raw.n_inliers):
        chosen, path_name = enh, "enhanced"  # the path with more geometric support decides
    if not chosen.success and edges is not None and edges.measurement.success:
        path_name = "edges"  # no feature path aligned: the geometric edges decide
    if keep is not None:
        keep.kpts_render, keep.kpts_photo = chosen.kpts_render, chosen.kpts_photo
        keep.inliers = chosen.inliers
        for name, res in (("raw", raw), ("enhanced", enh)):
            if res is not None:
                keep.paths[name] = res.images(scale)
    return chosen, path_name


def build_frame_checker(
    config: MeasuringConfig,
    references: Mapping[str, tuple[Frame, ...]] | None = None,
    panel_sink: Callable[[FrameMeasurement, FrameImages], Any] | None = None,
) -> FrameChecker:
    """Worker-side factory: a FrameChecker with its mesh, renderer and matcher loaded.

    ``panel_sink`` (picklable; one copy per worker) sees every measurement with its images.
    Then limits this process's OpenCV and BLAS threads (``config.threads``, pgt_check.threads)."""
    checker = FrameChecker(config, dict(references or {}), panel_sink)
    _ = checker.renderer
    _ = checker.matcher
    limit_threads(config.threads)
    return checker
