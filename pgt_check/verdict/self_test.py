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
  the limit claims to hold whatever the axis; random sign, the same for every size; on the
  boxes scene a random axis is flagged at 0.5x already). The
  registration check is run on those measurements (``verdict.shared.run_shared_checks``);
  flagged = it fails (the worse of its rigid and similarity fits, as the verdicts use it).
  One trial per size and kind: the curve is a step at the size where the check starts
  failing. It needs ``SHARED_MIN_FRAMES`` (5) frames, better 10 or more:
  the check's interval on ``N`` frames is wider than on the whole run, so a small ``N``
  flags later than the whole run would.

Measurements use the absolute paths only (render, raw match, geometric edges; no enhancement,
no references), through the ``measure(frames, config)`` the runner passes in (the one the
registration refinement uses), so the self-test is a re-measurement with the checker itself.

The detection curve of each (test, kind) is the share flagged against k (k = 0: the given
poses). Its empirical q-detection point ``k_q`` (q = 50 %, 95 %) is where the curve, made
monotone by its running maximum and linearly interpolated between the measured sizes, first
reaches q; None when it never does up to the largest size. A stated limit **held** when
``k_50`` or ``k_95`` lies within ``HELD_TOLERANCE`` (30 %) of it: ``|k_q - 1| <= 0.3``, or
when ``k_95`` lies above the band only by sampling noise: ``k_50 <= 1.3`` and the count flagged
at the band's upper end (the largest measured k <= 1.3) is consistent with a 95 % detection
rate (one-sided exact binomial test, p >= ``NOISE_ALPHA``; on 16 frames one frame still passing
at 1.3 x has p = 0.56, so the empirical 95 % point alone would fail a true limit that often).
Otherwise the curve says how it missed: *conservative* (already 95 % flagged below 0.7 x: the
limit is larger than needed), *understated* (not even 50 % flagged at 1.3 x: errors beyond the
stated limit pass), *shallow* (50 % below 0.7 x, 95 % above 1.3 x), *untested* (no limit
stated, no frame, or the given poses flagged in half the cases). See docs/outputs.md#self-test.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from pgt_check.config import RunConfig
from pgt_check.geometry.transforms import axis_angle_to_rotmat, move_pose
from pgt_check.measure.record import FrameMeasurement
from pgt_check.types import Frame
from pgt_check.verdict.accuracy import DetectionLimits
from pgt_check.verdict.decide import Verdict, judge
from pgt_check.verdict.status import FAILED

logger = logging.getLogger(__name__)

#: the injected sizes, as multiples of the stated limit (0.7 and 1.3: the ends of the band in
#: which the limit holds)
MULTIPLES: tuple[float, ...] = (0.5, 0.7, 1.0, 1.3, 2.0)
#: a stated limit holds when its empirical 50 % or 95 % detection point lies within this
#: fraction of it
HELD_TOLERANCE = 0.3
#: significance level of the binomial test that tells a 95 % point above the band from the
#: sampling noise of a few frames (module docstring)
NOISE_ALPHA = 0.05
#: the random directions are drawn from this seed (the same run gives the same self-test)
SEED = 0
#: the shared test needs as many frames as the registration check (``estimate_registration``)
SHARED_MIN_FRAMES = 5

MeasureFn = Callable[[Sequence[Frame], RunConfig], list[FrameMeasurement]]

SINGLE, SHARED = "single_frame", "shared"
ROTATION, TRANSLATION = "rotation", "translation"


@dataclass(frozen=True)
class CurvePoint:
    """One injected size: ``k`` x the stated limit = ``size`` (deg or scene units)."""

    k: float
    size: float
    n: int  # trials (frames; 1 for the shared test)
    flagged: int  # not PASS (single frame) / registration failed (shared)
    failed: int  # FAIL (single frame) / registration failed (shared)
    unverifiable: int  # UNVERIFIABLE (single frame) / registration not checked (shared)
    status: str = ""  # shared test: the registration check's status
    #: single frame: the frames still PASSing at this size, "id (corner error px / threshold
    #: px, path)": where a limit is missed, these say why
    missed: tuple[str, ...] = ()

    @property
    def share(self) -> float | None:
        return self.flagged / self.n if self.n else None


@dataclass(frozen=True)
class DetectionCurve:
    """The share flagged against the injected size, for one test and one kind of error."""

    test: str  # SINGLE / SHARED
    kind: str  # ROTATION (deg) / TRANSLATION (scene units)
    stated: float | None  # the stated limit (deg or scene units)
    stated_px: float | None
    points: tuple[CurvePoint, ...]
    k50: float | None
    k95: float | None
    judgement: str  # held, conservative, understated, shallow, untested
    #: p-value of the count flagged at the band's upper end under a 95 % detection rate
    #: (None when not needed: k_95 within the band, or no point measured there)
    upper_p: float | None = None

    @property
    def held(self) -> bool | None:
        return None if self.judgement == "untested" else self.judgement == "held"

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["held"] = self.held
        d["unit"] = "deg" if self.kind == ROTATION else "scene units"
        for p, q in zip(d["points"], self.points, strict=True):
            p["share"] = q.share
        return d


@dataclass(frozen=True)
class SelfTest:
    """summary.json -> ``self_test``."""

    n_requested: int
    frame_ids: tuple[str, ...]
    multiples: tuple[float, ...]
    curves: tuple[DetectionCurve, ...]
    seconds: float
    sentence: str = ""
    how: str = field(default=(
        "single frame: each chosen frame (PASS on absolute evidence) measured again at its "
        "given pose and moved by k x the stated single-frame limit (rotation alone about a "
        "random camera axis, or centre shift alone in a random direction, seeded), judged as a "
        "frame of this run; flagged = not PASS. shared: the chosen frames moved together by k "
        "x the stated shared limit (rotation about their centroid or translation, about / along "
        "the weakest world axis, the one the limit is derived for), registration check on "
        "them; flagged = failed. k_q: where the "
        "monotone (running maximum), linearly interpolated share flagged first reaches q; "
        "held: k_50 or k_95 within 30 % of 1, or k_50 <= 1.3 and the count flagged at 1.3 x "
        "consistent with 95 % detection (one-sided binomial, p >= 0.05: upper_p)"
    ))

    @property
    def held(self) -> bool | None:
        tested = [c.held for c in self.curves if c.held is not None]
        return None if not tested else all(tested)

    def to_json(self) -> dict[str, Any]:
        return {
            "n_requested": self.n_requested,
            "n_frames": len(self.frame_ids),
            "frame_ids": list(self.frame_ids),
            "multiples": list(self.multiples),
            "tolerance": HELD_TOLERANCE,
            "seed": SEED,
            "held": self.held,
            "curves": [c.to_json() for c in self.curves],
            "sentence": self.sentence,
            "how": self.how,
            "seconds": self.seconds,
        }


# -- the curve and its reading ----------------------------------------------------------------
def detection_point(ks: Sequence[float], shares: Sequence[float | None], q: float) -> float | None:
    """The smallest k at which the share flagged reaches ``q``: the curve made monotone by its
    running maximum, linearly interpolated between the measured ks (sorted ascending); None
    when it stays below ``q``. Points without trials (share None) are skipped."""
    pts = sorted((float(k), float(s)) for k, s in zip(ks, shares, strict=True) if s is not None)
    best = -1.0
    prev: tuple[float, float] | None = None
    for k, s in pts:
        s = max(s, best)
        if s >= q:
            if prev is None or prev[1] >= q:
                return k
            k0, s0 = prev
            return k0 + (q - s0) / (s - s0) * (k - k0)
        best, prev = s, (k, s)
    return None


def upper_end_p(points: Sequence[CurvePoint]) -> float | None:
    """P(this few flagged or fewer | 95 % detection) at the largest measured k in [1, 1.3]
    (exact binomial, one-sided); None when no point with trials lies there."""
    from scipy.stats import binom

    band = [p for p in points if 1.0 <= p.k <= 1.0 + HELD_TOLERANCE + 1e-9 and p.n > 0]
    if not band:
        return None
    p = max(band, key=lambda q: q.k)
    return float(binom.cdf(p.flagged, p.n, 0.95))


def judge_curve(k50: float | None, k95: float | None, baseline: float | None,
                upper_p: float | None = None) -> str:
    """held / conservative / understated / shallow / untested (module docstring);
    ``upper_p``: ``upper_end_p`` of the curve (None: no sampling-noise allowance)."""
    if baseline is None or baseline >= 0.5:
        return "untested"
    lo, hi = 1.0 - HELD_TOLERANCE, 1.0 + HELD_TOLERANCE
    if any(k is not None and lo <= k <= hi for k in (k50, k95)):
        return "held"
    if (k50 is not None and k50 <= hi and (k95 is None or k95 > hi) and upper_p is not None
            and upper_p >= NOISE_ALPHA):
        return "held"  # the 95 % point is above the band by the sampling noise of few trials
    if k95 is not None and k95 < lo:
        return "conservative"
    if k50 is None or k50 > hi:
        return "understated"
    return "shallow"


def _curve(test: str, kind: str, stated: float | None, stated_px: float | None,
           points: Sequence[CurvePoint]) -> DetectionCurve:
    ks = [p.k for p in points]
    shares = [p.share for p in points]
    zero = next((p for p in points if p.k == 0.0), None)
    # the given poses must be judged (and mostly not flagged) for the curve to mean anything
    base = None if zero is None or zero.unverifiable >= zero.n else zero.share
    k50, k95 = detection_point(ks, shares, 0.5), detection_point(ks, shares, 0.95)
    hi = 1.0 + HELD_TOLERANCE
    p_up = upper_end_p(points) if k95 is None or k95 > hi else None
    judgement = judge_curve(k50, k95, base, p_up) if points and stated else "untested"
    return DetectionCurve(test, kind, stated, stated_px, tuple(points), k50, k95, judgement,
                          p_up)


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


def choose_frames(rows: Sequence[Mapping[str, Any]], frames: Sequence[Frame],
                  n: int) -> list[Frame]:
    """Up to ``n`` frames, evenly spaced, of those that PASS with a per-frame accuracy bound
    (absolute evidence): an injected error is then the only reason to flag them."""
    by_id = {f.frame_id: f for f in frames}
    ok = [r["frame_id"] for r in rows
          if r.get("verdict") == Verdict.PASS.value and r.get("acc_rot_bound_deg") is not None
          and r["frame_id"] in by_id]
    if len(ok) > n:
        ok = [ok[i] for i in np.linspace(0, len(ok) - 1, n).round().astype(int)]
    return [by_id[fid] for fid in ok]


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
    """The shared curves: the chosen frames moved together along ``axes`` (k = 0: ``base``)."""
    curves = []
    for kind, (lim, lim_px) in together.items():
        pts = []
        if len(chosen) >= SHARED_MIN_FRAMES and base:
            pts.append(_shared_point(0.0, 0.0, base, ecfg, checks))
            d = axes[kind]  # one misregistration per kind, grown through the sizes
            if lim is not None:
                for k in MULTIPLES:
                    move = shared_move(chosen, kind, k * lim, d)
                    moved = [f.with_pose(move_pose(f.world_from_cam, move)) for f in chosen]
                    got = _measure_as(measure, [(f.frame_id, f) for f in moved], ecfg)
                    order = [got[f.frame_id] for f in moved if f.frame_id in got]
                    pts.append(_shared_point(k, k * lim, order, ecfg, checks))
        curves.append(_curve(SHARED, kind, lim, lim_px, pts))
    return curves


def run_self_test(
    frames: Sequence[Frame],
    rows: Sequence[Mapping[str, Any]],
    shared: Any,
    limits: DetectionLimits,
    config: RunConfig,
    measure: MeasureFn,
    n: int,
) -> SelfTest:
    """The self-test of this run's stated ``limits`` on up to ``n`` of its ``frames`` (module
    docstring). ``rows``: the run's judged rows; ``shared``: its ``SharedChecks`` (the context
    each moved frame is judged in; None without run-level checks)."""
    from pgt_check.verdict.shared import run_shared_checks

    t0 = time.perf_counter()
    chosen = choose_frames(rows, frames, n)
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
    path = getattr(m, name, None) if name in ("raw", "enhanced", "edges") else None
    err = getattr(path, "corner_error_px", None)
    thr = resolve_threshold_px(v, m.width, m.height)
    return f"{m.frame_id} ({_g(err)} px / {_g(thr)} px, {name or '?'})"


def _shared_point(k: float, size: float, ms: Sequence[FrameMeasurement], config: RunConfig,
                  checks: Callable[[Sequence[FrameMeasurement], RunConfig], Any]) -> CurvePoint:
    # the worse of the rigid and the similarity check, as the verdicts use it (on alike views
    # the rigid fit can trade a shift for a rotation and pass where the similarity fails)
    res = checks(ms, config)
    status = str(res.registration_status)
    rigid = str(res.registration.status)
    return CurvePoint(k, size, 1, int(status == FAILED), int(status == FAILED),
                      int(status == "not_checked"),
                      status if rigid == status else f"{status} (rigid {rigid})")


# -- what the CLI and the report say ------------------------------------------------------------
def _g(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2g}"


def curve_label(c: DetectionCurve) -> str:
    who = "single-frame" if c.test == SINGLE else "shared"
    return f"{who} {c.kind}"


def curve_phrase(c: DetectionCurve) -> str:
    """``single-frame rotation held (50 % at 0.82x, 95 % at 1.1x)``."""
    if c.judgement == "untested":
        return f"{curve_label(c)} untested"
    noise = ""
    band = (1.0 - HELD_TOLERANCE, 1.0 + HELD_TOLERANCE)
    in_band = any(k is not None and band[0] <= k <= band[1] for k in (c.k50, c.k95))
    if c.judgement == "held" and c.upper_p is not None and not in_band:
        end = max((p for p in c.points if 1.0 <= p.k <= band[1] + 1e-9 and p.n > 0),
                  key=lambda p: p.k)
        noise = (f"; {end.flagged}/{end.n} flagged at {end.k:g}x is within the sampling noise "
                 f"of 95 % detection, p = {c.upper_p:.2f}")
    return (f"{curve_label(c)} {c.judgement} (50 % at {_g(c.k50)}x, 95 % at {_g(c.k95)}x"
            f" the stated {_g(c.stated)} {'deg' if c.kind == ROTATION else 'units'}{noise})")


def self_test_sentence(st: SelfTest) -> str:
    """One line: whether the stated limits held within 30 %, and how each curve reads."""
    n = len(st.frame_ids)
    if not n:
        return (f"Self-test: no frame PASSes on absolute evidence, so the stated limits could "
                f"not be tested ({st.n_requested} requested).")
    held = st.held
    head = ("the stated detection limits held within 30 %" if held
            else "the stated detection limits did NOT all hold within 30 %" if held is False
            else "the stated detection limits could not be tested")
    return f"Self-test on {n} frames: {head}: " + "; ".join(curve_phrase(c) for c in st.curves) + "."
