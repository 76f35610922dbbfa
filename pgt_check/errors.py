"""Exceptions that mean 'the user's input is wrong' (CLI exit code 2, one-line message)."""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """A user-facing input problem: bad path, malformed file, bad option, changed fingerprint."""


class FormatError(InputError):
    """A malformed input file. The message names the file, the line and what was expected."""

    def __init__(self, path: str | Path, line: int | None, message: str) -> None:
        self.path = str(path)
        self.line = line
        where = f"{self.path}:{line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


class ConfigError(InputError):
    """An invalid configuration value or an unknown configuration key."""


class MissingExtraError(InputError):
    """An optional dependency is not installed; the message names the extra to install."""

    def __init__(self, module: str, extra: str) -> None:
        super().__init__(
            f"optional dependency '{module}' is not installed: "
            f"pip install 'pgt-check[{extra}]'"
        )
