"""Mesh colours against mesh geometry (``verdict.texture.texture_entry``): informational; the
CLI prints a finding, or that no geometric evidence could check it."""

from __future__ import annotations

from typing import Any

from pgt_check.verdict.checks.base import CheckContext, single_row
from pgt_check.verdict.shared_results import TextureCheck
from pgt_check.verdict.status import FINDING

KEY = "texture"
TITLE = "mesh colours vs geometry"


def run(ctx: CheckContext) -> TextureCheck | None:
    from pgt_check.verdict.texture import texture_entry

    return texture_entry(ctx.measurements, ctx.threshold_px)


def lines(entry: Any) -> list[str]:
    if isinstance(entry, dict) and (entry.get("status") == FINDING
                                    or entry.get("reason") == "no_geometric_evidence"):
        return [str(entry["message"])]
    return []


def table(entry: Any) -> list[tuple[str, Any]]:
    return single_row(TITLE, entry)
