"""Composes the pipeline steps: read -> render -> match -> homography -> verdict -> outputs.

Stage 1 (``FrameChecker.measure``) produces a JSON-serialisable measurement per frame and never
raises for one bad frame; stage 2 (``pgt_check.verdict``) applies thresholds; stage 3
(``pgt_check.report``) only reads records.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.config import MEASUREMENT_SECTIONS, RunConfig
from pgt_check.errors import InputError
from pgt_check.types import Camera, Frame, Trajectory

logger = logging.getLogger(__name__)


def working_scale(width: int, height: int, resize_max: int | None) -> tuple[int, int]:
    """Size (w, h) of the working images: the longest side capped at ``resize_max``."""
    if resize_max is None or max(width, height) <= resize_max:
        return width, height
    s = resize_max / max(width, height)
    return max(1, round(width * s)), max(1, round(height * s))


def _resize(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    from pgt_check.io.images import resize_image

    return resize_image(image, size)


def prepare_photo(image: np.ndarray, camera: Camera) -> tuple[np.ndarray, Camera]:
    """Bring a photo to the camera's pinhole model and size.

    A photo whose size differs from the camera's but has the same aspect ratio (within 1 %) is
    treated as a resized capture and the camera is scaled to it. Distorted camera models are
    undistorted to their pinhole part. Raises InputError for an incompatible size.
    """
    import cv2

    h, w = image.shape[:2]
    if (w, h) != (camera.width, camera.height):
        if abs(w / h - camera.width / camera.height) > 0.01 * camera.width / camera.height:
            raise InputError(
                f"image size {w}x{h} does not match camera {camera.width}x{camera.height}"
            )
        camera = camera.scaled(w / camera.width, h / camera.height) if not camera.is_distorted else camera
    if camera.is_distorted:
        pinhole = camera.as_pinhole()
        image = cv2.undistort(image, camera.K, camera.dist_coeffs, None, pinhole.K)
        camera = pinhole
    return image, camera


@dataclass
class FrameImages:
    """Working-resolution images and matches of one frame, kept only for report assets.

    photo / render / enhanced: (h, w, 3) float32 RGB [0, 1]; kpts_*: (N, 2) working pixels;
    inliers: (N,) bool of the homography that the verdict used.
    """

    photo: np.ndarray | None = None
    render: np.ndarray | None = None
    enhanced: np.ndarray | None = None
    kpts_render: np.ndarray | None = None
    kpts_photo: np.ndarray | None = None
    inliers: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class PathResult:
    """Matching + homography of one image (raw render or enhanced render) against the photo."""

    n_matches: int
    n_inliers: int
    inlier_ratio: float
    reason: str  # homography failure reason, "" on success
    photo_from_render: np.ndarray | None  # (3, 3) in original photo pixels
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


@dataclass
class FrameChecker:
    """Holds the per-process resources (mesh, renderer, matcher, enhancer) and measures frames.

    ``references`` maps a frame id to the frame whose photo serves as the enhancement reference
    (see ``pgt_check.enhance.reference``). Build the checker inside the process that uses it:
    GL contexts and models are not shared.
    """

    config: RunConfig
    references: Mapping[str, tuple[Frame, ...]] = field(default_factory=dict)
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
        """The MaRINeR adapter (only for method "mariner"; torch is imported on first use)."""
        if self._enhancer is None:
            from pgt_check.enhance.mariner import MarinerEnhancer

            e = self.config.enhance
            self._enhancer = MarinerEnhancer(
                weights=e.weights, device=e.device, short_side=e.short_side,
                iterations=e.iterations,
            )
        return self._enhancer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def measure(self, frame: Frame, keep: FrameImages | None = None) -> dict[str, Any]:
        """Stage-1 measurement of one frame; expected problems become ``error`` reasons.

        If ``keep`` is given, the working-resolution images and matches are stored in it
        (for report assets); the measurement itself is the same.
        """
        rec = base_record(frame)
        t_start = time.perf_counter()
        try:
            self._measure_into(frame, rec, keep)
        except InputError as err:
            rec["error"] = "image_unreadable"
            rec["error_detail"] = str(err)
        except Exception as err:  # one frame must not kill the run: recorded and counted
            if self.config.fail_fast:
                raise
            logger.error("frame %s: internal error: %s", frame.frame_id, err)
            rec["error"] = "internal_error"
            rec["error_detail"] = "".join(traceback.format_exception(err))[-2000:]
        rec["time_s"] = time.perf_counter() - t_start
        return rec

    def _load_photo(self, frame: Frame) -> tuple[np.ndarray, Camera]:
        from pgt_check.io import load_image

        return prepare_photo(load_image(frame.image_file), frame.camera)

    def _match_path(
        self, image: np.ndarray, photo_w: np.ndarray, mask: np.ndarray, size: tuple[int, int],
        scale: tuple[float, float], camera: Camera,
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

    def _enhance_decision(self, raw: PathResult, threshold: float) -> tuple[bool, str]:
        e = self.config.enhance
        if e.mode == "never":
            return False, "mode_never"
        if e.mode == "always":
            return True, "mode_always"
        if not raw.success:
            return True, f"raw_{raw.reason}"
        if raw.n_inliers < e.auto_min_inliers:
            return True, "raw_few_inliers"
        if abs(raw.corner_error_px - threshold) <= e.auto_margin * threshold:
            return True, "raw_near_threshold"
        return False, "raw_decisive"

    def _enhanced_image(
        self, frame: Frame, render, cam_w: Camera, ref: Frame
    ) -> tuple[np.ndarray, np.ndarray]:
        """The enhanced render at working size and the mask to detect render keypoints in."""
        ref_photo, ref_cam = self._load_photo(ref)
        sx = cam_w.width / frame.camera.width
        ref_size = (max(1, round(ref_cam.width * sx)), max(1, round(ref_cam.height * sx)))
        ref_cam_w = ref_cam.scaled(ref_size[0] / ref_cam.width, ref_size[1] / ref_cam.height)
        ref_photo_w = _resize(ref_photo, ref_size)
        if self.config.enhance.method == "reproject":
            from pgt_check.enhance.reproject import reproject_reference

            ref_render = self.renderer.render(ref_cam_w, ref.world_from_cam)
            img, filled = reproject_reference(
                render.rgb, render.depth, cam_w, frame.world_from_cam, ref_photo_w,
                ref_render.depth, ref_cam_w, ref.world_from_cam,
            )
            return img, render.coverage
        img = self.enhancer.enhance(render.rgb, ref_photo_w)
        return img, render.coverage

    def _measure_into(self, frame: Frame, rec: dict[str, Any], keep: FrameImages | None) -> None:
        from pgt_check.geometry.homography import corner_shift_and_zoom
        from pgt_check.verdict import resolve_threshold_px

        t = time.perf_counter()
        if frame.image_file is None or not Path(frame.image_file).is_file():
            rec["error"] = "image_missing"
            return
        photo, camera = self._load_photo(frame)
        rec["width"], rec["height"] = camera.width, camera.height
        size = working_scale(camera.width, camera.height, self.config.match.resize_max)
        scale = (size[0] / camera.width, size[1] / camera.height)
        cam_w = camera.scaled(*scale)
        photo_w = _resize(photo, size)
        rec["match_width"], rec["match_height"] = size
        rec["t_load_s"] = time.perf_counter() - t

        t = time.perf_counter()
        render = self.renderer.render(cam_w, frame.world_from_cam)
        rec["t_render_s"] = time.perf_counter() - t
        rec["coverage"] = render.coverage_fraction
        rec["shading"] = render.shading
        if keep is not None:
            keep.photo, keep.render = photo_w, render.rgb
        if rec["coverage"] < self.config.verdict.min_coverage:
            rec["error"] = "low_coverage"
            return

        raw = self._match_path(render.rgb, photo_w, render.coverage, size, scale, camera)
        _store_path(rec, raw, "raw")
        rec["t_match_s"], rec["t_homography_s"] = raw.t_match_s, raw.t_homography_s
        threshold = resolve_threshold_px(self.config.verdict, camera.width, camera.height)
        do_enhance, why = self._enhance_decision(raw, threshold)
        chosen, enhanced_img = raw, None
        if do_enhance:
            refs = [
                r for r in self.references.get(frame.frame_id, ())
                if r.image_file is not None and Path(r.image_file).is_file()
            ]
            if not refs:
                do_enhance, why = False, "no_reference"
            best: PathResult | None = None
            t_enh = 0.0
            for ref in refs:
                t = time.perf_counter()
                img, mask = self._enhanced_image(frame, render, cam_w, ref)
                t_enh += time.perf_counter() - t
                enh = self._match_path(img, photo_w, mask, size, scale, camera)
                rec["t_match_s"] += enh.t_match_s
                rec["t_homography_s"] += enh.t_homography_s
                # several references: keep the enhanced result with the most inliers
                if best is None or enh.n_inliers > best.n_inliers:
                    best, enhanced_img = enh, img
                    rec["reference_id"] = ref.frame_id
            if best is not None:
                rec["t_enhance_s"] = t_enh
                _store_path(rec, best, "enhanced")
                # raw or enhanced: the path with more geometric support decides
                if best.success and (not raw.success or best.n_inliers >= raw.n_inliers):
                    chosen = best
        rec["enhanced"], rec["enhanced_why"] = do_enhance, why
        rec["verdict_path"] = "enhanced" if chosen is not raw else "raw"
        if keep is not None:
            keep.enhanced = enhanced_img
            keep.kpts_render, keep.kpts_photo = chosen.kpts_render, chosen.kpts_photo
            keep.inliers = chosen.inliers
        rec["n_kpts_render"], rec["n_kpts_photo"] = chosen.n_kpts_render, chosen.n_kpts_photo
        rec["n_matches"], rec["n_inliers"] = chosen.n_matches, chosen.n_inliers
        rec["inlier_ratio"] = chosen.inlier_ratio
        if not chosen.success:
            rec["homography_reason"] = chosen.reason
            return
        h = chosen.photo_from_render
        rec["photo_from_render"] = h.tolist()
        rec["corner_error_px"] = chosen.corner_error_px
        dx, dy, zoom = corner_shift_and_zoom(h, camera.width, camera.height)
        rec["shift_dx_px"], rec["shift_dy_px"], rec["zoom"] = dx, dy, zoom
        if self.config.pose.enabled:
            self._pose_estimate(rec, chosen, render.depth, cam_w, frame)

    def _pose_estimate(self, rec, path: PathResult, depth, cam_w: Camera, frame: Frame) -> None:
        from pgt_check.geometry.pnp import estimate_pose_correction

        t = time.perf_counter()
        p = self.config.pose
        corr = estimate_pose_correction(
            path.kpts_render, path.kpts_photo, depth, cam_w, frame.world_from_cam,
            max_error_px=p.max_error_px, min_inliers=p.min_inliers,
        )
        rec["t_pose_s"] = time.perf_counter() - t
        rec["pose_inliers"] = corr.n_inliers
        if corr.success:
            rec["pose_dt"], rec["pose_drot_deg"] = corr.dt, corr.drot_deg
        else:
            rec["pose_reason"] = corr.reason


def _store_path(rec: dict[str, Any], p: PathResult, suffix: str) -> None:
    from pgt_check.geometry.homography import corner_shift_and_zoom

    rec[f"corner_error_px_{suffix}"] = p.corner_error_px
    if p.success and suffix == "raw":
        # the systematic-offset statistic uses the raw path: an enhanced render borrows its
        # appearance from a neighbouring photo, which shares (and so cancels) calibration errors
        dx, dy, zoom = corner_shift_and_zoom(p.photo_from_render, rec["width"], rec["height"])
        rec["shift_dx_px_raw"], rec["shift_dy_px_raw"], rec["zoom_raw"] = dx, dy, zoom
    rec[f"n_matches_{suffix}"] = p.n_matches
    rec[f"n_inliers_{suffix}"] = p.n_inliers
    rec[f"inlier_ratio_{suffix}"] = p.inlier_ratio
    rec[f"homography_reason_{suffix}"] = p.reason


def base_record(frame: Frame) -> dict[str, Any]:
    """An empty measurement record for ``frame`` (every key present, values None)."""
    return {
        "frame_id": frame.frame_id,
        "timestamp": frame.timestamp,
        "image_path": frame.image_path,
        "width": frame.camera.width,
        "height": frame.camera.height,
        "error": "",
        "error_detail": "",
        "coverage": None,
        "shading": None,
        "n_kpts_render": None,
        "n_kpts_photo": None,
        "n_matches": 0,
        "n_inliers": 0,
        "inlier_ratio": 0.0,
        "homography_reason": "",
        "corner_error_px": None,
        "shift_dx_px": None,
        "shift_dy_px": None,
        "zoom": None,
        "photo_from_render": None,
        "match_width": None,
        "match_height": None,
        "t_load_s": None,
        "t_render_s": None,
        "t_match_s": None,
        "t_homography_s": None,
        "t_enhance_s": None,
        "t_pose_s": None,
        "time_s": None,
        "corner_error_px_raw": None,
        "shift_dx_px_raw": None,
        "shift_dy_px_raw": None,
        "zoom_raw": None,
        "n_matches_raw": None,
        "n_inliers_raw": None,
        "inlier_ratio_raw": None,
        "homography_reason_raw": "",
        "corner_error_px_enhanced": None,
        "n_matches_enhanced": None,
        "n_inliers_enhanced": None,
        "inlier_ratio_enhanced": None,
        "homography_reason_enhanced": "",
        "enhanced": False,
        "enhanced_why": "",
        "reference_id": None,
        "verdict_path": None,
        "pose_dt": None,
        "pose_drot_deg": None,
        "pose_inliers": None,
        "pose_reason": "",
        "center": frame.center.tolist(),
    }


def load_trajectory(config: RunConfig) -> Trajectory:
    from pgt_check.io import read_trajectory

    inp = config.input
    if not inp.trajectory:
        raise InputError("no trajectory given")
    if not inp.mesh:
        raise InputError("no mesh given (--mesh)")
    if not Path(inp.mesh).is_file():
        raise InputError(f"mesh not found: {inp.mesh}")
    traj = read_trajectory(
        inp.trajectory, inp.format, images=inp.images, camera=inp.camera, sensors=inp.sensors
    )
    if len(traj) == 0:
        raise InputError(f"{inp.trajectory}: no frames with both a pose and an image")
    return traj


def _progress(iterable, total: int, desc: str):
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a core dependency
        return iterable
    return tqdm(iterable, total=total, desc=desc, unit="frame", disable=None)


def apply_verdicts(records: list[dict[str, Any]], config: RunConfig) -> list[dict[str, Any]]:
    """Stage 2 on stored measurements: adds verdict, reason and threshold_px to each record."""
    from pgt_check.verdict import decide, resolve_threshold_px

    out = []
    for rec in records:
        r = dict(rec)
        verdict, reason = decide(r, config.verdict)
        r["verdict"], r["reason"] = verdict.value, reason
        r["threshold_px"] = resolve_threshold_px(config.verdict, int(r["width"]), int(r["height"]))
        out.append(r)
    return out


def run(config: RunConfig) -> dict[str, Any]:
    """Check every frame of the configured trajectory and write the outputs to ``config.out``.

    Returns the summary (also written as summary.json). Raises InputError for user errors and
    RunInterrupted after a Ctrl-C (the frames done so far are kept for ``--resume``).
    """
    import functools

    t0 = time.perf_counter()
    traj = load_trajectory(config)
    frames = list(traj.frames)
    if config.limit is not None:
        frames = frames[: config.limit]
    logger.info("checking %d frames of %s (%s)", len(frames), traj.source, traj.format)
    references = pick_references(traj, frames, config)
    return check_frames(
        frames,
        config,
        functools.partial(build_frame_checker, config, references),
        extra={"trajectory_format": traj.format},
        t0=t0,
    )


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


class RunInterrupted(Exception):
    """The run stopped on Ctrl-C; ``done`` of ``total`` frames are stored in ``out``."""

    def __init__(self, done: int, total: int, out: str) -> None:
        super().__init__(f"interrupted: {done}/{total} frames done")
        self.done, self.total, self.out = done, total, out


def build_frame_checker(
    config: RunConfig, references: Mapping[str, tuple[Frame, ...]] | None = None
) -> FrameChecker:
    """Worker-side factory: a FrameChecker with its mesh, renderer and matcher loaded."""
    checker = FrameChecker(config, dict(references or {}))
    _ = checker.renderer
    _ = checker.matcher
    return checker


def error_record(frame: Frame, error: str, detail: str) -> dict[str, Any]:
    """Measurement record of a frame that could not be measured (e.g. ``worker_crashed``)."""
    rec = base_record(frame)
    rec["error"], rec["error_detail"] = error, detail
    return rec


def check_frames(
    frames: Sequence[Frame],
    config: RunConfig,
    checker_factory: Callable[[], Any],
    *,
    extra: dict[str, Any] | None = None,
    t0: float | None = None,
) -> dict[str, Any]:
    """Measure ``frames`` (skipping those already in the store), then write the outputs.

    Records stream from the executor into ``out/records.jsonl`` as frames finish; the outputs
    are built from the store in ``frames`` order, so a resumed run writes the same frames.csv
    as an uninterrupted one (timing columns aside).
    """
    from pgt_check.executor import ExecutorStats, iter_results, stop_on_sigint
    from pgt_check.report.outputs import write_outputs
    from pgt_check.store import RecordStore

    t0 = time.perf_counter() if t0 is None else t0
    out = Path(config.out)
    settings = {k: v for k, v in config.to_dict().items() if k in MEASUREMENT_SECTIONS}
    ids = [f.frame_id for f in frames]
    stats = ExecutorStats()
    with RecordStore.open(
        out,
        config.measurement_fingerprint(),
        resume=config.resume,
        overwrite=config.overwrite,
        settings=settings,
    ) as store:
        done = store.done_ids().intersection(ids)
        if done:
            logger.info("%d of %d frames already measured with these settings: skipped",
                        len(done), len(frames))
        todo = (f for f in frames if f.frame_id not in done)
        with stop_on_sigint() as stop:
            results = iter_results(
                todo, checker_factory, config, stop=stop, error_record=error_record, stats=stats
            )
            for rec in _progress(results, len(frames) - len(done), "pgt-check"):
                store.append(rec)
            interrupted = stop.is_set()
        if interrupted:
            n_done = len(store.done_ids().intersection(ids))
            if n_done < len(ids):
                logger.warning("interrupted: %d/%d frames done, stored in %s", n_done, len(ids),
                               out)
                raise RunInterrupted(n_done, len(ids), str(out))
        records = store.records_in_order(ids)
    records = apply_verdicts(records, config)
    assets = write_report_assets(frames, records, config, checker_factory)
    shadings = sorted({str(r["shading"]) for r in records if r.get("shading")})
    summary_extra = {
        "shading": shadings[0] if len(shadings) == 1 else (shadings or None),
        "executor": {
            "kind": config.executor,
            "workers": stats.workers,
            "frames_measured": stats.yielded,
            "frames_reused": len(done),
            "worker_crashes": stats.worker_crashes,
        },
        **(extra or {}),
        "wall_time_s": time.perf_counter() - t0,
    }
    # write_outputs rewrites records.jsonl in frame order; the records keep their _fingerprint,
    # so the rewritten file is a compacted store that a later --resume reads as usual
    return write_outputs(out, records, config, extra=summary_extra, assets=assets)


def write_report_assets(
    frames: Sequence[Frame],
    records: list[dict[str, Any]],
    config: RunConfig,
    checker_factory: Callable[[], Any],
) -> dict[str, dict[str, str]] | None:
    """Thumbnails for the report's detail panels: the selected frames are measured again here
    (in this process, keeping their images); other frames never keep images."""
    from pgt_check.report.assets import select_detail_frames, write_frame_assets

    if config.report_details <= 0:
        return None
    chosen = select_detail_frames(records, max_details=config.report_details)
    if not chosen:
        return None
    by_id = {f.frame_id: f for f in frames}
    rec_by_id = {r["frame_id"]: r for r in records}
    checker = checker_factory()
    assets: dict[str, dict[str, str]] = {}
    try:
        for fid in chosen:
            images = FrameImages()
            checker.measure(by_id[fid], keep=images)
            if images.photo is None:
                continue
            assets[fid] = write_frame_assets(Path(config.out), rec_by_id[fid], images)
    finally:
        checker.close()
    return assets




def finite_or_none(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x
