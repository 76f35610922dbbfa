"""The run-level checks as plug-ins: one module per check, one registry line each (``CHECKS``).

A check module has (``RunCheck``):

- ``KEY``: its entry's key in summary.json ``shared_errors`` (and in ``SharedChecks.entries``);
- ``TITLE``: its name in the report's table;
- ``run(ctx: CheckContext) -> entry | None``: the check on the run's pooled evidence (``ctx``,
  ``checks.base.CheckContext``, computes once what several checks share); None: no entry;
- ``lines(json) -> list[str]``: the lines ``pgt-check`` prints for its summary entry;
- ``table(json) -> list[(name, json)]``: its rows in the report's table.

An entry is a frozen dataclass with ``to_json()`` (its summary.json value). ``lines`` and
``table`` read that value back, so a run and ``pgt-check report`` (which reads summary.json)
print and show the same. ``verdict.shared.run_shared_checks`` runs the checks in registry order
into ``SharedChecks``; ``report.headline`` and ``report.tables`` loop over ``CHECKS``. The
registry order is the display order (headline lines, report rows, summary.json keys).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

from pgt_check.verdict.checks import (
    calibration,
    calibration_change,
    drift,
    frame_screen,
    registration,
    similarity,
    texture,
)
from pgt_check.verdict.checks.base import CheckContext

__all__ = ["CHECKS", "CheckContext", "CheckEntry", "RunCheck"]


class CheckEntry(Protocol):
    """A run-level check's result: its summary.json value."""

    def to_json(self) -> Any: ...


class RunCheck(Protocol):
    """A run-level check module (module docstring)."""

    KEY: str
    TITLE: str

    def run(self, ctx: CheckContext) -> CheckEntry | None: ...

    def lines(self, entry: Any) -> list[str]: ...

    def table(self, entry: Any) -> list[tuple[str, Mapping[str, Any]]]: ...


#: the run-level checks, in display order
CHECKS: tuple[RunCheck, ...] = (
    registration,
    similarity,
    drift,
    calibration,
    calibration_change,
    texture,
    frame_screen,
)
