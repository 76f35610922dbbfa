"""The first lines after a run that failed on an error all frames share: what failed, how big
(px, deg, scene units), what it most likely is, and the command that fixes or re-judges it.

Built from summary.json alone (``shared_errors``, ``accuracy``, ``settings``, and the files the
run wrote), so ``pgt-check`` and ``pgt-check report`` print the same lines."""

from __future__ import annotations

import logging
import math
import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pgt_check.report.calibrated_sensors import CALIBRATED_SENSORS

logger = logging.getLogger(__name__)

REGISTERED_TRAJECTORY = "registered_trajectory.txt"


def _g(v: Any, digits: int = 3) -> str:
    return f"{v:.{digits}g}" if isinstance(v, (int, float)) and math.isfinite(v) else "?"


def _ci(e: Mapping[str, Any], key: str) -> str:
    c = e.get(f"{key}_ci")
    return f" (95 % {_g(c[0])}-{_g(c[1])})" if isinstance(c, list) and len(c) == 2 else ""


def _failed(e: Any) -> bool:
    return isinstance(e, Mapping) and e.get("status") == "failed"


def _q(path: Any) -> str:
    return shlex.quote(str(path))


def failure_headline(summary: Mapping[str, Any], out: str | Path) -> list[str]:
    """Lines (without the ``pgt-check:`` prefix) for a run whose gate failed while a run-level
    check failed; [] otherwise."""
    if (summary.get("gate") or {}).get("passed", True):
        return []
    shared = summary.get("shared_errors") or {}
    reg, sim, drift = (shared.get(k) or {} for k in ("registration", "similarity", "drift"))
    calib = {k: v for k, v in (shared.get("calibration") or {}).items() if isinstance(v, Mapping)}
    change = {k: v for k, v in (shared.get("calibration_change") or {}).items()
              if isinstance(v, Mapping)}
    cal_failed = {k: v for k, v in calib.items() if _failed(v)}
    change_failed = {k: v for k, v in change.items() if _failed(v)}
    if not (_failed(reg) or _failed(sim) or _failed(drift) or cal_failed or change_failed):
        return []
    settings = summary.get("settings") or {}
    inp = settings.get("input") or {}
    traj, mesh = inp.get("trajectory") or "TRAJECTORY", inp.get("mesh") or "MESH"
    out = Path(out)
    lines: list[str] = []
    cal_sig = {k: v for k, v in calib.items() if v.get("status") in ("failed", "finding")}
    texture = (shared.get("texture") or {}).get("status") == "finding"
    rejudge = f"pgt-check report {_q(out)} --remove-calibration true"
    sensors_file = out / CALIBRATED_SENSORS
    fix_cal = (
        f"pgt-check {_q(traj)} --mesh {_q(mesh)} --sensors {_q(sensors_file)} "
        f"--out {_q(str(out) + '-calibrated')}"
    )
    if _failed(reg) or _failed(sim):
        e = reg if _failed(reg) else sim
        what = "the whole trajectory is off the mesh" if e is reg else (
            f"the trajectory's scale is off (x{_g(e.get('scale'), 5)})")
        lines.append(
            f"FAILED on an error all frames share: {what} by {_g(e.get('effect_px'))} px"
            f"{_ci(e, 'effect_px')} = {_g(e.get('angle_deg'))} deg{_ci(e, 'angle_deg')} and "
            f"{_g(e.get('translation'))} scene units{_ci(e, 'translation')} "
            f"(run-level {e.get('kind', 'rigid')} fit over {e.get('n_frames', '?')} frames)"
        )
        if e.get("ambiguous_with_calibration") and cal_sig:
            cam, c = next(iter(cal_sig.items()))
            pp = c.get("principal_point_shift_px") or [float("nan")] * 2
            lines.append(
                "most likely: the photo camera's calibration, not the registration: every frame "
                f"is displaced alike, as a principal point off by ({_g(pp[0])}, {_g(pp[1])}) px "
                f"or a camera-to-sensor rotation of {_g(c.get('rotation_deg'))} deg would do "
                "(e.g. photos from a camera beside the sensor whose poses are given); these "
                "views cannot tell the two apart"
                + ("; the mesh colours sit off its geometry too, as such an offset makes them"
                   if texture else "")
            )
            lines.append(f"re-judge as calibration: {rejudge}")
            if sensors_file.is_file():
                lines.append(f"fix: {fix_cal}")
            lines.append(
                "or, if it is a misregistration: "
                + (f"{_q(out / REGISTERED_TRAJECTORY)} holds the registered poses"
                   if (out / REGISTERED_TRAJECTORY).is_file()
                   else "re-run with --registration-rounds 8 --resume to write "
                   "registered_trajectory.txt (only the rounds are measured)")
            )
        else:
            lines.append(
                "most likely: a misregistration of the trajectory to the mesh (the alignment "
                "step: one transform for all frames)"
            )
            reg_file = out / REGISTERED_TRAJECTORY
            lines.append(
                f"fix: pgt-check {_q(reg_file)} --mesh {_q(mesh)} --out "
                f"{_q(str(out) + '-registered')}" if reg_file.is_file()
                else "fix: re-run with --registration-rounds 8 --resume (writes "
                "registered_trajectory.txt; only the rounds are measured)"
            )
    elif cal_failed:
        cam, c = next(iter(cal_failed.items()))
        pp = c.get("principal_point_shift_px") or [float("nan")] * 2
        lines.append(
            f"FAILED on an error all frames share: every photo of camera {cam} is displaced by "
            f"{_g(c.get('effect_px'))} px{_ci(c, 'effect_px')}: a camera-to-sensor rotation of "
            f"{_g(c.get('rotation_deg'))} deg{_ci(c, 'rotation_deg')} (principal point off by "
            f"({_g(pp[0])}, {_g(pp[1])}) px), focal length x{_g(c.get('focal_scale'), 5)}"
        )
        lines.append("most likely: the camera calibration (intrinsics or camera-to-sensor "
                     "mounting), not the poses")
        lines.append(f"re-judge as calibration: {rejudge}")
        if sensors_file.is_file():
            lines.append(f"fix: {fix_cal}")
    elif change_failed:
        cam, c = next(iter(change_failed.items()))
        lines.append(
            f"FAILED on an error all frames share: camera {cam} changed since the trusted run: "
            f"what is left moves the images by {_g(c.get('effect_px'))} px"
            f"{_ci(c, 'effect_px')} ({_g(c.get('rotation_deg'))} deg)"
        )
        lines.append("most likely: a new mounting, focus or principal point of that camera")
        lines.append("fix: calibrate again on a run you trust (its summary.json) and pass it "
                     "with --calibration-from")
    else:
        acc = (summary.get("accuracy") or {}).get("limits") or {}
        worst = max((p.get("effect_px") or 0.0 for p in drift.get("per_frame") or []),
                    default=float("nan"))
        ppd, ppu = acc.get("points_px_per_deg"), acc.get("points_px_per_unit")
        segs = ", ".join(f"{a} .. {b}" for a, b in drift.get("segments") or [])
        lines.append(
            f"FAILED on an error neighbouring frames share: drift of up to {_g(worst)} px "
            f"(about {_g(worst / ppd if ppd else None)} deg or "
            f"{_g(worst / ppu if ppu else None)} scene units) in {segs or 'a segment'}"
        )
        lines.append("most likely: SLAM / VIO drift along those segments")
        lines.append("fix: re-estimate those segments' poses (corrected_trajectory.txt holds "
                     "verified corrections of the FAIL frames, --correct fail)")
    return lines
