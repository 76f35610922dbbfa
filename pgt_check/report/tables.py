"""The report's tables as plain data: the frame-table column definitions and rows (values
rounded as in frames.csv), the shared-error rows and the raw-vs-enhanced comparison rows.
``pgt_check.report.html`` puts them into the page.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from pgt_check.report.text import display_path, redact_text

#: frame-table columns: (key, label, type, digits, hidden). type: num | int | str | verdict | bool
#: | flag; hidden columns show with "all columns" (and always in the detail cards)
Col = tuple[str, str, str, "int | None", bool]
BASE_COLUMNS: tuple[Col, ...] = (
    ("frame_id", "frame", "str", None, False),
    ("timestamp", "timestamp", "num", None, False),
    ("image_path", "image", "str", None, True),
    ("verdict", "verdict", "verdict", None, False),
    ("reason", "reason", "str", None, False),
    ("corner_error_px", "corner err [px]", "num", 2, False),
    ("threshold_px", "thr [px]", "num", 1, False),
    ("n_matches", "matches", "int", None, False),
    ("n_inliers", "inliers", "int", None, False),
    ("inlier_ratio", "inl. ratio", "num", 3, False),
    ("coverage", "coverage", "num", 3, True),
    ("shift_dx_px", "dx [px]", "num", 1, False),
    ("shift_dy_px", "dy [px]", "num", 1, False),
    ("zoom", "zoom", "num", 4, True),
    ("time_s", "frame run time [s]", "num", 2, True),
)
#: shown only when some record has a value for the key (new evidence / drift columns)
OPTIONAL_COLUMNS: tuple[Col, ...] = (
    ("evidence", "evidence", "str", None, False),
    ("drift_px", "drift [px]", "num", 2, False),
    ("decided_by", "decided by", "str", None, False),
    ("corner_error_px_edges", "err edges [px]", "num", 2, False),
)
#: shown only when the enhanced path ran on some frame; ``disagree`` is computed when absent
ENHANCED_COLUMNS: tuple[Col, ...] = (
    ("disagree", "raw\u2260enh.", "flag", None, False),
    ("verdict_path", "most inliers", "str", None, True),
    ("corner_error_px_raw", "err raw [px]", "num", 2, False),
    ("corner_error_px_enhanced", "err enh. [px]", "num", 2, False),
    ("raw_verdict", "verdict raw", "verdict", None, True),
    ("enhanced_verdict", "verdict enh.", "verdict", None, True),
    ("shift_dx_px_raw", "dx raw [px]", "num", 1, True),
    ("shift_dy_px_raw", "dy raw [px]", "num", 1, True),
    ("n_inliers_raw", "inl. raw", "int", None, True),
    ("n_inliers_enhanced", "inl. enh.", "int", None, True),
    ("inlier_ratio_raw", "ratio raw", "num", 3, True),
    ("inlier_ratio_enhanced", "ratio enh.", "num", 3, True),
    ("enhanced", "enhanced ran", "bool", None, True),
    ("enhanced_why", "why enhanced", "str", None, True),
    ("reference_id", "reference", "str", None, True),
)
#: shown only when some frame was corrected (``pgt_check.correct.frames``)
CORRECTION_TABLE_COLUMNS: tuple[tuple[str, str, str, int | None], ...] = (
    ("corr_applied", "corrected", "bool", None),
    ("corr_drot_deg", "corr. rot [deg]", "num", 3),
    ("corr_dt", "corr. shift [units]", "num", 4),
    ("corr_sigma_rot_deg", "± rot [deg]", "num", 3),
    ("corr_sigma_t", "± shift [units]", "num", 4),
    ("corr_corner_error_px", "err after corr. [px]", "num", 2),
)
#: the numbers of a run-level check's entry shown in its row (key, label, format)
SHARED_ERROR_NUMBERS = (
    ("angle_deg", "angle [deg]", ".3f"),
    ("translation", "translation [scene units]", ".4g"),
    ("translation_rel_depth", "translation / depth", ".3f"),
    ("scale", "scale", ".4f"),
    ("effect_px", "effect [px]", ".2f"),
)
SHARED_ERROR_STATUSES = ("passed", "failed", "inconclusive", "not_checked", "finding")


def table_value(value: Any, kind: str) -> Any:
    """A record value as carried in the page's table: floats rounded exactly as frames.csv."""
    if value is None:
        return None
    if kind == "bool":
        return bool(value)
    if isinstance(value, bool):
        return value
    if isinstance(value, float):
        return float(f"{value:.6g}") if math.isfinite(value) else None
    if isinstance(value, int):
        return value
    if kind in ("num", "int"):
        return None
    return str(value)


def has_enhanced_path(records: Sequence[Mapping[str, Any]]) -> bool:
    """True when the enhanced path ran (was matched) on some frame."""
    return any(
        r.get("n_matches_enhanced") is not None or r.get("corner_error_px_enhanced") is not None
        for r in records
    )


def table_columns(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The table's columns: the base ones, optional ones some record has a value for, and the
    raw-vs-enhanced ones when the enhanced path ran (``disagree`` always among them)."""
    cols = [*BASE_COLUMNS]
    for c in OPTIONAL_COLUMNS:
        if any(r.get(c[0]) not in (None, "") for r in records):
            cols.insert(5 if c[0] == "evidence" else len(cols), c)
    if has_enhanced_path(records):
        cols += [
            c for c in ENHANCED_COLUMNS
            if c[0] == "disagree" or any(r.get(c[0]) is not None for r in records)
        ]
    present = set().union(*(r.keys() for r in records)) if records else set()
    cols += [(*c, False) for c in CORRECTION_TABLE_COLUMNS if c[0] in present]
    return [
        {"key": k, "label": lbl, "type": t, "digits": d, "hidden": h} for k, lbl, t, d, h in cols
    ]


def table_rows(
    records: Sequence[Mapping[str, Any]], columns: Sequence[Mapping[str, Any]],
    absolute_paths: bool = False,
) -> list[list[Any]]:
    """The table's rows (one value per column, ``table_value``): ``disagree`` computed, image
    paths and free-text reasons with absolute paths shortened."""
    from pgt_check.report.paths import disagreement

    rows = []
    for r in records:
        row = []
        for c in columns:
            v = r.get(c["key"])
            if c["key"] == "disagree":
                v = disagreement(r)
            elif c["key"] == "image_path":
                v = display_path(str(v or ""), absolute_paths)
            elif c["key"] in ("reason", "enhanced_why"):
                v = redact_text(str(v or ""), absolute_paths)
            row.append(table_value(v, c["type"]))
        rows.append(row)
    return rows


def _with_ci(entry: Mapping[str, Any], key: str, spec: str) -> str | None:
    v = entry.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    text = format(v, spec)
    ci = entry.get(f"{key}_ci")
    if isinstance(ci, (list, tuple)) and len(ci) == 2 and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in ci
    ):
        text += f" [{format(ci[0], spec)}, {format(ci[1], spec)}]"
    return text


def _shared_error_entry(name: str, entry: Mapping[str, Any]) -> dict[str, Any]:
    status = str(entry.get("status") or "not_checked")
    numbers = [
        (label, text) for key, label, spec in SHARED_ERROR_NUMBERS
        if (text := _with_ci(entry, key, spec)) is not None
    ]
    return {
        "name": name,
        "status": status,
        "status_class": status if status in SHARED_ERROR_STATUSES else "other",
        "message": str(entry.get("message") or ""),
        "numbers": numbers,
    }


def shared_error_rows(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """``summary["shared_errors"]`` as display rows: each check's ``table`` rows of its entry in
    registry order (``verdict.checks.CHECKS``: one per check, or one per camera), then entries
    of checks this version does not know (a newer run's), by key."""
    from pgt_check.verdict.checks import CHECKS

    se = summary.get("shared_errors")
    if not isinstance(se, Mapping):
        return []
    known = {c.KEY for c in CHECKS}
    pairs = [pair for c in CHECKS if c.KEY in se for pair in c.table(se[c.KEY])]
    for key in sorted(k for k in se if k not in known):
        entry = se[key]
        if not isinstance(entry, Mapping):
            continue
        if "status" in entry:
            pairs.append((str(key), entry))
            continue
        pairs += [(f"{key} (camera {cam})", sub) for cam, sub in entry.items()  # per camera id
                  if isinstance(sub, Mapping) and "status" in sub]
    return [_shared_error_entry(name, entry) for name, entry in pairs]


def comparison_rows(comparison: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """The run-level raw-vs-enhanced table: (quantity, raw, enhanced) strings."""
    raw, enh = comparison.get("raw") or {}, comparison.get("enhanced") or {}
    spec = (
        ("frames_ran", "frames matched", "d"),
        ("frames_with_homography", "frames with a homography", "d"),
        ("frames_decided", "frames decided (more inliers)", "d"),
        ("frames_above_threshold", "frames above the threshold", "d"),
        ("median_matches", "median matches", ".0f"),
        ("median_inliers", "median inliers", ".0f"),
        ("median_inlier_ratio", "median inlier ratio", ".3f"),
        ("median_corner_error_px", "median corner error [px]", ".2f"),
    )
    return [(label, fmt(raw.get(k), f), fmt(enh.get(k), f)) for k, label, f in spec]


def fmt(value: Any, spec: str = ".2f") -> str:
    """A number formatted with ``spec``; ``-`` for None / non-finite, other values as text."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return "-" if value in (None, "") else str(value)
    return format(value, spec) if math.isfinite(value) else "-"
