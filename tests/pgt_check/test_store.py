"""RecordStore: append-only records.jsonl, tolerant reading, resume / overwrite policy."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from pgt_check.errors import InputError
from pgt_check.records_file import FINGERPRINT_KEY, iter_records
from pgt_check.store import RecordStore

SETTINGS = {"match": {"method": "sift", "max_keypoints": 4096}}


def rec(i: int, **kw) -> dict:
    return {"frame_id": f"f{i:03d}", "corner_error_px": float(i), **kw}


def fill(out, fingerprint: str, ids, **open_kw) -> None:
    with RecordStore.open(out, fingerprint, settings=SETTINGS, **open_kw) as store:
        for i in ids:
            store.append(rec(i, fp=fingerprint))


def test_append_read_and_run_json(tmp_path):
    fill(tmp_path, "aaa", range(5))
    lines = (tmp_path / "records.jsonl").read_text().splitlines()
    assert len(lines) == 5
    assert all(json.loads(line)[FINGERPRINT_KEY] == "aaa" for line in lines)
    info = json.loads((tmp_path / "run.json").read_text())
    assert info["fingerprint"] == "aaa" and info["settings"] == SETTINGS and info["version"]
    with RecordStore.open(tmp_path, "aaa") as store:
        assert store.done_ids() == {f"f{i:03d}" for i in range(5)}
        ordered = store.records_in_order(["f004", "f000"])
        assert [r["frame_id"] for r in ordered] == ["f004", "f000"]
        with pytest.raises(KeyError, match="f009"):
            store.records_in_order(["f000", "f009"])


def test_latest_record_per_frame_wins(tmp_path):
    with RecordStore.open(tmp_path, "aaa") as store:
        store.append(rec(1, corner_error_px=1.0))
        store.append(rec(1, corner_error_px=2.0))
        assert store.latest()["f001"]["corner_error_px"] == 2.0


def test_numpy_values_are_written_as_json(tmp_path):
    with RecordStore.open(tmp_path, "aaa") as store:
        store.append(rec(1, n=np.int64(3), h=np.eye(2), x=np.float32(0.5)))
        got = store.latest()["f001"]
    assert got["n"] == 3 and got["h"] == [[1.0, 0.0], [0.0, 1.0]] and got["x"] == 0.5


def test_torn_last_line_is_ignored_and_cut_on_open(tmp_path):
    fill(tmp_path, "aaa", range(3))
    path = tmp_path / "records.jsonl"
    good = path.read_bytes()
    path.write_bytes(good + b'{"_fingerprint": "aaa", "frame_id": "f00')
    assert [r["frame_id"] for r in iter_records(path)] == ["f000", "f001", "f002"]
    with RecordStore.open(tmp_path, "aaa") as store:
        assert path.read_bytes() == good
        store.append(rec(3))
    assert [r["frame_id"] for r in iter_records(path)] == ["f000", "f001", "f002", "f003"]


def test_unreadable_middle_line_is_skipped_with_a_warning(tmp_path, caplog):
    fill(tmp_path, "aaa", range(2))
    path = tmp_path / "records.jsonl"
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], "not json", "[1, 2]", lines[1]]) + "\n")
    with caplog.at_level(logging.WARNING, logger="pgt_check.records_file"):
        ids = [r["frame_id"] for r in iter_records(path)]
    assert ids == ["f000", "f001"]
    assert "skipped 2 unreadable lines" in caplog.text


def test_changed_settings_need_resume_or_overwrite(tmp_path):
    fill(tmp_path, "aaa", range(4))
    new_settings = {"match": {"method": "sift", "max_keypoints": 512}}
    with pytest.raises(InputError, match=r"--resume.*--overwrite") as info:
        RecordStore.open(tmp_path, "bbb", settings=new_settings)
    assert "match.max_keypoints" in str(info.value)
    # the refused run changed nothing
    assert json.loads((tmp_path / "run.json").read_text())["fingerprint"] == "aaa"

    # --resume: frames of the old settings are not done; new records are appended
    with RecordStore.open(tmp_path, "bbb", resume=True) as store:
        assert store.done_ids() == set()
        store.append(rec(0))
        store.append(rec(1))
    assert json.loads((tmp_path / "run.json").read_text())["fingerprint"] == "bbb"
    # back to the first settings: their records are still valid, nothing lost
    with RecordStore.open(tmp_path, "aaa", resume=True) as store:
        assert store.done_ids() == {"f000", "f001", "f002", "f003"}
        assert store.latest()["f000"]["fp"] == "aaa"
    assert len((tmp_path / "records.jsonl").read_text().splitlines()) == 6  # append-only


def test_same_settings_rerun_keeps_records(tmp_path):
    fill(tmp_path, "aaa", range(3))
    with RecordStore.open(tmp_path, "aaa") as store:
        assert len(store.done_ids()) == 3


def test_overwrite_starts_fresh(tmp_path):
    fill(tmp_path, "aaa", range(3))
    with RecordStore.open(tmp_path, "bbb", overwrite=True) as store:
        assert store.done_ids() == set()
        store.append(rec(7))
    assert [r["frame_id"] for r in iter_records(tmp_path / "records.jsonl")] == ["f007"]
    with pytest.raises(InputError, match="exclude each other"):
        RecordStore.open(tmp_path, "bbb", overwrite=True, resume=True)


def test_records_without_run_json_are_of_unknown_settings(tmp_path):
    (tmp_path / "records.jsonl").write_text(json.dumps(rec(1)) + "\n")
    with pytest.raises(InputError, match="other measurement settings"):
        RecordStore.open(tmp_path, "aaa")
    with RecordStore.open(tmp_path, "aaa", resume=True) as store:
        assert store.done_ids() == set()


def test_one_writer_at_a_time(tmp_path):
    with RecordStore.open(tmp_path, "aaa"):
        with pytest.raises(InputError, match="another pgt-check run"):
            RecordStore.open(tmp_path, "aaa")
    RecordStore.open(tmp_path, "aaa").close()  # released on close


def test_fsync_per_batch(tmp_path, monkeypatch):
    import os

    calls = []
    real = os.fsync
    monkeypatch.setattr("pgt_check.store.os.fsync", lambda fd: (calls.append(fd), real(fd)))
    with RecordStore.open(tmp_path, "aaa", sync_every=10, sync_interval_s=1e9) as store:
        n0 = len(calls)
        for i in range(25):
            store.append(rec(i))
        assert len(calls) - n0 == 2
        # but every record is already written to the OS (survives a SIGKILL)
        assert len((tmp_path / "records.jsonl").read_text().splitlines()) == 25
    assert len(calls) - n0 == 3  # the rest on close


def test_records_read_as_typed_values_with_their_input_key(tmp_path):
    """``append_measurement`` stamps a record with its input key; ``latest_records`` reads the
    frame, fingerprint and input key back typed (None where a record has no input key)."""
    from pgt_check.records_file import INPUT_KEY, StoredRecord

    with RecordStore.open(tmp_path, "fp1", settings=SETTINGS) as store:
        store.append_measurement(rec(0), "k0")
        store.append(rec(1))
        got = store.latest_records()
        assert set(store.latest_records(["f001"])) == {"f001"}
    assert got["f000"] == StoredRecord("f000", "fp1", "k0", got["f000"].data)
    assert got["f000"].data[INPUT_KEY] == "k0" and got["f000"].data["corner_error_px"] == 0.0
    assert got["f001"].input_key is None
