"""The judging sections of the run config, grouped as a user thinks of them: the per-frame
verdict (``verdict``), the gate (``gate``), the run-level checks with their refinement
(``run_checks``) and the pose corrections (``correct``); ``MOVED_KEYS`` maps the older layout.
Re-exported by ``pgt_check.config``, where ``RunConfig`` composes them with the measurement
sections.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Protocol

from pgt_check.config.load import check_range as _check_range

__all__ = ["MAX_UNVERIFIABLE_DEFAULT", "MOVED_KEYS", "CorrectConfig", "GateConfig",
           "JudgingConfig", "RunChecksConfig", "VerdictConfig"]


#: default gate limit on the UNVERIFIABLE share: wide of what the shared real datasets give
#: with default settings, and it fails a run where most frames cannot be checked (a run with no
#: verified frame always fails; README "CI gate")
MAX_UNVERIFIABLE_DEFAULT = 0.5


@dataclass(frozen=True)
class VerdictConfig:
    """The per-frame verdict (``pgt_check.verdict.decide``): thresholds and evidence minimums."""

    #: PASS threshold on the corner error in original photo pixels; None = rel_diag * diagonal
    threshold_px: float | None = None
    threshold_rel_diag: float = 0.02
    #: render coverage below this fraction -> UNVERIFIABLE(low_coverage), or FAIL(off_mesh) when
    #: it is also at most a quarter of what its neighbouring frames' renders cover and they see
    #: the mesh well (``verdict/off_mesh.py``: a gross pose error, not missing evidence)
    min_coverage: float = 0.05
    min_inliers: int = 15
    min_inlier_ratio: float = 0.0
    #: a FAIL of any path with at least this many homography inliers is a FAIL, whichever path
    #: has more inliers (a confident FAIL is never overruled)
    confident_inliers: int = 40
    #: frames per evidence path measured again at poses moved by a known amount, to check that
    #: the path tells right from wrong on this run; a path that does not decides no frame
    #: (``path_cannot_separate``, ``verdict/separation.py``); 0 = off
    separation_frames: int = 8

    def __post_init__(self) -> None:
        _check_range("verdict.threshold_px", self.threshold_px, 0, lo_open=True)
        _check_range("verdict.threshold_rel_diag", self.threshold_rel_diag, 0, lo_open=True)
        _check_range("verdict.min_coverage", self.min_coverage, 0, 1)
        _check_range("verdict.min_inliers", self.min_inliers, 0)
        _check_range("verdict.min_inlier_ratio", self.min_inlier_ratio, 0, 1)
        _check_range("verdict.confident_inliers", self.confident_inliers, 0)
        _check_range("verdict.separation_frames", self.separation_frames, 0, 10_000)

    def threshold_for(self, width: int, height: int) -> float:
        """The PASS threshold in original photo pixels for an image of this size."""
        if self.threshold_px is not None:
            return float(self.threshold_px)
        return float(self.threshold_rel_diag * math.hypot(width, height))


@dataclass(frozen=True)
class GateConfig:
    """The run's gate (exit code, JUnit): the shares of FAIL / UNVERIFIABLE frames it allows,
    internal errors, and optionally a required pose accuracy (``verdict.run_stats.gate``,
    ``verdict.accuracy``)."""

    #: the gate passes while FAIL frames / all frames <= this
    max_fail_fraction: float = 0.0
    #: and while UNVERIFIABLE frames / all frames <= this (1.0 = never gate on them). The
    #: default was chosen from the shared real datasets (see README "CI gate")
    max_unverifiable_fraction: float = MAX_UNVERIFIABLE_DEFAULT
    #: and while frames with internal_error / worker_crashed <= this (a crash is never "fine")
    max_internal_errors: int = 0
    #: ``--require-accuracy DEG,UNITS``: the gate also fails when more than
    #: ``max_fail_fraction`` of the frames, or a shared error, are not verified to within this
    #: rotation (deg) / camera-centre distance (scene units) at 95 % (``verdict.accuracy``);
    #: None = not required
    require_accuracy_deg: float | None = None
    require_accuracy_units: float | None = None

    def __post_init__(self) -> None:
        _check_range("gate.max_fail_fraction", self.max_fail_fraction, 0, 1)
        _check_range("gate.max_unverifiable_fraction", self.max_unverifiable_fraction, 0, 1)
        _check_range("gate.max_internal_errors", self.max_internal_errors, 0)
        _check_range("gate.require_accuracy_deg", self.require_accuracy_deg, 0, 180,
                     lo_open=True)
        _check_range("gate.require_accuracy_units", self.require_accuracy_units, 0,
                     lo_open=True)


@dataclass(frozen=True)
class RunChecksConfig:
    """The run-level checks of errors many frames share (registration, drift, calibration;
    ``pgt_check.verdict.shared``) and the refinement of a failed registration estimate
    (``pgt_check.correct.registration``); docs/run-level-checks.md."""

    #: run the checks (off: relative evidence alone leaves frames UNVERIFIABLE)
    enabled: bool = True
    #: their threshold in photo px; None = threshold_rel x the per-frame threshold (pooled
    #: evidence is precise, and an error all frames share matters more)
    threshold_px: float | None = None
    threshold_rel: float = 0.15
    #: judge frames after removing the estimated per-camera calibration error (absolute paths)
    remove_calibration: bool = False
    #: the calibration error also has a camera-frame translation (the photos come from a
    #: camera beside the sensor whose poses are given, e.g. RGB beside depth); fitted where the
    #: points' depths differ enough. Off by default: for cameras circling the scene it can
    #: mimic a world rotation, which would then be taken for calibration
    calibration_translation: bool = False
    #: a trusted run's summary.json: its per-camera calibration estimate is removed instead of
    #: one estimated on this run (which views that cannot separate calibration from
    #: registration would let absorb a misregistration)
    calibration_from: str | None = None
    #: when the registration check fails: at most this many rounds of measuring frames again
    #: at the poses the estimate corrects and fitting what is left, stopping once what is left
    #: is below the shared threshold twice: the first estimate's rotation / translation split
    #: is far off where the misregistration zooms the images (reports/shared_errors.md);
    #: bounded in time by ``correct.budget``. 0 (default): deferred, so that a failing run pays
    #: only for what it measured (a round costs about what the main pass's evidence cost:
    #: reports/pipeline_timing.md); ``--registration-rounds 8 --resume`` measures only the
    #: rounds and writes registered_trajectory.txt
    refine_rounds: int = 0
    #: frames measured per round (evenly spaced; the pooled fit needs a few dozen)
    refine_frames: int = 30

    def __post_init__(self) -> None:
        _check_range("run_checks.threshold_px", self.threshold_px, 0, lo_open=True)
        _check_range("run_checks.threshold_rel", self.threshold_rel, 0, lo_open=True)
        _check_range("run_checks.refine_rounds", self.refine_rounds, 0, 1000)
        _check_range("run_checks.refine_frames", self.refine_frames, 3, 100_000)

    @property
    def removes_calibration(self) -> bool:
        """Whether the verdicts take a calibration error out (this run's or a trusted one)."""
        return bool(self.remove_calibration or self.calibration_from)


@dataclass(frozen=True)
class CorrectConfig:
    """Pose corrections after the verdicts (``pgt_check.correct.frames``): iterate render -> raw
    match -> PnP from each frame's PnP estimate; writes corrected_trajectory.txt."""

    #: which frames: "fail" (FAIL verdicts), "all" (every measured frame) or "none"
    frames: Literal["none", "fail", "all"] = "fail"
    #: render -> match -> PnP rounds per frame; each round's render is enhanced with the next
    #: of up to ``correct.frames.CORRECTION_REFERENCES`` (4) vouched references, so 4 rounds
    #: use each of them once
    rounds: int = 4
    #: PnP bootstrap resamples for the uncertainty (0 = the last update only)
    bootstrap: int = 12
    #: the registration refinement's rounds together (``run_checks.refine_rounds``), and the
    #: per-frame corrections together, may each take at most this multiple of the main pass's
    #: measuring time (the frames' summed ``timings.total``): a round / frame is not started
    #: when those so far plus one more (as long as the mean so far) would exceed it; the first
    #: always runs (0 = no bound). The rounds also stop when what is left grows (the estimate
    #: oscillates)
    budget: float = 2.0
    #: longest image side of the corrections' renders and matching, where larger than
    #: ``match.resize_max`` (None / 0 = the original size): a pose is estimated from these
    #: matches, not only checked, so they work finer than the verdict's matching
    resize_max: int | None = 640

    def __post_init__(self) -> None:
        if self.resize_max == 0:  # 0 = the original size (as match.resize_max)
            object.__setattr__(self, "resize_max", None)
        _check_range("correct.resize_max", self.resize_max, 16, 65_536)
        _check_range("correct.rounds", self.rounds, 1, 1000)
        _check_range("correct.bootstrap", self.bootstrap, 0, 10_000)
        _check_range("correct.budget", self.budget, 0, 1e6)


class JudgingConfig(Protocol):
    """What the verdict stage reads of the settings: its judging sections, and nothing else
    (``verdict.judge_run``, ``run_shared_checks``, the run-level checks, ``judge_outcome``).
    ``RunConfig`` has them; a type checker refuses a judging function that reads more."""

    @property
    def verdict(self) -> VerdictConfig: ...

    @property
    def gate(self) -> GateConfig: ...

    @property
    def run_checks(self) -> RunChecksConfig: ...


#: settings of the layout before the gate and the run-level checks had sections of their own
#: (config.json of older runs, older config files): old (section, key) -> new (section, key)
MOVED_KEYS: dict[tuple[str, str], tuple[str, str]] = {
    ("verdict", "max_fail_fraction"): ("gate", "max_fail_fraction"),
    ("verdict", "max_unverifiable_fraction"): ("gate", "max_unverifiable_fraction"),
    ("verdict", "max_internal_errors"): ("gate", "max_internal_errors"),
    ("verdict", "require_accuracy_deg"): ("gate", "require_accuracy_deg"),
    ("verdict", "require_accuracy_units"): ("gate", "require_accuracy_units"),
    ("verdict", "shared_checks"): ("run_checks", "enabled"),
    ("verdict", "shared_threshold_px"): ("run_checks", "threshold_px"),
    ("verdict", "shared_threshold_rel"): ("run_checks", "threshold_rel"),
    ("verdict", "remove_calibration"): ("run_checks", "remove_calibration"),
    ("verdict", "calibration_translation"): ("run_checks", "calibration_translation"),
    ("verdict", "calibration_from"): ("run_checks", "calibration_from"),
    ("correct", "registration_rounds"): ("run_checks", "refine_rounds"),
    ("correct", "registration_frames"): ("run_checks", "refine_frames"),
}
