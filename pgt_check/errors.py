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
        self.message = message
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


class SetupError(InputError):
    """The chosen method cannot run here (missing weights, a backend that cannot be built).

    Found before the run starts (CLI exit code 2), never turned into a per-frame outcome."""


class ImageSizeMismatchError(InputError):
    """A photo whose pixel size does not fit its camera (per-frame ``image_size_mismatch``)."""


class PixelCapError(InputError):
    """An image whose header declares more pixels than the cap (per-frame
    ``pixel_cap_exceeded``); raised before decoding, so memory stays bounded."""


class ReferenceUnreadableError(InputError):
    """The reference photo of the enhanced path cannot be read (per-frame
    ``reference_unreadable``)."""


class RunInterrupted(Exception):
    """The run stopped on Ctrl-C or SIGTERM (not an input error); ``done`` of ``total`` frames are stored in ``out``."""

    def __init__(self, done: int, total: int, out: str) -> None:
        super().__init__(f"interrupted: {done}/{total} frames done")
        self.done, self.total, self.out = done, total, out
