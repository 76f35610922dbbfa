"""A finished run's stored measurements and settings, read back for re-judging without
measuring (``pgt-check report``, ``pgt_check.api.frames_dataframe``)."""

from __future__ import annotations

from pathlib import Path

from pgt_check.common.files import MAX_SMALL_JSON_BYTES, load_json_limited, regular_file_size
from pgt_check.config import moved_to_sections
from pgt_check.errors import InputError
from pgt_check.measure.record import FrameMeasurement, OldRecordError
from pgt_check.records_file import FINGERPRINT_KEY


def load_run(out_dir: Path) -> tuple[list[FrameMeasurement], dict]:
    """The stored measurements (trajectory order) and config.json of a finished run.

    Reads the current records of ``records.jsonl`` (the fingerprint and frame order come from
    ``run.json``); records of another pgt-check record layout are an InputError.
    """
    from pgt_check.output_layout import OUTPUTS
    from pgt_check.records_file import iter_records

    rec_path, cfg_path, run_path = (
        out_dir / OUTPUTS.records,
        out_dir / OUTPUTS.config_json,
        out_dir / OUTPUTS.run,
    )
    for p in (rec_path, cfg_path, run_path):
        if not p.exists():
            raise InputError(f"{p} not found: is {out_dir} a pgt-check output directory?")
    regular_file_size(rec_path, "record store")
    info = load_json_limited(run_path, MAX_SMALL_JSON_BYTES, OUTPUTS.run)
    cfg = load_json_limited(cfg_path, MAX_SMALL_JSON_BYTES, OUTPUTS.config_json)
    if not isinstance(info, dict):
        raise InputError(f"{run_path}: expected a JSON object; got {type(info).__name__}")
    if not isinstance(cfg, dict):
        raise InputError(f"{cfg_path}: expected a JSON object; got {type(cfg).__name__}")
    ids = info.get("frame_ids")
    if ids is not None and (
        not isinstance(ids, list) or not all(isinstance(i, str) for i in ids)
    ):
        raise InputError(f"{run_path}: expected 'frame_ids' to be a list of strings")
    latest = {
        str(r["frame_id"]): r
        for r in iter_records(rec_path)
        if r.get(FINGERPRINT_KEY) == info.get("fingerprint")
    }
    order = ids or list(latest)
    missing = [fid for fid in order if fid not in latest]
    if missing:
        raise InputError(
            f"{out_dir}: {len(missing)} of {len(order)} frames have no record (e.g. "
            f"{missing[0]!r}): the run did not finish; resume it first"
        )
    if not isinstance(info, dict) or not isinstance(cfg, dict):
        raise InputError(f"{out_dir}: run.json or config.json is not a JSON object")
    try:
        return [FrameMeasurement.from_json(latest[fid]) for fid in order], moved_to_sections(cfg)
    except OldRecordError as err:
        raise InputError(f"{rec_path}: {err}") from err
    except (KeyError, ValueError, TypeError, AttributeError, IndexError) as err:
        raise InputError(f"{rec_path}: a record is malformed ({type(err).__name__}: {err})") from err
