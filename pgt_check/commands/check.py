"""``pgt-check TRAJECTORY --mesh MESH --out DIR``: check the poses frame by frame (the command
run when no subcommand is named; ``pgt_check.cli.main`` dispatches).

Exit codes (each means one thing, a CI gate relies on them):
0 the poses were checked and the gate passed; 1 they were checked and the gate failed (too many
FAIL or UNVERIFIABLE frames, none verified, internal errors); 2 usage, input or setup error:
one line ``pgt-check: error: ...`` naming the file or option, never a traceback (``-v`` adds
one); 130 interrupted (SIGINT or SIGTERM), with the command that resumes the run.
Errors are told apart by exception type at this boundary (``pgt_check.errors``), not by message.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pgt_check import __version__
from pgt_check.commands import subcommands_help
from pgt_check.commands.common import (
    OneLineErrorParser,
    configure_logging,
    install_sigterm_handler,
    parse_args,
)
from pgt_check.common.files import safe_text
from pgt_check.config import RunConfig, load_config_file, merge
from pgt_check.errors import ConfigError, InputError

logger = logging.getLogger("pgt_check")

EXIT_PASSED, EXIT_FAILED, EXIT_INPUT = 0, 1, 2


def build_parser() -> argparse.ArgumentParser:
    import textwrap

    from pgt_check.config import PRESETS

    p = OneLineErrorParser(
        prog="pgt-check",
        description="Check pseudo-ground-truth camera poses frame by frame against a mesh.",
        epilog=subcommands_help() + "\n\n" + textwrap.fill(
            "Exit codes: 0 checked and the gate passed, 1 checked and the gate failed, 2 "
            "usage, input or setup error, 130 interrupted (resumable).", 79),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("trajectory", nargs="?", default=None,
                   help="pose file or COLMAP model directory (optional when --config gives it)")
    p.add_argument("--mesh", default=None, help="mesh (PLY/OBJ/GLB) in the poses' world frame "
                   "(required unless --config gives it)")
    p.add_argument("--out", default=None, help="output directory (default: pgt-check-out)")
    p.add_argument("--config", default=None, help="JSON or TOML config file (CLI options win); "
                   "a run's own config.json replays that run")
    p.add_argument("--print-config", action="store_true",
                   help="print the resolved config as JSON and exit")
    p.add_argument("--preset", default=None, choices=list(PRESETS),
                   help="named settings from the error-vs-runtime study (config file and CLI "
                   "options override them)")
    _add_input_args(p)
    _add_method_args(p)
    _add_verdict_args(p)
    _add_run_args(p)
    return p


def _add_input_args(p: argparse.ArgumentParser) -> None:
    """Options of the input, render and match sections."""
    from pgt_check.io import FORMATS
    from pgt_check.match import MATCHERS
    from pgt_check.render import BACKENDS

    g = p.add_argument_group("input")
    g.add_argument("--format", default=None, choices=["auto", *FORMATS])
    g.add_argument("--images", default=None, help="image folder or list (TUM, pgt, COLMAP, hloc)")
    g.add_argument("--camera", default=None, help="intrinsics for TUM / hloc, e.g. "
                   "PINHOLE,640,480,fx,fy,cx,cy (COLMAP convention: top-left pixel centre at "
                   "0.5,0.5)")
    g.add_argument("--sensors", default=None, help="LaMAR sensors file (default: paired by "
                   "suffix); for hloc a COLMAP model or query list with the intrinsics")
    g.add_argument("--dataparser-transforms", default=None,
                   help="nerfstudio: dataparser_transforms.json to undo (poses back in the "
                   "mesh's frame)")
    g = p.add_argument_group("render")
    g.add_argument("--renderer", default=None, choices=list(BACKENDS))
    g.add_argument("--shading", default=None, choices=["auto", "vertex", "texture", "shaded"],
                   help="'shaded' renders geometry only (for colourless meshes)")
    g = p.add_argument_group("match")
    g.add_argument("--matcher", default=None, choices=list(MATCHERS),
                   help="sift (default), orb, akaze; with the [enhance] extra: xfeat, "
                   "xfeat-lighterglue, aliked-lightglue, disk-lightglue, loftr")
    g.add_argument("--max-keypoints", type=int, default=None)
    g.add_argument("--loftr-weights", default=None,
                   help="LoFTR checkpoint for --matcher loftr (none is bundled)")
    g.add_argument("--resize-max", type=int, default=None,
                   help="longest side used for matching, px (0 = original size)")


def _add_method_args(p: argparse.ArgumentParser) -> None:
    """Options of the enhanced and edge paths, the pose estimate and corrections."""
    from pgt_check.enhance import ENHANCERS

    g = p.add_argument_group("enhance (MaRINeR) and pose estimate")
    g.add_argument("--enhance", default=None, choices=["never", "auto", "always"],
                   help="enhance renders with a reference photo: auto (default: only frames "
                   "whose raw result is not decisive), always, or never (raw only)")
    g.add_argument("--enhance-method", default=None, choices=list(ENHANCERS),
                   help="reproject (default: the reference photo projected through the mesh) "
                   "or mariner (the learned MaRINeR enhancer, needs the [enhance] extra)")
    g.add_argument("--weights", default=None, help="MaRINeR checkpoint (default: shipped)")
    g.add_argument("--iterations", type=int, default=None, help="MaRINeR refinement iterations")
    g.add_argument("--reference", default=None, choices=["nearest", "self", "none"],
                   help="reference photo: nearest other frame (default); 'self' = the frame's "
                   "own photo (evaluation upper bound only: it hides pose errors)")
    g.add_argument("--no-pose-estimate", action="store_true", help="skip the PnP pose estimate")
    g.add_argument("--edges", default=None, choices=["never", "auto", "always"],
                   help="geometric-edge path (mesh silhouettes and creases vs photo edges; "
                   "absolute evidence without texture): auto (default: where the raw feature "
                   "path is not decisive), always, never")
    g.add_argument("--edges-tile-grid", type=int, default=None, metavar="N",
                   help="the edge alignment also starts from the shifts of N x N image tiles "
                   "(default 0 = off; 3 recovers the rotation / translation split of a "
                   "misregistration on alike views, at a cost: README, edge path)")
    g.add_argument("--correct", default=None, choices=["none", "fail", "all"],
                   help="correct the poses of FAIL frames (default), all frames or none: "
                   "render -> match -> PnP rounds; writes corrected_trajectory.txt (input's "
                   "format) and bad_frames.txt")
    g.add_argument("--correct-rounds", type=int, default=None,
                   help="render -> match -> PnP rounds per corrected frame (default 4)")
    g.add_argument("--registration-rounds", type=int, default=None, metavar="N",
                   help="when the registration check fails, up to N rounds of measuring up to "
                   "30 frames again at the corrected poses to refine its estimate (8 will "
                   "do, stopping once converged; default 0: deferred, with --resume a rerun "
                   "measures only the rounds); writes registered_trajectory.txt")


def _add_verdict_args(p: argparse.ArgumentParser) -> None:
    """Verdict, gate and run-level (shared-error) options."""
    g = p.add_argument_group("verdict and gate")
    g.add_argument("--threshold-px", type=float, default=None,
                   help="PASS threshold on the corner error (default: 2%% of the image diagonal)")
    g.add_argument("--threshold-rel-diag", type=float, default=None)
    g.add_argument("--min-inliers", type=int, default=None)
    g.add_argument("--min-coverage", type=float, default=None)
    g.add_argument("--max-fail-fraction", type=float, default=None,
                   help="gate: largest allowed fraction of FAIL frames (default 0)")
    g.add_argument("--max-unverifiable-fraction", type=float, default=None,
                   help="gate: largest allowed fraction of UNVERIFIABLE frames (default 0.5); "
                   "a run with no verified frame always fails")
    g.add_argument("--max-internal-errors", type=int, default=None,
                   help="gate: frames with internal errors or crashed workers allowed "
                   "(default 0)")
    g.add_argument("--shared-threshold-px", type=float, default=None,
                   help="threshold of the run-level registration / drift / calibration checks "
                   "(default: 0.15 x the per-frame threshold, 0.3 %% of the diagonal)")
    g.add_argument("--no-shared-checks", action="store_true",
                   help="skip the run-level checks (then a PASS resting on reprojected "
                   "references alone is UNVERIFIABLE)")
    g.add_argument("--remove-calibration", action="store_true",
                   help="judge frames after removing the estimated per-camera calibration "
                   "error (a shared principal-point / camera-to-rig / focal error; see the "
                   "summary's shared_errors.calibration)")
    g.add_argument("--calibration-translation", action="store_true",
                   help="the calibration error may include a camera-to-rig translation (photos "
                   "from a camera beside the posed sensor, e.g. RGB beside depth); estimated "
                   "where depths differ enough, reported and removed with --remove-calibration")
    g.add_argument("--require-accuracy", default=None, type=_accuracy_pair,
                   metavar="DEG,UNITS",
                   help="gate also on the pose accuracy: fail when the 95 %% bound of more than "
                   "--max-fail-fraction of the frames, or of a shared error, exceeds DEG "
                   "degrees or UNITS scene units (summary.json accuracy; the px threshold "
                   "still decides PASS / FAIL)")
    g.add_argument("--separation-frames", type=int, default=None, metavar="N",
                   help="measure N frames per evidence path again at poses moved by 4x the "
                   "threshold: a path whose error does not grow with the move cannot tell "
                   "right from wrong on this run and decides no frame (path_cannot_separate; "
                   "summary.json path_separation); default 8, 0 = off")
    g.add_argument("--self-test", type=int, default=None, metavar="N",
                   help="after the verdicts, measure N PASS frames again at poses moved by "
                   "0.5-2x the stated detection limits (and those frames moved together for "
                   "the shared limit): the empirical detection curve in summary.json "
                   "self_test and the report; default 0 = off (docs/outputs.md#self-test)")
    g.add_argument("--calibration-from", default=None, metavar="SUMMARY_JSON",
                   help="remove the calibration estimated by a trusted run (its summary.json) "
                   "instead of one estimated on this run")


def _accuracy_pair(text: str) -> tuple[float, float]:
    """``DEG,UNITS`` of ``--require-accuracy``: two positive finite numbers."""
    import math

    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        deg, units = (float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected DEG,UNITS (two numbers, e.g. 0.5,0.02), got {text!r}"
        ) from None
    if not (math.isfinite(deg) and math.isfinite(units) and 0 < deg <= 180 and units > 0):
        raise argparse.ArgumentTypeError(
            f"DEG must be in (0, 180] and UNITS > 0, got {text!r}"
        )
    return deg, units


def _add_run_args(p: argparse.ArgumentParser) -> None:
    """Run, output, scale and resume options."""
    g = p.add_argument_group("run")
    g.add_argument("--limit", type=int, default=None,
                   help="check only the first N frames (N >= 1)")
    g.add_argument("--max-image-pixels", type=int, default=None,
                   help="images whose header declares more pixels are not decoded "
                   "(UNVERIFIABLE pixel_cap_exceeded; default 100000000)")
    g.add_argument("--fail-fast", action="store_true", help="re-raise internal errors")
    g.add_argument("--report-details", type=int, default=None,
                   help="frames with image panels in report.html (default 40)")
    g.add_argument("--absolute-paths", action="store_true",
                   help="show absolute paths in the report (default: relative or shortened)")
    g = p.add_argument_group("scale and resume")
    g.add_argument("--executor", default=None, choices=["serial", "process", "dask"],
                   help="serial (default), a local process pool, or a Dask cluster")
    g.add_argument("--workers", type=int, default=None,
                   help="worker processes for process / local Dask (default: all cores)")
    g.add_argument("--threads", type=int, default=None,
                   help="OpenCV and BLAS threads per process (default 1; 0 = every core)")
    g.add_argument("--scheduler", default=None,
                   help="address of a running Dask scheduler, e.g. tcp://host:8786 "
                   "(implies --executor dask)")
    g.add_argument("--resume", action="store_true",
                   help="keep frames already in --out measured with the same settings, "
                   "measure the others")
    g.add_argument("--overwrite", action="store_true",
                   help="discard the records already in --out and start fresh")
    g.add_argument("-v", "--verbose", action="count", default=0)
    g.add_argument("-q", "--quiet", action="store_true")
    g.add_argument("--version", action="version", version=f"pgt-check {__version__}")


def _override_table(args: argparse.Namespace) -> dict[tuple[str, ...], Any]:
    """Config key path -> the value its command-line option gives (None: not given)."""
    return {
        ("input", "trajectory"): args.trajectory,
        ("input", "mesh"): args.mesh,
        ("input", "format"): args.format,
        ("input", "images"): args.images,
        ("input", "camera"): args.camera,
        ("input", "sensors"): args.sensors,
        ("input", "dataparser_transforms"): args.dataparser_transforms,
        ("render", "backend"): args.renderer,
        ("render", "shading"): args.shading,
        ("match", "method"): args.matcher,
        ("match", "max_keypoints"): args.max_keypoints,
        ("match", "loftr_weights"): args.loftr_weights,
        ("enhance", "mode"): args.enhance,
        ("enhance", "method"): args.enhance_method,
        ("enhance", "weights"): args.weights,
        ("enhance", "iterations"): args.iterations,
        ("enhance", "reference", "mode"): args.reference,
        ("pose", "enabled"): False if args.no_pose_estimate else None,
        ("edges", "mode"): args.edges,
        ("edges", "tile_grid"): args.edges_tile_grid,
        ("run_checks", "threshold_px"): args.shared_threshold_px,
        ("run_checks", "enabled"): False if args.no_shared_checks else None,
        ("run_checks", "remove_calibration"): True if args.remove_calibration else None,
        ("run_checks", "calibration_translation"): True if args.calibration_translation else None,
        ("run_checks", "calibration_from"): args.calibration_from,
        ("gate", "require_accuracy_deg"): (
            None if args.require_accuracy is None else args.require_accuracy[0]
        ),
        ("gate", "require_accuracy_units"): (
            None if args.require_accuracy is None else args.require_accuracy[1]
        ),
        ("correct", "frames"): args.correct,
        ("correct", "rounds"): args.correct_rounds,
        ("run_checks", "refine_rounds"): args.registration_rounds,
        ("report_details",): args.report_details,
        ("self_test",): args.self_test,
        ("verdict", "separation_frames"): args.separation_frames,
        ("absolute_paths",): True if args.absolute_paths else None,
        # 0 = original size: MatchConfig turns it into None
        ("match", "resize_max"): args.resize_max,
        ("input", "max_image_pixels"): args.max_image_pixels,
        ("gate", "max_internal_errors"): args.max_internal_errors,
        ("verdict", "threshold_px"): args.threshold_px,
        ("verdict", "threshold_rel_diag"): args.threshold_rel_diag,
        ("verdict", "min_inliers"): args.min_inliers,
        ("verdict", "min_coverage"): args.min_coverage,
        ("gate", "max_fail_fraction"): args.max_fail_fraction,
        ("gate", "max_unverifiable_fraction"): args.max_unverifiable_fraction,
        ("out",): args.out,
        ("limit",): args.limit,
        ("executor",): args.executor or ("dask" if args.scheduler else None),
        ("workers",): args.workers,
        ("threads",): args.threads,
        ("scheduler",): args.scheduler,
    }


def _cli_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The settings the command-line options give, nested like a config file."""
    out: dict[str, Any] = {}
    for path, value in _override_table(args).items():
        if value is None or value is ...:
            continue
        node = out
        for key in path[:-1]:
            node = node.setdefault(key, {})
        node[path[-1]] = value
    if args.fail_fast:
        out["fail_fast"] = True
    for flag in ("resume", "overwrite"):
        if getattr(args, flag):
            out[flag] = True
    return out


def resume_command(argv: Sequence[str]) -> str:
    """The command line that resumes the run started with ``argv``."""
    import shlex

    args = [a for a in argv if a not in ("--overwrite", "--resume")]
    return shlex.join(["pgt-check", *args, "--resume"])


#: config keys -> the CLI option that sets them (named in ConfigError messages)
_OPTION_OF = {
    "verdict.threshold_px": "--threshold-px",
    "verdict.threshold_rel_diag": "--threshold-rel-diag",
    "verdict.min_inliers": "--min-inliers",
    "verdict.min_coverage": "--min-coverage",
    "gate.max_fail_fraction": "--max-fail-fraction",
    "gate.max_unverifiable_fraction": "--max-unverifiable-fraction",
    "gate.max_internal_errors": "--max-internal-errors",
    "match.max_keypoints": "--max-keypoints",
    "match.resize_max": "--resize-max",
    "enhance.iterations": "--iterations",
    "input.max_image_pixels": "--max-image-pixels",
    "limit": "--limit",
    "workers": "--workers",
    "threads": "--threads",
    "report_details": "--report-details",
    "edges.tile_grid": "--edges-tile-grid",
    "correct.rounds": "--correct-rounds",
    "run_checks.refine_rounds": "--registration-rounds",
    "run_checks.threshold_px": "--shared-threshold-px",
    "gate.require_accuracy_deg": "--require-accuracy",
    "gate.require_accuracy_units": "--require-accuracy",
    "scheduler": "--scheduler",
    "self_test": "--self-test",
    "verdict.separation_frames": "--separation-frames",
}


def load_config(args: argparse.Namespace) -> RunConfig:
    from pgt_check.config import PRESETS

    base = PRESETS[args.preset] if args.preset else {}
    if args.config:
        base = merge(base, load_config_file(args.config))
    try:
        return RunConfig.from_dict(merge(base, _cli_overrides(args)))
    except ConfigError as err:
        key = str(err).split(":", 1)[0]
        if key in _OPTION_OF:
            raise ConfigError(f"{_OPTION_OF[key]} (config {err})") from err
        raise


def _print_summary(out: str) -> None:
    """The lines after a run, from the summary.json it wrote (``report.headline``)."""
    from pgt_check.report.headline import summary_lines
    from pgt_check.report.outputs import read_summary

    for line in summary_lines(read_summary(Path(out)), out):
        print(f"pgt-check: {safe_text(line)}")


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(build_parser(), argv)
    if isinstance(args, int):  # argparse's code: 2 on usage errors, 0 on --help/--version
        return args
    configure_logging(args.verbose, args.quiet)
    install_sigterm_handler()
    from pgt_check.runner import RunInterrupted, run

    try:
        config = load_config(args)
        if args.print_config:
            import json

            print(json.dumps(config.to_dict(), indent=2))
            return EXIT_PASSED
        outcome = run(config)
    except (InputError, OSError) as err:
        # InputError covers ConfigError, FormatError, MissingExtraError and SetupError; an
        # OSError that reaches here is a file the user named (--out, an input) that cannot be
        # read or written
        if args.verbose:
            logger.exception("input error")
        print(f"pgt-check: error: {safe_text(_one_line(err))}", file=sys.stderr)
        return EXIT_INPUT
    except RunInterrupted as err:
        print(f"pgt-check: {err}; resume with: {safe_text(resume_command(argv))}",
              file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print(f"pgt-check: aborted; resume with: {safe_text(resume_command(argv))}",
              file=sys.stderr)
        return 130
    _print_summary(config.out)
    return EXIT_PASSED if outcome.gate.passed else EXIT_FAILED


def _one_line(err: BaseException) -> str:
    if isinstance(err, OSError) and not isinstance(err, InputError):
        what = err.strerror or type(err).__name__
        return f"{err.filename}: {what}" if err.filename else f"{what}: {err}"
    return " ".join(str(err).split("\n"))

