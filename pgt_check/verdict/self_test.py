"""Self-test of the stated detection limits (``--self-test N``, config ``self_test``; #27).

The run states two detection limits (``verdict.accuracy.detection_limits``): the smallest error
of one frame it would flag and the smallest error shared by all frames, each as a rotation alone
(deg) and a translation alone (scene units). The self-test measures frames again at poses moved
by known amounts around those limits and reports how often the checker flags them:

* single frame: ``N`` frames that PASS on absolute evidence (evenly spaced along the run) are
  measured at their given pose and at poses moved by k x the stated single-frame limit, k in
  ``MULTIPLES``: a rotation alone (camera frame, random axis) or a camera-centre shift alone
  (random direction), one seeded random direction per frame and kind, the same for every
  size (each frame's error grows along it, so the curve is the share of frames whose error
  is flagged at that size). Each moved
  measurement is judged as a frame of this run (``verdict.decide.judge`` with the run's own
  run-level checks and calibration handling); flagged = not PASS;
* shared: the same ``N`` frames moved as a whole (the trajectory misregistered) by k x the
  stated shared limit: a rotation about their camera centroid or a translation, about / along
  the world axis the stated limit is derived for (where the image effect is smallest:
  the limit claims to hold whatever the axis; on the boxes scene a random axis is flagged at
  0.5x already), in both directions along it: two trials per size, since the run's own shared
  offset (a fused mesh's, say) adds to one sign and has to be cancelled by the other first.
  The registration check is run on those measurements (``verdict.shared.run_shared_checks``);
  flagged = it fails (the worse of its rigid and similarity fits, as the verdicts use it).
  The curve is 0, 1/2 or 1 at each size: 50 % where one direction is flagged, 100 % where
  both are. It needs ``SHARED_MIN_FRAMES`` (5) frames, better 10 or more:
  the check's interval on ``N`` frames is wider than on the whole run, so a small ``N``
  flags later than the whole run would.

Measurements use the absolute paths only (render, raw match, geometric edges; no enhancement,
no references), through the ``measure(frames, config)`` the runner passes in (the one the
registration refinement uses), so the self-test is a re-measurement with the checker itself.

The curves, their reading and the sentences: ``verdict.self_test_curves``.
See docs/outputs.md#self-test.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from pgt_check.common.sequences import evenly_spaced
from pgt_check.config import RunConfig
from pgt_check.geometry.transforms import axis_angle_to_rotmat, move_pose
from pgt_check.measure.record import FrameMeasurement
from pgt_check.types import Frame
from pgt_check.verdict.accuracy import DetectionLimits
from pgt_check.verdict.decide import judge
from pgt_check.verdict.judgement import Verdict
from pgt_check.verdict.result import FrameResult, RunResult
from pgt_check.verdict.self_test_curves import (  # noqa: F401  (re-exported)
    HELD_TOLERANCE,
    MULTIPLES,
    NOISE_ALPHA,
    ROTATION,
    SEED,
    SHARED,
    SINGLE,
    TRANSLATION,
    CurvePoint,
    DetectionCurve,
    SelfTest,
    _curve,
    _g,
    curve_label,
    curve_phrase,
    detection_point,
    judge_curve,
    self_test_sentence,
    upper_end_p,
)
from pgt_check.verdict.status import FAILED

logger = logging.getLogger(__name__)

#: the shared test needs as many frames as the registration check (``estimate_registration``)
SHARED_MIN_FRAMES = 5

MeasureFn = Callable[[Sequence[Frame], RunConfig], list[FrameMeasurement]]




# -- the moves --------------------------------------------------------------------------------
def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def moved_frame(frame: Frame, kind: str, size: float, direction: np.ndarray) -> Frame:
    """``frame`` with its camera rotated by ``size`` deg about ``direction`` (camera axes) or
    its centre moved by ``size`` scene units along ``direction`` (world axes)."""
    p = np.array(frame.world_from_cam, dtype=np.float64)
    if kind == ROTATION:
        p[:3, :3] = p[:3, :3] @ axis_angle_to_rotmat(direction, size)
    else:
        p[:3, 3] += size * direction
    return frame.with_pose(p)


def shared_move(frames: Sequence[Frame], kind: str, size: float,
                direction: np.ndarray) -> np.ndarray:
    """(4, 4) ``moved_from_world``: a rotation by ``size`` deg about ``direction`` through the
    frames' camera centroid, or a translation by ``size`` scene units along ``direction``."""
    m = np.eye(4)
    if kind == ROTATION:
        c = np.mean([np.asarray(f.world_from_cam)[:3, 3] for f in frames], axis=0)
        r = axis_angle_to_rotmat(direction, size)
        m[:3, :3] = r
        m[:3, 3] = c - r @ c
    else:
        m[:3, 3] = size * direction
    return m


def weakest_world_axes(ms: Sequence[FrameMeasurement],
                       rng: np.random.Generator) -> dict[str, np.ndarray]:
    """kind -> the world axis (random sign) about / along which a shared error moves the
    images of ``ms`` least: the axis the stated shared limit is derived for
    (``verdict.frame_bounds.world_axis_sensitivity``); a random direction without evidence."""
    from pgt_check.verdict.frame_bounds import world_axis_sensitivity

    rot, tra = world_axis_sensitivity(ms) if ms else (np.full(3, np.nan), np.full(3, np.nan))
    out = {}
    for kind, per in ((ROTATION, rot), (TRANSLATION, tra)):
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if np.isfinite(per).any():
            out[kind] = sign * np.eye(3)[int(np.nanargmin(per))]
        else:
            out[kind] = _unit(rng)
    return out


def choose_frames(results: Sequence[FrameResult], frames: Sequence[Frame],
                  n: int) -> list[Frame]:
    """Up to ``n`` frames, evenly spaced, of those that PASS with a per-frame accuracy bound
    (absolute evidence): an injected error is then the only reason to flag them."""
    by_id = {f.frame_id: f for f in frames}
    ok = [r.frame_id for r in results
          if r.verdict == Verdict.PASS.value and r.bound.bounded and r.frame_id in by_id]
    return [by_id[fid] for fid in evenly_spaced(ok, n)]


def evidence_config(config: RunConfig) -> RunConfig:
    """Absolute evidence only: no enhancement, no report panels (verdict settings stay)."""
    return replace(config, enhance=replace(config.enhance, mode="never"), report_details=0)


def _measure_as(measure: MeasureFn, jobs: Sequence[tuple[str, Frame]],
                config: RunConfig) -> dict[str, FrameMeasurement]:
    """Measure frames under unique ids (``jobs``: (key, frame)); key -> the measurement under
    the frame's own id again (the run-level checks key their per-frame results by it)."""
    tagged = [replace(f, frame_id=key) for key, f in jobs]
    own = {key: f.frame_id for key, f in jobs}
    ms = measure(tagged, config)
    return {m.frame_id: replace(m, frame_id=own[m.frame_id]) for m in ms if m.frame_id in own}


# -- the test ---------------------------------------------------------------------------------
_Plan = dict[tuple[str, float], list[str]]  # (kind, k) -> keys; ("", 0.0): the given poses
_Limits = Mapping[str, tuple[float | None, float | None]]


def _single_jobs(chosen: Sequence[Frame], single: _Limits,
                 rng: np.random.Generator) -> tuple[list[tuple[str, Frame]], _Plan]:
    """Every chosen frame at its given pose and at each size and kind: (jobs, plan)."""
    jobs: list[tuple[str, Frame]] = []
    plan: _Plan = {}
    for f in chosen:
        jobs.append((f"{f.frame_id}#self-test:0", f))
        plan.setdefault(("", 0.0), []).append(jobs[-1][0])
        for kind, (lim, _) in single.items():
            d = _unit(rng)  # one direction per frame and kind, grown through the sizes
            for k in MULTIPLES:
                if lim is None:
                    continue
                key = f"{f.frame_id}#self-test:{kind}:{k:g}"
                jobs.append((key, moved_frame(f, kind, k * lim, d)))
                plan.setdefault((kind, k), []).append(key)
    return jobs, plan


def _tally(ms: Mapping[str, FrameMeasurement], keys: Sequence[str], v: Any,
           shared: Any) -> tuple[int, int, int, int, str, tuple[str, ...]]:
    """The ``CurvePoint`` counts of the measurements ``keys`` judged as frames of the run."""
    judged = {x: judge(ms[x], v, shared) for x in keys if x in ms}
    got = [j.verdict for j in judged.values()]
    fail = sum(g is Verdict.FAIL for g in got)
    unv = sum(g is Verdict.UNVERIFIABLE for g in got)
    missed = tuple(_missed(ms[x], j, v) for x, j in judged.items() if j.verdict is Verdict.PASS)
    return len(keys), fail + unv + (len(keys) - len(got)), fail, unv, "", missed


def _single_curves(single: _Limits, chosen: Sequence[Frame], plan: _Plan, v: Any, shared: Any,
                   ms: Mapping[str, FrameMeasurement]) -> list[DetectionCurve]:
    """The single-frame curve of each kind from the measurements ``ms`` of ``plan``."""
    zero = _tally(ms, plan.get(("", 0.0), []), v, shared)
    curves = []
    for kind, (lim, lim_px) in single.items():
        pts = [CurvePoint(0.0, 0.0, *zero)] if chosen else []
        if lim is not None and chosen:
            pts += [CurvePoint(k, k * lim, *_tally(ms, plan[(kind, k)], v, shared))
                    for k in MULTIPLES]
        curves.append(_curve(SINGLE, kind, lim, lim_px, pts))
    return curves


def _shared_curves(together: _Limits, chosen: Sequence[Frame], base: Sequence[FrameMeasurement],
                   axes: Mapping[str, np.ndarray], measure: MeasureFn, ecfg: RunConfig,
                   checks: Callable[[Sequence[FrameMeasurement], RunConfig], Any]
                   ) -> list[DetectionCurve]:
    """The shared curves: the chosen frames moved together along ``axes``, both directions
    (k = 0: ``base``, one trial)."""
    curves = []
    for kind, (lim, lim_px) in together.items():
        pts = []
        if len(chosen) >= SHARED_MIN_FRAMES and base:
            pts.append(_shared_point(0.0, 0.0, [_shared_status(base, ecfg, checks)]))
            if lim is not None:
                for k in MULTIPLES:
                    statuses = [
                        _shared_status(_moved_measured(chosen, kind, k * lim, sign * axes[kind],
                                                       measure, ecfg), ecfg, checks)
                        for sign in (1.0, -1.0)
                    ]
                    pts.append(_shared_point(k, k * lim, statuses))
        curves.append(_curve(SHARED, kind, lim, lim_px, pts))
    return curves


def _moved_measured(chosen: Sequence[Frame], kind: str, size: float, direction: np.ndarray,
                    measure: MeasureFn, ecfg: RunConfig) -> list[FrameMeasurement]:
    """The chosen frames moved together (``shared_move``) and measured again, in order."""
    move = shared_move(chosen, kind, size, direction)
    moved = [f.with_pose(move_pose(f.world_from_cam, move)) for f in chosen]
    got = _measure_as(measure, [(f.frame_id, f) for f in moved], ecfg)
    return [got[f.frame_id] for f in moved if f.frame_id in got]


def run_self_test(
    frames: Sequence[Frame],
    result: RunResult,
    limits: DetectionLimits,
    config: RunConfig,
    measure: MeasureFn,
    n: int,
) -> SelfTest:
    """The self-test of this run's stated ``limits`` on up to ``n`` of its ``frames`` (module
    docstring). ``result``: the run's verdicts; its ``shared`` checks are the context each moved
    frame is judged in (None without run-level checks)."""
    from pgt_check.verdict.shared import run_shared_checks

    t0 = time.perf_counter()
    chosen = choose_frames(result.frames, frames, n)
    shared = result.shared
    ecfg = evidence_config(config)
    rng = np.random.default_rng(SEED)
    single = {ROTATION: (limits.frame_deg, limits.frame_px),
              TRANSLATION: (limits.frame_units, limits.frame_px)}
    together = {ROTATION: (limits.shared_deg, limits.shared_px),
                TRANSLATION: (limits.shared_units, limits.shared_px)}
    jobs, plan = _single_jobs(chosen, single, rng)
    logger.info("self-test: %d frames measured again at %d poses (single-frame limit)",
                len(chosen), len(jobs))
    ms = _measure_as(measure, jobs, ecfg) if jobs else {}
    curves = _single_curves(single, chosen, plan, config.verdict, shared, ms)
    base = [ms[k] for k in plan.get(("", 0.0), []) if k in ms]
    axes = weakest_world_axes(base, rng)
    curves += _shared_curves(together, chosen, base, axes, measure, ecfg, run_shared_checks)
    st = SelfTest(n, tuple(f.frame_id for f in chosen), MULTIPLES, tuple(curves),
                  time.perf_counter() - t0)
    return replace(st, sentence=self_test_sentence(st))


def _missed(m: FrameMeasurement, j: Any, v: Any) -> str:
    """``id (corner error px / threshold px, path)`` of a moved frame that still PASSes."""
    from pgt_check.verdict.decide import resolve_threshold_px

    name = j.decided_by
    path = m.path(name)
    err = None if path is None else path.corner_error_px
    thr = resolve_threshold_px(v, m.width, m.height)
    return f"{m.frame_id} ({_g(err)} px / {_g(thr)} px, {name or '?'})"


def _shared_status(ms: Sequence[FrameMeasurement], config: RunConfig,
                   checks: Callable[[Sequence[FrameMeasurement], RunConfig], Any]
                   ) -> tuple[str, str]:
    """(status, rigid status) of the registration check on ``ms``: the worse of the rigid and
    the similarity check, as the verdicts use it (on alike views the rigid fit can trade a
    shift for a rotation and pass where the similarity fails)."""
    res = checks(ms, config)
    return str(res.registration_status), str(res.registration.status)


def _shared_point(k: float, size: float, statuses: Sequence[tuple[str, str]]) -> CurvePoint:
    """One size of a shared curve from its trials' ``_shared_status`` (``status``: each
    trial's, joined by " / ")."""
    failed = sum(st == FAILED for st, _ in statuses)
    return CurvePoint(k, size, len(statuses), failed, failed,
                      sum(st == "not_checked" for st, _ in statuses),
                      " / ".join(st if rigid == st else f"{st} (rigid {rigid})"
                                 for st, rigid in statuses))
