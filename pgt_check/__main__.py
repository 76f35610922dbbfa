"""``python -m pgt_check ...``: exactly the ``pgt-check`` console script (same ``main``, same
arguments, same exit codes: 0 gate passed, 1 gate failed, 2 usage or input error)."""

from __future__ import annotations

import sys

from pgt_check.cli import main

if __name__ == "__main__":
    sys.exit(main())
