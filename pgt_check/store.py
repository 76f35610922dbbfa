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
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
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
from pgt_check.errors import FormatError, InputError
from pgt_check.output_layout import OUTPUTS

logger = logging.getLogger(__name__)

#: files up to this size are hashed whole; bigger ones by size + first/last MiB + 64 samples
FULL_HASH_MAX_BYTES = 256 << 20
_SAMPLE_BYTES = 1 << 20


def content_hash(path: str | Path) -> str:
    """A cheap, mtime-independent hash of a file's content (or a directory's files).

    A file of at most ``FULL_HASH_MAX_BYTES`` (256 MiB): sha256 of its bytes. A bigger file:
    sha256 of its size, its first and last MiB and 64 evenly spaced 4 KiB samples (an edit
    that keeps the size and touches none of those bytes goes unnoticed: documented trade-off
    for multi-GB meshes). A directory (a COLMAP model): the hashes of its files by name.
    Returns "missing" for a path that does not exist.
    """
    import hashlib

    path = Path(path)
    if path.is_dir():
        h = hashlib.sha256()
        for child in sorted(p for p in path.iterdir() if p.is_file()):
            h.update(f"{child.name}={content_hash(child)};".encode())
        return "dir:" + h.hexdigest()[:32]
    if not path.is_file():
        return "missing"
    size = path.stat().st_size
    h = hashlib.sha256(f"{size};".encode())
    with open(path, "rb") as f:
        if size <= FULL_HASH_MAX_BYTES:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        else:
            h.update(f.read(_SAMPLE_BYTES))
            for i in range(64):
                f.seek(size * i // 64)
                h.update(f.read(4096))
            f.seek(size - _SAMPLE_BYTES)
            h.update(f.read(_SAMPLE_BYTES))
    return h.hexdigest()[:32]


def mesh_content_hash(path: str | Path, side_files: Iterable[str] = ()) -> str:
    """The content hash of a mesh as its loader read it: ``content_hash`` of the mesh file and
    of each side file it read (``MeshData.side_files``: OBJ materials and textures, glTF
    buffers and images; ``"missing:<name>"`` entries are hashed as the name). A mesh without
    side files (PLY, GLB) hashes as its file alone."""
    import hashlib

    main = content_hash(path)
    side = list(side_files)
    if not side:
        return main
    h = hashlib.sha256(f"{main};".encode())
    folder = Path(path).absolute().parent
    for name in side:
        if name.startswith("missing:"):
            key, digest = name, "missing"
        else:  # named relative to the mesh: a moved dataset folder keeps its hash
            key, digest = os.path.relpath(name, folder), content_hash(name)
        h.update(f"{key}={digest};".encode())
    return "mesh+side:" + h.hexdigest()[:32]


#: written last by ``report.outputs.write_outputs``: the output files and their sha256. Its
#: absence means the output set is incomplete (a run or ``pgt-check report`` is writing, or was
#: killed midway). It also says which files of the folder pgt-check wrote (``owned_outputs``)
COMPLETION_MARKER = OUTPUTS.completion_marker
#: run.json's key of the output names a run claims while its outputs are incomplete
OUTPUTS_KEY = "outputs"


def owned_outputs(out_dir: str | Path) -> set[str]:
    """The output files of ``out_dir`` that pgt-check wrote, which a run may replace or remove:
    those the completion marker lists; while the outputs are incomplete (no marker: a run or
    ``pgt-check report`` was stopped midway), the names run.json claims (a run claims every
    output name once it found none of them foreign). Nothing in a folder without either."""
    out = Path(out_dir)
    marker = out / COMPLETION_MARKER
    if marker.is_file():
        try:
            files = load_json_limited(marker, MAX_SMALL_JSON_BYTES, COMPLETION_MARKER)["files"]
            if isinstance(files, dict):
                return {str(k) for k in files}
        except (InputError, KeyError, TypeError):
            pass  # unreadable: what run.json claims
    run = out / RUN_FILE
    if run.is_file():
        try:  # a special or oversized run.json is an InputError of its own
            claimed = load_json_limited(run, MAX_SMALL_JSON_BYTES, RUN_FILE).get(OUTPUTS_KEY)
        except (FormatError, AttributeError):  # not JSON, not an object: claims nothing
            return set()
        if isinstance(claimed, list):
            return {str(k) for k in claimed}
    return set()


def check_outputs_owned(out_dir: str | Path, names: Iterable[str]) -> None:
    """InputError naming the first of ``names`` (output files, relative to ``out_dir``) that
    exists in ``out_dir`` but was not written there by pgt-check (``owned_outputs``): a run
    would replace or remove a file of the user's (a ``calibrated/`` session of their own)."""
    out = Path(out_dir)
    owned = None
    for name in names:
        path = out / name
        if not os.path.lexists(path):
            continue
        if owned is None:
            owned = owned_outputs(out)
        if name not in owned:
            raise InputError(
                f"{path}: this file was not written by pgt-check (no earlier run's "
                f"{COMPLETION_MARKER} in {out} lists it) and a run would replace or remove it: "
                "move it away or choose another --out"
            )


def _store_file_is_ours(path: Path) -> bool | None:
    """Whether the store file ``path`` (run.json, records.jsonl or the completion marker) was
    written by pgt-check, from its content: None when there is nothing to lose (missing,
    empty, a symbolic link, which is replaced and its target left alone) or it cannot be
    read as a regular file (refused where it is opened)."""
    if path.is_symlink() or not path.is_file():
        return None
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return None
    if not head.strip():
        return None
    if path.name == RECORDS_FILE:  # JSON lines: the first one a frame's record
        first = head.lstrip().split(b"\n", 1)[0]
        return first.startswith(b"{") and (
            b'"' + FINGERPRINT_KEY.encode() + b'"' in first or b'"frame_id"' in first)
    try:
        info = load_json_limited(path, MAX_SMALL_JSON_BYTES, path.name)
    except InputError:
        return False
    return isinstance(info, dict) and (
        info.get("tool") == "pgt-check" or (path.name == RUN_FILE and "fingerprint" in info)
    )


def check_store_files_owned(out_dir: str | Path) -> None:
    """InputError naming run.json, records.jsonl or outputs.complete.json in ``out_dir`` when
    it holds data pgt-check did not write there, and the folder is not one of pgt-check's
    (none of the three is recognisably the tool's). A run replaces run.json and the marker,
    and ``--overwrite`` empties records.jsonl: another tool's file of such a name is the
    user's (the third audit: a ``run.json`` or ``records.jsonl`` of one's own in ``--out``
    was replaced, with ``--overwrite`` even records.jsonl). A damaged file of a pgt-check
    folder stays the run's to handle (unknown settings: ``--resume`` / ``--overwrite``)."""
    out = Path(out_dir)
    seen = {name: _store_file_is_ours(out / name)
            for name in (RUN_FILE, RECORDS_FILE, COMPLETION_MARKER)}
    if any(ours for ours in seen.values()):
        return
    for name, ours in seen.items():
        if ours is False:
            raise InputError(
                f"{out / name}: this file was not written by pgt-check and a run would replace "
                "it: move it away or choose another --out"
            )


#: run.json's key of the input files' content hashes (absolute path -> ``content_hash``)
INPUT_FILES_KEY = "input_files"


def changed_inputs(run_info: Mapping[str, Any], config_input: Mapping[str, Any] | None = None
                   ) -> tuple[list[str], list[str]]:
    """(changed, unreadable): the input files of a run (run.json, ``INPUT_FILES_KEY``) whose
    content differs now from when they were measured, and those that cannot be read any more
    (moved or deleted: not checked). A run.json of an older version without that key: its mesh
    alone (``settings.inputs.mesh`` against ``config_input["mesh"]``, where the hash covers the
    mesh file alone)."""
    files = run_info.get(INPUT_FILES_KEY)
    if not isinstance(files, Mapping):
        settings = run_info.get("settings")
        stored = (settings or {}).get("inputs", {}).get("mesh") if isinstance(settings, Mapping) \
            else None
        mesh = (config_input or {}).get("mesh")
        if not isinstance(stored, str) or not mesh or stored.startswith("mesh+side:"):
            return [], []
        files = {os.path.abspath(str(mesh)): stored}
    changed, unreadable = [], []
    for path, digest in files.items():
        try:
            now = content_hash(path)
        except OSError:
            now = "missing"
        if now == "missing":
            unreadable.append(str(path))
        elif now != digest:
            changed.append(str(path))
    return changed, unreadable


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


def _truncate_torn_tail(path: Path) -> int:
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
            removed = _truncate_torn_tail(self.path)
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
