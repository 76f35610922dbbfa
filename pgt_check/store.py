"""Per-frame result store: an append-only ``records.jsonl`` plus ``run.json`` in the out dir.

Each line of ``records.jsonl`` is one stage-1 measurement record (a JSON object) carrying the
``_fingerprint`` of the measurement settings it was made with (``RunConfig.
measurement_fingerprint``). Lines are appended as frames finish, flushed to the OS per record
(a SIGKILL loses nothing written) and fsync'd per batch (a power cut loses at most one batch).

Reading is tolerant: a torn last line (the process died mid-write) is ignored and cut off when
the store is opened for appending; an unreadable line elsewhere (not JSON, not a record, or
longer than ``MAX_RECORD_LINE_BYTES``: read past in bounded chunks, never held whole) is skipped
with a warning (its frame is then measured again). The record of a frame is the *latest* line with that frame id
and the current fingerprint, so a resumed run appends new lines and never edits old ones.

``run.json`` holds the current fingerprint, the measurement settings and the tool version
(written atomically by ``files.atomic_write_text``, read with a size bound). A
rerun with the same fingerprint skips the frames already recorded; with a different fingerprint
it stops with ``InputError`` unless ``resume`` (recompute the frames without a record for the new
settings) or ``overwrite`` (start fresh) is given. One run at a time may write a store (an
advisory ``flock`` on ``records.jsonl``; released by the OS even after SIGKILL).

The line format and tolerant reading are ``records_file``'s, the input files' hashes
``content_hash``'s, and which output files a run may replace ``ownership``'s.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from pgt_check import __version__
from pgt_check.common.files import (
    MAX_SMALL_JSON_BYTES,
    atomic_write_text,
    load_json_limited,
    open_append,
)
from pgt_check.content_hash import INPUT_FILES_KEY
from pgt_check.errors import FormatError, InputError
from pgt_check.ownership import OUTPUTS_KEY, check_outputs_owned, check_store_files_owned
from pgt_check.records_file import (
    FINGERPRINT_KEY,
    INPUT_KEY,
    RECORDS_FILE,
    RUN_FILE,
    StoredRecord,
    encode_record,
    iter_records,
    truncate_torn_tail,
)

logger = logging.getLogger(__name__)

def _settings_diff(old: Mapping[str, Any], new: Mapping[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two nested settings dicts."""
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            out += _settings_diff(a, b, f"{prefix}{key}.")
        elif a != b:
            out.append(f"{prefix}{key}")
    return out


class RecordStore:
    """Append-only per-frame records of one output directory (see the module docstring).

    Use :meth:`open` (applies the resume / overwrite policy, writes ``run.json``, opens the file
    for appending); then :meth:`append` each record as its frame finishes and :meth:`close`
    (or use it as a context manager). Only the process that opened it writes to it.
    """

    def __init__(
        self,
        out_dir: str | Path,
        fingerprint: str,
        *,
        sync_every: int = 64,
        sync_interval_s: float = 2.0,
    ) -> None:
        self.out_dir = Path(out_dir)
        self.fingerprint = fingerprint
        self.path = self.out_dir / RECORDS_FILE
        self.run_path = self.out_dir / RUN_FILE
        self.sync_every = sync_every
        self.sync_interval_s = sync_interval_s
        self._file: IO[bytes] | None = None
        self._unsynced = 0
        self._last_sync = time.monotonic()
        self.n_appended = 0

    # -- opening ----------------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        out_dir: str | Path,
        fingerprint: str,
        *,
        resume: bool = False,
        overwrite: bool = False,
        settings: Mapping[str, Any] | None = None,
        frame_ids: Iterable[str] | None = None,
        outputs: Iterable[str] = (),
        input_files: Mapping[str, str] | None = None,
        **kwargs: Any,
    ) -> RecordStore:
        """Open the store of ``out_dir`` for a run with ``fingerprint``.

        ``outputs``: the output files the run may write or remove (relative names); each one
        that exists must have been written by pgt-check (``check_outputs_owned``), and run.json
        claims them all for this run. ``input_files``: path -> content hash of each input file
        (kept in run.json for ``changed_inputs``). Raises InputError if ``out_dir`` holds a file of such a
        name that pgt-check did not write, records of other settings and neither ``resume``
        nor ``overwrite`` is set, or if another run is writing to it.
        """
        if resume and overwrite:
            raise InputError("--resume and --overwrite exclude each other: pick one")
        store = cls(out_dir, fingerprint, **kwargs)
        outputs = sorted(set(outputs))
        check_outputs_owned(store.out_dir, outputs)  # before anything is written
        check_store_files_owned(store.out_dir)
        store.out_dir.mkdir(parents=True, exist_ok=True)
        store._open_file()
        try:
            check_outputs_owned(store.out_dir, outputs)  # again, under the lock
            check_store_files_owned(store.out_dir)
            store._apply_policy(
                resume=resume, overwrite=overwrite, settings=settings,
                frame_ids=None if frame_ids is None else list(frame_ids), outputs=outputs,
                input_files=input_files,
            )
        except BaseException:
            store.close()
            raise
        return store

    def _open_file(self) -> None:
        self._file = open_append(self.path)  # a symlink is replaced, never written through
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no lock
            return
        try:
            fcntl.flock(self._file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as err:
            self._file.close()
            self._file = None
            raise InputError(
                f"{self.out_dir}: another pgt-check run is writing to this directory "
                "(wait for it to finish or choose another --out)"
            ) from err

    def read_run_info(self) -> dict[str, Any] | None:
        """``run.json`` (None when there is none). One that is not a JSON object counts as
        unknown settings (``{}``, with a warning); one larger than ``MAX_SMALL_JSON_BYTES`` is
        an InputError, never read whole."""
        if not self.run_path.is_file():
            return None
        try:
            info = load_json_limited(self.run_path, MAX_SMALL_JSON_BYTES, RUN_FILE)
        except FormatError:
            info = None
        if not isinstance(info, dict):
            logger.warning(
                "%s is not a JSON object; treating the stored settings as unknown", self.run_path
            )
            return {}
        return info

    def _apply_policy(
        self, *, resume: bool, overwrite: bool, settings: Mapping[str, Any] | None,
        frame_ids: list[str] | None = None, outputs: list[str] | None = None,
        input_files: Mapping[str, str] | None = None,
    ) -> None:
        assert self._file is not None
        has_records = self.path.stat().st_size > 0
        info = self.read_run_info()
        if overwrite and (has_records or info is not None):
            logger.info("--overwrite: discarding the records in %s", self.path)
            self._file.truncate(0)
            has_records = False
        elif has_records:
            removed = truncate_torn_tail(self.path)
            if removed:
                logger.info("%s: cut %d bytes of an interrupted write", self.path, removed)
            old = (info or {}).get("fingerprint")
            if old != self.fingerprint and not resume:
                what = ""
                if info and settings is not None and isinstance(info.get("settings"), Mapping):
                    diff = _settings_diff(info["settings"], settings)
                    if diff:
                        what = f" (changed: {', '.join(diff[:6])})"
                raise InputError(
                    f"{self.out_dir} holds results of other measurement settings{what}: pass "
                    "--resume to keep the frames whose settings are unchanged and measure the "
                    "others, --overwrite to start fresh, or choose another --out"
                )
            if info and info.get("version") not in (None, __version__):
                logger.warning(
                    "%s was written by pgt-check %s (this is %s)",
                    self.out_dir,
                    info.get("version"),
                    __version__,
                )
        self._write_run_info(settings, frame_ids, outputs, input_files)

    def _write_run_info(
        self, settings: Mapping[str, Any] | None, frame_ids: list[str] | None = None,
        outputs: list[str] | None = None, input_files: Mapping[str, str] | None = None,
    ) -> None:
        info = {
            "tool": "pgt-check",
            "version": __version__,
            "fingerprint": self.fingerprint,
            "records": RECORDS_FILE,
            "settings": dict(settings) if settings is not None else None,
            # the run's frames in trajectory order (records are appended as frames finish)
            "frame_ids": frame_ids,
            # the output names this run may write (``owned_outputs`` while no marker lists them)
            OUTPUTS_KEY: list(outputs or ()),
            # what the measurements read (``changed_inputs``: what changed since)
            INPUT_FILES_KEY: dict(input_files or {}),
        }
        atomic_write_text(self.run_path, json.dumps(info, indent=2, default=str) + "\n")

    # -- reading ----------------------------------------------------------------------------
    def iter_current(self) -> Iterator[dict[str, Any]]:
        """Records made with the current fingerprint, in file order (duplicates included)."""
        for rec in iter_records(self.path):
            if rec.get(FINGERPRINT_KEY) == self.fingerprint:
                yield rec

    def done_ids(self) -> set[str]:
        """Frame ids that have a record for the current fingerprint."""
        self._flush(sync=False)
        return {str(rec["frame_id"]) for rec in self.iter_current()}

    def latest(self, frame_ids: Iterable[str] | None = None) -> dict[str, dict[str, Any]]:
        """The latest current-fingerprint record per frame id (only ``frame_ids`` if given)."""
        self._flush(sync=False)
        wanted = None if frame_ids is None else set(frame_ids)
        out: dict[str, dict[str, Any]] = {}
        for rec in self.iter_current():
            fid = str(rec["frame_id"])
            if wanted is None or fid in wanted:
                out[fid] = rec
        return out

    def latest_records(self, frame_ids: Iterable[str] | None = None) -> dict[str, StoredRecord]:
        """``latest`` read as typed ``StoredRecord``s."""
        return {fid: StoredRecord.of(rec) for fid, rec in self.latest(frame_ids).items()}

    def records_in_order(self, frame_ids: Iterable[str]) -> list[dict[str, Any]]:
        """Current records of ``frame_ids`` in that order; KeyError names the first missing."""
        ids = list(frame_ids)
        latest = self.latest(ids)
        missing = [fid for fid in ids if fid not in latest]
        if missing:
            raise KeyError(f"{len(missing)} frames have no record, e.g. {missing[0]!r}")
        return [latest[fid] for fid in ids]

    # -- writing ----------------------------------------------------------------------------
    def append(self, record: Mapping[str, Any]) -> None:
        """Append one record (written to the OS now, fsync'd per batch)."""
        if self._file is None:
            raise RuntimeError("RecordStore is not open")
        self._file.write(encode_record(record, self.fingerprint))
        self.n_appended += 1
        self._unsynced += 1
        now = time.monotonic()
        sync = self._unsynced >= self.sync_every or now - self._last_sync >= self.sync_interval_s
        self._flush(sync=sync)

    def append_measurement(self, record: Mapping[str, Any], input_key: str) -> None:
        """Append a frame's measurement (``FrameMeasurement.to_json``) with its input key."""
        self.append({**record, INPUT_KEY: input_key})

    def _flush(self, *, sync: bool) -> None:
        if self._file is None:
            return
        self._file.flush()
        if sync and self._unsynced:
            os.fsync(self._file.fileno())
            self._unsynced = 0
            self._last_sync = time.monotonic()

    def close(self) -> None:
        if self._file is None:
            return
        try:
            self._flush(sync=True)
        finally:
            self._file.close()  # also releases the flock
            self._file = None

    def __enter__(self) -> RecordStore:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
