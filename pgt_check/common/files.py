"""Reading and writing the user's files safely (no dependency inside the package but ``errors``).

Reading: every input file is a regular file (a device, FIFO or directory is refused before it is
opened: ``/dev/zero`` would never end, a FIFO would block) and is read only up to a size bound
checked before reading (``read_bytes_limited``, ``read_text_limited``, ``load_json_limited``).

Writing: ``atomic_write_bytes`` / ``atomic_write_text`` write to a fresh temporary file beside
the destination (created exclusively, so an existing file or symlink of that name is never
followed) and rename it over the destination: a symlink at the destination is replaced, never
written through, and readers never see half a file. Text is encoded so that any name the
filesystem allows (undecodable bytes, control characters) can be written (``safe_text``).
"""

from __future__ import annotations

import json
import logging
import os
import re
import stat
import tempfile
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pgt_check.errors import FormatError, InputError

logger = logging.getLogger(__name__)

#: largest pose file / image list / sensors file / transforms.json read (bytes)
MAX_INPUT_TEXT_BYTES = 512 * 1024**2
#: largest config file, summary.json, run.json or other small JSON document read (bytes)
MAX_SMALL_JSON_BYTES = 64 * 1024**2

__all__ = [
    "MAX_INPUT_TEXT_BYTES",
    "MAX_SMALL_JSON_BYTES",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_inputs_not_outputs",
    "current_umask",
    "first_unsafe_char",
    "open_append",
    "load_json_limited",
    "read_bytes_limited",
    "read_text_limited",
    "regular_file_size",
    "safe_text",
]


def _size_text(n: int) -> str:
    for unit, scale in (("GiB", 1024**3), ("MiB", 1024**2), ("KiB", 1024)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


def regular_file_size(path: str | Path, what: str = "file") -> int:
    """The size of ``path`` after checking that it is a regular file (symlinks followed).

    Raises InputError (naming ``what``) for a missing path and for anything that is not a
    regular file: a directory, a device such as ``/dev/zero``, a FIFO or a socket."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except OSError as err:
        raise InputError(f"{path}: cannot read {what} ({err.strerror or err})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise InputError(f"{path}: expected a regular file as {what}; got {kind}")
    return int(st.st_size)


def read_bytes_limited(path: str | Path, limit: int, what: str = "file") -> bytes:
    """The bytes of the regular file ``path``; InputError if it is larger than ``limit`` bytes
    (checked on its size before reading, and again while reading: a file that grows is cut)."""
    size = regular_file_size(path, what)
    if size > limit:
        raise InputError(
            f"{path}: {what} is {_size_text(size)}, more than the {_size_text(limit)} read at most"
        )
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as err:
        raise InputError(f"{path}: cannot read {what} ({err.strerror or err})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # replaced since the check
            raise InputError(f"{path}: expected a regular file as {what}")
        try:
            data = fh.read(limit + 1)
        except OSError as err:
            raise InputError(f"{path}: cannot read {what} ({err.strerror or err})") from None
    if len(data) > limit:
        raise InputError(f"{path}: {what} is larger than the {_size_text(limit)} read at most")
    return data


def read_text_limited(path: str | Path, limit: int = MAX_INPUT_TEXT_BYTES, what: str = "file"
                      ) -> str:
    """A UTF-8 text file (a leading BOM is dropped) of at most ``limit`` bytes; FormatError for
    bytes that are not UTF-8, InputError for a file that is missing, special or too large."""
    data = read_bytes_limited(path, limit, what)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise FormatError(path, None, f"expected a UTF-8 text file; got {err.reason} at byte "
                          f"{err.start}") from None


def parse_json_text(path: str | Path, text: str) -> Any:
    """``json.loads`` with every failure a FormatError (syntax, nesting too deep)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as err:
        raise FormatError(
            path, err.lineno, f"expected valid JSON; got {err.msg} (column {err.colno})"
        ) from None
    except RecursionError:
        raise FormatError(path, None, "expected JSON; got values nested too deeply") from None
    except ValueError as err:  # e.g. an integer literal with too many digits
        raise FormatError(path, None, f"expected valid JSON; got {err}") from None


def load_json_limited(path: str | Path, limit: int = MAX_SMALL_JSON_BYTES, what: str = "file"
                      ) -> Any:
    """A JSON document (UTF-8, a BOM allowed) of at most ``limit`` bytes."""
    return parse_json_text(path, read_text_limited(path, limit, what))


# lone surrogates (undecodable bytes of a file name, as Python decodes them) and control
# characters (C0 but tab, DEL, C1, line and paragraph separators): escaped wherever text is
# written (a tab keeps text on one line and is kept)
_UNSAFE = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")


def _escape(match: re.Match[str]) -> str:
    ch = match.group(0)
    code = ord(ch)
    if 0xDC80 <= code <= 0xDCFF:  # an undecodable byte (surrogateescape): show the byte
        return f"\\x{code - 0xDC00:02x}"
    return {"\n": "\\n", "\r": "\\r"}.get(
        ch, f"\\x{code:02x}" if code <= 0xFF else f"\\u{code:04x}"
    )


def first_unsafe_char(text: str) -> str | None:
    """The first character of ``text`` that ``safe_text`` would escape (a line break, another
    control character but tab, a lone surrogate), or None: a name without one is written
    verbatim on one line of every text output."""
    match = _UNSAFE.search(text)
    return match.group(0) if match else None


def safe_text(value: Any) -> str:
    """``str(value)`` that fits on one line of any UTF-8 text output: control characters (but
    tab) become ``\\n``, ``\\x07``..., undecodable file-name bytes ``\\xff``, other lone
    surrogates ``\\udxxx``."""
    text = "" if value is None else str(value)
    return _UNSAFE.sub(_escape, text)


_UMASK_LOCK = threading.Lock()


def current_umask() -> int:
    """The process's umask, read without changing it where the system tells it
    (``/proc/self/status``); elsewhere set and restored under a lock."""
    try:
        with open("/proc/self/status", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a new temporary file beside it, then rename.

    The temporary file is created exclusively (an existing file or symlink is never opened), a
    symlink at ``path`` is replaced (never written through), and on any failure the
    temporary file is removed. The file gets the mode a plain ``open`` would give it (0666
    less the umask; ``mkstemp`` alone made every output 0600, unreadable to a CI artifact
    uploader running as another user: issue #39 item 12)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:80]}.", suffix=".tmp", dir=path.parent)
    try:
        if hasattr(os, "fchmod"):
            os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def atomic_write_text(path: str | Path, text: str) -> None:
    """``atomic_write_bytes`` of ``text`` as UTF-8. Lone surrogates (undecodable bytes of a file
    name that reached the text unescaped) are written as ``\\udcff``-style escapes instead of
    failing (format-aware writers escape them first: ``safe_text``)."""
    atomic_write_bytes(path, text.encode("utf-8", errors="backslashreplace"))


def open_append(path: str | Path) -> Any:
    """``path`` opened for appending bytes (created if missing), never through a link: a
    symlink at ``path`` is replaced by a new empty file (the file it points to is left as it
    was; logged), and the open itself refuses to follow one (``O_NOFOLLOW``), so a link made
    in between is not written through either. The one way an output is appended to (the
    record store); ``atomic_write_bytes`` is the one way one is replaced."""
    path = Path(path)
    if path.is_symlink():
        logger.warning("%s was a symbolic link (to %s); it is replaced by a new file and the "
                       "file it pointed to is left unchanged", path, os.readlink(path))
        path.unlink()
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
    fd = os.open(path, flags | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise InputError(f"{path}: expected a regular file to append to")
        return os.fdopen(fd, "ab")
    except BaseException:
        os.close(fd)
        raise


def _real(path: str | Path) -> str:
    return os.path.normcase(os.path.realpath(os.fspath(path)))


def check_inputs_not_outputs(
    inputs: Iterable[tuple[str, str | Path | None]], outputs: Iterable[str | Path], option: str
) -> None:
    """Refuse a run that would write over its own input: InputError when an input (``(what,
    path)``; None skipped) is one of the ``outputs`` (files or folders the command writes,
    symlinks resolved) or lies inside an output folder. ``option`` names the output option."""
    outs = [_real(o) for o in outputs]
    for what, path in inputs:
        if path is None or path == "":
            continue
        p = _real(path)
        for o in outs:
            if p == o or p.startswith(o.rstrip(os.sep) + os.sep):
                raise InputError(
                    f"{option} {o}: would overwrite the {what} {path}; choose another {option}"
                )
