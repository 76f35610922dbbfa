"""The text readers' shared parsing (``io/_text.py``): data lines, fields, numbers, timestamps,
quaternions and unique keys, every failure a FormatError naming the file and line."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from pgt_check.errors import FormatError
from pgt_check.io._text import (
    QuaternionCounter,
    UniqueKeys,
    data_lines,
    is_integer_token,
    parse_float,
    parse_int,
    parse_timestamp,
    read_text,
    split_row,
)

P = "poses.txt"


def test_data_lines_skip_comments_and_blanks_with_line_numbers(tmp_path):
    f = tmp_path / "a.txt"
    f.write_text("# header\n\n  1 2 3  \n# more\n4 5 6\n")
    assert read_text(f)[2] == "  1 2 3  "
    assert data_lines(f) == [(3, "1 2 3"), (5, "4 5 6")]
    f.write_text("# only a comment\n\n")
    with pytest.raises(FormatError, match="at least one data row") as err:
        data_lines(f)
    assert err.value.line == 2
    assert data_lines(f, allow_empty=True) == []


def test_split_row_checks_the_field_count():
    assert split_row(P, 3, " a, b ,c", count=3, sep=",", layout="a, b, c") == ["a", "b", "c"]
    assert split_row(P, 3, "a  b\tc d", count=(3, 4), sep=None, layout="x") == list("abcd")
    with pytest.raises(FormatError, match=r"expected 8 or 9 fields \(tum\); got 2") as err:
        split_row(P, 7, "1 2", count=(8, 9), sep=None, layout="tum")
    assert (err.value.path, err.value.line) == (P, 7)


def test_numbers():
    assert parse_float(P, 1, "1e-3", "tx") == 0.001
    with pytest.raises(FormatError, match="expected a number for tx; got 'abc'"):
        parse_float(P, 1, "abc", "tx")
    for token in ("nan", "inf", "-inf"):
        with pytest.raises(FormatError, match="finite number for qw"):
            parse_float(P, 1, token, "qw")
    assert parse_int(P, 1, "0042", "id") == 42
    with pytest.raises(FormatError, match="an integer for id"):
        parse_int(P, 1, "4.2", "id")


def test_integer_timestamps_stay_exact():
    assert is_integer_token("000010") and is_integer_token("-5") and not is_integer_token("1.0")
    assert not is_integer_token("1e3")
    big = "1700000000123456"  # a microsecond timestamp: exact as an integer
    assert parse_timestamp(P, 1, big) == 1700000000123456.0
    assert parse_timestamp(P, 1, "12.25") == 12.25
    with pytest.raises(FormatError, match="timestamp"):
        parse_timestamp(P, 1, "noon")


def test_quaternions_are_normalised_with_one_warning_per_file(caplog):
    q = QuaternionCounter(P)
    np.testing.assert_allclose(q.rotation(1, (1.0, 0.0, 0.0, 0.0)), np.eye(3))
    r = q.rotation(2, (1.005, 0.0, 0.0, 0.0))  # 0.5 % off unit length: normalised, counted
    np.testing.assert_allclose(r, np.eye(3))
    q.rotation(3, (0.0, 0.0, 0.0, 1.00001))  # within the warning tolerance: not counted
    assert q.count == 1 and q.worst == pytest.approx(0.005)
    pose = q.rigid(4, (1.0, 0.0, 0.0, 0.0), (1.0, 2.0, 3.0))
    np.testing.assert_allclose(pose[:3, 3], [1, 2, 3])
    with caplog.at_level(logging.WARNING, logger="pgt_check.io._text"):
        q.report()
    assert "normalised 1 quaternion(s)" in caplog.text
    with pytest.raises(FormatError, match="expected a unit quaternion") as err:
        q.rotation(9, (2.0, 0.0, 0.0, 0.0))  # far from unit: refused
    assert err.value.line == 9


def test_unique_keys_name_the_first_occurrence():
    keys = UniqueKeys(P, "unique frame ids")
    keys.add("a", "'a'", 3)
    assert "a" in keys and "b" not in keys
    with pytest.raises(
        FormatError, match=r"expected unique frame ids; got 'a' again \(first on line 3\)"
    ):
        keys.add("a", "'a'", 8)
    js = UniqueKeys("t.json", "unique file paths")
    js.add("x", "x", None, where="frames[0]")
    with pytest.raises(
        FormatError,
        match=r"frames\[4\]: expected unique file paths; got x again \(first at frames\[0\]\)",
    ):
        js.add("x", "x", None, where="frames[4]")
