"""Which files of an output folder pgt-check wrote, so that a run never replaces a user's file.

The completion marker lists the outputs of a finished run; while outputs are incomplete run.json
claims their names (``owned_outputs``). ``check_outputs_owned`` and ``check_store_files_owned``
refuse a folder holding a file of such a name that another tool or the user wrote. Split out of
``store.py`` (its size).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from pgt_check.common.files import MAX_SMALL_JSON_BYTES, load_json_limited
from pgt_check.errors import FormatError, InputError
from pgt_check.output_layout import OUTPUTS
from pgt_check.records_file import FINGERPRINT_KEY, RECORDS_FILE, RUN_FILE

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
