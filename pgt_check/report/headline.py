"""What ``pgt-check`` prints after a run (``summary_lines``), led by the first lines after a run
that failed on an error all frames share (``failure_headline``): what failed, how big (px, deg,
scene units), what it most likely is, and the command that fixes or re-judges it.

Built from summary.json alone (``shared_errors``, ``accuracy``, ``settings``, and the files the
run wrote), so ``pgt-check`` and ``pgt-check report`` print the same headline."""

from __future__ import annotations

import logging
import math
import shlex
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pgt_check.output_layout import OUTPUTS

logger = logging.getLogger(__name__)


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
    traj, mesh = _InputCommand.of(inp, summary), inp.get("mesh") or "MESH"
    out = Path(out)
    cal_sig = {k: v for k, v in calib.items() if v.get("status") in ("failed", "finding")}
    texture = (shared.get("texture") or {}).get("status") == "finding"
    if _failed(reg) or _failed(sim):
        e = reg if _failed(reg) else sim
        return _registration_lines(e, e is reg, cal_sig, texture, out, traj, mesh)
    if cal_failed:
        return _calibration_lines(cal_failed, out, traj, mesh)
    if change_failed:
        return _calibration_change_lines(change_failed)
    return _drift_lines(summary, drift)


#: trajectory formats that read a sensors file (``--sensors``); the others take ``--camera``
SENSORS_FORMATS = ("lamar", "hloc")


class _InputCommand:
    """The trajectory part of a re-run command: the trajectory and the input options of the
    run but its intrinsics (``--sensors`` / ``--camera``), and the intrinsics option that
    loads a calibrated camera for its format: ``--sensors calibrated_sensors.txt`` where the
    format reads one, ``--camera MODEL,w,h,...`` (the file's one camera) where it does not
    (TUM, COLMAP, ...: ``--sensors`` is refused there)."""

    def __init__(self, path: Any, options: str, fmt: Any, camera_args: list[str]) -> None:
        self.path, self.options, self.fmt, self.camera_args = path, options, fmt, camera_args

    @classmethod
    def of(cls, inp: Mapping[str, Any], summary: Mapping[str, Any]) -> _InputCommand:
        options = ""
        fmt = inp.get("format")
        if fmt and fmt != "auto":
            options += f" --format {_q(fmt)}"
        for key, flag in (("images", "--images"),
                          ("dataparser_transforms", "--dataparser-transforms")):
            if inp.get(key):
                options += f" {flag} {_q(inp[key])}"
        cams = ((summary.get("calibrated_sensors") or {}).get("cameras") or {}).values()
        args = [str(c["camera_arg"]) for c in cams
                if isinstance(c, Mapping) and c.get("camera_arg")]
        return cls(inp.get("trajectory") or "TRAJECTORY", options,
                   summary.get("trajectory_format") or fmt, args)

    def __str__(self) -> str:
        return str(self.path)

    def intrinsics(self, sensors_file: Path) -> str | None:
        """The option that loads the calibrated intrinsics; None where none can (several
        cameras in a format without a sensors file)."""
        if self.fmt in SENSORS_FORMATS or self.fmt is None:  # None: an older summary
            return f"--sensors {_q(sensors_file)}"
        if len(self.camera_args) == 1:
            return f"--camera {_q(self.camera_args[0])}"
        return None


def _calibration_fixes(out: Path, traj: Any, mesh: Any, texture: bool = False) -> list[str]:
    """The re-judge-as-calibration command, and the re-run with the run's calibration written
    out: exactly (the ``calibrated/`` rig session) and as intrinsics (calibrated sensors).
    ``texture``: the mesh colours sit off its geometry like the photos (painted with these
    poses): the re-run judges on the geometry alone, or the colours show the offset back."""
    lines = [f"re-judge as calibration: pgt-check report {_q(out)} --remove-calibration true"]
    rig = out / OUTPUTS.calibrated_dir / "trajectories.txt"
    if rig.is_file():
        lines.append(f"fix (the estimate as a camera-to-sensor rig): pgt-check {_q(rig)} --mesh "
                     f"{_q(mesh)} --out {_q(str(out) + '-calibrated')}"
                     + (" --shading shaded" if texture else ""))
    sensors_file = out / OUTPUTS.calibrated_sensors
    cmd = traj if isinstance(traj, _InputCommand) else _InputCommand(traj, "", "lamar", [])
    intrinsics = cmd.intrinsics(sensors_file) if sensors_file.is_file() else None
    if intrinsics is not None:
        lines.append(
            f"{'or, as intrinsics only' if rig.is_file() else 'fix'}: pgt-check {_q(cmd.path)}"
            f"{cmd.options} --mesh {_q(mesh)} {intrinsics} --out "
            f"{_q(str(out) + '-calibrated')}"
        )
    return lines


def _registration_lines(
    e: Mapping[str, Any],
    is_reg: bool,
    cal_sig: Mapping[str, Mapping[str, Any]],
    texture: bool,
    out: Path,
    traj: Any,
    mesh: Any,
) -> list[str]:
    """Lines for a failed registration (``is_reg``) or similarity check ``e``: its size, then
    calibration or misregistration as the likely cause with the commands for it."""
    what = "the whole trajectory is off the mesh" if is_reg else (
        f"the trajectory's scale is off (x{_g(e.get('scale'), 5)})")
    lines = [
        f"FAILED on an error all frames share: {what} by {_g(e.get('effect_px'))} px"
        f"{_ci(e, 'effect_px')} = {_g(e.get('angle_deg'))} deg{_ci(e, 'angle_deg')} and "
        f"{_g(e.get('translation'))} scene units{_ci(e, 'translation')} "
        f"(run-level {e.get('kind', 'rigid')} fit over {e.get('n_frames', '?')} frames)"
    ]
    if e.get("ambiguous_with_calibration") and cal_sig:
        return lines + _calibration_or_registration(
            next(iter(cal_sig.values())), texture, out, traj, mesh
        )
    return lines + _misregistration(out, mesh)


def _calibration_or_registration(
    c: Mapping[str, Any], texture: bool, out: Path, traj: Any, mesh: Any
) -> list[str]:
    """Lines naming calibration (camera check ``c``) as the likely cause of a run-level offset
    these views cannot tell from a misregistration, with the commands for either."""
    pp = c.get("principal_point_shift_px") or [float("nan")] * 2
    return [
        "most likely: the photo camera's calibration, not the registration: every frame "
        f"is displaced alike, as a principal point off by ({_g(pp[0])}, {_g(pp[1])}) px "
        f"or a camera-to-sensor rotation of {_g(c.get('rotation_deg'))} deg would do "
        "(e.g. photos from a camera beside the sensor whose poses are given); these "
        "views cannot tell the two apart"
        + ("; the mesh colours sit off its geometry too, as such an offset makes them"
           if texture else ""),
        *_calibration_fixes(out, traj, mesh, texture),
        "or, if it is a misregistration: "
        + (f"{_q(out / OUTPUTS.registered_trajectory)} holds the registered poses"
           if (out / OUTPUTS.registered_trajectory).is_file()
           else "re-run with --registration-rounds 8 --resume to write "
           "registered_trajectory.txt (only the rounds are measured)"),
    ]


def _misregistration(out: Path, mesh: Any) -> list[str]:
    """Lines naming a misregistration as the likely cause, with the command that fixes it."""
    reg_file = out / OUTPUTS.registered_trajectory
    return [
        "most likely: a misregistration of the trajectory to the mesh (the alignment "
        "step: one transform for all frames)",
        f"fix: pgt-check {_q(reg_file)} --mesh {_q(mesh)} --out "
        f"{_q(str(out) + '-registered')}" if reg_file.is_file()
        else "fix: re-run with --registration-rounds 8 --resume (writes "
        "registered_trajectory.txt; only the rounds are measured)",
    ]


def _calibration_lines(
    cal_failed: Mapping[str, Mapping[str, Any]], out: Path, traj: Any, mesh: Any
) -> list[str]:
    """Lines for a failed per-camera calibration check (the first failed camera)."""
    cam, c = next(iter(cal_failed.items()))
    pp = c.get("principal_point_shift_px") or [float("nan")] * 2
    return [
        f"FAILED on an error all frames share: every photo of camera {cam} is displaced by "
        f"{_g(c.get('effect_px'))} px{_ci(c, 'effect_px')}: a camera-to-sensor rotation of "
        f"{_g(c.get('rotation_deg'))} deg{_ci(c, 'rotation_deg')} (principal point off by "
        f"({_g(pp[0])}, {_g(pp[1])}) px), focal length x{_g(c.get('focal_scale'), 5)}",
        "most likely: the camera calibration (intrinsics or camera-to-sensor "
        "mounting), not the poses",
        *_calibration_fixes(out, traj, mesh),
    ]


def _calibration_change_lines(change_failed: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Lines for a camera whose calibration changed since the trusted run (the first one)."""
    cam, c = next(iter(change_failed.items()))
    return [
        f"FAILED on an error all frames share: camera {cam} changed since the trusted run: "
        f"what is left moves the images by {_g(c.get('effect_px'))} px"
        f"{_ci(c, 'effect_px')} ({_g(c.get('rotation_deg'))} deg)",
        "most likely: a new mounting, focus or principal point of that camera",
        "fix: calibrate again on a run you trust (its summary.json) and pass it "
        "with --calibration-from",
    ]


def _drift_lines(summary: Mapping[str, Any], drift: Mapping[str, Any]) -> list[str]:
    """Lines for failed drift: the worst frame's effect in px, deg and scene units, and where."""
    acc = (summary.get("accuracy") or {}).get("limits") or {}
    worst = max((p.get("effect_px") or 0.0 for p in drift.get("per_frame") or []),
                default=float("nan"))
    ppd, ppu = acc.get("points_px_per_deg"), acc.get("points_px_per_unit")
    segs = ", ".join(f"{a} .. {b}" for a, b in drift.get("segments") or [])
    return [
        f"FAILED on an error neighbouring frames share: drift of up to {_g(worst)} px "
        f"(about {_g(worst / ppd if ppd else None)} deg or "
        f"{_g(worst / ppu if ppu else None)} scene units) in {segs or 'a segment'}",
        "most likely: SLAM / VIO drift along those segments",
        "fix: re-estimate those segments' poses (corrected_trajectory.txt holds "
        "verified corrections of the FAIL frames, --correct fail)",
    ]


def shared_error_lines(shared: Mapping[str, Any]) -> list[str]:
    """The lines of the run-level checks worth reading (failed, inconclusive, a finding): each
    check's ``lines`` of its summary entry, in registry order (``verdict.checks.CHECKS``)."""
    from pgt_check.verdict.checks import CHECKS

    return [line for check in CHECKS for line in check.lines(shared.get(check.KEY))]


def summary_lines(summary: Mapping[str, Any], out: str | Path) -> list[str]:
    """The lines printed after a run: the failure headline, counts and median error, the
    systematic offset, the run-level checks worth reading, the accuracy statement, the self-test,
    the gate and where the report is."""
    lines = failure_headline(summary, out)
    c = summary["counts"]
    err = summary["statistics"]["corner_error_px"]
    med = "-" if err["median"] is None else f"{err['median']:.2f}"
    lines.append(
        f"{summary['n_frames']} frames: {c['PASS']} PASS, {c['FAIL']} FAIL, "
        f"{c['UNVERIFIABLE']} UNVERIFIABLE; median corner error {med} px "
        f"(threshold {summary['threshold_px']:.1f} px)"
    )
    sysoff = summary["statistics"]["systematic_offset"]
    if sysoff.get("systematic"):
        lines.append(str(sysoff["message"]))
    lines += shared_error_lines(summary.get("shared_errors") or {})
    lines += [f"accuracy: {s}" for s in (summary.get("accuracy") or {}).get("sentences") or ()]
    if (summary.get("self_test") or {}).get("sentence"):
        lines.append(str(summary["self_test"]["sentence"]))
    lines += [f"separation: {s}" for s in
              (summary.get("path_separation") or {}).get("sentences") or ()]
    gate = summary["gate"]
    lines.append(f"gate {'PASSED' if gate['passed'] else 'FAILED'}: {gate['explanation']}")
    lines.append(f"report: {Path(out) / OUTPUTS.report_html} (all outputs in {out})")
    return lines
