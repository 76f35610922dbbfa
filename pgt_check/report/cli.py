"""``pgt-check report OUT_DIR``: rebuild verdicts and outputs from stored records (no recompute).

Rewrites frames.csv, summary.json, report.html (+ plots) and junit.xml; the detail images already
in ``OUT_DIR/assets/`` (listed in ``assets/index.json``) are reused, never re-rendered.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from pgt_check.config import RunConfig, merge
from pgt_check.errors import InputError


def load_run(out_dir: Path) -> tuple[list[dict], dict]:
    """Read records.jsonl and config.json of a finished run."""
    rec_path, cfg_path = out_dir / "records.jsonl", out_dir / "config.json"
    for p in (rec_path, cfg_path):
        if not p.is_file():
            raise InputError(f"{p} not found: is {out_dir} a pgt-check output directory?")
    records = []
    for i, line in enumerate(rec_path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as err:
            raise InputError(f"{rec_path}:{i}: not a JSON record ({err})") from err
    return records, json.loads(cfg_path.read_text())


def report_main(argv: Sequence[str]) -> int:
    p = argparse.ArgumentParser(
        prog="pgt-check report", description="Rebuild outputs of a run from its stored records."
    )
    p.add_argument("out_dir")
    p.add_argument("--threshold-px", type=float, default=None, help="re-judge with a new threshold")
    p.add_argument("--max-fail-fraction", type=float, default=None)
    p.add_argument(
        "--absolute-paths",
        action="store_true",
        default=None,
        help="show absolute paths of this machine in the report (default: shortened)",
    )
    try:
        args = p.parse_args(list(argv))
    except SystemExit as exc:
        return int(exc.code or 0)
    from pgt_check.report.outputs import write_outputs
    from pgt_check.runner import apply_verdicts

    try:
        out = Path(args.out_dir)
        records, cfg = load_run(out)
        override: dict = {"verdict": {}}
        if args.threshold_px is not None:
            override["verdict"]["threshold_px"] = args.threshold_px
        if args.max_fail_fraction is not None:
            override["verdict"]["max_fail_fraction"] = args.max_fail_fraction
        if args.absolute_paths:
            override["absolute_paths"] = True
        config = RunConfig.from_dict(merge(cfg, override))
        old = (
            json.loads((out / "summary.json").read_text())
            if (out / "summary.json").is_file()
            else {}
        )
        extra = {
            k: old[k]
            for k in ("trajectory_format", "shading", "setup_s", "wall_time_s")
            if k in old
        }
        summary = write_outputs(out, apply_verdicts(records, config), config, extra)
    except InputError as err:
        print(f"pgt-check report: error: {err}", file=sys.stderr)
        return 2
    c = summary["counts"]
    print(
        f"pgt-check report: {c['PASS']} PASS, {c['FAIL']} FAIL, {c['UNVERIFIABLE']} UNVERIFIABLE; "
        f"gate {'PASSED' if summary['gate']['passed'] else 'FAILED'}"
    )
    return 0 if summary["gate"]["passed"] else 1
