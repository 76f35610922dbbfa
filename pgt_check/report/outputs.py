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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from pgt_check import __version__
from pgt_check.config import RunConfig
from pgt_check.correct.pose import CORRECTION_COLUMNS
from pgt_check.files import safe_text
from pgt_check.measure.columns import MEASUREMENT_COLUMNS, TIMING_COLUMNS
from pgt_check.report.files import atomic_write_text
from pgt_check.store import COMPLETION_MARKER, check_outputs_owned
from pgt_check.verdict.frame_bounds import ACCURACY_COLUMNS
from pgt_check.verdict.result import VERDICT_COLUMNS, RunResult

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
#: correction columns (``pgt_check.correct.pose``) are an optional tail: empty for frames
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


def timing_summary(records: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
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


def build_summary(
    records: list[dict[str, Any]], config: RunConfig, extra: dict[str, Any] | None = None
) -> dict[str, Any]:
    from pgt_check.report.paths import path_comparison
    from pgt_check.verdict import gate, run_statistics
    from pgt_check.verdict.accuracy import run_accuracy
    from pgt_check.verdict.decide import resolve_threshold_px

    if records:
        w, h = int(records[0]["width"]), int(records[0]["height"])
    else:
        w, h = 0, 0
    threshold = resolve_threshold_px(config.verdict, w, h)
    stats = run_statistics(records, threshold)
    passed, why = gate(stats["counts"], config.gate, stats["unverifiable_reasons"])
    accuracy = run_accuracy(
        records, (extra or {}).get("shared_errors"), config, threshold
    )
    if passed and accuracy.gate_passed is False:  # --require-accuracy
        passed, why = False, accuracy.gate_explanation
    elif passed and accuracy.gate_passed:
        why = f"{why}; {accuracy.gate_explanation}"
    changed = (extra or {}).get("inputs_changed")
    if isinstance(changed, Mapping) and changed.get("files") and not changed.get("rejudged"):
        # ``pgt-check report`` on measurements whose inputs changed since: fail closed
        passed, why = False, str(changed.get("explanation") or "inputs changed")
    summary = {
        "tool": "pgt-check",
        "version": __version__,
        "gate": {"passed": passed, "explanation": why},
        "counts": stats["counts"],
        "n_frames": stats["n_frames"],
        "threshold_px": threshold,
        "statistics": stats,
        "accuracy": accuracy.to_json(),
        "timing": timing_summary(records),
        "raw_vs_enhanced": path_comparison(records),
        "settings": config.to_dict(),
        "fingerprint": config.measurement_fingerprint(),
        "versions": versions(),
    }
    if extra:
        summary.update(extra)
    return _clean(summary)


#: the files ``write_outputs`` writes (or removes: calibrated_sensors.txt, older plots)
OUTPUT_FILES = ("frames.csv", "config.json", "summary.json", "report.html", "junit.xml",
                "assets/index.json", "calibrated_sensors.txt")


def report_files() -> tuple[str, ...]:
    """Every file ``write_outputs`` (a run's last step and ``pgt-check report``) may write or
    remove, relative to the output folder: ``OUTPUT_FILES`` and the plots of either format."""
    from pgt_check.report.plots import PLOT_NAMES

    plots = [f"assets/plot_{n}.{ext}" for n in PLOT_NAMES for ext in ("svg", "png")]
    return (*OUTPUT_FILES, *plots)


def output_files() -> tuple[str, ...]:
    """Every file of fixed name a run may write or remove in its output folder (relative
    names; the record store and the report panels, named by frame hashes, aside): those of
    ``report_files``, of the correction stage and the separation check's probes. The completion marker lists those present;
    a run refuses to start where one exists that no marker lists (``store.check_outputs_owned``:
    it is not the tool's to replace)."""
    from pgt_check.correct.calibration import CALIBRATED_DIR, CALIBRATED_FILES
    from pgt_check.correct.frames import BAD_FRAMES_NAME, CORRECTED_NAME
    from pgt_check.correct.pose import CORRECTIONS_FILE
    from pgt_check.correct.registration import REFINED_FILE, REGISTERED_NAME
    from pgt_check.verdict.separation import SEPARATION_FILE

    return (*report_files(), CORRECTIONS_FILE, CORRECTED_NAME, BAD_FRAMES_NAME, REFINED_FILE,
            REGISTERED_NAME, SEPARATION_FILE,
            *(f"{CALIBRATED_DIR}/{n}" for n in CALIBRATED_FILES))


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
    for name in output_files():
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
    """Write frames.csv, config.json and summary.json into ``out`` from the verdict rows
    (``pgt_check.verdict.apply_verdicts``); return the summary. records.jsonl is the
    measurement store and is never rewritten here. With ``report`` (default) also report.html,
    its plots and junit.xml; ``assets`` (``{frame_id: {kind: relative path}}`` from
    ``write_frame_assets``) become the detail images, None keeps whatever
    ``assets/index.json`` already lists."""
    out = Path(out)
    check_outputs_owned(out, report_files())  # nothing of the user's is replaced or removed
    out.mkdir(parents=True, exist_ok=True)
    remove_completion_marker(out)
    atomic_write_text(out / "frames.csv", frames_csv_text(records))
    atomic_write_text(out / "config.json", json.dumps(config.settings_dict(), indent=2) + "\n")
    summary = build_summary(records, config, extra)
    # a significant calibration estimate as intrinsics a re-run loads (``--sensors``)
    from pgt_check.report.calibrated_sensors import write_calibrated_sensors

    calibrated = write_calibrated_sensors(out, records, summary.get("shared_errors"),
                                          summary.get("calibrated_rig"))
    if calibrated is not None:
        summary["calibrated_sensors"] = _clean(calibrated)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
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


def write_run(
    out: Path,
    result: RunResult,
    config: RunConfig,
    facts: RunFacts,
    *,
    assets: dict[str, dict[str, str]] | None = None,
) -> dict[str, Any]:
    """``write_outputs`` for a run's typed result (``verdict.RunResult``, or the correction
    stage's ``correct.result.CorrectedRun``): its rows and its summary sections, after
    ``facts``; return the summary."""
    extra = {**facts.sections(), **result.summary_extra()}
    if facts.wall_time_s is not None:
        extra["wall_time_s"] = facts.wall_time_s
    return write_outputs(out, result.rows(), config, extra=extra, assets=assets)
