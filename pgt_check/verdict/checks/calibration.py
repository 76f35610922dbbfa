"""The calibration check, per camera: the shared camera-frame error of its frames (principal
point, camera-to-rig rotation, focal length); ``failed`` above the per-frame threshold, a
``finding`` between it and the shared one."""

from __future__ import annotations

from typing import Any

from pgt_check.verdict.checks.base import CheckContext, camera_lines, camera_rows
from pgt_check.verdict.shared_results import CameraChecks

KEY = "calibration"
TITLE = "calibration"


def run(ctx: CheckContext) -> CameraChecks:
    return CameraChecks(ctx.calibrations.checks)


def lines(entry: Any) -> list[str]:
    return camera_lines(entry)


def table(entry: Any) -> list[tuple[str, Any]]:
    return camera_rows(TITLE, entry)
