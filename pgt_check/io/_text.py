"""Shared parsing helpers for the text readers: every failure becomes a FormatError(path, line)."""

from __future__ import annotations

import logging
import math
from collections.abc import Hashable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pgt_check.common.files import MAX_INPUT_TEXT_BYTES, first_unsafe_char, read_text_limited
from pgt_check.errors import FormatError
from pgt_check.geometry.transforms import QuaternionError, make_rigid, quat_to_rotmat

logger = logging.getLogger(__name__)

#: quaternions further than this from unit norm are normalised with a (counted) warning
QUAT_WARN_TOLERANCE = 1e-4


def read_text(path: Path) -> list[str]:
    """All lines of a UTF-8 text file (a BOM allowed); InputError if missing, not a regular file
    or larger than ``MAX_INPUT_TEXT_BYTES``, FormatError if not text."""
    return read_text_limited(path, MAX_INPUT_TEXT_BYTES).splitlines()


def data_lines(path: Path, *, allow_empty: bool = False) -> list[tuple[int, str]]:
    """(1-based line number, stripped text) of every non-blank line not starting with '#'.

    Raises FormatError on a file with no data row unless ``allow_empty``.
    """
    lines = read_text(path)
    rows = [(i, s) for i, s in enumerate((raw.strip() for raw in lines), start=1)]
    rows = [(i, s) for i, s in rows if s and not s.startswith("#")]
    if not rows and not allow_empty:
        raise FormatError(path, max(len(lines), 1), "expected at least one data row; got none")
    return rows


def split_row(
    path: Path, line: int, text: str, *, count: int | Sequence[int], sep: str | None, layout: str
) -> list[str]:
    """Split a row on ``sep`` (None = whitespace), strip fields, check the field count."""
    fields = [f.strip() for f in (text.split(sep) if sep else text.split())]
    counts = (count,) if isinstance(count, int) else tuple(count)
    if len(fields) not in counts:
        want = " or ".join(str(c) for c in counts)
        raise FormatError(path, line, f"expected {want} fields ({layout}); got {len(fields)}")
    return fields


def parse_float(path: Path, line: int, token: str, what: str) -> float:
    """A finite float, else FormatError naming the field."""
    try:
        value = float(token)
    except ValueError:
        raise FormatError(path, line, f"expected a number for {what}; got {token!r}") from None
    if not math.isfinite(value):
        raise FormatError(path, line, f"expected a finite number for {what}; got {token!r}")
    return value


def parse_int(path: Path, line: int, token: str, what: str) -> int:
    try:
        return int(token)
    except ValueError:
        raise FormatError(path, line, f"expected an integer for {what}; got {token!r}") from None


def is_integer_token(token: str) -> bool:
    """True for tokens like '10' or '000010' (no decimal point or exponent)."""
    return token.lstrip("+-").isdigit()


def parse_timestamp(path: Path, line: int, token: str) -> float:
    """A timestamp as a float (integers stay exact up to 2**53)."""
    return (
        float(parse_int(path, line, token, "timestamp"))
        if is_integer_token(token)
        else parse_float(path, line, token, "timestamp")
    )


def check_frame_id(
    path: Path | str, line: int | None, frame_id: str, where: str | None = None,
    what: str = "frame id",
) -> None:
    """Refuse (FormatError naming the file and line, or ``where`` in a file without lines) a
    frame id with a line break, another control character (but tab) or an undecodable byte.

    Frame ids are written verbatim, one per line, in ``bad_frames.txt`` and in the trajectory
    files a run writes, where a consumer looks them up: an escaped id would not match, a raw
    one would split into several lines (issue #39 item 9). No pose format produces one from
    ordinary file names, so such an id is refused at read time rather than escaped."""
    ch = first_unsafe_char(frame_id)
    if ch is None:
        return
    prefix = f"{where}: " if where else ""
    raise FormatError(
        path, line,
        f"{prefix}expected the {what} without line breaks or other control characters (frame ids "
        f"are written one per line in bad_frames.txt and the trajectory files); got "
        f"{frame_id!r} (character U+{ord(ch):04X})",
    )


def check_frame_ids(frames: Sequence[Any], source: str | Path | None) -> None:
    """``check_frame_id`` of every frame (for readers without lines, and in-memory
    trajectories): the first bad id is a FormatError naming ``source`` and its position."""
    for i, frame in enumerate(frames):
        check_frame_id(source or "trajectory", None, frame.frame_id, where=f"frame {i + 1}")


class QuaternionCounter:
    """Counts quaternions that needed normalising, to log one WARNING per file."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.count = 0
        self.worst = 0.0

    def rotation(self, line: int, wxyz: Sequence[float]) -> np.ndarray:
        """(4,) Hamilton (w, x, y, z) -> (3, 3); FormatError beyond the norm tolerance."""
        q = np.asarray(wxyz, dtype=np.float64)
        try:
            r = quat_to_rotmat(q)
        except QuaternionError as err:
            raise FormatError(
                self.path, line, f"expected a unit quaternion (qw qx qy qz); got {err}"
            ) from None
        off = abs(float(np.linalg.norm(q)) - 1.0)
        if off > QUAT_WARN_TOLERANCE:
            self.count += 1
            self.worst = max(self.worst, off)
        return r

    def rigid(self, line: int, wxyz: Sequence[float], t: Sequence[float]) -> np.ndarray:
        return make_rigid(self.rotation(line, wxyz), np.asarray(t, dtype=np.float64))

    def report(self) -> None:
        if self.count:
            logger.warning(
                "%s: normalised %d quaternion(s) that were not unit (largest |norm - 1| = %.2g)",
                self.path,
                self.count,
                self.worst,
            )



class UniqueKeys:
    """Where each key of a file was first seen; a repeated key is a FormatError naming both.

    ``expected`` completes "expected ..." in the message (e.g. "unique sensor ids").
    """

    def __init__(self, path: Path | str, expected: str) -> None:
        self.path = path
        self.expected = expected
        self.first: dict[Hashable, int | str | None] = {}

    def add(self, key: Hashable, shown: str, line: int | None, where: str | None = None) -> None:
        """Record ``key`` at ``line`` (or at ``where``, for files without lines, e.g. JSON).

        ``shown``: how the key is written in the message.
        """
        if key in self.first:
            first = self.first[key]
            at = f"on line {first}" if isinstance(first, int) else f"at {first}"
            prefix = f"{where}: " if where else ""
            raise FormatError(
                self.path,
                line,
                f"{prefix}expected {self.expected}; got {shown} again (first {at})",
            )
        self.first[key] = line if where is None else where

    def __contains__(self, key: object) -> bool:
        return key in self.first
