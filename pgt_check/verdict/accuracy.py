"""How accurate are the poses: the run's statement, its detection limits, and the accuracy
gate (``--require-accuracy DEG,UNITS``). The per-frame bounds it pools (the ``acc_*`` columns)
come from ``verdict.frame_bounds``.

Per run (``run_accuracy``): how many frames are verified to within X deg / Y units, percentiles
of the bounds, the shared errors as sizes with their 95 % intervals, and the detection limits of
this run. The limits come from this run's own noise, not from constants: the single-frame limit
is the error flagged in 95 % of (frame, error axis) pairs, each frame at its threshold plus the
median per-frame bootstrap noise, with its own sensitivities over error axes (``pooled_detection_size``;
px per degree / per scene unit as the check's homography measures them); the shared limit is the
shared threshold plus the half-width of the registration fit's own 95 % interval, turned with
the image effect of a world rotation / translation as the registration check measures it
(``world_sensitivity``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, cast

import numpy as np

from pgt_check.config import GateConfig
from pgt_check.config.judge import JudgingConfig
from pgt_check.verdict.accuracy_text import _fmt, _need, accuracy_sentences  # re-exported
from pgt_check.verdict.result import RunResult
from pgt_check.verdict.shared import SharedChecks
from pgt_check.verdict.status import NOT_CHECKED

logger = logging.getLogger(__name__)

@dataclass(frozen=True)
class Percentiles:
    p50: float | None
    p90: float | None
    max: float | None

    @staticmethod
    def of(values: Sequence[float]) -> Percentiles:
        a = np.asarray([v for v in values if v is not None and math.isfinite(v)], np.float64)
        if not len(a):
            return Percentiles(None, None, None)
        return Percentiles(
            float(np.percentile(a, 50)), float(np.percentile(a, 90)), float(np.max(a))
        )


@dataclass(frozen=True)
class SharedSize:
    """One run-level shared error as a size with its 95 % interval (None where not measured)."""

    check: str  # registration, similarity, calibration:<camera>, drift
    status: str
    rotation_deg: float | None = None
    rotation_deg_ci: tuple[float, float] | None = None
    translation: float | None = None
    translation_ci: tuple[float, float] | None = None
    effect_px: float | None = None
    effect_px_ci: tuple[float, float] | None = None
    #: rotation / translation converted from px with the run's sensitivities (drift, which
    #: is measured in px only)
    from_px: bool = False

    def upper(self) -> tuple[float | None, float | None]:
        """Upper 95 % bounds (rotation deg, translation units), None where unknown."""
        r = self.rotation_deg_ci[1] if self.rotation_deg_ci else self.rotation_deg
        t = self.translation_ci[1] if self.translation_ci else self.translation
        return r, t


@dataclass(frozen=True)
class DetectionLimits:
    """The smallest errors this run would flag (rotation alone, translation alone)."""

    frame_px: float | None
    frame_deg: float | None
    frame_units: float | None
    shared_px: float | None
    shared_deg: float | None
    shared_units: float | None
    #: median per-frame noise (what one frame cannot tell from zero)
    noise_px: float | None
    noise_deg: float | None
    noise_units: float | None
    px_per_deg: float | None
    px_per_unit: float | None
    points_px_per_deg: float | None
    points_px_per_unit: float | None
    how: str
    #: why the shared limits are not stated ("" when they are)
    shared_note: str = ""


@dataclass(frozen=True)
class RunAccuracy:
    """summary.json -> ``accuracy`` (``to_json``) and the sentences the CLI prints."""

    n_frames: int
    n_bounded: int
    within_deg: float | None
    within_units: float | None
    #: where X / Y come from: "required" (--require-accuracy), "p90_pass": the 90th
    #: percentile of the PASS frames' bounds, or "p90_all": of all bounded frames (none PASS)
    within_from: str
    n_within: int
    rotation_bound_deg: Percentiles
    translation_bound: Percentiles
    effect_bound_px: Percentiles
    shared: tuple[SharedSize, ...]
    limits: DetectionLimits
    gate_passed: bool | None = None
    gate_explanation: str = ""
    sentences: tuple[str, ...] = field(default=())

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["shared"] = [asdict(s) for s in self.shared]
        d["sentences"] = list(self.sentences)
        return d


def _num(x: Any) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _ci(x: Any) -> tuple[float, float] | None:
    if not isinstance(x, (list, tuple)) or len(x) != 2:
        return None
    a, b = _num(x[0]), _num(x[1])
    return None if a is None or b is None else (a, b)


def _median(values: Sequence[Any]) -> float | None:
    a = [v for v in (_num(x) for x in values) if v is not None]
    return float(np.median(a)) if a else None


def shared_sizes(
    shared: SharedChecks | None, px_per_deg: float | None, px_per_unit: float | None
) -> tuple[SharedSize, ...]:
    """The run-level checks that were measured, as sizes with intervals."""
    if shared is None:
        return ()
    out = []
    for key, e in (("registration", shared.registration), ("similarity", shared.similarity)):
        if e.status == NOT_CHECKED:
            continue
        out.append(
            SharedSize(
                key, str(e.status), _num(e.angle_deg), _ci(e.angle_deg_ci),
                _num(e.translation), _ci(e.translation_ci),
                _num(e.effect_px), _ci(e.effect_px_ci),
            )  # fmt: skip
        )
    cams = shared.calibration
    for cam, c in sorted(cams.items()):
        if c.status == NOT_CHECKED:
            continue
        t = c.translation
        tn = _num(np.linalg.norm(np.asarray(t, float))) if isinstance(t, list) else None
        out.append(
            SharedSize(
                "calibration" if len(cams) == 1 else f"calibration ({cam})", str(c.status),
                _num(c.rotation_deg),
                _ci(c.rotation_deg_ci), tn, None, _num(c.effect_px),
                _ci(c.effect_px_ci),
            )  # fmt: skip
        )
    d = shared.drift
    if d.status != NOT_CHECKED:
        worst = max((p for p in d.per_frame if _num(p.effect_px) is not None),
                    key=lambda p: cast(float, p.effect_px), default=None)
        if worst is not None:
            px, lo = _num(worst.effect_px), _num(worst.lo_px)
            assert px is not None  # a finite effect (filtered above)
            ci = None if lo is None else (lo, px + (px - lo))
            out.append(
                SharedSize(
                    "drift", str(d.status),
                    None if not px_per_deg else px / px_per_deg,
                    None if not (ci and px_per_deg) else (ci[0] / px_per_deg, ci[1] / px_per_deg),
                    None if not px_per_unit else px / px_per_unit,
                    None if not (ci and px_per_unit) else (ci[0] / px_per_unit,
                                                           ci[1] / px_per_unit),
                    px, ci, from_px=True,
                )  # fmt: skip
            )
    return tuple(out)


#: one-sided 95 % point of the standard normal (a frame's lognormal spread over error axes)
_Z95 = 1.6448536269514722


def pooled_detection_size(
    rows: Sequence[Mapping[str, Any]], threshold_px: float, noise_px: float | None,
    mid_key: str, low_key: str, q: float = 0.95,
) -> float | None:
    """The error size (deg or units) flagged in a share ``q`` of (frame, error axis) pairs.

    Each frame flags an error once its corner error exceeds its threshold plus the run's
    median bootstrap noise ``noise_px`` (a frame's own noise is its pose fit's, which on
    frames with little evidence reaches tens of px while their corner error does not): at
    ``e / g`` for an axis of sensitivity ``g``. Over error axes the frame's size is taken as lognormal through its
    median (``mid_key`` sensitivity) and 95 % point (``low_key``, the 5 % quantile of the
    sensitivities); the frames' distributions are pooled with equal weight and the pooled
    ``q`` point is found by bisection. None without a frame that has both sensitivities."""
    mus, sigmas = [], []
    for r in rows:
        mid, low = _num(r.get(mid_key)), _num(r.get(low_key))
        if not mid or not low or mid <= 0 or low <= 0:
            continue
        e = (_num(r.get("threshold_px")) or threshold_px) + (noise_px or 0.0)
        mus.append(math.log(e / mid))
        sigmas.append(max(math.log(mid / low), 0.0) / _Z95)
    if not mus:
        return None
    from scipy.special import ndtr

    mu, sg = np.asarray(mus), np.asarray(sigmas)

    def share(log_size: float) -> float:
        z = np.where(sg > 0, (log_size - mu) / np.where(sg > 0, sg, 1.0),
                     np.where(log_size >= mu, np.inf, -np.inf))
        return float(np.mean(ndtr(z)))  # the standard normal CDF, elementwise

    lo, hi = float(np.min(mu - 6 * sg)) - 1.0, float(np.max(mu + 6 * sg)) + 1.0
    for _ in range(60):
        mid_log = 0.5 * (lo + hi)
        lo, hi = (mid_log, hi) if share(mid_log) < q else (lo, mid_log)
    return math.exp(hi)


#: why a run that removes a calibration estimated on its own frames states no shared limit
NOT_SEPARABLE = (
    "not stated: the calibration removed (--remove-calibration) is estimated on the same "
    "frames and absorbs the part of a shared error that moves the images as a calibration "
    "error does; calibrate on a trusted run and pass --calibration-from"
)


def detection_limits(
    rows: Sequence[Mapping[str, Any]],
    threshold_px: float,
    shared: SharedChecks | None,
    calibration_removed: bool = False,
) -> DetectionLimits:
    """This run's detection limits from its own noise (module docstring). With
    ``calibration_removed`` (a calibration estimated on this run's frames removed; not a
    trusted one) no shared limit is stated (``NOT_SEPARABLE``): on 7-Scenes the
    self-test found a shared translation of twice the limit the registration check alone
    supports absorbed by the removal (reports/accuracy.md)."""
    noise_px = _median([r.get("acc_noise_px") for r in rows])
    # a single frame's limit: flagged in 95 % of (frame, error axis) pairs, each frame at its
    # own threshold + the median noise, with its own sensitivities (a limit at the median
    # frame and one axis was met well above 1x by the self-test: reports/accuracy.md)
    frame_deg = pooled_detection_size(rows, threshold_px, noise_px, "acc_px_per_deg",
                                      "acc_low_px_per_deg")
    frame_units = pooled_detection_size(rows, threshold_px, noise_px, "acc_px_per_unit",
                                        "acc_low_px_per_unit")
    # the shared limit: the registration check's own sensitivity to a world rotation /
    # translation (``world_sensitivity``, stored with the registration entry by judge_run);
    # else the frames' camera-frame sensitivity at their points
    reg = shared.registration if shared is not None else None
    reg_s = reg.sensitivity if reg is not None else None
    pts_ppd = (_num(reg_s.px_per_deg) if reg_s else None) or _median(
        [r.get("acc_pts_px_per_deg") for r in rows])
    pts_ppu = (_num(reg_s.px_per_unit) if reg_s else None) or _median(
        [r.get("acc_pts_px_per_unit") for r in rows])
    frame_px = None if noise_px is None else threshold_px + noise_px
    shared_px = None
    thr_shared = _num(shared.threshold_px) if shared is not None else None
    ci = _ci(reg.effect_px_ci) if reg is not None else None
    note = NOT_SEPARABLE if calibration_removed else ""
    if thr_shared is not None and ci is not None and not note:
        shared_px = thr_shared + 0.5 * (ci[1] - ci[0])

    def conv(px: float | None, per: float | None) -> float | None:
        return None if px is None or not per else px / per

    def per(size: float | None) -> float | None:  # the sensitivity the limit amounts to
        return None if frame_px is None or not size else frame_px / size

    return DetectionLimits(
        frame_px, frame_deg, frame_units,
        shared_px, conv(shared_px, pts_ppd), conv(shared_px, pts_ppu),
        noise_px, _median([r.get("acc_noise_deg") for r in rows]),
        _median([r.get("acc_noise_t") for r in rows]), per(frame_deg), per(frame_units),
        pts_ppd, pts_ppu,
        "single frame: the rotation alone / translation alone flagged in 95 % of (frame, "
        "error axis) pairs: each frame flags an error once its corner error (its points' "
        "image motion fitted by a homography, as the check measures it) exceeds its "
        "threshold + the median per-frame bootstrap noise; per frame lognormal over error axes through its "
        "median and 5 % sensitivities, pooled over the frames; shared: shared threshold + "
        "half-width of the registration fit's 95 % interval (px), turned with the image "
        "effect of a world rotation about the camera centroid / a world translation as the "
        "registration check measures it, about / along the world axis where it is smallest",
        note,
    )  # fmt: skip


def run_accuracy(
    result: RunResult, shared: SharedChecks | None, config: JudgingConfig, threshold_px: float
) -> RunAccuracy:
    """The run's accuracy statement from its verdicts (each frame's verdict, threshold and
    ``FrameBound``) and the run-level checks as reported (``shared``)."""
    rows = [
        {"verdict": f.verdict, "threshold_px": f.threshold_px, **f.bound.columns()}
        for f in result.frames
    ]
    return accuracy_of_rows(rows, shared, config, threshold_px)


def accuracy_of_rows(
    rows: Sequence[Mapping[str, Any]],
    shared: SharedChecks | None,
    config: JudgingConfig,
    threshold_px: float,
) -> RunAccuracy:
    """``run_accuracy`` over the frames' columns (``verdict``, ``threshold_px`` and the
    ``ACCURACY_COLUMNS`` of frames.csv: a stored run's rows, or the test's)."""
    bounded = [
        r for r in rows
        if _num(r.get("acc_rot_bound_deg")) is not None and _num(r.get("acc_t_bound")) is not None
    ]  # fmt: skip
    rot = [float(r["acc_rot_bound_deg"]) for r in bounded]
    tra = [float(r["acc_t_bound"]) for r in bounded]
    req = config.gate.require_accuracy_deg, config.gate.require_accuracy_units
    if req != (None, None):
        x, y, src = req[0], req[1], "required"
    else:
        # the level most PASS frames reach (FAIL frames' errors are their own finding)
        ok = [r for r in bounded if r.get("verdict") == "PASS"]
        src = "p90_pass" if ok else "p90_all"
        ok = ok or bounded
        x = float(np.percentile([float(r["acc_rot_bound_deg"]) for r in ok], 90)) if ok else None
        y = float(np.percentile([float(r["acc_t_bound"]) for r in ok], 90)) if ok else None
    n_within = sum(
        1 for a, b in zip(rot, tra, strict=True)
        if (x is None or a <= x) and (y is None or b <= y)
    )  # fmt: skip
    # a trusted calibration (--calibration-from, which wins over --remove-calibration) is not
    # estimated on these frames: it absorbs nothing of their shared error (#39 item 11)
    rc = config.run_checks
    limits = detection_limits(rows, threshold_px, shared,
                              rc.remove_calibration and not rc.calibration_from)
    sizes = shared_sizes(shared, limits.points_px_per_deg, limits.points_px_per_unit)
    acc = RunAccuracy(
        len(rows), len(bounded), x, y, src, n_within if bounded else 0,
        Percentiles.of(rot), Percentiles.of(tra),
        Percentiles.of([float(r["acc_px_bound"]) for r in bounded if _num(r.get("acc_px_bound"))]),
        sizes, limits,
    )  # fmt: skip
    passed, why = (None, "")
    if req != (None, None):
        passed, why = accuracy_gate(rows, acc, config.gate)
    acc = RunAccuracy(**{**acc.__dict__, "gate_passed": passed, "gate_explanation": why})
    return RunAccuracy(**{**acc.__dict__, "sentences": tuple(accuracy_sentences(acc))})


def accuracy_gate(
    rows: Sequence[Mapping[str, Any]], acc: RunAccuracy, config: GateConfig
) -> tuple[bool, str]:
    """``--require-accuracy``: fails when more than ``max_fail_fraction`` of the frames have a
    95 % bound above the required accuracy, or none at all (UNVERIFIABLE frames are left to
    ``max_unverifiable_fraction``), or when a shared error's upper 95 % bound exceeds it.
    Fails closed: a frame without a bound is not verified to the required accuracy."""
    x, y = config.require_accuracy_deg, config.require_accuracy_units
    judged = [r for r in rows if r.get("verdict") != "UNVERIFIABLE"]
    over = 0
    unbounded = 0
    for r in judged:
        a, b = _num(r.get("acc_rot_bound_deg")), _num(r.get("acc_t_bound"))
        if a is None or b is None:
            unbounded += 1
        elif (x is not None and a > x) or (y is not None and b > y):
            over += 1
    total = max(len(rows), 1)
    frac = (over + unbounded) / total
    need = _need(x, y)
    for s in acc.shared:
        if s.from_px or s.status == "not_checked":
            continue
        ru, tu = s.upper()
        if (x is not None and ru is not None and ru > x) or (
            y is not None and tu is not None and tu > y
        ):
            return False, (
                f"accuracy: the shared {s.check} error may be as large as "
                f"{_fmt(ru)} deg / {_fmt(tu)} units (95 %), above the required {need}"
            )
    if not frac <= config.max_fail_fraction:
        return False, (
            f"accuracy: {over + unbounded} of {len(rows)} frames ({frac:.3f} > max "
            f"{config.max_fail_fraction:.3f}) are not verified to {need} at 95 % "
            f"({over} with a larger bound, {unbounded} without absolute evidence for a bound)"
        )
    return True, (
        f"accuracy: {len(judged) - over - unbounded} of {len(rows)} frames verified to {need} "
        f"at 95 % (fraction not verified {frac:.3f} <= max {config.max_fail_fraction:.3f})"
    )
