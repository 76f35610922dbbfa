"""The run's accuracy statement, its detection limits and the accuracy gate
(``verdict.accuracy``), on rows whose per-frame bounds are known."""

from __future__ import annotations

import pytest

from pgt_check.config import RunConfig
from pgt_check.errors import ConfigError
from pgt_check.verdict.accuracy import accuracy_of_rows
from pgt_check.verdict.frame_bounds import ACCURACY_COLUMNS
from pgt_check.verdict.shared import SharedChecks


def run_accuracy_rows(rows, shared, config, threshold_px):
    """``accuracy_of_rows`` with the run-level checks given as their summary section."""
    return accuracy_of_rows(rows, None if shared is None else SharedChecks.from_summary(shared),
                            config, threshold_px)


def _row(fid: str, verdict: str, rot: float | None, t: float | None, noise_px: float = 0.5):
    r = dict.fromkeys(ACCURACY_COLUMNS)
    r.update(frame_id=fid, verdict=verdict)
    if rot is not None:
        r.update(
            acc_rot_deg=rot / 2, acc_rot_bound_deg=rot, acc_t=t / 2, acc_t_bound=t,
            acc_px=1.0, acc_px_bound=2.0, acc_noise_px=noise_px, acc_noise_deg=0.05,
            acc_noise_t=0.002, acc_px_per_deg=12.0, acc_px_per_unit=250.0,
            acc_low_px_per_deg=10.0, acc_low_px_per_unit=200.0,
            acc_pts_px_per_deg=8.0, acc_pts_px_per_unit=160.0,
        )
    return r


SHARED = {
    "threshold_px": 1.5,
    "registration": {
        "status": "passed", "angle_deg": 0.05, "angle_deg_ci": [0.01, 0.09],
        "translation": 0.001, "translation_ci": [0.0, 0.003], "effect_px": 0.5,
        "effect_px_ci": [0.3, 0.9],
    },
    "similarity": {"status": "not_checked"},
    "drift": {"status": "not_checked"},
    "calibration": {},
}


def rows():
    out = [_row(f"{i}", "PASS", 0.1 + 0.01 * i, 0.004 + 0.0001 * i) for i in range(9)]
    out.append(_row("bad", "FAIL", 3.0, 0.2))
    out.append(_row("rel", "PASS", None, None))  # relative evidence: no bound
    return out


def test_statement_counts_percentiles_and_limits():
    acc = run_accuracy_rows(rows(), SHARED, RunConfig(), threshold_px=8.0)
    assert acc.n_frames == 11 and acc.n_bounded == 10
    assert acc.within_from == "p90_pass"
    assert acc.within_deg == pytest.approx(0.172, abs=1e-3)
    assert acc.n_within == 8  # the PASS frames at or below their own 90th percentile
    assert acc.rotation_bound_deg.max == 3.0
    # single frame: threshold + noise over the 5 % axis sensitivity (identical frames: the
    # pooled 95 % point is every frame's own)
    assert acc.limits.frame_px == pytest.approx(8.5)
    assert acc.limits.frame_deg == pytest.approx(0.85)
    assert acc.limits.frame_units == pytest.approx(8.5 / 200)
    # shared: shared threshold + half the registration interval, over the point sensitivities
    assert acc.limits.shared_px == pytest.approx(1.5 + 0.3)
    assert acc.limits.shared_deg == pytest.approx(1.8 / 8)
    reg = next(s for s in acc.shared if s.check == "registration")
    assert reg.rotation_deg_ci == (0.01, 0.09)
    assert any(s.startswith("8 of 11 frames are verified") for s in acc.sentences)
    assert acc.gate_passed is None  # nothing required
    d = acc.to_json()
    assert d["limits"]["frame_px"] == pytest.approx(8.5) and isinstance(d["sentences"], list)


def _gate(**gate) -> RunConfig:
    return RunConfig.from_dict({"gate": gate})


def test_gate_on_required_accuracy():
    lax = _gate(require_accuracy_deg=1.0, require_accuracy_units=0.05, max_fail_fraction=0.2)
    acc = run_accuracy_rows(rows(), SHARED, lax, 8.0)
    # 'bad' is above and 'rel' has no bound: 2 of 11 <= 0.2
    assert acc.gate_passed, acc.gate_explanation
    strict = _gate(require_accuracy_deg=1.0, require_accuracy_units=0.05,
                   max_fail_fraction=0.1)
    acc = run_accuracy_rows(rows(), SHARED, strict, 8.0)
    assert acc.gate_passed is False and "1 without absolute evidence" in acc.gate_explanation
    # a shared error whose upper bound exceeds the requirement fails the gate
    tight = _gate(require_accuracy_deg=0.08, require_accuracy_units=1.0, max_fail_fraction=1.0)
    acc = run_accuracy_rows(rows(), SHARED, tight, 8.0)
    assert acc.gate_passed is False and "registration" in acc.gate_explanation


def test_require_accuracy_config_is_typed_and_range_checked():
    with pytest.raises(ConfigError):
        RunConfig.from_dict({"gate": {"require_accuracy_deg": -1.0}})
    with pytest.raises(ConfigError):
        RunConfig.from_dict({"gate": {"require_accuracy_deg": 200.0}})
    with pytest.raises(ConfigError):
        RunConfig.from_dict({"gate": {"require_accuracy_units": "1cm"}})
    with pytest.raises(ConfigError):
        RunConfig.from_dict({"gate": {"require_accuracy": [1, 2]}})  # unknown key
    cfg = RunConfig.from_dict({"gate": {"require_accuracy_deg": 0.5,
                                        "require_accuracy_units": 0.02}})
    assert (cfg.gate.require_accuracy_deg, cfg.gate.require_accuracy_units) == (0.5, 0.02)


def test_no_bounds_is_said_plainly():
    acc = run_accuracy_rows([_row("a", "PASS", None, None)], None, RunConfig(), 8.0)
    assert acc.n_bounded == 0 and acc.sentences[0].startswith("None of the 1 frames")


def test_pooled_detection_size_is_the_95_percent_point_of_the_pooled_frames():
    import math

    from pgt_check.verdict.accuracy import pooled_detection_size

    # two kinds of frames: sensitive ones (median 20 px/deg, 5 % axis 10) and weak ones
    # (median 5, 5 % axis 4); threshold 8 + noise 1 -> sizes lognormal per frame
    frames = [dict(acc_px_per_deg=20.0, acc_low_px_per_deg=10.0, acc_noise_px=30.0)] * 3
    frames += [dict(acc_px_per_deg=5.0, acc_low_px_per_deg=4.0, acc_noise_px=0.1)]
    # the run's median noise (1 px) counts, not a frame's own (its pose fit's)
    size = pooled_detection_size(frames, 8.0, 1.0, "acc_px_per_deg", "acc_low_px_per_deg")
    # Monte Carlo of the stated model: the share of (frame, axis) sizes at or below it is 95 %
    import numpy as np

    rng = np.random.default_rng(0)
    draws = []
    for f in frames:
        mu = math.log(9.0 / f["acc_px_per_deg"])
        sg = math.log(f["acc_px_per_deg"] / f["acc_low_px_per_deg"]) / 1.6448536
        draws.append(np.exp(rng.normal(mu, sg, 200_000)))
    assert np.mean(np.concatenate(draws) <= size) == pytest.approx(0.95, abs=0.003)
    # the weak frame alone decides more than its share: above the sensitive frames' own 95 %
    assert size > 9.0 / 10.0
    # threshold per row wins over the run's; frames without sensitivities are left out
    rows_thr = [dict(f, threshold_px=16.0) for f in frames] + [dict(acc_px_per_deg=None)]
    assert pooled_detection_size(rows_thr, 8.0, 1.0, "acc_px_per_deg",
                                 "acc_low_px_per_deg") == pytest.approx(size * 17 / 9, rel=1e-6)
    assert pooled_detection_size([{}], 8.0, None, "acc_px_per_deg", "acc_low_px_per_deg") is None


def test_no_shared_limit_when_the_run_removes_its_own_calibration():
    """With --remove-calibration the calibration is estimated on the same frames and absorbs
    the part of a shared error that looks like one: a shared limit would be a promise the
    removal breaks, so none is stated, and the sentence says why."""
    from pgt_check.verdict.accuracy import NOT_SEPARABLE

    removed = RunConfig.from_dict({"run_checks": {"remove_calibration": True}})
    acc = run_accuracy_rows(rows(), SHARED, removed, threshold_px=8.0)
    assert acc.limits.shared_px is None and acc.limits.shared_deg is None
    assert acc.limits.shared_note == NOT_SEPARABLE
    assert any("--calibration-from" in s for s in acc.sentences)
    assert acc.limits.frame_deg == pytest.approx(0.85)  # the single-frame limit stands
    lim = run_accuracy_rows(rows(), SHARED, RunConfig(), threshold_px=8.0).limits
    assert lim.shared_px == pytest.approx(1.8) and lim.shared_note == ""
