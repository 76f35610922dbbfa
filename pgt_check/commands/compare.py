"""``pgt-check compare A B``: two pose sources for the same images (what is compared and how:
``pgt_check.stages.compare``). Writes ``compare.csv`` and ``compare.json`` (``--out``) and prints a
summary. Exit codes: 0 done, 2 usage or input error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pgt_check.commands.common import (
    OneLineErrorParser,
    configure_logging,
    install_sigterm_handler,
    parse_args,
    path_arg,
)
from pgt_check.common.files import atomic_write_text, check_inputs_not_outputs, safe_text
from pgt_check.errors import InputError
from pgt_check.output_layout import COMPARE_OUTPUTS
from pgt_check.stages.compare import (
    check_compare_options,
    checker_config,
    compare_trajectories,
    rows_csv_text,
    summary_lines,
)


def build_parser() -> argparse.ArgumentParser:
    from pgt_check.registry import FORMATS, MATCHERS

    p = OneLineErrorParser(
        prog="pgt-check compare",
        description="Compare two pose sources for the same images: per-frame difference "
        "(deg, scene units, px) and, with --mesh, which source the images support.",
        epilog="Exit codes: 0 done, 2 usage or input error.",
    )
    p.add_argument("a", help="first pose file (or COLMAP model)")
    p.add_argument("b", help="second pose file (or COLMAP model)")
    p.add_argument("--mesh", default=None, help="mesh: measure both sources against the photos")
    p.add_argument("--sensors-a", default=None, help="LaMAR sensors file of A")
    p.add_argument("--sensors-b", default=None, help="LaMAR sensors file of B")
    p.add_argument("--format-a", default="auto", choices=["auto", *FORMATS])
    p.add_argument("--format-b", default="auto", choices=["auto", *FORMATS])
    p.add_argument("--images", default=None, help="image folder or list (both sources)")
    p.add_argument("--camera", default=None, help="intrinsics for TUM / hloc sources")
    p.add_argument("--matcher", default=None, choices=list(MATCHERS))
    p.add_argument("--shading", default=None, choices=["auto", "vertex", "texture", "shaded"])
    p.add_argument("--enhance", default=None, choices=["never", "auto", "always"],
                   help="enhanced path as in pgt-check (default auto)")
    p.add_argument("--threshold-px", type=float, default=None,
                   help="verdict threshold (default 2%% of the image diagonal)")
    p.add_argument("--tie-px", type=float, default=0.5,
                   help="corner errors closer than this are a tie (default 0.5 px)")
    p.add_argument("--limit", type=int, default=None, help="compare only the first N frames")
    p.add_argument("--out", default=".", type=path_arg, help="folder for compare.csv and compare.json")
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def main(argv: Sequence[str]) -> int:
    args = parse_args(build_parser(), argv)
    if isinstance(args, int):
        return args
    configure_logging(0, args.quiet, logging.ERROR)  # -q: errors only
    install_sigterm_handler()
    try:
        return _compare(args)
    except (InputError, ValueError, OSError) as err:  # ValueError: a bad setting (ConfigError)
        print(f"pgt-check compare: error: {_error_text(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pgt-check compare: interrupted", file=sys.stderr)
        return 130


def _error_text(err: BaseException) -> str:
    if isinstance(err, OSError) and not isinstance(err, InputError) and err.filename:
        return safe_text(f"{err.filename}: {err.strerror or type(err).__name__}")
    return safe_text(" ".join(str(err).split("\n")))


def _compare(args: argparse.Namespace) -> int:
    from pgt_check.io import read_trajectory
    from pgt_check.report.outputs import json_safe

    settings: dict[str, Any] = {}
    if args.matcher:
        settings["match"] = {"method": args.matcher}
    if args.shading:
        settings["render"] = {"shading": args.shading}
    if args.enhance:
        settings["enhance"] = {"mode": args.enhance}
    if args.threshold_px is not None:
        settings["verdict"] = {"threshold_px": args.threshold_px}
    check_compare_options(args.tie_px, args.limit)
    if settings:  # checked up front, also without --mesh
        checker_config(args.mesh or "", settings)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a folder")
    check_inputs_not_outputs(
        [("pose source A", args.a), ("pose source B", args.b), ("mesh", args.mesh),
         ("sensors file of A", args.sensors_a), ("sensors file of B", args.sensors_b),
         ("images", args.images)],
        COMPARE_OUTPUTS.paths(out), "--out",
    )
    cam = {"camera": args.camera} if args.camera else {}
    a = read_trajectory(args.a, args.format_a, images=args.images, sensors=args.sensors_a, **cam)
    b = read_trajectory(args.b, args.format_b, images=args.images, sensors=args.sensors_b, **cam)
    res = compare_trajectories(a, b, args.mesh, tie_px=args.tie_px, limit=args.limit,
                               settings=settings)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"--out {out}: cannot create the folder ({err.strerror or err})") from None
    atomic_write_text(out / COMPARE_OUTPUTS.rows_csv, rows_csv_text(res.rows))
    summary = json_safe(res.summary)  # non-finite numbers become null (counted in the stats)
    atomic_write_text(out / COMPARE_OUTPUTS.summary_json,
                      json.dumps(summary, indent=2, default=str) + "\n")
    for line in summary_lines(res.summary):
        print(safe_text(line))
    print(f"pgt-check compare: wrote {safe_text(out / COMPARE_OUTPUTS.rows_csv)}")
    return 0
