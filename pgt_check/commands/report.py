"""``pgt-check report OUT_DIR``: rebuild verdicts and outputs from stored records (no recompute).

Rewrites frames.csv, summary.json, report.html (+ plots) and junit.xml; the detail images already
in ``OUT_DIR/assets/`` (listed in ``assets/index.json``) are reused, never re-rendered.
Exit codes: 0 the gate passed, 1 it failed, 2 usage or input error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from pgt_check.commands.common import (
    OneLineErrorParser,
    install_sigterm_handler,
    parse_args,
    path_arg,
)
from pgt_check.common.files import MAX_SMALL_JSON_BYTES, load_json_limited, safe_text
from pgt_check.config import RunConfig
from pgt_check.errors import InputError
from pgt_check.measure.record import FrameMeasurement
from pgt_check.output_layout import OUTPUTS
from pgt_check.verdict.outcome import InputsChanged


def _warn_stale_auto_decisions(records: list[FrameMeasurement], config: RunConfig) -> None:
    """``--enhance auto`` decided per frame with the threshold of the measuring run; say so when
    re-judging with another one (re-measure with ``pgt-check ... --resume`` to update them)."""
    stale = [
        m
        for m in records
        if m.auto_threshold_px is not None
        and abs(m.auto_threshold_px - config.verdict.threshold_for(m.width, m.height)) > 1e-9
    ]
    if stale:
        print(
            f"pgt-check report: note: {len(stale)} frames were measured with --enhance auto "
            f"under a threshold of {stale[0].auto_threshold_px:.1f} px; which of them were "
            "enhanced was decided with that threshold (rerun pgt-check with the new threshold "
            "and --resume to re-measure them)",
            file=sys.stderr,
        )


def _old_summary(path: Path) -> dict:
    """The previous summary.json (for run facts the records lack); {} if missing or corrupt
    (it is rebuilt anyway)."""
    if not path.exists():
        return {}
    try:
        old = load_json_limited(path, MAX_SMALL_JSON_BYTES, OUTPUTS.summary_json)
    except InputError:
        print(f"pgt-check report: note: {path} is unreadable; rebuilding it", file=sys.stderr)
        return {}
    return old if isinstance(old, dict) else {}


#: the config sections a re-judge may change (the measurements stay): section -> the flag
#: names of fields whose own name would be ambiguous, and the fields left out (they measure)
_REJUDGE_SECTIONS: dict[str, tuple[dict[str, str], tuple[str, ...]]] = {
    "verdict": ({}, ()),
    "gate": ({}, ()),
    "run_checks": ({"enabled": "shared_checks", "threshold_px": "shared_threshold_px",
                    "threshold_rel": "shared_threshold_rel"},
                   ("refine_rounds", "refine_frames")),
}


def _verdict_fields() -> list[tuple[str, str, str, type, object]]:
    """(section, field, flag name, type, default) of every setting a re-judge may change."""
    import dataclasses
    import typing

    from pgt_check.config import RunConfig

    cfg = RunConfig()
    out = []
    for section, (names, skip) in _REJUDGE_SECTIONS.items():
        cls = type(getattr(cfg, section))
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if f.name in skip:
                continue
            tp = hints[f.name]
            args = [a for a in typing.get_args(tp) if a is not type(None)] or [tp]
            tp = args[0] if args[0] in (int, float, str, bool) else str
            out.append((section, f.name, names.get(f.name, f.name), tp,
                        getattr(getattr(cfg, section), f.name)))
    return out


def _bool_arg(text: str) -> bool:
    """argparse type of the boolean flags: ``parse_bool``; any other word is a usage error
    (exit 2), never read as false."""
    from pgt_check.config.load import parse_bool

    try:
        return parse_bool(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_verdict_flags(p: argparse.ArgumentParser) -> None:
    """One ``--name`` flag per field of the ``verdict``, ``gate`` and ``run_checks`` sections
    (derived, so new fields come along)."""
    g = p.add_argument_group("verdict, gate and run-level check settings (re-judge without "
                             "re-measuring)")
    for section, name, flag_name, tp, default in _verdict_fields():
        flag, dest = "--" + flag_name.replace("_", "-"), f"{section}__{name}"
        if tp is bool:
            g.add_argument(flag, dest=dest, default=None, type=_bool_arg,
                           metavar="{true,false}",
                           help=f"(default {default}; also yes/no, on/off, 1/0)")
        else:
            g.add_argument(flag, dest=dest, type=tp, default=None, metavar=flag_name.upper(),
                           help=f"(default {default})")


def verdict_overrides(args: argparse.Namespace) -> dict[str, dict[str, object]]:
    """The re-judge flags given, nested by section like a config file."""
    out: dict[str, dict[str, object]] = {}
    for section, name, _, _, _ in _verdict_fields():
        value = getattr(args, f"{section}__{name}")
        if value is not None:
            out.setdefault(section, {})[name] = value
    return out


def build_parser() -> argparse.ArgumentParser:
    p = OneLineErrorParser(
        prog="pgt-check report", description="Rebuild outputs of a run from its stored records."
    )
    p.add_argument("out_dir", type=path_arg)
    add_verdict_flags(p)
    p.add_argument(
        "--rejudge-stale", action="store_true",
        help="judge the stored measurements as they are although an input they were measured "
        "on changed since (mesh, trajectory, sensors, images: run.json's content hashes); "
        "without it the gate fails when one changed",
    )
    p.add_argument(
        "--absolute-paths",
        action="store_true",
        default=None,
        help="show absolute paths of this machine in the report (default: shortened)",
    )
    return p


def main(argv: Sequence[str]) -> int:
    args = parse_args(build_parser(), argv)
    if isinstance(args, int):
        return args
    install_sigterm_handler()
    try:
        return _report(args)
    except KeyboardInterrupt:
        print("pgt-check report: interrupted; the outputs are incomplete: run pgt-check report "
              "again to rebuild them", file=sys.stderr)
        return 130


def _inputs_changed(out: Path, cfg: dict, rejudge: bool) -> InputsChanged | None:
    """summary.json's ``inputs_changed``: the input files (run.json's content hashes) that
    changed since they were measured, said on stderr; None when none did. Without ``rejudge``
    its explanation is the gate's (``build_summary`` fails the gate on it)."""
    from pgt_check.content_hash import changed_inputs
    from pgt_check.records_file import RUN_FILE

    info = load_json_limited(out / RUN_FILE, MAX_SMALL_JSON_BYTES, RUN_FILE)
    inp = cfg.get("input") if isinstance(cfg, dict) else None
    changed, unreadable = changed_inputs(info if isinstance(info, dict) else {},
                                         inp if isinstance(inp, dict) else None)
    if unreadable:
        print(f"pgt-check report: note: {len(unreadable)} input files of the measurements "
              f"cannot be read any more and were not checked for changes (e.g. "
              f"{safe_text(unreadable[0])})", file=sys.stderr)
    if not changed:
        return None
    names = ", ".join(safe_text(p) for p in changed[:3]) + (
        f" and {len(changed) - 3} more" if len(changed) > 3 else "")
    what = f"{len(changed)} input file(s) changed since they were measured: {names}"
    if rejudge:
        print(f"pgt-check report: warning: {what}; --rejudge-stale: the stored measurements "
              "are judged as they are", file=sys.stderr)
    else:
        print(f"pgt-check report: {what}; the stored measurements are not of these "
              "inputs, so the gate fails: measure again (pgt-check ... --resume), or pass "
              "--rejudge-stale to judge the stored measurements as they are", file=sys.stderr)
    return InputsChanged(tuple(changed), tuple(unreadable), rejudge,
                         f"{what}: measure again with --resume (or pgt-check report "
                         "--rejudge-stale judges the stored measurements as they are)")


def _check_trusted_summary_not_ours(out: Path, calibration_from: str | None) -> None:
    """InputError when ``--calibration-from`` is one of this folder's own outputs (its
    summary.json): a run refuses that (``--out`` would overwrite it); ``report`` took the run's
    own estimate as the trusted calibration and then rewrote the file it names (third audit,
    #39)."""
    from pgt_check.common.files import check_inputs_not_outputs
    from pgt_check.stages.inputs import run_output_paths

    try:
        check_inputs_not_outputs([("--calibration-from summary", calibration_from)],
                                 run_output_paths(out), "OUT_DIR")
    except InputError:
        raise InputError(
            f"--calibration-from {calibration_from}: is an output of {out} itself, which this "
            "report rewrites (and the run's own estimate is not a trusted calibration): pass "
            "the summary.json of another, trusted run"
        ) from None


def _report(args: argparse.Namespace) -> int:
    from pgt_check.rejudge import rejudge, stored_run
    from pgt_check.report.outputs import RunFacts, outputs_complete, write_outcome

    try:
        out = Path(args.out_dir)
        override: dict = verdict_overrides(args)
        if args.absolute_paths:
            override["absolute_paths"] = True
        stored = stored_run(out, override)
        config = stored.config
        _check_trusted_summary_not_ours(out, config.run_checks.calibration_from)
        _warn_stale_auto_decisions(stored.measurements, config)
        complete, why = outputs_complete(out)
        if not complete:
            print(f"pgt-check report: note: the output set in {out} was incomplete ({why}); "
                  "rebuilding all of it", file=sys.stderr)
        old = _old_summary(out / OUTPUTS.summary_json)
        extra = {
            k: old[k]
            for k in ("trajectory_format", "shading", "setup_s", "wall_time_s",
                      "images_outside_dataset", "warnings", "executor", "corrections",
                      "self_test", "calibrated_rig")  # calibrated/ is not rewritten here
            if k in old
        }
        outcome = rejudge(stored, inputs_changed=_inputs_changed(out, dict(stored.settings),
                                                                 args.rejudge_stale),
                          note=lambda s: print(f"pgt-check report: note: {s}", file=sys.stderr))
        summary = write_outcome(out, outcome, config, RunFacts(carried=extra))
    except (InputError, OSError) as err:
        print(f"pgt-check report: error: {safe_text(err)}", file=sys.stderr)
        return 2
    from pgt_check.report.headline import failure_headline
    from pgt_check.verdict import Verdict

    for line in failure_headline(summary, out):
        print(f"pgt-check report: {safe_text(line)}")
    n = outcome.statistics.count
    print(
        f"pgt-check report: {n(Verdict.PASS)} PASS, {n(Verdict.FAIL)} FAIL, "
        f"{n(Verdict.UNVERIFIABLE)} UNVERIFIABLE; "
        f"gate {'PASSED' if outcome.gate.passed else 'FAILED'}"
    )
    return 0 if outcome.gate.passed else 1
