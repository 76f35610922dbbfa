"""What the command-line entry points share."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from pgt_check.common.files import safe_text


class OneLineErrorParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line (``PROG: error: MESSAGE (see PROG
    --help)``) and exit 2, without argparse's usage block above it (``--help`` shows it): the
    parser of every command and subcommand."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {safe_text(message)} (see {self.prog} --help)\n")


def path_arg(text: str) -> str:
    """argparse type of a path option or argument: an empty or blank path is a usage error
    (exit 2), never the current directory by accident."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected a path, got {text!r}")
    return text


def parse_args(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.Namespace | int:
    """``parser.parse_args`` without SystemExit: the namespace, or the exit code argparse chose
    (2 for a usage error, 0 after --help / --version) for the caller to return."""
    try:
        return parser.parse_args(list(argv))
    except SystemExit as exc:
        return int(exc.code or 0)


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def install_sigterm_handler() -> None:
    """SIGTERM (CI cancel, docker stop) ends a command like Ctrl-C: exit 130. pycolmap is
    imported first where installed, so its crash-dump handler (glog) cannot replace this one
    later."""
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        pass
    try:
        signal.signal(signal.SIGTERM, _raise_interrupt)
    except ValueError:  # not the main thread (library use)
        pass


class OneLineFormatter(logging.Formatter):
    """Log lines that stay one line each: the message's control characters and undecodable
    file-name bytes are escaped (``safe_text``); a traceback (``-v``) follows unchanged."""

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 - logging API
        record.message = safe_text(record.message)
        return super().formatMessage(record)


def configure_logging(verbose: int, quiet: bool, quiet_level: int = logging.WARNING) -> None:
    """The ``pgt_check`` logger of a command: ``quiet_level`` with ``quiet``, DEBUG with
    ``-vv``, else INFO; one line per record on stderr."""
    level = quiet_level if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(OneLineFormatter("[%(levelname)s] %(name)s: %(message)s"))
    root = logging.getLogger("pgt_check")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = True  # library users and test log capture see the records too
