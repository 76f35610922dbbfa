"""Reading and writing the user's files safely (``pgt_check/common/files.py``): size bounds, regular
files only, UTF-8 and JSON as FormatErrors, one-line safe text, atomic writes that replace a
symlink, and refusing outputs that are inputs."""

from __future__ import annotations

import os

import pytest

from pgt_check.common.files import (
    atomic_write_bytes,
    atomic_write_text,
    check_inputs_not_outputs,
    load_json_limited,
    read_bytes_limited,
    read_text_limited,
    regular_file_size,
    safe_text,
)
from pgt_check.errors import FormatError, InputError


def test_regular_file_size_refuses_missing_paths_and_directories(tmp_path):
    f = tmp_path / "a.txt"
    f.write_bytes(b"12345")
    assert regular_file_size(f) == 5
    with pytest.raises(InputError, match="pose file not found"):
        regular_file_size(tmp_path / "gone.txt", "pose file")
    with pytest.raises(InputError, match="got a directory"):
        regular_file_size(tmp_path)
    if os.path.exists("/dev/null"):
        with pytest.raises(InputError, match="not a regular file"):
            regular_file_size("/dev/null")


def test_read_bytes_limited_checks_the_size_before_reading(tmp_path):
    f = tmp_path / "a.bin"
    f.write_bytes(b"x" * 2048)
    assert read_bytes_limited(f, 2048) == b"x" * 2048
    with pytest.raises(InputError, match=r"image list is 2.0 KiB, more than the 1.0 KiB"):
        read_bytes_limited(f, 1024, "image list")


def test_read_text_limited_drops_a_bom_and_refuses_bytes_that_are_not_utf8(tmp_path):
    f = tmp_path / "a.txt"
    f.write_bytes(b"\xef\xbb\xbfline 1\nline 2\n")
    assert read_text_limited(f) == "line 1\nline 2\n"
    f.write_bytes(b"ok\n\xff\xfe")
    with pytest.raises(FormatError, match="expected a UTF-8 text file") as err:
        read_text_limited(f)
    assert err.value.path == str(f)


def test_load_json_limited_turns_every_failure_into_a_format_error(tmp_path):
    f = tmp_path / "a.json"
    f.write_text('{"a": [1, 2]}')
    assert load_json_limited(f) == {"a": [1, 2]}
    f.write_text('{"a": ')
    with pytest.raises(FormatError, match="expected valid JSON") as err:
        load_json_limited(f)
    assert err.value.line == 1
    f.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(FormatError, match="nested too deeply"):
        load_json_limited(f)
    f.write_text("[" + "1" * 10)
    with pytest.raises(InputError, match="more than"):
        load_json_limited(f, limit=4)


def test_safe_text_keeps_one_line():
    assert safe_text(None) == ""
    assert safe_text("a\tb") == "a\tb"  # tab kept
    assert safe_text("a\nb\rc\x07") == "a\\nb\\rc\\x07"
    assert safe_text("\u2028") == "\\u2028"
    name = b"img\xff.jpg".decode("utf-8", "surrogateescape")
    assert safe_text(name) == "img\\xff.jpg"
    assert safe_text(3.5) == "3.5"


def test_atomic_write_replaces_a_symlink_and_leaves_no_temporary_file(tmp_path):
    target = tmp_path / "target.txt"
    target.write_text("keep me")
    link = tmp_path / "out.txt"
    link.symlink_to(target)
    atomic_write_text(link, "new")
    assert not link.is_symlink() and link.read_text() == "new"
    assert target.read_text() == "keep me"  # never written through
    atomic_write_text(tmp_path / "s.txt", b"x\xff".decode("utf-8", "surrogateescape"))
    assert (tmp_path / "s.txt").read_bytes() == b"x\\udcff"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt", "s.txt", "target.txt"]


def test_atomic_write_removes_its_temporary_file_on_failure(tmp_path):
    with pytest.raises(TypeError):
        atomic_write_bytes(tmp_path / "a.bin", "not bytes")  # type: ignore[arg-type]
    assert list(tmp_path.iterdir()) == []


def test_check_inputs_not_outputs(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "traj.txt").write_text("")
    check_inputs_not_outputs(
        [("trajectory", tmp_path / "traj.txt"), ("mesh", None)], [out], "--out"
    )
    with pytest.raises(InputError, match="--out .*would overwrite the trajectory"):
        check_inputs_not_outputs([("trajectory", out / "traj.txt")], [out], "--out")
    with pytest.raises(InputError, match="would overwrite the mesh"):
        check_inputs_not_outputs([("mesh", out)], [out], "--out")
    # a sibling whose name starts like the output folder is not inside it
    check_inputs_not_outputs([("mesh", tmp_path / "out2" / "m.ply")], [out], "--out")
