"""A finished run judged again from its stored measurements, without measuring: the one path of
``pgt-check report`` and of the Python API's rows (``api.check``).

``stored_run`` reads a run folder back (records.jsonl, config.json) with the settings a
re-judgement changes; ``rejudge`` runs the verdict stage on the stored measurements, takes the
correction stage's stored files (``correct.result.stored_corrections``: corrections.json, a
registration refinement that started from this judgement's estimate) and decides the gate:
a ``RunOutcome``, as ``runner.run`` returns it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pgt_check.config import RunConfig, merge
from pgt_check.errors import InputError
from pgt_check.measure.record import FrameMeasurement
from pgt_check.verdict.outcome import InputsChanged, RunOutcome, judge_outcome

logger = logging.getLogger(__name__)

__all__ = ["StoredRun", "rejudge", "stored_run"]


@dataclass(frozen=True)
class StoredRun:
    """A finished run read back: its folder, its stored measurements (trajectory order), the
    settings it was measured with (config.json as stored, older layouts moved to their new
    place) and the config to judge with (those settings with the overrides)."""

    out: Path
    measurements: list[FrameMeasurement]
    settings: Mapping[str, Any]
    config: RunConfig


def stored_run(out: str | Path, overrides: Mapping[str, Any] | None = None) -> StoredRun:
    """``out``'s stored run (``report.stored.load_run``) with ``overrides`` (nested by section
    like a config file) merged into its settings; InputError for a folder that holds no
    finished run or a setting out of range."""
    from pgt_check.report.stored import load_run

    out = Path(out)
    records, settings = load_run(out)
    config = RunConfig.from_dict(merge(settings, dict(overrides or {})))
    return StoredRun(out, records, settings, config)


def rejudge(
    out: str | Path | StoredRun,
    overrides: Mapping[str, Any] | RunConfig | None = None,
    *,
    inputs_changed: InputsChanged | None = None,
    note: Callable[[str], None] | None = None,
) -> RunOutcome:
    """The outcome of judging ``out``'s stored measurements again (``out``: a run folder, or
    the ``StoredRun`` read from it). ``overrides``: settings merged into the stored ones
    (``stored_run``), or the ``RunConfig`` to judge with (the API: the run's own).
    ``inputs_changed``: input files changed since they were measured (the gate fails unless
    they are re-judged on purpose). ``note`` receives what the user should know (a stale
    registration refinement left out); default: logged.

    The separation check's stored probes and the correction stage's stored files are reused,
    nothing is measured. InputError when a stored record cannot be judged (malformed)."""
    from pgt_check.correct.result import stored_corrections
    from pgt_check.output_layout import OUTPUTS
    from pgt_check.verdict import judge_run
    from pgt_check.verdict.separation import load_probes

    note = note or logger.info
    if isinstance(out, StoredRun):
        if overrides is not None:
            raise ValueError("rejudge: a StoredRun carries its config; pass no overrides")
        stored = out
    elif isinstance(overrides, RunConfig):
        from pgt_check.report.stored import load_run

        stored = StoredRun(Path(out), load_run(Path(out))[0], {}, overrides)
    else:
        stored = stored_run(out, overrides)
    try:
        judged = judge_run(stored.measurements, stored.config, load_probes(stored.out))
    except (KeyError, ValueError, TypeError, AttributeError, IndexError) as err:
        if isinstance(err, InputError):
            raise
        raise InputError(
            f"{stored.out}: the stored records cannot be judged, one is malformed "
            f"({type(err).__name__}: {err}); measure again with --overwrite"
        ) from err
    result, stale = stored_corrections(judged, stored.out)
    if stale:
        note(f"{OUTPUTS.registration_refined} was measured for another registration estimate "
             "(other verdict settings); the estimate shown is not refined")
    return judge_outcome(result, stored.config, inputs_changed)
