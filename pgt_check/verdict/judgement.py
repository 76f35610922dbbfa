"""What a frame's judgement holds: the verdicts, one path's outcome and the ``Judgement``
(``verdict.decide`` makes them; results, reports and the corrections read them)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

#: the reason prefix of a path that cannot tell right from wrong on this run
#: (``verdict.separation.CANNOT_SEPARATE``)
CANNOT_SEPARATE = "path_cannot_separate"


class Verdict(str, Enum):
    PASS = "PASS"
    FAIL = "FAIL"
    UNVERIFIABLE = "UNVERIFIABLE"


class PathOutcome(NamedTuple):
    """What one path alone says (``decide.path_outcome``): its verdict and why."""

    verdict: Verdict
    reason: str


@dataclass(frozen=True)
class Judgement:
    """The verdict of one frame with what it rests on.

    evidence: "absolute" (a path that depends only on the mesh and this pose decided),
    "relative+registration" (a reprojected reference decided, and the run-level registration
    check passed), "relative" (a reprojected reference decided; nothing absolute confirms it),
    or "none". raw_verdict / enhanced_verdict: what each path alone says ("" if it did not run).
    """

    verdict: Verdict
    reason: str
    evidence: str
    raw_verdict: str
    enhanced_verdict: str
    #: the path the verdict rests on (raw, enhanced, edges; "" when none ran)
    decided_by: str = ""
    #: that path's corner error as the verdict compared it (the camera's calibration error
    #: removed where the run removes it), photo px; None without a deciding path or error
    error_px: float | None = None
    #: what the frame's own absolute evidence alone says (``decide.own_outcome``: the raw path with
    #: confident inliers, else the geometric edges), before the run-level checks and whatever
    #: path decided: a frame that FAILs on a shared error (a failed registration check, a
    #: drifting segment) can still be right up to that error ("" when not judged)
    own_verdict: str = ""

    @property
    def disagree(self) -> bool | None:
        """Raw and enhanced paths both verifiable, with different verdicts (None unless both
        paths gave a PASS or FAIL)."""
        verifiable = (Verdict.PASS.value, Verdict.FAIL.value)
        if self.raw_verdict not in verifiable or self.enhanced_verdict not in verifiable:
            return None
        both = {self.raw_verdict, self.enhanced_verdict}
        return both == {Verdict.PASS.value, Verdict.FAIL.value}
