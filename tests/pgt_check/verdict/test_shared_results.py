"""The typed entries of the run-level checks (``verdict/shared_results.py``): ``to_json`` writes the
summary.json entry key for key (the order summary.json has always had), later steps' fields only
once set, and ``from_json`` reads such an entry back."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from pgt_check.verdict.shared_entries import registration_entry, shared_or_not
from pgt_check.verdict.shared_results import RegistrationCheck, Sensitivity

REGISTRATION_KEYS = [
    "status", "reason", "kind", "angle_deg", "angle_deg_ci", "translation", "translation_ci",
    "translation_rel_depth", "translation_rel_depth_ci", "scale", "scale_ci", "effect_px",
    "effect_px_ci", "n_frames", "n_points", "n_inliers", "ambiguous_with_calibration",
    "corrected_world_from_world", "coherence_p", "message",
]


def _estimate(**kw) -> SimpleNamespace:
    est = dict(
        success=True, reason="", angle_deg=1.5, angle_deg_ci=(1.2, 1.8), translation=0.05,
        translation_ci=(0.03, 0.07), translation_frac=0.02, translation_frac_ci=(0.01, 0.03),
        scale=1.0, scale_ci=(1.0, 1.0), effect_px=6.0, effect_px_ci=(4.5, 7.5), n_frames=12,
        n_points=900, n_inliers=700, ambiguous_with_calibration=False,
        corrected_world_from_world=np.eye(4), coherence_p=0.01,
    )  # fmt: skip
    est.update(kw)
    return SimpleNamespace(**est)


def test_registration_to_json_keys_in_summary_order_and_later_fields_once_set():
    e = registration_entry(_estimate(), 3.0, "rigid")
    assert list(e.to_json()) == REGISTRATION_KEYS
    e = replace(shared_or_not(e, np.array([0.5, 1.0]), 2.0), frames_left_out=("f3",))
    e = replace(e, sensitivity=Sensitivity(7.8, 150.0), refinement={"stopped": "converged"})
    d = e.to_json()
    assert list(d) == [*REGISTRATION_KEYS, "frames_agreeing", "frames_left_out", "sensitivity",
                       "refinement"]
    assert d["frames_left_out"] == ["f3"] and d["frames_agreeing"] == 1.0
    assert d["sensitivity"] == {"px_per_deg": 7.8, "px_per_unit": 150.0}
    json.dumps(d)


def test_registration_from_json_reads_its_entry_back():
    e = registration_entry(
        _estimate(success=False, reason="too_few_frames", effect_px=math.nan,
                  effect_px_ci=(math.nan,) * 2), 3.0, "similarity",
    )
    e = replace(e, frames_agreeing=0.5, frames_left_out=(), sensitivity=Sensitivity(1.0, 2.0))
    back = RegistrationCheck.from_json(json.loads(json.dumps(e.to_json())))
    assert back == e and back.to_json() == e.to_json()
    # a partial entry (a summary of another version) keeps the defaults for what it lacks
    part = RegistrationCheck.from_json({"status": "failed", "effect_px": 3.0, "other": 1})
    assert part.status == "failed" and part.corrected_world_from_world is None
    assert "frames_agreeing" not in part.to_json()
