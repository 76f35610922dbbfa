"""Second hostile-input audit (issue #25): the run store (``records.jsonl``, ``run.json``).

A single huge line of ``records.jsonl`` is read past in bounded chunks and counted as a corrupt
record (its frame measured again), like any unreadable line; ``run.json`` is read with a size
bound, one that is not a JSON object is "unknown settings" (never a traceback), and it is
written by the one atomic writer (``files.atomic_write_text``: no fixed temp name to follow)."""

from __future__ import annotations

import json
import logging
import tracemalloc
from pathlib import Path

from pgt_check.records_file import MAX_RECORD_LINE_BYTES, iter_records


def _record(fid: str) -> bytes:
    return (json.dumps({"_fingerprint": "f", "frame_id": fid, "x": 1}) + "\n").encode()


def _huge_line(path: Path, n_bytes: int, *, newline: bool = True) -> None:
    """Append a line of ``n_bytes`` NUL bytes (sparse on disk, cheap to make)."""
    with open(path, "r+b") as f:
        end = f.seek(0, 2)
        f.truncate(end + n_bytes)
        if newline:
            f.seek(0, 2)
            f.write(b"\n")


def test_huge_line_is_skipped_with_bounded_memory(tmp_path, caplog):
    path = tmp_path / "records.jsonl"
    path.write_bytes(_record("a"))
    _huge_line(path, 8 * MAX_RECORD_LINE_BYTES)  # 128 MiB on one line (sparse)
    with open(path, "ab") as f:
        f.write(_record("b"))
    tracemalloc.start()
    try:
        with caplog.at_level(logging.WARNING, logger="pgt_check.records_file"):
            ids = [r["frame_id"] for r in iter_records(path)]
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert ids == ["a", "b"]  # the records around it are kept
    # the 128 MiB line was never held whole (readline's buffer of the bound may double)
    assert peak < 3 * MAX_RECORD_LINE_BYTES
    assert "skipped 1 unreadable lines, 1 of them longer than the 16 MiB" in caplog.text


def test_huge_torn_last_line_is_ignored(tmp_path):
    path = tmp_path / "records.jsonl"
    path.write_bytes(_record("a"))
    _huge_line(path, 2 * MAX_RECORD_LINE_BYTES, newline=False)
    assert [r["frame_id"] for r in iter_records(path)] == ["a"]


def test_line_at_the_bound_is_still_read(tmp_path):
    path = tmp_path / "records.jsonl"
    rec = _record("a")
    pad = MAX_RECORD_LINE_BYTES - len(rec)  # the line, newline included, is the bound + 0
    path.write_bytes(rec[:-2] + b" " * pad + rec[-2:])
    assert len(path.read_bytes()) == MAX_RECORD_LINE_BYTES
    assert [r["frame_id"] for r in iter_records(path)] == ["a"]


def _lines(path: Path) -> list[bytes]:
    return path.read_bytes().splitlines(keepends=True)


def test_cli_huge_record_line_is_a_corrupt_record(cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    rec = out / "records.jsonl"
    first, second = _lines(rec)
    rec.write_bytes(first)
    _huge_line(rec, 2 * MAX_RECORD_LINE_BYTES)  # the second frame's record replaced
    rc, out_text, err = cli(*base_args(out=out)[:-1])  # not -q: the warning is shown
    case("records.jsonl: one 32 MiB line (a record's place)", "the record is corrupt: its frame "
         "measured again, exit as before", f"{rc}: " + next(
             (ln for ln in err.splitlines() if "unreadable" in ln), "no warning")[-110:])
    assert rc == 0 and "Traceback" not in err
    assert "longer than the 16 MiB a record may have" in err
    assert "measuring 1 of 2 frames" in err or "1 of 2" in err
    frames = [json.loads(x)["frame_id"] for x in _lines(rec)[2:]]
    assert frames == [json.loads(second)["frame_id"]]  # measured again, appended


def test_run_json_not_an_object_is_unknown_settings(cli, base_args, tmp_path, case):
    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    (out / "run.json").write_text("[1, 2]\n")
    rc, _, err = cli(*base_args(out=out))
    case("run.json is a JSON list", "2, one line (settings unknown: --resume/--overwrite)",
         f"{rc}: {err.strip().splitlines()[-1][:110]}")
    assert rc == 2 and "Traceback" not in err and "--resume" in err
    rc, _, err = cli(*base_args("--resume", out=out))
    assert rc == 0 and "Traceback" not in err
    assert json.loads((out / "run.json").read_text())["tool"] == "pgt-check"


def test_run_json_too_large_is_refused(cli, base_args, tmp_path, monkeypatch):
    import pgt_check.store as store

    out = tmp_path / "out"
    assert cli(*base_args(out=out))[0] == 0
    monkeypatch.setattr(store, "MAX_SMALL_JSON_BYTES", 64)
    rc, _, err = cli(*base_args(out=out))
    assert rc == 2 and "run.json" in err and "read at most" in err and "Traceback" not in err


def test_run_json_written_atomically_not_through_a_link(cli, base_args, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me\n")
    (out / "run.json.tmp").symlink_to(victim)  # the old fixed temp name
    (out / "run.json").symlink_to(victim)
    assert cli(*base_args(out=out))[0] == 0
    assert victim.read_text() == "keep me\n"
    assert not (out / "run.json").is_symlink()
    assert json.loads((out / "run.json").read_text())["tool"] == "pgt-check"
