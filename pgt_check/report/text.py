"""Text made safe for the report page: absolute paths of this machine shortened (in paths and
inside free text such as tracebacks) and JSON that cannot end its ``<script>`` block early.
"""

from __future__ import annotations

import json
import re
from pathlib import PurePosixPath, PureWindowsPath
from typing import Any

# An absolute POSIX path (/a/b) or Windows path (C:\a or \\server\share) inside free text.
_ABS_PATH_RE = re.compile(
    r"""(?<![\w.:/\\])(?:[A-Za-z]:[\\/]|\\\\|/(?=[^\s/]))[^\s"'<>|,;:()\[\]]*"""
)


def is_absolute_path(path: str) -> bool:
    return PurePosixPath(path).is_absolute() or PureWindowsPath(path).is_absolute()


def display_path(path: str, absolute_paths: bool = False) -> str:
    """How a path is shown in the report: as given unless it is absolute and not allowed.

    An absolute path becomes ``…/<parent>/<name>`` (the last two components), so the report never
    reveals the directory layout of the machine that produced it.
    """
    if absolute_paths or not path or not is_absolute_path(path):
        return path
    parts = PureWindowsPath(path).parts if "\\" in path else PurePosixPath(path).parts
    tail = [p for p in parts[1:] if p not in ("/", "\\")][-2:]
    return "…/" + "/".join(tail) if tail else "…"


def redact_text(text: str, absolute_paths: bool = False) -> str:
    """Replace absolute paths inside free text (tracebacks, messages) by their short form."""
    if absolute_paths or not text:
        return text
    return _ABS_PATH_RE.sub(lambda m: display_path(m.group(0)), text)


def script_json(obj: Any) -> str:
    """JSON for a ``<script type="application/json">`` block that cannot end the block early.

    ``<``, ``>`` and ``&`` become ``\\u003c`` etc., so ``</script>`` and ``<!--`` cannot appear;
    U+2028/2029 are escaped too. Non-finite floats must already be None (raises otherwise).
    """
    text = json.dumps(obj, ensure_ascii=False, allow_nan=False, separators=(",", ":"))
    return (
        text.replace("<", "\\u003c")
        .replace(">", "\\u003e")
        .replace("&", "\\u0026")
        .replace("\u2028", "\\u2028")
        .replace("\u2029", "\\u2029")
    )
