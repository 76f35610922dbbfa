"""With ``--calibration-from``, per camera: what is left of the calibration after removing the
trusted run's; ``failed`` (the camera changed since) makes its frames not PASS. No entry
without ``--calibration-from``."""

from __future__ import annotations

from typing import Any

from pgt_check.verdict.checks.base import CheckContext, camera_lines, camera_rows
from pgt_check.verdict.shared_results import CameraChecks

KEY = "calibration_change"
TITLE = "calibration change since the trusted run"


def run(ctx: CheckContext) -> CameraChecks | None:
    change = ctx.calibrations.change
    return CameraChecks(change) if change else None


def lines(entry: Any) -> list[str]:
    return camera_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return camera_rows(TITLE, entry)
