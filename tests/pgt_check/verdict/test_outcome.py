"""The run's outcome decided in the verdict stage (``verdict.outcome``): statistics, accuracy and
the gate of a judged run, the gate's order of rules (counts, then ``--require-accuracy``, then
changed inputs), and the rows path (``outcome_parts_of_rows``) deciding the same as the typed one."""

from __future__ import annotations

from dataclasses import replace

import pytest
from report_testdata import from_flat, synthetic_measurements

from pgt_check.config import RunConfig
from pgt_check.verdict import judge_run
from pgt_check.verdict.decide import resolve_threshold_px
from pgt_check.verdict.outcome import (
    InputsChanged,
    RunOutcome,
    decide_gate,
    judge_outcome,
    outcome_parts_of_rows,
    run_threshold,
)
from pgt_check.verdict.result import RunResult
from pgt_check.verdict.run_stats import Gate

LENIENT = {"gate": {"max_fail_fraction": 1.0, "max_unverifiable_fraction": 1.0,
                    "max_internal_errors": 1000}}


def _outcome(config: RunConfig) -> RunOutcome:
    ms = [from_flat(r) for r in synthetic_measurements(n=40, hostile=False)]
    return judge_outcome(judge_run(ms, config), config)


@pytest.fixture(scope="module")
def strict() -> tuple[RunOutcome, RunConfig]:
    config = RunConfig()
    return _outcome(config), config


@pytest.fixture(scope="module")
def lenient() -> tuple[RunOutcome, RunConfig]:
    config = RunConfig.from_dict(LENIENT)
    return _outcome(config), config


def test_the_outcome_counts_the_judged_frames_and_gates_on_them(strict):
    outcome, config = strict
    assert outcome.statistics.n_frames == len(outcome.result.frames) == 40
    assert sum(outcome.statistics.counts.values()) == 40
    assert outcome.threshold_px == resolve_threshold_px(config.verdict, 640, 480)
    # synthetic_measurements holds bad poses: the default gate (no FAIL allowed) fails on them
    assert outcome.statistics.counts["FAIL"] > 0
    assert outcome.gate == Gate.of(outcome.statistics, config.gate)
    assert outcome.gate.passed is False
    assert outcome.shared is outcome.result.shared_as_reported
    assert outcome.inputs_changed is None


def test_a_lenient_gate_passes_the_same_frames(lenient):
    outcome, config = lenient
    assert outcome.gate.passed is True
    assert outcome.gate == Gate.of(outcome.statistics, config.gate)


def test_rows_decide_what_the_typed_run_decides(strict):
    outcome, config = strict
    threshold, stats, accuracy, gate = outcome_parts_of_rows(
        outcome.result.rows(), outcome.shared, config)
    assert threshold == outcome.threshold_px
    assert stats.to_json() == outcome.statistics.to_json()
    assert gate == outcome.gate
    assert accuracy.to_json() == outcome.accuracy.to_json()


def test_the_accuracy_gate_fails_a_passed_gate_or_adds_its_explanation(lenient):
    outcome, config = lenient
    failed = replace(outcome.accuracy, gate_passed=False, gate_explanation="too inaccurate")
    assert decide_gate(outcome.statistics, failed, config) == Gate(False, "too inaccurate")
    passed = replace(outcome.accuracy, gate_passed=True, gate_explanation="accurate enough")
    gate = decide_gate(outcome.statistics, passed, config)
    assert gate.passed and gate.explanation == f"{outcome.gate.explanation}; accurate enough"


def test_changed_inputs_fail_the_gate_unless_rejudged_on_purpose(lenient):
    outcome, config = lenient
    changed = InputsChanged(("mesh.glb",), explanation="mesh.glb changed since it was measured")
    gate = decide_gate(outcome.statistics, outcome.accuracy, config, changed)
    assert gate == Gate(False, "mesh.glb changed since it was measured")
    assert decide_gate(outcome.statistics, outcome.accuracy, config,
                       replace(changed, explanation="")) == Gate(False, "inputs changed")
    rejudged = replace(changed, rejudged=True)
    assert decide_gate(outcome.statistics, outcome.accuracy, config, rejudged) == outcome.gate
    assert decide_gate(outcome.statistics, outcome.accuracy, config,
                       InputsChanged(())) == outcome.gate


def test_inputs_changed_round_trips_through_its_summary_entry():
    changed = InputsChanged(("a.txt", "mesh.glb"), ("gone.jpg",), True, "why")
    assert changed.to_json() == {"files": ["a.txt", "mesh.glb"], "unreadable": ["gone.jpg"],
                                 "rejudged": True, "explanation": "why"}
    assert InputsChanged.from_json(changed.to_json()) == changed
    assert InputsChanged.from_json({}) == InputsChanged(())


def test_a_run_without_frames_has_the_threshold_of_a_zero_size_image():
    config = RunConfig()
    empty = RunResult((), None)
    assert run_threshold(empty, config) == resolve_threshold_px(config.verdict, 0, 0)
