"""Can each evidence path tell right from wrong on this run? (issue #38 item 5)

A path whose corner error does not follow the pose (MaRINeR on a colourless 7-Scenes mesh: per
frame AUC 0.47, 4 of 24 correct frames PASS) must not decide a verdict: its PASS and its FAIL
are both chance. The run checks each path that decides frames, with frames moved by known
amounts (the self-test's machinery, ``verdict.self_test``), against a null that needs no
constant fitted to a scene:

* **the probes**: up to ``n`` frames on which the path measured a homography (evenly spaced
  along the run, chosen without looking at its error) are measured again at their pose rotated
  by +theta and -theta about one random axis in the image plane, theta moving the image centre
  by ``MOVE_MULTIPLE`` x the frame's threshold (``probe_plan``; the runner measures them,
  ``stages.remeasure.separation_stage``, with the path forced on and, for a reference path, the same
  reference).
* **the statistic**: per frame the rank r of e0, the path's corner error at the given pose,
  among (e0, e+, e-), its errors at the given and the two moved poses (1 = smallest; a moved
  copy the path cannot align ranks above any error). A path that measures the pose gives r = 1
  on a correct frame and r <= 2 on a wrong one: |e + m|^2 + |e - m|^2 = 2 |e|^2 + 2 |m|^2, so
  at most one of the two moves can bring a wrong frame closer (a single random move could
  cancel it as often as not). For a path whose error does not follow the pose the three are
  exchangeable: r is 1, 2 or 3 with equal chance where all three align, and a copy that does
  not align is as likely at any pose (``rank_probabilities``, with the path's failure rate on
  this run's given poses, ``failure_rate``).
* **the test**: the rank sum T = sum r against its exact null (independent ranks with those
  probabilities: the run's own values and failure rate, nothing fitted to a scene),
  one-sided at ``ALPHA``. Not significant: the path cannot separate on this run (``failed``):
  it decides no frame (its outcome is UNVERIFIABLE ``path_cannot_separate``; another path that
  separates may decide). Fewer than ``MIN_PAIRS`` usable frames: ``not_tested`` (the path keeps
  deciding; the summary says so).

The probe measurements are stored (``OUTPUTS.separation_probes``) so ``pgt-check report``
judges them again with its own settings.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.sequences import evenly_spaced
from pgt_check.config import VerdictConfig
from pgt_check.measure.record import FrameMeasurement
from pgt_check.output_layout import OUTPUTS
from pgt_check.verdict.judgement import CANNOT_SEPARATE  # re-exported: the reason prefix

#: the probe moves the image centre by this x the frame's threshold (a clear error: a path
#: that cannot see it cannot tell a PASS from a FAIL; large against the errors of wrong frames,
#: so that neither move brings most of them closer)
MOVE_MULTIPLE = 4.0
#: significance of the sign test (one-sided)
ALPHA = 0.05
#: fewer usable frames than this: the path is not tested (5 frames all ranked first:
#: p = 3^-5 = 0.004; one ranked second: 0.025)
MIN_PAIRS = 5
#: frames probed per path by default (0 = off; ``verdict.separation_frames``): with 8, T <= 11
#: (at most three frames ranked second) is significant, p = 0.024
DEFAULT_FRAMES = 8
#: the paths probed
PATHS = ("raw", "enhanced", "edges")
SEED = 38

PASSED, FAILED, NOT_TESTED = "passed", "failed", "not_tested"


@dataclass(frozen=True)
class ProbeJob:
    """One moved copy to measure: frame ``frame_id`` rotated by ``angle_deg`` about ``axis``
    (camera axes, in the image plane), for the ``paths`` probed on it; ``key``: its unique id."""

    key: str
    frame_id: str
    sign: int
    axis: tuple[float, float, float]
    angle_deg: float
    paths: tuple[str, ...]
    #: the enhanced path's reference in the frame's own measurement ("" if none)
    reference_id: str = ""


@dataclass(frozen=True)
class Probe:
    """A measured ``ProbeJob`` (its measurement under the frame's own id)."""

    job: ProbeJob
    measurement: FrameMeasurement

    def to_json(self) -> dict[str, Any]:
        j = self.job
        m = self.measurement.to_json()
        m["evidence"] = None  # the probe's error is what counts; its points are large
        return {"key": j.key, "frame_id": j.frame_id, "sign": j.sign, "axis": list(j.axis),
                "angle_deg": j.angle_deg, "paths": list(j.paths),
                "reference_id": j.reference_id, "measurement": m}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Probe:
        job = ProbeJob(str(d["key"]), str(d["frame_id"]), int(d["sign"]),
                       tuple(float(x) for x in d["axis"]),  # type: ignore[arg-type]  # (3,)
                       float(d["angle_deg"]),
                       tuple(str(p) for p in d["paths"]), str(d.get("reference_id") or ""))
        return cls(job, FrameMeasurement.from_json(d["measurement"]))


@dataclass(frozen=True)
class PathSeparation:
    """One path's test: ``status`` passed / failed / not_tested, the usable frames, how many
    were measured further off at both moved poses (``n_higher``), the rank test's p-value, the medians of the path's
    error at the given and at the moved poses, and the move (px at the image centre)."""

    path: str
    status: str
    n_frames: int
    n_higher: int
    p_value: float | None
    move_px: float | None
    median_given_px: float | None = None
    median_moved_px: float | None = None
    frames: tuple[str, ...] = ()
    #: the sum of the given poses' ranks (module docstring)
    rank_sum: int = 0
    #: the path's failure rate on the run's given poses (the null's, ``rank_probabilities``)
    failure_rate: float = 0.0

    @property
    def reason(self) -> str:
        """The UNVERIFIABLE reason of a frame whose deciding path failed the test."""
        return (f"{CANNOT_SEPARATE} (the {self.path} path measured {self.n_higher} of "
                f"{self.n_frames} frames moved by {_g(self.move_px)} px further off both ways "
                f"than at their pose, rank test p = {_g(self.p_value)}: it does not tell right from wrong on "
                "this run)")

    def to_json(self) -> dict[str, Any]:
        return {"path": self.path, "status": self.status, "n_frames": self.n_frames,
                "n_higher": self.n_higher, "p_value": self.p_value, "move_px": self.move_px,
                "median_given_px": self.median_given_px,
                "median_moved_px": self.median_moved_px, "rank_sum": self.rank_sum,
                "failure_rate": self.failure_rate,
                "frames": list(self.frames)}


@dataclass(frozen=True)
class Separation:
    """Every probed path's ``PathSeparation`` (empty: the check did not run)."""

    paths: tuple[PathSeparation, ...] = ()
    alpha: float = ALPHA
    move_multiple: float = MOVE_MULTIPLE
    barred_frames: int = field(default=0, compare=False)

    @property
    def barred(self) -> dict[str, str]:
        """path -> the reason of the frames it cannot decide (the paths that failed)."""
        return {p.path: p.reason for p in self.paths if p.status == FAILED}

    def summary(self) -> dict[str, Any]:
        """summary.json -> ``path_separation``."""
        return {
            "how": "each path's corner error at frames rotated by +/- theta (moving the image "
                   f"centre by {self.move_multiple:g} x the threshold) against the error at "
                   "their pose: the given pose's rank among the three per frame, rank sum "
                   "against its exact null (the three exchangeable), one-sided at alpha "
                   f"{self.alpha:g}; n_higher: frames measured further off at both moved "
                   f"poses; a path that fails cannot decide ({CANNOT_SEPARATE})",
            "paths": {p.path: p.to_json() for p in self.paths},
            "barred": sorted(self.barred),
            "frames_barred": self.barred_frames,
            "sentences": self.sentences(),
        }

    def sentences(self) -> list[str]:
        """One line per path for the CLI and the report."""
        out = []
        for p in self.paths:
            if p.status == NOT_TESTED:
                out.append(f"the {p.path} path was not tested for separation ({p.n_frames} "
                           f"usable frames, {MIN_PAIRS} needed)")
                continue
            verb = "separates" if p.status == PASSED else "CANNOT SEPARATE: it decides no frame"
            out.append(f"the {p.path} path {verb}: {p.n_higher} of {p.n_frames} frames moved by "
                       f"{_g(p.move_px)} px measured further off both ways (p = "
                       f"{_g(p.p_value)}; median "
                       f"{_g(p.median_given_px)} px at the poses, {_g(p.median_moved_px)} px "
                       "moved)")
        return out


def _g(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.3g}"


def rank_probabilities(q: float = 0.0) -> tuple[float, float, float]:
    """P(r = 1, 2, 3) of the given pose's rank under the null (the path does not see the pose)
    when it fails to align any pose with probability ``q`` (its failure rate on this run's
    given poses) and the given pose aligned: both moved copies align (1 - q)^2: r uniform; one
    fails 2 q (1 - q): r = 1 or 2; both fail q^2: r = 1 (a failure ranks above any error)."""
    q = min(max(float(q), 0.0), 1.0)
    both = (1.0 - q) ** 2 / 3.0
    return both + q * (1.0 - q) + q * q, both + q * (1.0 - q), both


def rank_sum_p(rank_sum: int, n: int, q: float = 0.0) -> float:
    """P(T <= rank_sum) for T the sum of ``n`` independent ranks with the null probabilities
    ``rank_probabilities(q)`` (exact; q = 0: uniform {1, 2, 3})."""
    if n <= 0:
        return 1.0
    probs = rank_probabilities(q)
    dist = np.zeros(2 * n + 1)  # of T - n
    dist[0] = 1.0
    for _ in range(n):
        nxt = np.zeros_like(dist)
        for k in range(3):
            nxt[k:] += probs[k] * dist[: len(dist) - k]
        dist = nxt
    return float(min(1.0, dist[: max(0, rank_sum - n) + 1].sum()))


def failure_rate(measurements: Sequence[FrameMeasurement], name: str,
                 config: VerdictConfig) -> float:
    """The share of the frames the path ran on where it did not align (no usable homography):
    the null's failure probability (``rank_probabilities``), from the run's own measurements."""
    errs = [e for m in measurements if (e := _error(m, name, config)) is not None]
    return float(np.mean([math.isinf(e) for e in errs])) if errs else 0.0


def _path_ok(m: FrameMeasurement, name: str) -> bool:
    p = getattr(m, name, None)
    return p is not None and not p.reason and p.corner_error_px is not None and \
        math.isfinite(p.corner_error_px)


def _focal(m: FrameMeasurement) -> float | None:
    if not m.intrinsics:
        return None
    f = 0.5 * (float(m.intrinsics[0]) + float(m.intrinsics[1]))
    return f if f > 0 else None


def probe_plan(
    measurements: Sequence[FrameMeasurement],
    config: VerdictConfig,
    n: int,
    paths: Iterable[str] | None = None,
) -> list[ProbeJob]:
    """The moved copies to measure (module docstring): per path (default: every path with a
    homography on ``MIN_PAIRS`` frames or more: one that decides no frame now may decide once
    another is barred), up to ``n`` frames with a homography of that path, evenly
    spaced, chosen without looking at its error (frames already chosen for another path
    first, so a frame serves several paths with one measurement); each chosen frame twice
    (+theta, -theta about one seeded random axis in the image plane). [] with ``n`` = 0."""
    if n <= 0:
        return []
    names = set(PATHS if paths is None else paths)
    chosen: dict[str, list[str]] = {}
    for name in (p for p in PATHS if p in names):
        ok = [m.frame_id for m in measurements if _path_ok(m, name) and _focal(m)]
        if len(ok) < MIN_PAIRS:
            continue
        reuse = [f for f in ok if f in chosen]
        pick = evenly_spaced(reuse, n)
        if len(pick) < n:
            pick += evenly_spaced([f for f in ok if f not in chosen], n - len(pick))
        for fid in pick:
            chosen.setdefault(fid, []).append(name)
    rng = np.random.default_rng(SEED)
    jobs = []
    for m in measurements:
        a = rng.uniform(0, 2 * math.pi)  # drawn for every frame: the axis is the frame's own
        if m.frame_id not in chosen:
            continue
        f = _focal(m) or 1.0
        thr = config.threshold_for(m.width, m.height)
        angle = math.degrees(math.atan(MOVE_MULTIPLE * thr / f))
        axis = (math.cos(a), math.sin(a), 0.0)
        ref = m.enhanced.reference_id if m.enhanced is not None else ""
        for sign in (1, -1):
            jobs.append(ProbeJob(f"{m.frame_id}#separation:{'+' if sign > 0 else '-'}",
                                 m.frame_id, sign, axis, sign * angle,
                                 tuple(chosen[m.frame_id]), ref or ""))
    return jobs


def _error(m: FrameMeasurement | None, name: str, config: VerdictConfig) -> float | None:
    """The path's corner error as a probe reads it: None when the path did not run, inf when
    it ran without a usable homography (flagged), else the error."""
    p = None if m is None else m.path(name)
    if p is None:
        return None
    if p.reason or p.n_inliers < config.min_inliers or p.corner_error_px is None or \
            not math.isfinite(p.corner_error_px):
        return math.inf
    return float(p.corner_error_px)


def path_separation(
    measurements: Sequence[FrameMeasurement],
    probes: Sequence[Probe],
    config: VerdictConfig,
) -> Separation:
    """Every probed path's test from the run's measurements and the measured ``probes``
    (module docstring). An empty ``Separation`` without probes."""
    if not probes:
        return Separation()
    by_id = {m.frame_id: m for m in measurements}
    moved: dict[tuple[str, int], Probe] = {(p.job.frame_id, p.job.sign): p for p in probes}
    names = [n for n in PATHS if any(n in p.job.paths for p in probes)]
    out = []
    for name in names:
        fids = list(dict.fromkeys(p.job.frame_id for p in probes if name in p.job.paths))
        given, moved_e, ranks, used, move = [], [], [], [], []
        for fid in fids:
            m = by_id.get(fid)
            e0 = _error(m, name, config)
            ep = [_error(moved[(fid, s)].measurement if (fid, s) in moved else None, name, config)
                  for s in (1, -1)]
            # a moved copy the path cannot align ranks above any error; the null accounts for
            # the path failing as often at any pose (``failure_rate``)
            pair = [e for e in ep if e is not None]
            if e0 is None or not math.isfinite(e0) or len(pair) < len(ep):
                continue
            assert m is not None  # it has an error
            ranks.append(1 + sum(e <= e0 for e in pair))  # a tie counts against the path
            given.append(e0)
            moved_e.extend(pair)
            used.append(fid)
            f = _focal(m)
            if f:
                move.append(f * math.tan(math.radians(abs(moved[(fid, 1)].job.angle_deg))))
        n = len(ranks)
        q = failure_rate(measurements, name, config)
        p_value = rank_sum_p(sum(ranks), n, q) if n else None
        if n < MIN_PAIRS:
            status = NOT_TESTED
        else:
            status = PASSED if p_value is not None and p_value < ALPHA else FAILED
        fin = [x for x in moved_e if math.isfinite(x)]
        out.append(PathSeparation(
            name, status, n, sum(r == 1 for r in ranks), p_value,
            float(np.median(move)) if move else None,
            float(np.median(given)) if given else None,
            float(np.median(fin)) if fin else None,
            tuple(used), sum(ranks), q))
    return Separation(tuple(out))


def save_probes(out: str | Path, probes: Sequence[Probe], fingerprint: str = "") -> Path:
    """Write the probes to ``out / OUTPUTS.separation_probes`` (atomic); returns its path."""
    from pgt_check.common.files import atomic_write_text

    path = Path(out) / OUTPUTS.separation_probes
    doc = {"version": 1, "fingerprint": fingerprint, "probes": [p.to_json() for p in probes]}
    atomic_write_text(path, json.dumps(doc))
    return path


def load_probes(out: str | Path, fingerprint: str | None = None) -> list[Probe]:
    """The probes stored in ``out`` ([] when there are none, or when ``fingerprint`` is given
    and they were measured under another one)."""
    path = Path(out) / OUTPUTS.separation_probes
    if not path.is_file():
        return []
    from pgt_check.common.files import load_json_limited

    doc = load_json_limited(path, 256 * 1024 * 1024, OUTPUTS.separation_probes)
    if fingerprint is not None and doc.get("fingerprint") != fingerprint:
        return []
    return [Probe.from_json(d) for d in doc.get("probes") or ()]
