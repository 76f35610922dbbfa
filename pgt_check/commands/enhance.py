"""``pgt-check enhance RENDERS MODEL --out DIR``: enhance a folder of renders with the nearest
training photos (the inputs, naming convention and outputs: ``pgt_check.stages.enhance_folder``).

Exit codes: 0 done; 2 usage, input or setup error (one line, no traceback); 130 interrupted.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from pgt_check.commands.common import (
    OneLineErrorParser,
    configure_logging,
    install_sigterm_handler,
    parse_args,
    path_arg,
)
from pgt_check.common.files import safe_text
from pgt_check.errors import InputError
from pgt_check.stages.enhance_folder import enhance_folder, summary_lines


def build_parser() -> argparse.ArgumentParser:
    from pgt_check.io import FORMATS

    p = OneLineErrorParser(
        prog="pgt-check enhance",
        description="Enhance a folder of renders with the nearest training photos (MaRINeR or "
        "reprojection); with --gt, PSNR-Y/SSIM-Y/LPIPS of raw vs enhanced. Renders are named "
        "like the model's images (or like the entries of --render-poses) to take their poses. "
        "Exit codes: 0 done, 2 usage, input or setup error.",
    )
    p.add_argument("renders", help="folder of rendered images (.png/.jpg, top level)")
    p.add_argument("model", help="training images with poses: transforms.json, COLMAP model or "
                   "any pose file pgt-check reads")
    p.add_argument("--out", required=True, type=path_arg, help="output folder")
    p.add_argument("--format", default="auto", choices=["auto", *FORMATS],
                   help="format of MODEL")
    p.add_argument("--images", default=None, help="image folder of MODEL")
    p.add_argument("--sensors", default=None, help="LaMAR sensors file of MODEL")
    p.add_argument("--camera", default=None, help="intrinsics for TUM / hloc pose files")
    p.add_argument("--dataparser-transforms", default=None,
                   help="nerfstudio dataparser_transforms.json to undo (MODEL)")
    p.add_argument("--render-poses", default=None,
                   help="pose file for the renders (any format pgt-check reads); default: the "
                   "renders are named like MODEL's images")
    p.add_argument("--render-poses-format", default="auto", choices=["auto", *FORMATS])
    p.add_argument("--method", default="mariner", choices=["mariner", "reproject"])
    p.add_argument("--mesh", default=None, help="mesh for --method reproject")
    p.add_argument("--shading", default="auto", choices=["auto", "vertex", "texture", "shaded"],
                   help="mesh shading for --method reproject (depth only is used)")
    p.add_argument("--weights", default=None, help="MaRINeR checkpoint (default: shipped)")
    p.add_argument("--iterations", type=int, default=None,
                   help="MaRINeR refinement iterations (default: the checkpoint's)")
    p.add_argument("--short-side", type=int, default=160,
                   help="MaRINeR working size, shorter side in px (default 160)")
    p.add_argument("--device", default="cpu", help="torch device for MaRINeR (cpu, cuda, auto)")
    p.add_argument("--max-rotation-deg", type=float, default=45.0,
                   help="largest rotation between a render and its reference (default 45)")
    p.add_argument("--translation-scale", type=float, default=None,
                   help="scene units worth 10 deg in the reference distance (default: 10 %% of "
                   "the training cameras' extent)")
    p.add_argument("--allow-same-view", action="store_true",
                   help="let a render take the model photo of its own view (same name or pose) "
                   "as reference: an upper bound, the enhancer then sees the ground truth")
    p.add_argument("--gt", default=None, help="folder of ground-truth photos named like the "
                   "renders: writes metrics.csv and metrics.md")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS in the metrics")
    p.add_argument("--limit", type=int, default=None, help="only the first N renders")
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def main(argv: Sequence[str]) -> int:
    args = parse_args(build_parser(), argv)
    if isinstance(args, int):
        return args
    configure_logging(0, args.quiet, logging.ERROR)  # -q: errors only
    install_sigterm_handler()
    try:
        summary = enhance_folder(args)
    except (InputError, ValueError, OSError) as err:
        if isinstance(err, OSError) and not isinstance(err, InputError) and err.filename:
            text = f"{err.filename}: {err.strerror or type(err).__name__}"
        else:
            text = " ".join(str(err).split("\n"))
        print(f"pgt-check enhance: error: {safe_text(text)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pgt-check enhance: interrupted", file=sys.stderr)
        return 130
    for line in summary_lines(summary, args.out):
        print(line)
    return 0
