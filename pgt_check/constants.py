"""The named constants that change verdicts, in one place (the settings a user may change are
in ``pgt_check.config``: ``verdict``, ``gate``, ``run_checks``). Each says what it decides and
why it has its value; the measured reasons are in the reports linked. The modules that use them
(``measure``, ``verdict``) import them from here (layer 0: every stage may).
"""

from __future__ import annotations

# --- which paths a frame's verdict rests on (``measure.steps``) -----------------------------

#: the edge path decides alone (the enhanced path is left out) when its share of supported
#: render edges is at least this
EDGES_DECISIVE_SUPPORT = 0.5

# --- per-frame verdict (``verdict.decide``) ------------------------------------------------

#: the band around the threshold (fraction of it) where an absolute result is not clear, as
#: ``enhance.auto_margin`` (default 0.5): a reference is off when its own render's error is
#: beyond 1.5 x the threshold; a PASS of the frame's own render overrules a relative FAIL
#: through such a reference only within 0.5 x the threshold
CLEAR_MARGIN = 0.5

# --- off the mesh (``verdict.off_mesh``) ------------------------------------------------------

#: measured frames on each side (trajectory order) whose coverage forms a frame's neighbourhood
NEIGHBOURS_PER_SIDE = 3
#: fewer measured neighbours than this: no comparison (the frame stays ``low_coverage``)
MIN_NEIGHBOURS = 2
#: off the mesh: coverage at most this fraction of the neighbours' median coverage
OFF_MESH_RATIO = 0.25
#: the neighbours' median coverage must be at least this many times ``min_coverage``
MIN_NEIGHBOUR_FACTOR = 2.0

# --- run-level checks (``verdict.shared``) ----------------------------------------------------

#: significance of the registration check's coherence test (``geometry.shared_errors.solver.
#: _coherence_p``): a correction above the shared threshold FAILs the run only when the frames
#: pull together at this level; otherwise it may be the frames' own errors summed (a noisy
#: evidence path on few frames: the colourless castle judged by MaRINeR alone fitted a 3 deg
#: "misregistration" at p = 0.97, reports/mariner_alone.md) and the check is inconclusive.
#: The usual 5 %, not fitted
COHERENCE_ALPHA = 0.05
#: a frame whose absolute evidence leaves more than this fraction of the per-frame threshold
#: after the shared correction has an error of its own: it is left out of the pooled fits, and
#: a passed registration check does not cover it
OWN_ERROR_FRACTION = 0.5
#: the drift check's threshold relative to the shared one. A drift window is fitted on a few
#: frames, where view-dependent errors the model lacks show as a local correction of a few px
#: (on 7-Scenes above the shared threshold where the camera looks at near surfaces or turns
#: fast: reports/shared_errors.md)
DRIFT_THRESHOLD_FACTOR = 2.0
#: points per frame in the pooled run-level fits: one frame, one vote. A frame whose evidence
#: has several sources (raw matches + edges) would otherwise weigh up to twice as much as one
#: with edges alone (reports/shared_errors.md, castle with the `accurate` preset)
MAX_FRAME_EVIDENCE_POINTS = 200
#: all frames' points together in the pooled fits: past MAX_POOLED_POINTS / 200 frames each frame
#: gives fewer points (never under MIN_FRAME_EVIDENCE_POINTS), so the run-level checks of a long
#: trajectory cost about what a 200-frame run costs, until the floor is reached (linear after
#: it); their precision is then already far below the threshold (reports/scaling.md)
MAX_POOLED_POINTS = 40_000
MIN_FRAME_EVIDENCE_POINTS = 24

# --- per-frame pose bounds (``verdict.frame_bounds``; the ``--require-accuracy`` gate) --------

#: the bound rests on the feature paths' points alone (raw, enhanced) when they have at least
#: this many and give a bound: the geometric-edge points' photo positions come from a 2D
#: alignment model and carry no parallax, so their fit turns a camera shift into a rotation;
#: fewer feature points alone were too noisy (reports/accuracy.md, "Translation bound bias")
FEATURE_ONLY_MIN_POINTS = 40
