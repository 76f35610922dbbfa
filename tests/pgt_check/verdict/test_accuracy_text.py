"""The accuracy statement's sentences (``verdict.accuracy_text``) on statements built by hand."""

from __future__ import annotations

from pgt_check.verdict.accuracy import (
    DetectionLimits,
    Percentiles,
    RunAccuracy,
    SharedSize,
    accuracy_sentences,
)
from pgt_check.verdict.accuracy_text import _need


def _acc(**kw) -> RunAccuracy:
    lim = DetectionLimits(8.5, 0.85, 0.0425, None, None, None, 0.5, 0.05, 0.002, None, None,
                          8.0, 160.0, "how", shared_note="not stated: a reason")
    p = Percentiles(0.1, 0.2, 3.0)
    base = dict(
        n_frames=11, n_bounded=10, within_deg=0.172, within_units=0.0049,
        within_from="p90_pass", n_within=8, rotation_bound_deg=p, translation_bound=p,
        effect_bound_px=p, shared=(), limits=lim,
    )
    return RunAccuracy(**{**base, **kw})


def test_sentences_say_the_numbers_and_skip_the_similarity_check():
    shared = (
        SharedSize("registration", "passed", 0.05, (0.01, 0.09), None, None, 0.5, (0.3, 0.9)),
        SharedSize("similarity", "passed", 0.05),
        SharedSize("drift", "passed", 0.1, None, 0.002, None, 1.2, (0.8, 1.6), from_px=True),
    )
    out = accuracy_sentences(_acc(shared=shared, gate_passed=False,
                                  gate_explanation="accuracy: 3 of 11 frames"))
    assert out[0].startswith("8 of 11 frames are verified to within 0.172 deg and 0.0049 scene")
    assert out[1].startswith("Per-frame 95 % bounds: median 0.1 deg")
    assert out[2] == ("Shared registration error (passed): 0.05 deg (95 % 0.01-0.09), "
                      "0.5 px (95 % 0.3-0.9).")
    assert out[3].startswith("Largest drift along the trajectory (passed): 1.2 px (95 % 0.8-1.6)")
    assert "an error shared by all frames: not stated: a reason" in out[4]
    assert out[5] == "Accuracy gate FAILED: 3 of 11 frames."
    assert len(out) == 6


def test_no_bounds_and_the_required_accuracy_are_said_plainly():
    out = accuracy_sentences(_acc(n_bounded=0))
    assert out[0].startswith("None of the 11 frames has absolute evidence")
    assert _need(0.5, None) == "0.5 deg" and _need(0.5, 0.01) == "0.5 deg / 0.01 scene units"
