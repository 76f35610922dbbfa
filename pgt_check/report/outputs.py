"""Run outputs: frames.csv, summary.json, config.json (written atomically), and
the human/CI report (report.html, junit.xml; see ``pgt_check.report.html.build_report``)."""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import platform
import statistics
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pgt_check import __version__
from pgt_check.common.files import safe_text
from pgt_check.config import RunConfig
from pgt_check.correct.correction import CORRECTION_COLUMNS
from pgt_check.measure.columns import MEASUREMENT_COLUMNS, TIMING_COLUMNS
from pgt_check.output_layout import OUTPUTS
from pgt_check.ownership import COMPLETION_MARKER, check_outputs_owned
from pgt_check.report.files import atomic_write_text
from pgt_check.verdict.frame_bounds import ACCURACY_COLUMNS
from pgt_check.verdict.result import VERDICT_COLUMNS

if TYPE_CHECKING:  # pragma: no cover
    from pgt_check.verdict.accuracy import RunAccuracy
    from pgt_check.verdict.outcome import RunOutcome
    from pgt_check.verdict.run_stats import Gate, RunStatistics
    from pgt_check.verdict.shared import SharedChecks

logger = logging.getLogger(__name__)

def _frame_columns() -> tuple[str, ...]:
    """frames.csv columns: id, timestamp, path, the verdict, then the measurement's CSV columns
    (``pgt_check.measure.record.MEASUREMENT_COLUMNS``); the threshold sits beside the error."""
    measured = [c.name for c in MEASUREMENT_COLUMNS if c.csv]
    head, rest = measured[:3], measured[3:]
    i = rest.index("corner_error_px") + 1
    extra = [c for c in VERDICT_COLUMNS if c not in ("verdict", "reason", "threshold_px")]
    return (*head, "verdict", "reason", *rest[:i], "threshold_px", *rest[i:], *extra)


#: frames.csv columns, in order. ``corner_error_px`` is the one the verdict used. The
#: correction columns (``pgt_check.correct.correction``) are an optional tail: empty for frames
#: that were not corrected.
FRAME_COLUMNS = (*_frame_columns(), *ACCURACY_COLUMNS, *CORRECTION_COLUMNS)

#: timing columns (left out when comparing runs)
STAGES = TIMING_COLUMNS


def _clean(value: Any) -> Any:
    """JSON-safe value: non-finite floats become None."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


json_safe = _clean  # public name: JSON-safe copy of a summary (non-finite floats -> None)


#: first characters that make a spreadsheet read a cell as a formula (OWASP CSV injection)
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value: Any) -> Any:
    """A cell of every CSV output (frames.csv, compare.csv, references.csv, metrics.csv).

    Text (ids, paths, reasons) starting with ``= + - @``, tab or CR gets a leading ``'`` so
    spreadsheets show it as text; control characters and undecodable file-name bytes are
    escaped (``safe_text``: one line per row, always UTF-8); numbers are never changed (a
    negative number stays a number), non-finite ones are empty."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return value
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    if isinstance(value, str):
        return "'" + safe_text(value) if value.startswith(_FORMULA_START) else safe_text(value)
    return value


_csv_value = csv_cell  # the name older callers use


def csv_text(columns: Sequence[str], rows: Sequence[Mapping[str, Any]]) -> str:
    """A CSV document: the header, then one line per row (cells through ``csv_cell``)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    for r in rows:
        writer.writerow([csv_cell(r.get(c)) for c in columns])
    return buf.getvalue()


def frames_csv_text(records: list[dict[str, Any]]) -> str:
    return csv_text(FRAME_COLUMNS, records)


def versions() -> dict[str, str]:
    out = {"pgt-check": __version__, "python": platform.python_version()}
    for pkg in (
        "numpy",
        "opencv-contrib-python-headless",
        "moderngl",
        "trimesh",
        "torch",
        "kornia",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            continue
    return out


def timing_summary(records: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, float]]:
    out = {}
    for key in TIMING_COLUMNS:
        vals = sorted(r[key] for r in records if isinstance(r.get(key), (int, float)))
        if not vals:
            continue
        p90 = vals[min(len(vals) - 1, math.ceil(0.9 * len(vals)) - 1)]
        out[key.removesuffix("_s")] = {
            "median_s": statistics.median(vals),
            "p90_s": p90,
            "total_s": sum(vals),
        }
    return out


def summary_sections(
    records: Sequence[Mapping[str, Any]],
    config: RunConfig,
    threshold_px: float,
    statistics: RunStatistics,
    accuracy: RunAccuracy,
    gate: Gate,
    extra: Mapping[str, Any],
) -> dict[str, Any]:
    """summary.json: the gate, counts, statistics and accuracy the verdict stage decided, the
    report's own tables over the rows (timing, raw vs enhanced), the settings, then ``extra``
    (the run's facts and its results' sections); JSON-safe."""
    from pgt_check.report.paths import path_comparison

    summary = {
        "tool": "pgt-check",
        "version": __version__,
        "gate": gate.to_json(),
        "counts": dict(statistics.counts),
        "n_frames": statistics.n_frames,
        "threshold_px": threshold_px,
        "statistics": statistics.to_json(),
        "accuracy": accuracy.to_json(),
        "timing": timing_summary(list(records)),
        "raw_vs_enhanced": path_comparison(records),
        "settings": config.to_dict(),
        "fingerprint": config.measurement_fingerprint(),
        "versions": versions(),
    }
    summary.update(extra)
    return _clean(summary)


def outcome_summary(outcome: RunOutcome, config: RunConfig, facts: RunFacts) -> dict[str, Any]:
    """summary.json of a run's outcome: ``facts``, then its results' sections."""
    extra = facts.sections()
    if outcome.inputs_changed is not None:
        extra["inputs_changed"] = outcome.inputs_changed.to_json()
    extra.update(outcome.result.summary_extra())
    if facts.wall_time_s is not None:
        extra["wall_time_s"] = facts.wall_time_s
    return summary_sections(outcome.result.rows(), config, outcome.threshold_px,
                            outcome.statistics, outcome.accuracy, outcome.gate, extra)


def build_summary(
    records: list[dict[str, Any]], config: RunConfig, extra: dict[str, Any] | None = None
) -> dict[str, Any]:
    """summary.json of judged frames.csv rows without a ``RunOutcome`` (tests, benchmarks on
    rows): the verdict stage's statistics, accuracy and gate over the rows
    (``verdict.outcome.outcome_parts_of_rows``), ``extra``'s ``shared_errors`` and
    ``inputs_changed`` read back as their typed values."""
    from pgt_check.verdict.outcome import InputsChanged, outcome_parts_of_rows
    from pgt_check.verdict.shared import SharedChecks

    extra = dict(extra or {})
    shared, changed = extra.get("shared_errors"), extra.get("inputs_changed")
    threshold, stats, accuracy, gate = outcome_parts_of_rows(
        records, SharedChecks.from_summary(shared) if isinstance(shared, Mapping) else None,
        config, InputsChanged.from_json(changed) if isinstance(changed, Mapping) else None)
    return summary_sections(records, config, threshold, stats, accuracy, gate, extra)


def remove_completion_marker(out: Path) -> None:
    """Mark ``out``'s output set incomplete (called before any output is rewritten)."""
    try:
        (Path(out) / COMPLETION_MARKER).unlink()
    except FileNotFoundError:
        pass


def write_completion_marker(out: Path) -> None:
    import hashlib

    out = Path(out)
    files = {}
    for name in OUTPUTS.marked_files():
        p = out / name
        if p.is_file() and not p.is_symlink():
            files[name] = hashlib.sha256(p.read_bytes()).hexdigest()
    text = json.dumps({"tool": "pgt-check", "version": __version__, "files": files}, indent=2)
    atomic_write_text(out / COMPLETION_MARKER, text + "\n")


def outputs_complete(out: Path) -> tuple[bool, str]:
    """Whether ``out`` holds a complete output set: the marker exists and every file it lists
    has the sha256 it lists. Returns (complete, why not)."""
    import hashlib

    out = Path(out)
    marker = out / COMPLETION_MARKER
    if not marker.is_file():
        return False, f"{COMPLETION_MARKER} is missing (the outputs were not finished)"
    try:
        files = json.loads(marker.read_text(encoding="utf-8"))["files"]
        for name, digest in files.items():
            p = out / name
            if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != digest:
                return False, f"{name} does not match {COMPLETION_MARKER}"
    except (ValueError, KeyError, TypeError, AttributeError, OSError) as err:
        return False, f"{COMPLETION_MARKER} is unreadable ({err})"
    return True, ""


def write_outputs(
    out: Path,
    records: list[dict[str, Any]],
    config: RunConfig,
    extra: dict[str, Any] | None = None,
    *,
    report: bool = True,
    assets: dict[str, dict[str, str]] | None = None,
) -> dict[str, Any]:
    """``write_summary`` of judged frames.csv rows without a ``RunOutcome``
    (``build_summary``: tests, benchmarks); return the summary."""
    return write_summary(out, records, lambda: build_summary(records, config, extra), config,
                         report=report, assets=assets)


def write_summary(
    out: Path,
    records: list[dict[str, Any]],
    summary_of: Callable[[], dict[str, Any]],
    config: RunConfig,
    *,
    shared: SharedChecks | None = None,
    report: bool = True,
    assets: dict[str, dict[str, str]] | None = None,
) -> dict[str, Any]:
    """Write frames.csv (``records``), config.json and summary.json (``summary_of()``) into
    ``out``; return the summary. records.jsonl is the measurement store and is never rewritten
    here. With ``report`` (default) also report.html, its plots and junit.xml; ``assets``
    (``{frame_id: {kind: relative path}}`` from ``write_frame_assets``) become the detail
    images, None keeps whatever ``assets/index.json`` already lists."""
    out = Path(out)
    check_outputs_owned(out, OUTPUTS.report_files())  # nothing of the user's is replaced
    out.mkdir(parents=True, exist_ok=True)
    remove_completion_marker(out)
    atomic_write_text(out / OUTPUTS.frames_csv, frames_csv_text(records))
    atomic_write_text(out / OUTPUTS.config_json,
                      json.dumps(config.settings_dict(), indent=2) + "\n")
    summary = summary_of()
    # a significant calibration estimate as intrinsics a re-run loads (``--sensors``)
    from pgt_check.report.calibrated_sensors import write_calibrated_sensors

    if shared is None and isinstance(summary.get("shared_errors"), Mapping):
        from pgt_check.verdict.shared import SharedChecks

        shared = SharedChecks.from_summary(summary["shared_errors"])  # rows without a result
    calibrated = write_calibrated_sensors(out, records, shared, summary.get("calibrated_rig"))
    if calibrated is not None:
        summary["calibrated_sensors"] = _clean(calibrated)
    atomic_write_text(out / OUTPUTS.summary_json, json.dumps(summary, indent=2) + "\n")
    if report:
        from pgt_check.report.html import build_report

        build_report(out, records, summary, assets, absolute_paths=config.absolute_paths)
    write_completion_marker(out)  # last: the set is complete
    logger.info("wrote %s", out)
    return summary


@dataclass(frozen=True)
class ExecutorSummary:
    """summary.json -> ``executor``: how the frames were measured."""

    kind: str
    workers: int
    frames_measured: int
    frames_reused: int
    worker_crashes: int

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "workers": self.workers,
                "frames_measured": self.frames_measured, "frames_reused": self.frames_reused,
                "worker_crashes": self.worker_crashes}


@dataclass(frozen=True)
class RunFacts:
    """What summary.json says about the run beside its results: the trajectory's format, the
    mesh shading used, the executor, image paths outside the dataset folder (a warning), the
    wall time; ``carried``: sections of an earlier summary.json kept as written (``pgt-check
    report`` re-judges stored measurements and keeps how they were measured)."""

    trajectory_format: str | None = None
    shading: str | list[str] | None = None
    executor: ExecutorSummary | None = None
    outside_dataset: Sequence[str] = ()
    wall_time_s: float | None = None
    carried: Mapping[str, Any] = field(default_factory=dict)

    def sections(self) -> dict[str, Any]:
        out: dict[str, Any] = dict(self.carried)
        if self.shading is not None or self.executor is not None:
            out["shading"] = self.shading
        if self.executor is not None:
            out["executor"] = self.executor.to_json()
        if self.trajectory_format is not None:
            out["trajectory_format"] = self.trajectory_format
        if self.outside_dataset:
            n, first = len(self.outside_dataset), self.outside_dataset[0]
            out["images_outside_dataset"] = {"count": n,
                                             "examples": list(self.outside_dataset[:5])}
            out["warnings"] = [
                f"{n} image paths point outside the dataset folder (e.g. {first!r}): they "
                "were read and their thumbnails may appear in this report"
            ]
        return out


def read_summary(out: Path) -> dict[str, Any]:
    """``out``'s summary.json as written (what the printed lines are built from, so
    ``pgt-check`` and ``pgt-check report`` print alike)."""
    return json.loads((Path(out) / OUTPUTS.summary_json).read_text(encoding="utf-8"))


def write_outcome(
    out: Path,
    outcome: RunOutcome,
    config: RunConfig,
    facts: RunFacts,
    *,
    assets: dict[str, dict[str, str]] | None = None,
) -> dict[str, Any]:
    """Write a run's outcome (``verdict.outcome.RunOutcome``: its result's rows; the gate,
    statistics and accuracy the verdict stage decided; the result's summary sections, after
    ``facts``); return the summary written."""
    return write_summary(out, outcome.result.rows(),
                         lambda: outcome_summary(outcome, config, facts), config,
                         shared=outcome.shared, assets=assets)
