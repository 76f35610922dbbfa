"""A run's outcome: the judged (and corrected) run with its statistics, accuracy statement and
the CI gate, decided here, in the verdict stage (``judge_outcome``). ``runner.run`` and
``runner.rejudge`` return it; the commands and the API read ``outcome.gate.passed``;
``pgt_check.report`` only serialises it (``report.outputs.write_outcome``)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pgt_check.config.judge import JudgingConfig
from pgt_check.verdict.accuracy import RunAccuracy, run_accuracy
from pgt_check.verdict.decide import resolve_threshold_px
from pgt_check.verdict.result import RunResult
from pgt_check.verdict.run_stats import Gate, RunStatistics, run_statistics
from pgt_check.verdict.shared import SharedChecks

__all__ = ["InputsChanged", "RunOutcome", "decide_gate", "judge_outcome"]


@dataclass(frozen=True)
class InputsChanged:
    """summary.json -> ``inputs_changed`` (``pgt-check report``): the input files that changed
    since they were measured (run.json's content hashes), those that cannot be read any more,
    whether the stored measurements are judged anyway (``--rejudge-stale``) and the gate's
    explanation when they are not."""

    files: tuple[str, ...]
    unreadable: tuple[str, ...] = ()
    rejudged: bool = False
    explanation: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"files": list(self.files), "unreadable": list(self.unreadable),
                "rejudged": self.rejudged, "explanation": self.explanation}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> InputsChanged:
        return cls(tuple(d.get("files") or ()), tuple(d.get("unreadable") or ()),
                   bool(d.get("rejudged")), str(d.get("explanation") or ""))


@dataclass(frozen=True)
class RunOutcome:
    """What a run (or a re-judgement of a stored one) ends with: ``result`` (the verdict
    stage's ``RunResult``, after the correction stage a ``correct.result.CorrectedRun``), the
    per-frame threshold of the run's image size, the run statistics, the accuracy statement and
    the gate; ``inputs_changed`` when a re-judgement found changed inputs."""

    result: RunResult
    threshold_px: float
    statistics: RunStatistics
    accuracy: RunAccuracy
    gate: Gate
    inputs_changed: InputsChanged | None = None

    @property
    def shared(self) -> SharedChecks | None:
        """The run-level checks as reported (a failed registration's estimate refined)."""
        return self.result.shared_as_reported


def decide_gate(
    statistics: RunStatistics,
    accuracy: RunAccuracy,
    config: JudgingConfig,
    inputs_changed: InputsChanged | None = None,
) -> Gate:
    """The gate over the verdict counts (``Gate.of``), then the accuracy gate
    (``--require-accuracy``: fails a passed gate, or adds its explanation), then changed inputs
    not re-judged on purpose (fail closed)."""
    gate = Gate.of(statistics, config.gate)
    if gate.passed and accuracy.gate_passed is False:  # --require-accuracy
        gate = Gate(False, accuracy.gate_explanation)
    elif gate.passed and accuracy.gate_passed:
        gate = Gate(True, f"{gate.explanation}; {accuracy.gate_explanation}")
    if inputs_changed is not None and inputs_changed.files and not inputs_changed.rejudged:
        # ``pgt-check report`` on measurements whose inputs changed since: fail closed
        gate = Gate(False, inputs_changed.explanation or "inputs changed")
    return gate


def run_threshold(result: RunResult, config: JudgingConfig) -> float:
    """The per-frame threshold of the run's (first frame's) image size; 0 x 0 without frames."""
    m = result.frames[0].measurement if result.frames else None
    w, h = (int(m.width), int(m.height)) if m is not None else (0, 0)
    return resolve_threshold_px(config.verdict, w, h)


def judge_outcome(
    result: RunResult, config: JudgingConfig, inputs_changed: InputsChanged | None = None
) -> RunOutcome:
    """The outcome of a judged (and corrected) run: statistics over its frames, the accuracy
    statement with the run-level checks as reported, and the gate."""
    threshold = run_threshold(result, config)
    stats = run_statistics(result, threshold)
    accuracy = run_accuracy(result, result.shared_as_reported, config, threshold)
    gate = decide_gate(stats, accuracy, config, inputs_changed)
    return RunOutcome(result, threshold, stats, accuracy, gate, inputs_changed)


def outcome_parts_of_rows(
    rows: Sequence[Mapping[str, Any]],
    shared: SharedChecks | None,
    config: JudgingConfig,
    inputs_changed: InputsChanged | None = None,
) -> tuple[float, RunStatistics, RunAccuracy, Gate]:
    """``judge_outcome``'s threshold, statistics, accuracy and gate over judged frames.csv rows
    (no ``RunResult``: rows built by tests and benchmarks, ``report.outputs.build_summary``)."""
    from pgt_check.verdict.accuracy import accuracy_of_rows
    from pgt_check.verdict.run_stats import statistics_of_rows

    w, h = (int(rows[0]["width"]), int(rows[0]["height"])) if rows else (0, 0)
    threshold = resolve_threshold_px(config.verdict, w, h)
    stats = statistics_of_rows(rows, threshold)
    accuracy = accuracy_of_rows(rows, shared, config, threshold)
    return threshold, stats, accuracy, decide_gate(stats, accuracy, config, inputs_changed)
