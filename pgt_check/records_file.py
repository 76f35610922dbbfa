"""The format of ``records.jsonl``: one JSON line per measurement record, stamped with the
fingerprint of its settings (``encode_record``), read tolerantly (``iter_records``: a torn last
line and unreadable or oversized lines are skipped, never held whole) and a torn tail cut off
before appending. ``store.RecordStore`` keeps the file; split out of ``store.py`` (its size).
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from pgt_check.output_layout import OUTPUTS

logger = logging.getLogger(__name__)

RECORDS_FILE = OUTPUTS.records
#: longest line of records.jsonl read (a record is ~15 KB; a longer line is a corrupt record)
MAX_RECORD_LINE_BYTES = 16 * 1024**2
RUN_FILE = OUTPUTS.run
FINGERPRINT_KEY = "_fingerprint"
#: a record's key of the frame's inputs (pose, camera, image content, reference photos:
#: ``stages.inputs.frame_input_keys``); a stored record counts as done only with the same key
INPUT_KEY = "input_key"


@dataclass(frozen=True)
class StoredRecord:
    """One record of the store read as the store keys it: the frame, the fingerprint and the
    input key it was measured with (None: a record without one), and the record itself (a
    ``FrameMeasurement.to_json`` with those keys)."""

    frame_id: str
    fingerprint: str | None
    input_key: str | None
    data: Mapping[str, Any]

    @classmethod
    def of(cls, rec: Mapping[str, Any]) -> StoredRecord:
        key, fp = rec.get(INPUT_KEY), rec.get(FINGERPRINT_KEY)
        return cls(str(rec["frame_id"]), None if fp is None else str(fp),
                   None if key is None else str(key), rec)


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays in records become plain JSON numbers and lists."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"record value of type {type(value).__name__} is not JSON-serialisable")


def encode_record(record: Mapping[str, Any], fingerprint: str) -> bytes:
    """One JSONL line (with trailing newline) for ``record`` stamped with ``fingerprint``."""
    rec = {FINGERPRINT_KEY: fingerprint}
    rec.update((k, v) for k, v in record.items() if k != FINGERPRINT_KEY)
    return (json.dumps(rec, default=_json_default) + "\n").encode("utf-8")


def _skip_rest_of_line(f: IO[bytes]) -> tuple[int, bool]:
    """Read past the rest of the current line in bounded chunks; (bytes skipped, whether a
    newline ended it: False at the end of the file)."""
    skipped = 0
    while True:
        chunk = f.readline(1 << 20)
        skipped += len(chunk)
        if not chunk:
            return skipped, False
        if chunk.endswith(b"\n"):
            return skipped, True


def iter_records(path: str | Path) -> Iterator[dict[str, Any]]:
    """Records of a JSONL file in file order; skips a torn last line and unreadable lines.

    A line longer than ``MAX_RECORD_LINE_BYTES`` is never held in memory: it is read past in
    bounded chunks and counted as an unreadable line (its frame is measured again), like a line
    that is not JSON."""
    path = Path(path)
    if not path.is_file():
        return
    bad = oversized = 0
    with open(path, "rb") as f:
        while True:
            raw = f.readline(MAX_RECORD_LINE_BYTES + 1)
            if not raw:
                break
            if len(raw) > MAX_RECORD_LINE_BYTES and not raw.endswith(b"\n"):
                skipped, ended = _skip_rest_of_line(f)
                if not ended:  # a torn last line, however long
                    logger.info("%s: ignoring an incomplete last line (%d bytes)", path,
                                len(raw) + skipped)
                    break
                bad += 1
                oversized += 1
                continue
            if not raw.endswith(b"\n"):
                logger.info("%s: ignoring an incomplete last line (%d bytes)", path, len(raw))
                break
            if not raw.strip():
                continue
            try:
                rec = json.loads(raw)
            except (ValueError, RecursionError):
                bad += 1
                continue
            if isinstance(rec, dict) and "frame_id" in rec:
                yield rec
            else:
                bad += 1
    if bad:
        longer = (f", {oversized} of them longer than the {MAX_RECORD_LINE_BYTES >> 20} MiB a "
                  "record may have" if oversized else "")
        logger.warning(
            "%s: skipped %d unreadable lines%s (those frames are measured again)", path, bad,
            longer,
        )


def truncate_torn_tail(path: Path) -> int:
    """Cut a last line that has no newline (a write killed midway); return bytes removed."""
    with open(path, "rb+") as f:
        end = f.seek(0, os.SEEK_END)
        pos, chunk = end, 1 << 16
        while pos > 0:
            start = max(0, pos - chunk)
            f.seek(start)
            data = f.read(pos - start)
            i = data.rfind(b"\n")
            if i >= 0:
                keep = start + i + 1
                break
            pos = start
        else:
            keep = 0
        if keep < end:
            f.truncate(keep)
            f.flush()
            os.fsync(f.fileno())
        return end - keep
