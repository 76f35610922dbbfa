"""The command-line commands, one module each, and the table ``pgt-check`` dispatches on.

``pgt-check TRAJECTORY --mesh MESH`` (no subcommand) is :mod:`pgt_check.commands.check`; the
subcommands are listed in :data:`SUBCOMMANDS`. Every command module follows one convention:

* ``build_parser() -> argparse.ArgumentParser``: a ``commands.common.OneLineErrorParser`` whose ``prog``
  is ``pgt-check`` or ``pgt-check NAME`` (usage errors are one line and exit 2; ``--help``);
* ``main(argv) -> int``: parse, run the library function it wraps, print, return the exit code
  (0 done / gate passed, 1 gate failed, 2 usage, input or setup error, 130 interrupted).

A new subcommand is a module here plus one row in :data:`SUBCOMMANDS`; ``pgt-check --help``
lists it from that row (the module is imported only when the subcommand runs).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Subcommand:
    module: str  #: the module with ``build_parser`` and ``main``
    usage: str  #: its positional arguments, as shown in ``pgt-check --help``
    summary: str  #: one line for ``pgt-check --help``

    def main(self) -> Callable[[Sequence[str]], int]:
        return importlib.import_module(self.module).main


#: ``pgt-check NAME ...`` -> the command module that runs it
SUBCOMMANDS: dict[str, Subcommand] = {
    "report": Subcommand(
        "pgt_check.commands.report", "OUT_DIR",
        "rebuild the outputs of a finished run from its stored records (re-judge with new "
        "verdict settings, nothing measured again)",
    ),
    "compare": Subcommand(
        "pgt_check.commands.compare", "A B",
        "compare two pose sources of the same images (per-frame difference; with --mesh, "
        "which source the images support)",
    ),
    "enhance": Subcommand(
        "pgt_check.commands.enhance", "RENDERS MODEL --out DIR",
        "enhance a folder of renders with the nearest training photos (MaRINeR or "
        "reprojection)",
    ),
}


def subcommands_help(width: int = 79) -> str:
    """The subcommand list of ``pgt-check --help`` (lines of at most ``width`` characters)."""
    import textwrap

    lines = ["subcommands (each with --help):"]
    for name, sub in SUBCOMMANDS.items():
        lines.append(f"  pgt-check {name} {sub.usage}")
        lines += textwrap.wrap(sub.summary, width, initial_indent=" " * 6,
                               subsequent_indent=" " * 6)
    return "\n".join(lines)
