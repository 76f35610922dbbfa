"""The self-test's detection curves and their reading (``verdict.self_test`` measures them).

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

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

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

SINGLE, SHARED = "single_frame", "shared"
ROTATION, TRANSLATION = "rotation", "translation"


@dataclass(frozen=True)
class CurvePoint:
    """One injected size: ``k`` x the stated limit = ``size`` (deg or scene units)."""

    k: float
    size: float
    n: int  # trials (frames; the shared test: both directions, one at k = 0)
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
        "the weakest world axis, the one the limit is derived for, in both directions: two "
        "trials per size), registration check on them; flagged = failed. k_q: where the "
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


def _band_end(points: Sequence[CurvePoint]) -> CurvePoint | None:
    """The point with trials at the largest measured k in [1, 1.3] (the band's upper end)."""
    end = [p for p in points if 1.0 <= p.k <= 1.0 + HELD_TOLERANCE + 1e-9 and p.n > 0]
    return max(end, key=lambda q: q.k) if end else None


def _in_band(k50: float | None, k95: float | None) -> bool:
    """``k_50`` or ``k_95`` within ``HELD_TOLERANCE`` of 1."""
    lo, hi = 1.0 - HELD_TOLERANCE, 1.0 + HELD_TOLERANCE
    return any(k is not None and lo <= k <= hi for k in (k50, k95))


def upper_end_p(points: Sequence[CurvePoint]) -> float | None:
    """P(this few flagged or fewer | 95 % detection) at the band's upper end (``_band_end``;
    exact binomial, one-sided); None when no point with trials lies there."""
    from scipy.stats import binom

    p = _band_end(points)
    return None if p is None else float(binom.cdf(p.flagged, p.n, 0.95))


def judge_curve(k50: float | None, k95: float | None, baseline: float | None,
                upper_p: float | None = None) -> str:
    """held / conservative / understated / shallow / untested (module docstring);
    ``upper_p``: ``upper_end_p`` of the curve (None: no sampling-noise allowance)."""
    if baseline is None or baseline >= 0.5:
        return "untested"
    lo, hi = 1.0 - HELD_TOLERANCE, 1.0 + HELD_TOLERANCE
    if _in_band(k50, k95):
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
    end = _band_end(c.points)
    if c.judgement == "held" and c.upper_p is not None and end is not None \
            and not _in_band(c.k50, c.k95):
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
