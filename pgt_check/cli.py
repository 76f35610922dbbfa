"""The console script ``pgt-check`` (``pgt_check.cli:main``; ``python -m pgt_check`` is the same).

``pgt-check NAME ...`` runs the subcommand ``NAME`` of ``pgt_check.commands.SUBCOMMANDS``
(report, compare, enhance); anything else is the check itself,
``pgt-check TRAJECTORY --mesh MESH`` (``pgt_check.commands.check``). Exit codes: 0 checked and
the gate passed (or the subcommand is done), 1 checked and the gate failed, 2 usage, input or
setup error (one line, no traceback), 130 interrupted.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from pgt_check.commands import SUBCOMMANDS


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in SUBCOMMANDS:
        return SUBCOMMANDS[argv[0]].main()(argv[1:])
    from pgt_check.commands import check

    return check.main(argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
