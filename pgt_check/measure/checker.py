"""Stage 1: measure one frame (render, match raw and enhanced, homography, PnP).

``FrameChecker.measure(frame) -> FrameMeasurement`` never raises for one bad frame: expected
problems become a ``MeasureReason``, unexpected ones ``internal_error`` (re-raised with
``fail_fast``). The checker holds the per-process resources (mesh, renderer, matcher,
enhancer); build it inside the process that uses it (GL contexts and models are not shared).
"""

from __future__ import annotations

import logging
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.enhance.base import Evidence, ReferenceView, View
from pgt_check.errors import InputError
from pgt_check.measure.record import (
    EnhanceWhy,
    FrameMeasurement,
    MeasureReason,
    PathMeasurement,
    PoseEstimate,
    Timings,
    failed_measurement,
)
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)


@dataclass
class FrameImages:
    """Working-resolution images and matches of one frame, filled on request for report panels.

    photo / render / enhanced: (h, w, 3) float32 RGB [0, 1]; kpts_*: (N, 2) working pixels;
    inliers: (N,) bool of the homography of the deciding path. ``paths`` holds the matches of
    each path that ran ("raw", "enhanced") with its homography in working pixels.
    """

    photo: np.ndarray | None = None
    render: np.ndarray | None = None
    enhanced: np.ndarray | None = None
    kpts_render: np.ndarray | None = None
    kpts_photo: np.ndarray | None = None
    inliers: np.ndarray | None = None
    paths: dict[str, PathImages] = field(default_factory=dict)


@dataclass(frozen=True)
class PathImages:
    """Matches of one path for report panels: (N, 2) working pixels, (N,) bool inliers and the
    photo_from_render homography in working pixels (None when it failed)."""

    kpts_render: np.ndarray
    kpts_photo: np.ndarray
    inliers: np.ndarray
    photo_from_render: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class PathResult:
    """Matching + homography of one image against the photo, with its arrays (in-process only).

    ``photo_from_render`` is in original photo pixels; keypoints in working pixels.
    """

    n_matches: int
    n_inliers: int
    inlier_ratio: float
    reason: str  # homography failure reason, "" on success
    photo_from_render: np.ndarray | None
    corner_error_px: float | None
    kpts_render: np.ndarray
    kpts_photo: np.ndarray
    inliers: np.ndarray
    n_kpts_render: int
    n_kpts_photo: int
    t_match_s: float
    t_homography_s: float

    @property
    def success(self) -> bool:
        return self.photo_from_render is not None

    def images(self, scale: tuple[float, float]) -> PathImages:
        """The matches for report panels, homography back in working pixels (``scale``: working
        / original size)."""
        from pgt_check.geometry.homography import scale_homography

        h = None
        if self.photo_from_render is not None:
            h = scale_homography(self.photo_from_render, 1.0 / scale[0], 1.0 / scale[1])
        return PathImages(self.kpts_render, self.kpts_photo, self.inliers, h)

    def measurement(
        self, kind: str, method: str, evidence: Evidence, camera: Camera,
        reference_id: str | None = None,
    ) -> PathMeasurement:
        """The stored (JSON-able) part of this result; shifts in ``camera``'s pixels."""
        from pgt_check.geometry.homography import corner_shift_and_zoom

        h = dx = dy = zoom = None
        if self.success:
            h = tuple(tuple(map(float, r)) for r in self.photo_from_render)
            dx, dy, zoom = corner_shift_and_zoom(self.photo_from_render, camera.width,
                                                 camera.height)
        return PathMeasurement(
            kind=kind, method=method, evidence=evidence, n_kpts_render=self.n_kpts_render,
            n_kpts_photo=self.n_kpts_photo, n_matches=self.n_matches, n_inliers=self.n_inliers,
            inlier_ratio=self.inlier_ratio, reason=self.reason, photo_from_render=h,
            corner_error_px=self.corner_error_px, shift_dx_px=dx, shift_dy_px=dy, zoom=zoom,
            reference_id=reference_id,
        )


@dataclass
class _Clock:
    """Accumulates seconds per stage of one frame."""

    spent: dict[str, float] = field(default_factory=dict)

    def add(self, stage: str, seconds: float) -> None:
        self.spent[stage] = self.spent.get(stage, 0.0) + seconds

    def timings(self, total: float) -> Timings:
        return Timings(**self.spent, total=total)


@dataclass
class FrameChecker:
    """Holds the per-process resources and measures frames (see the module docstring).

    ``references`` maps a frame id to the frames whose photos serve as enhancement references,
    best first (see ``pick_references``).
    """

    config: RunConfig
    references: Mapping[str, tuple[Frame, ...]] = field(default_factory=dict)
    #: called as ``panel_sink(measurement, images)`` after each frame (images kept for it; it
    #: decides which frames get report panels, e.g. ``report.assets.PanelWriter``)
    panel_sink: Callable[[FrameMeasurement, FrameImages], Any] | None = None
    _renderer: Any = field(default=None, init=False, repr=False)
    _matcher: Any = field(default=None, init=False, repr=False)
    _mesh: Any = field(default=None, init=False, repr=False)
    _enhancer: Any = field(default=None, init=False, repr=False)

    @property
    def mesh(self):
        if self._mesh is None:
            from pgt_check.render import load_mesh

            self._mesh = load_mesh(self.config.input.mesh, shading=self.config.render.shading)
        return self._mesh

    @property
    def renderer(self):
        if self._renderer is None:
            from pgt_check.render import make_renderer

            self._renderer = make_renderer(self.mesh, backend=self.config.render.backend)
        return self._renderer

    @property
    def matcher(self):
        if self._matcher is None:
            from pgt_check.match import make_matcher

            m = self.config.match
            options: dict[str, Any] = {"max_keypoints": m.max_keypoints}
            if m.method == "loftr":
                options["weights"] = m.loftr_weights
            self._matcher = make_matcher(m.method, **options)
        return self._matcher

    @property
    def enhancer(self):
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
        clock = _Clock()
        if keep is None and self.panel_sink is not None:
            keep = FrameImages()
        try:
            m = self._measure(frame, keep, clock)
        except InputError as err:
            m = failed_measurement(frame, MeasureReason.IMAGE_UNREADABLE, str(err))
        except Exception as err:  # one frame must not kill the run: recorded and counted
            if self.config.fail_fast:
                raise
            logger.error("frame %s: internal error: %s", frame.frame_id, err)
            m = failed_measurement(frame, MeasureReason.INTERNAL_ERROR, format_exception(err))
        m = m.with_timings(clock.timings(time.perf_counter() - t_start))
        if self.panel_sink is not None:
            try:
                self.panel_sink(m, keep)
            except Exception as err:  # panels are a convenience: the run goes on without them
                if self.config.fail_fast:
                    raise
                logger.warning("frame %s: report panels not written: %s", frame.frame_id, err)
        return m

    def _measure(self, frame: Frame, keep: FrameImages | None, clock: _Clock) -> FrameMeasurement:
        base = failed_measurement(frame, MeasureReason.NONE)
        t = time.perf_counter()
        if frame.image_file is None or not Path(frame.image_file).is_file():
            return _replace(base, error=MeasureReason.IMAGE_MISSING)
        photo, camera = self._load_photo(frame)
        from pgt_check.io.images import resize_image
        from pgt_check.io.photo import working_scale

        size = working_scale(camera.width, camera.height, self.config.match.resize_max)
        scale = (size[0] / camera.width, size[1] / camera.height)
        cam_w = camera.scaled(*scale)
        photo_w = resize_image(photo, size)
        clock.add("load", time.perf_counter() - t)
        t = time.perf_counter()
        render = self.renderer.render(cam_w, frame.world_from_cam)
        clock.add("render", time.perf_counter() - t)
        m = _replace(
            base, width=camera.width, height=camera.height, match_width=size[0],
            match_height=size[1], coverage=render.coverage_fraction, shading=render.shading,
        )
        if keep is not None:
            keep.photo, keep.render = photo_w, render.rgb
        if m.coverage < self.config.verdict.min_coverage:
            return _replace(m, error=MeasureReason.LOW_COVERAGE)

        raw = self._match_path(render.rgb, photo_w, render.coverage, size, scale, camera, clock)
        threshold = self.config.verdict.threshold_for(camera.width, camera.height)
        why, detail = self._enhance_decision(raw, threshold)
        view = View(render, cam_w, frame.world_from_cam)
        enh = ref_id = None
        if why in (EnhanceWhy.MODE_ALWAYS, EnhanceWhy.RAW_FAILED, EnhanceWhy.RAW_FEW_INLIERS,
                   EnhanceWhy.RAW_NEAR_THRESHOLD):
            enh, ref_id, enh_img, n_tried = self._enhanced_path(
                frame, view, photo_w, size, scale, camera, clock
            )
            if n_tried == 0:
                why, detail = EnhanceWhy.NO_REFERENCE, ""
            if keep is not None:
                keep.enhanced = enh_img
        chosen, path_name = raw, "raw"
        if enh is not None and enh.success and (not raw.success or enh.n_inliers >= raw.n_inliers):
            chosen, path_name = enh, "enhanced"  # the path with more geometric support decides
        if keep is not None:
            keep.kpts_render, keep.kpts_photo = chosen.kpts_render, chosen.kpts_photo
            keep.inliers = chosen.inliers
            for name, res in (("raw", raw), ("enhanced", enh)):
                if res is not None:
                    keep.paths[name] = res.images(scale)
        pose = None
        if chosen.success and self.config.pose.enabled:
            pose = self._pose_estimate(chosen, render.depth, cam_w, frame, clock)
        method = self.config.enhance.method
        return _replace(
            m,
            raw=raw.measurement("raw", "render", Evidence.ABSOLUTE, camera),
            enhanced=None if enh is None else enh.measurement(
                "enhanced", method, self.enhancer.evidence, camera, ref_id),
            enhance_ran=why not in (EnhanceWhy.MODE_NEVER, EnhanceWhy.RAW_DECISIVE,
                                    EnhanceWhy.NO_REFERENCE),
            enhance_why=why, enhance_why_detail=detail, verdict_path=path_name, pose=pose,
            auto_threshold_px=threshold if self.config.enhance.mode == "auto" else None,
        )

    def _load_photo(self, frame: Frame) -> tuple[np.ndarray, Camera]:
        from pgt_check.io import load_image
        from pgt_check.io.photo import prepare_photo

        return prepare_photo(load_image(frame.image_file), frame.camera)

    def _match_path(
        self, image: np.ndarray, photo_w: np.ndarray, mask: np.ndarray, size: tuple[int, int],
        scale: tuple[float, float], camera: Camera, clock: _Clock,
    ) -> PathResult:
        from pgt_check.geometry.homography import (
            corner_error,
            estimate_homography,
            scale_homography,
        )

        t = time.perf_counter()
        matches = self.matcher.match(image, photo_w, mask0=mask)
        t_match = time.perf_counter() - t
        t = time.perf_counter()
        res = estimate_homography(matches.kpts0, matches.kpts1, size[0], size[1],
                                  self.config.homography)
        t_h = time.perf_counter() - t
        clock.add("match", t_match)
        clock.add("homography", t_h)
        h = err = None
        if res.success:
            h = scale_homography(res.photo_from_render, *scale)
            err = corner_error(h, camera.width, camera.height)
        n = len(matches)
        return PathResult(
            n, res.n_inliers, res.n_inliers / n if n else 0.0,
            "" if res.success else res.reason.value, h, err, matches.kpts0, matches.kpts1,
            res.inliers, matches.n_kpts0, matches.n_kpts1, t_match, t_h,
        )

    def _enhance_decision(self, raw: PathResult, threshold: float) -> tuple[EnhanceWhy, str]:
        e = self.config.enhance
        if e.mode == "never":
            return EnhanceWhy.MODE_NEVER, ""
        if e.mode == "always":
            return EnhanceWhy.MODE_ALWAYS, ""
        if not raw.success:
            return EnhanceWhy.RAW_FAILED, raw.reason
        if raw.n_inliers < e.auto_min_inliers:
            return EnhanceWhy.RAW_FEW_INLIERS, ""
        if abs(raw.corner_error_px - threshold) <= e.auto_margin * threshold:
            return EnhanceWhy.RAW_NEAR_THRESHOLD, ""
        return EnhanceWhy.RAW_DECISIVE, ""

    def _reference_view(self, frame: Frame, cam_w: Camera, ref: Frame) -> ReferenceView:
        """The reference photo at the same pixel scale as the frame's working image."""
        from pgt_check.io.images import resize_image

        ref_photo, ref_cam = self._load_photo(ref)
        sx = cam_w.width / frame.camera.width
        ref_size = (max(1, round(ref_cam.width * sx)), max(1, round(ref_cam.height * sx)))
        ref_cam_w = ref_cam.scaled(ref_size[0] / ref_cam.width, ref_size[1] / ref_cam.height)
        return ReferenceView(ref.frame_id, resize_image(ref_photo, ref_size), ref_cam_w,
                             ref.world_from_cam)

    def _enhanced_path(
        self, frame: Frame, view: View, photo_w: np.ndarray, size: tuple[int, int],
        scale: tuple[float, float], camera: Camera, clock: _Clock,
    ) -> tuple[PathResult | None, str | None, np.ndarray | None, int]:
        """Enhance with each reference, match again; keep the result with the most inliers.

        Returns (result, reference id, enhanced image, number of references tried).
        """
        refs = [
            r for r in self.references.get(frame.frame_id, ())
            if r.image_file is not None and Path(r.image_file).is_file()
        ]
        best: PathResult | None = None
        best_id = best_img = None
        for ref in refs:
            t = time.perf_counter()
            out = self.enhancer.enhance(view, self._reference_view(frame, view.camera, ref),
                                        self.renderer)
            clock.add("enhance", time.perf_counter() - t)
            # keypoints are detected where the mesh covers the render (the reference may
            # leave holes, which keep the render's own colour)
            res = self._match_path(out.image, photo_w, view.render.coverage, size, scale, camera,
                                   clock)
            if best is None or res.n_inliers > best.n_inliers:
                best, best_id, best_img = res, ref.frame_id, out.image
        return best, best_id, best_img, len(refs)

    def _pose_estimate(
        self, path: PathResult, depth: np.ndarray, cam_w: Camera, frame: Frame, clock: _Clock
    ) -> PoseEstimate:
        from pgt_check.geometry.pnp import estimate_pose_correction

        t = time.perf_counter()
        p = self.config.pose
        corr = estimate_pose_correction(
            path.kpts_render, path.kpts_photo, depth, cam_w, frame.world_from_cam,
            max_error_px=p.max_error_px, min_inliers=p.min_inliers,
        )
        clock.add("pose", time.perf_counter() - t)
        if not corr.success:
            return PoseEstimate(corr.n_inliers, corr.reason.value)
        return PoseEstimate(
            corr.n_inliers, "", corr.dt, corr.drot_deg,
            tuple(tuple(map(float, r)) for r in corr.world_from_cam),
        )


def _replace(m: FrameMeasurement, **changes: Any) -> FrameMeasurement:
    from dataclasses import replace

    return replace(m, **changes)


def format_exception(err: BaseException) -> str:
    """The last 2000 characters of a traceback (stored as an internal error's detail)."""
    return "".join(traceback.format_exception(err))[-2000:]


def pick_references(
    traj: Trajectory, frames: Sequence[Frame], config: RunConfig
) -> dict[str, tuple[Frame, ...]]:
    """Reference frames per checked frame, best first (any frame of the trajectory may serve)."""
    if config.enhance.mode == "never":
        return {}
    from pgt_check.enhance.reference import select_references

    choices = select_references(traj.frames, config.enhance.reference)
    by_id = traj.by_id()
    refs = {f.frame_id: tuple(by_id[i] for i in choices[f.frame_id].frame_ids) for f in frames}
    missing = sum(not r for r in refs.values())
    if missing:
        logger.warning("%d of %d frames have no usable reference and are checked raw only",
                       missing, len(frames))
    return refs


def build_frame_checker(
    config: RunConfig,
    references: Mapping[str, tuple[Frame, ...]] | None = None,
    panel_sink: Callable[[FrameMeasurement, FrameImages], Any] | None = None,
) -> FrameChecker:
    """Worker-side factory: a FrameChecker with its mesh, renderer and matcher loaded.

    ``panel_sink`` (picklable; one copy per worker) sees every measurement with its images."""
    checker = FrameChecker(config, dict(references or {}), panel_sink)
    _ = checker.renderer
    _ = checker.matcher
    return checker
