"""What the registration refinement (``correct.registration``) produces and how the run reports it:
the rounds (``RefineRound``), the refined correction (``RefinedRegistration``), its file
(``registration_refined.json``, reused by a rerun that starts from the same correction), the
summary's registration entry with the refined correction and its ``refinement`` block, and
the registered trajectory.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.files import atomic_write_text
from pgt_check.geometry.transforms import move_pose, rotation_angle_deg
from pgt_check.output_layout import OUTPUTS
from pgt_check.types import Trajectory
from pgt_check.verdict.shared import SharedChecks
from pgt_check.verdict.shared_results import RegistrationCheck

logger = logging.getLogger(__name__)

#: the start correction of a stored refinement must match the main pass's within this
#: (elementwise, absolute) to be reused
SAME_START_ATOL = 1e-6


@dataclass(frozen=True)
class RefineRound:
    """One round: the registration check on evidence measured at the poses corrected so far."""

    round: int
    n_frames: int  # frames measured
    n_evidence: int  # of them with absolute evidence
    status: str  # the residual rigid check (passed: the corrected poses agree with the mesh)
    angle_deg: float | None
    angle_deg_ci: list[float] | None
    translation: float | None
    translation_ci: list[float] | None
    effect_px: float | None
    effect_px_ci: list[float] | None
    time_s: float
    #: the composed correction after this round (None when its residual fit failed)
    total_angle_deg: float | None = None
    total_translation: float | None = None


@dataclass(frozen=True)
class RefinedRegistration:
    """The refined corrections (corrected_world_from_world, nested lists) and their rounds.

    ``start``: the main pass's rigid correction the rounds started from; ``origin``: the
    centroid of the checked camera centres of every measured frame (the refined translation
    is that point's displacement; the first pass's is about the centroid of the frames with
    evidence, a difference of (R - I) times their offset: negligible for small angles);
    ``stopped``: why the rounds ended ("converged", "round limit", "time limit", "not
    converging", or the round whose residual fit did not succeed);
    ``kept``: how many rounds' updates ``rigid`` composes (fewer than ``rounds`` where a later
    update made what is left grow; None = all)."""

    start: list[list[float]]
    rigid: list[list[float]]
    origin: list[float]
    rounds: tuple[RefineRound, ...]
    stopped: str
    fingerprint: str = ""
    frame_ids: tuple[str, ...] = field(default_factory=tuple)
    kept: int | None = None

    @property
    def n_kept(self) -> int:
        """Rounds whose updates ``rigid`` composes."""
        return len(self.rounds) if self.kept is None else self.kept

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["rounds"] = [asdict(r) for r in self.rounds]
        d["frame_ids"] = list(self.frame_ids)
        return d

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> RefinedRegistration:
        return cls(
            start=d["start"],
            rigid=d["rigid"],
            origin=list(d["origin"]),
            rounds=tuple(RefineRound(**r) for r in d.get("rounds", ())),
            stopped=str(d.get("stopped", "")),
            fingerprint=str(d.get("fingerprint", "")),
            frame_ids=tuple(d.get("frame_ids", ())),
            kept=d.get("kept"),
        )


def _summary_of(c: np.ndarray, origin: np.ndarray) -> tuple[float, float, float]:
    """(angle deg, translation of ``origin``, scale) of a rigid / similarity (4, 4)."""
    s = float(np.cbrt(np.linalg.det(c[:3, :3])))
    angle = rotation_angle_deg(c[:3, :3] / s)
    t = float(np.linalg.norm(c[:3, :3] @ origin + c[:3, 3] - origin))
    return angle, t, s


def _refined_entry(
    entry: RegistrationCheck,
    c: np.ndarray,
    origin: np.ndarray,
    last: RefineRound,
    refined: RefinedRegistration,
) -> RegistrationCheck:
    """The registration entry with the refined correction ``c``. The
    intervals: the refined value +- half the width of the last round's interval (approximate:
    the uncertainty of the last residual fit, the earlier rounds' being applied)."""
    angle, t, _ = _summary_of(c, origin)
    t1, rel1 = entry.translation, entry.translation_rel_depth
    depth = t1 / rel1 if t1 and rel1 else None

    def around(value: float, ci: Any) -> list[float] | None:
        if not ci or len(ci) != 2:
            return None
        w = 0.5 * (float(ci[1]) - float(ci[0]))
        return [max(0.0, value - w), value + w]

    t_ci = around(t, last.translation_ci)
    return replace(
        entry,
        angle_deg=angle,
        angle_deg_ci=around(angle, last.angle_deg_ci),
        translation=t,
        translation_ci=t_ci,
        translation_rel_depth=None if depth is None else t / depth,
        translation_rel_depth_ci=None
        if depth is None or t_ci is None
        else [v / depth for v in t_ci],
        corrected_world_from_world=c.tolist(),
        refinement=_refinement_record(entry, refined),
    )


_FIRST_KEYS = (
    "angle_deg", "angle_deg_ci", "translation", "translation_ci", "translation_rel_depth",
    "translation_rel_depth_ci", "scale", "scale_ci", "corrected_world_from_world", "message",
)


def _refinement_record(entry: RegistrationCheck, refined: RefinedRegistration) -> dict[str, Any]:
    """The summary's ``refinement`` block: the first estimate, the rounds, why they stopped."""
    first = entry.to_json()
    return {
        "first_pass": {k: first[k] for k in _FIRST_KEYS},
        "rounds": [asdict(r) for r in refined.rounds],
        "rounds_kept": refined.n_kept,
        "stopped": refined.stopped,
        "n_frames": len(refined.frame_ids) if refined.rounds else 0,
        "file": OUTPUTS.registration_refined,
        "trajectory_file": OUTPUTS.registered_trajectory,
    }


def registration_entries(shared: SharedChecks) -> tuple[RegistrationCheck, RegistrationCheck]:
    """The rigid and the similarity check of the run-level checks."""
    return shared.registration, shared.similarity


def refined_registration(
    entry: RegistrationCheck, refined: RefinedRegistration
) -> RegistrationCheck:
    """The rigid registration check with the refined correction and its ``refinement`` record
    (the status and image effect stay the main pass's, which decided the verdicts); ``entry``
    itself when it has no correction."""
    if entry.corrected_world_from_world is None:
        return entry
    n = len(refined.rounds)
    if refined.n_kept == 0:  # every update undone: the first estimate stands
        did = (f"Refinement stopped after {n} round(s) ({refined.stopped}): the first "
               f"estimate is reported")
        return replace(entry, message=f"{entry.message}. {did}",
                       refinement=_refinement_record(entry, refined))
    last = refined.rounds[refined.n_kept - 1]
    origin = np.asarray(refined.origin, np.float64)
    new = _refined_entry(entry, np.asarray(refined.rigid, np.float64), origin, last, refined)
    rel = new.translation_rel_depth
    message = (
        f"{entry.message}. Refined by measuring {len(refined.frame_ids)} frames "
        f"again at the corrected poses ({n} round(s), {refined.stopped}): "
        f"{new.angle_deg:.2f} deg, {new.translation:.4g} scene units"
        + (f" ({100 * rel:.1f} % of the scene depth)" if rel is not None else "")
        + f" (first estimate {entry.angle_deg:.2f} deg, {entry.translation:.4g}); "
        + (f"the last round found {_px(last.effect_px)} px left ({last.status})"
           if refined.n_kept == n else
           f"round {refined.n_kept + 1} found {_px(refined.rounds[refined.n_kept].effect_px)} "
           f"px left at it ({refined.rounds[refined.n_kept].status})")
    )
    return replace(new, message=message)


def apply_refinement(shared: SharedChecks, refined: RefinedRegistration | None) -> SharedChecks:
    """The run-level checks with the refined rigid correction (``refined_registration``). The
    similarity entry keeps its first estimate: its scale was already right
    (reports/shared_errors.md) and rigid rounds cannot refine a scale."""
    if refined is None:
        return shared
    return shared.with_entries(registration=refined_registration(shared.registration, refined))


def _px(x: float | None) -> str:
    return f"{x if x is not None else float('nan'):.1f}"


def save_refinement(out_dir: str | Path, refined: RefinedRegistration) -> Path:
    path = Path(out_dir) / OUTPUTS.registration_refined
    atomic_write_text(path, json.dumps(refined.to_json(), indent=1) + "\n")  # whole, renamed
    return path


def load_refinement(
    out_dir: str | Path, shared: SharedChecks, fingerprint: str | None = None
) -> RefinedRegistration | None:
    """The stored refinement when it started from this run's rigid correction (and, if
    given, was measured with the same settings); else None (stale or absent)."""
    path = Path(out_dir) / OUTPUTS.registration_refined
    c = registration_entries(shared)[0].corrected_world_from_world
    if not path.is_file() or c is None:
        return None
    try:
        refined = RefinedRegistration.from_json(json.loads(path.read_text()))
    except (ValueError, KeyError, TypeError) as err:
        logger.warning(
            "%s unreadable, the registration refinement is measured again: %s", path, err
        )
        return None
    if fingerprint is not None and refined.fingerprint != fingerprint:
        return None
    if not np.allclose(np.asarray(refined.start), np.asarray(c), atol=SAME_START_ATOL, rtol=0):
        return None
    return refined


def registered_trajectory(trajectory: Trajectory, refined: RefinedRegistration) -> Trajectory:
    """Every frame moved by the refined rigid correction."""
    c = np.asarray(refined.rigid, np.float64)
    frames = tuple(f.with_pose(move_pose(f.world_from_cam, c)) for f in trajectory.frames)
    return Trajectory(frames, trajectory.source, trajectory.format, dict(trajectory.metadata))
