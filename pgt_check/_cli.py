"""What the command-line entry points share."""

from __future__ import annotations

import argparse
from collections.abc import Sequence


def parse_args(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.Namespace | int:
    """``parser.parse_args`` without SystemExit: the namespace, or the exit code argparse chose
    (2 for a usage error, 0 after --help / --version) for the caller to return."""
    try:
        return parser.parse_args(list(argv))
    except SystemExit as exc:
        return int(exc.code or 0)
