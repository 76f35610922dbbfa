"""The output folder of a run: the name of every file and folder ``pgt-check`` writes there,
which of them the completion marker (``outputs.complete.json``) covers, and which ones a run
claims before it starts (an input among them would be overwritten).

One frozen ``OutputLayout`` (the module-level ``OUTPUTS``); every writer, the completion marker,
the ownership check (``ownership.check_outputs_owned``) and the input-vs-output check
(``stages.inputs.run_output_paths``) read their names from it. Names are relative to the output folder,
``/``-separated. A new output file is one field here (with its group) and the line that writes it.
The other commands' outputs are named here too (``COMPARE_OUTPUTS``, ``ENHANCE_OUTPUTS``).

Groups (the ``group`` of each field):

- ``store``: the record store (``records.jsonl``, ``run.json``); written as frames finish,
  resumable, never listed by the marker.
- ``marker``: the completion marker itself, written last.
- ``report``: what ``report.outputs.write_outputs`` writes or removes (a run's last step and
  ``pgt-check report``), with the plots (``plot_files``); listed by the marker.
- ``correct`` / ``verdict``: the correction stage's files and the separation check's probes;
  listed by the marker.
- folders: ``assets/`` (the plots, ``assets/index.json`` and the panels under
  ``assets/frames/``, named by frame hashes, so not listed one by one) and ``calibrated/`` (the
  calibrated rig, ``calibrated_files``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

__all__ = ["COMPARE_OUTPUTS", "ENHANCE_OUTPUTS", "OUTPUTS", "CompareLayout", "EnhanceLayout",
           "OutputLayout"]

STORE, MARKER, REPORT, CORRECT, VERDICT = "store", "marker", "report", "correct", "verdict"
#: the groups the completion marker lists, in the order it lists them
MARKED_GROUPS = (REPORT, CORRECT, VERDICT)


def _name(name: str, group: str) -> str:
    return field(default=name, metadata={"group": group})


@dataclass(frozen=True)
class OutputLayout:
    """Every output name of a run (module docstring); ``OUTPUTS`` is the one instance."""

    # the record store
    records: str = _name("records.jsonl", STORE)
    run: str = _name("run.json", STORE)
    # written last: the output files and their sha256 (``report.outputs``, ``store``)
    completion_marker: str = _name("outputs.complete.json", MARKER)
    # the report (``report.outputs.write_outputs``, ``report.html``, ``report.assets``,
    # ``report.calibrated_sensors``)
    frames_csv: str = _name("frames.csv", REPORT)
    config_json: str = _name("config.json", REPORT)
    summary_json: str = _name("summary.json", REPORT)
    report_html: str = _name("report.html", REPORT)
    junit_xml: str = _name("junit.xml", REPORT)
    assets_index: str = _name("assets/index.json", REPORT)
    calibrated_sensors: str = _name("calibrated_sensors.txt", REPORT)
    # the correction stage (``pgt_check.correct``)
    corrections: str = _name("corrections.json", CORRECT)
    corrected_trajectory: str = _name("corrected_trajectory.txt", CORRECT)
    bad_frames: str = _name("bad_frames.txt", CORRECT)
    registration_refined: str = _name("registration_refined.json", CORRECT)
    registered_trajectory: str = _name("registered_trajectory.txt", CORRECT)
    # the separation check's probe measurements (``verdict.separation``)
    separation_probes: str = _name("separation_probes.json", VERDICT)
    # folders: the report's images and the calibrated rig (a LaMAR session)
    assets_dir: str = "assets"
    panels_dir: str = "assets/frames"  # one .jpg per panel and one .json per frame, by hash
    calibrated_dir: str = "calibrated"
    #: the files of ``calibrated_dir`` (``correct.calibration.write_calibrated_rig``)
    calibrated_files: tuple[str, ...] = ("sensors.txt", "images.txt", "trajectories.txt",
                                         "rigs.txt")
    #: the report's figures, ``assets/plot_<name>.<format>`` (``report.plots``; PNG: older runs)
    plot_names: tuple[str, ...] = ("error_hist", "error_time", "raw_vs_enhanced", "top_view",
                                   "drift")
    plot_formats: tuple[str, ...] = ("svg", "png")

    def group(self, group: str) -> tuple[str, ...]:
        """The file names of one group, in field order."""
        return tuple(getattr(self, f.name) for f in fields(self)
                     if f.metadata.get("group") == group)

    def plot_file(self, name: str, fmt: str = "svg") -> str:
        """``assets/plot_<name>.<fmt>``."""
        return f"{self.assets_dir}/plot_{name}.{fmt}"

    def plot_files(self) -> tuple[str, ...]:
        """Every plot name of either format (a regenerated report removes those it did not
        draw)."""
        return tuple(self.plot_file(n, ext) for n in self.plot_names for ext in self.plot_formats)

    def report_files(self) -> tuple[str, ...]:
        """Every file ``write_outputs`` (a run's last step and ``pgt-check report``) may write or
        remove: the ``report`` group and the plots."""
        return (*self.group(REPORT), *self.plot_files())

    def calibrated_paths(self) -> tuple[str, ...]:
        """The calibrated rig's files, ``calibrated/<name>``."""
        return tuple(f"{self.calibrated_dir}/{n}" for n in self.calibrated_files)

    def marked_files(self) -> tuple[str, ...]:
        """Every file of fixed name a run may write or remove (the record store and the panels,
        named by frame hashes, aside), in the order the completion marker lists those present:
        the report's, the correction stage's, the separation probes, the calibrated rig. A run
        refuses to start where one exists that no marker lists (``ownership.check_outputs_owned``:
        it is not the tool's to replace)."""
        return (*self.report_files(), *self.group(CORRECT), *self.group(VERDICT),
                *self.calibrated_paths())

    def top_level(self) -> tuple[str, ...]:
        """Every name directly in the output folder a run writes (files and folders, sorted):
        an input there would be overwritten (``stages.inputs.run_output_paths``)."""
        names = {n.split("/")[0] for n in (*self.group(STORE), *self.group(MARKER),
                                            *self.marked_files())}
        return tuple(sorted(names))

    def paths(self, out: str | Path) -> list[Path]:
        """``top_level`` as paths in ``out``."""
        return [Path(out) / n for n in self.top_level()]


OUTPUTS = OutputLayout()


@dataclass(frozen=True)
class CompareLayout:
    """What ``pgt-check compare`` writes in its ``--out``."""

    rows_csv: str = "compare.csv"
    summary_json: str = "compare.json"

    def paths(self, out: str | Path) -> list[Path]:
        return [Path(out) / self.rows_csv, Path(out) / self.summary_json]


@dataclass(frozen=True)
class EnhanceLayout:
    """What ``pgt-check enhance`` writes in its ``--out`` (metrics only with ground truth)."""

    images_dir: str = "images"
    references_csv: str = "references.csv"
    metrics_csv: str = "metrics.csv"
    metrics_md: str = "metrics.md"

    def paths(self, out: str | Path) -> list[Path]:
        return [Path(out) / n for n in (self.images_dir, self.references_csv, self.metrics_csv,
                                        self.metrics_md)]


COMPARE_OUTPUTS = CompareLayout()
ENHANCE_OUTPUTS = EnhanceLayout()
