"""Which frames vouch for others: a relative result (a frame reprojected through a reference
photo) says only that the frame and its reference agree, so it counts where the reference is a
frame the run passes on its own absolute evidence. Used by the verdicts' second pass
(``verdict.apply``) and by the corrections' choice of references (``correct.frames``)."""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace

from pgt_check.config import VerdictConfig
from pgt_check.enhance.base import Evidence
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.decide import path_outcome
from pgt_check.verdict.judgement import Judgement, Verdict


def vouches(j: Judgement) -> bool:
    """PASS on the frame's own absolute evidence. A PASS through the frame's references says
    only that the two agree: on 7-Scenes (40 % wrong) a correct frame FAILed at 44 px through
    such a neighbour and measured 14 px through one that passed on its own render."""
    return j.verdict is Verdict.PASS and j.evidence == Evidence.ABSOLUTE.value


def vouched_frames(ms: Sequence[FrameMeasurement], judged: Sequence[Judgement]) -> set[str]:
    """The frames whose first-pass verdict is PASS on their own absolute evidence: the only
    references that vouch for another frame's relative result (``vouched_reference``)."""
    return {m.frame_id for m, j in zip(ms, judged, strict=True) if vouches(j)}


def vouched_reference(
    m: FrameMeasurement,
    judgement: Judgement,
    vouched: Collection[str],
    config: VerdictConfig,
) -> FrameMeasurement | None:
    """``m`` judged through another reference, where the reprojected reference that decided
    is not ``vouched`` for (the frames the run passes on their own absolute evidence) and
    another tried reference is: a relative result says only that the frame and its reference
    agree or not, and a reference the run does not pass on its own evidence cannot tell which
    of the two is off (neighbours err together). The other reference's result must be
    verifiable and confident (``confident_inliers``: a weak result would hand the verdict to
    a path that merely does not contradict); the one with the most inliers is taken. None
    when nothing changes.
    """
    p = m.enhanced
    if (
        judgement.decided_by != "enhanced"
        or p is None
        or p.evidence is not Evidence.RELATIVE
        or not m.enhanced_alternatives
        or (p.reference_id or "") in vouched
    ):
        return None
    usable = [
        a
        for a in m.enhanced_alternatives
        if (a.reference_id or "") in vouched
        and a.n_inliers >= config.confident_inliers
        and path_outcome(m, a, config)[0] is not Verdict.UNVERIFIABLE
    ]
    if not usable:
        return None
    alt = max(usable, key=lambda a: a.n_inliers)
    rest = tuple(a for a in m.enhanced_alternatives if a is not alt) + (p,)
    raw_first = m.raw is not None and not m.raw.reason and m.raw.n_inliers > alt.n_inliers
    return replace(
        m,
        enhanced=alt,
        enhanced_alternatives=rest,
        verdict_path="raw" if raw_first else "enhanced",
    )
