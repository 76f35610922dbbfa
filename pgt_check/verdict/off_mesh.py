"""A frame whose render shows (almost) nothing of the mesh while its neighbours see it well.

Render coverage below ``verdict.min_coverage`` leaves a frame without evidence to match
(``low_coverage``, UNVERIFIABLE). That is right where the camera really looks past the mesh,
but it made the verdict softer the worse the pose: a frame moved 30 m off the mesh was
UNVERIFIABLE (which the gate tolerates up to its allowance) while one moved 0.25 m FAILed.
The neighbours tell the two apart. Frames next to each other in the trajectory look at about
the same part of the scene, so their coverages are alike; a frame that sees a quarter or less
of what its neighbours see, and too little to be matched, is evidence of a gross pose error:
FAIL ``off_mesh``. A frame whose whole neighbourhood covers little (a segment outside the
scanned area) stays ``low_coverage``.

The rule adapts to the run: it compares each frame with the median coverage of its own
neighbours (``NEIGHBOURS_PER_SIDE`` measured frames on each side in trajectory order; frames
without a render, e.g. a missing image, are passed over), not with a fixed level. The
neighbourhood must see the mesh well: a median of at least ``MIN_NEIGHBOUR_FACTOR`` x
``min_coverage`` (so borderline neighbours never turn a frame into a FAIL), from at least
``MIN_NEIGHBOURS`` frames.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

from pgt_check.constants import (
    MIN_NEIGHBOUR_FACTOR,
    MIN_NEIGHBOURS,
    NEIGHBOURS_PER_SIDE,
    OFF_MESH_RATIO,
)
from pgt_check.measure.record import FrameMeasurement, MeasureReason

OFF_MESH = "off_mesh"


def _coverage(m: FrameMeasurement) -> float | None:
    """The render coverage of a frame that was rendered (None otherwise)."""
    c = m.coverage
    return float(c) if c is not None and math.isfinite(c) else None


def off_mesh_frames(
    measurements: Sequence[FrameMeasurement], min_coverage: float
) -> dict[str, str]:
    """frame id -> FAIL reason (``off_mesh (...)``) for each frame below ``min_coverage`` whose
    neighbours see the mesh well (module docstring). Measurements in trajectory order."""
    rendered = [(m, c) for m in measurements if (c := _coverage(m)) is not None]
    out: dict[str, str] = {}
    for k, (m, c) in enumerate(rendered):
        if c >= min_coverage or m.error not in (MeasureReason.NONE, MeasureReason.LOW_COVERAGE):
            continue
        lo = max(0, k - NEIGHBOURS_PER_SIDE)
        around = [cov for _, cov in rendered[lo:k] + rendered[k + 1 : k + 1 + NEIGHBOURS_PER_SIDE]]
        if len(around) < MIN_NEIGHBOURS:
            continue
        median = statistics.median(around)
        if median >= MIN_NEIGHBOUR_FACTOR * min_coverage and c <= OFF_MESH_RATIO * median:
            out[m.frame_id] = (
                f"{OFF_MESH} (the render at this pose covers {100 * c:.1f} % of the image, "
                f"its {len(around)} neighbours {100 * median:.0f} %: a gross pose error)"
            )
    return out
