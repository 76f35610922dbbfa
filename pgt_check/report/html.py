"""report.html (+ plots under assets/) and junit.xml from judged records: stage 3 only reads.

``build_report`` is the entry point. The page is one self-contained file (inline CSS and JS from
this package, no network assets) that opens from disk. The frame table travels as JSON in a
``<script type="application/json">`` block and is rendered by a small vanilla-JS table with
pagination; detail panels are built on demand. All user data (frame ids, file names, reasons,
settings) is autoescaped by jinja2 or inserted with ``textContent`` by the script.
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

from pgt_check.report.assets import (
    ASSET_KINDS,
    existing_assets,
    load_assets_index,
    select_detail_frames,
    write_assets_index,
)

logger = logging.getLogger(__name__)

REPORT_NAME = "report.html"
JUNIT_NAME = "junit.xml"
PAGE_SIZE = 100
#: longest error_detail (e.g. a traceback) carried into the page, characters
MAX_DETAIL_CHARS = 1200

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
)
#: shown only when the enhanced path ran on some frame; ``disagree`` is computed when absent
ENHANCED_COLUMNS: tuple[Col, ...] = (
    ("disagree", "raw\u2260enh.", "flag", None, False),
    ("verdict_path", "decided by", "str", None, False),
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
#: shown only when some frame was corrected (``pgt_check.corrections``)
CORRECTION_TABLE_COLUMNS: tuple[tuple[str, str, str, int | None], ...] = (
    ("corr_applied", "corrected", "bool", None),
    ("corr_drot_deg", "corr. rot [deg]", "num", 3),
    ("corr_dt", "corr. shift [units]", "num", 4),
    ("corr_sigma_rot_deg", "± rot [deg]", "num", 3),
    ("corr_sigma_t", "± shift [units]", "num", 4),
    ("corr_corner_error_px", "err after corr. [px]", "num", 2),
)
KIND_LABELS = {
    "render": "render",
    "enhanced": "enhanced render",
    "photo": "photo",
    "diff": "render | photo | difference",
    "blend": "50 % blend render/photo",
    "checker": "checkerboard render/photo",
    "arrows_raw": "RAW path: matches (green inliers, red outliers) and homography arrows",
    "arrows_enhanced": "ENHANCED path: matches and homography arrows",
}
#: shared-error checks in display order, with their titles (others follow with their key)
SHARED_ERROR_TITLES = {
    "registration": "registration",
    "similarity": "similarity (scale)",
    "drift": "drift",
    "calibration": "calibration",
}
SHARED_ERROR_NUMBERS = (
    ("angle_deg", "angle [deg]", ".3f"),
    ("translation", "translation [scene units]", ".4g"),
    ("translation_rel_depth", "translation / depth", ".3f"),
    ("scale", "scale", ".4f"),
    ("effect_px", "effect [px]", ".2f"),
)
SHARED_ERROR_STATUSES = ("passed", "failed", "inconclusive", "not_checked", "finding")

# An absolute POSIX path (/a/b) or Windows path (C:\a or \\server\share) inside free text.
_ABS_PATH_RE = re.compile(
    r"""(?<![\w.:/\\])(?:[A-Za-z]:[\\/]|\\\\|/(?=[^\s/]))[^\s"'<>|,;:()\[\]]*"""
)


def is_absolute_path(path: str) -> bool:
    return PurePosixPath(path).is_absolute() or PureWindowsPath(path).is_absolute()


def display_path(path: str, absolute_paths: bool = False) -> str:
    """How a path is shown in the report: as given unless it is absolute and not allowed.

    An absolute path becomes ``…/<parent>/<name>`` (the last two components), so the report never
    reveals the directory layout of the machine that produced it.
    """
    if absolute_paths or not path or not is_absolute_path(path):
        return path
    parts = PureWindowsPath(path).parts if "\\" in path else PurePosixPath(path).parts
    tail = [p for p in parts[1:] if p not in ("/", "\\")][-2:]
    return "…/" + "/".join(tail) if tail else "…"


def redact_text(text: str, absolute_paths: bool = False) -> str:
    """Replace absolute paths inside free text (tracebacks, messages) by their short form."""
    if absolute_paths or not text:
        return text
    return _ABS_PATH_RE.sub(lambda m: display_path(m.group(0)), text)


def script_json(obj: Any) -> str:
    """JSON for a ``<script type="application/json">`` block that cannot end the block early.

    ``<``, ``>`` and ``&`` become ``\\u003c`` etc., so ``</script>`` and ``<!--`` cannot appear;
    U+2028/2029 are escaped too. Non-finite floats must already be None (raises otherwise).
    """
    text = json.dumps(obj, ensure_ascii=False, allow_nan=False, separators=(",", ":"))
    return (
        text.replace("<", "\\u003c")
        .replace(">", "\\u003e")
        .replace("&", "\\u0026")
        .replace("\u2028", "\\u2028")
        .replace("\u2029", "\\u2029")
    )


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
    """``summary["shared_errors"]`` as display rows: one per check, and one per camera for
    checks given per camera id (calibration). Known checks first."""
    se = summary.get("shared_errors")
    if not isinstance(se, Mapping):
        return []
    keys = [k for k in SHARED_ERROR_TITLES if k in se] + sorted(
        k for k in se if k not in SHARED_ERROR_TITLES
    )
    rows = []
    for key in keys:
        entry = se[key]
        if not isinstance(entry, Mapping):
            continue
        title = SHARED_ERROR_TITLES.get(key, str(key))
        if "status" in entry:
            rows.append(_shared_error_entry(title, entry))
            continue
        for cam, sub in entry.items():  # per camera id
            if isinstance(sub, Mapping) and "status" in sub:
                rows.append(_shared_error_entry(f"{title} (camera {cam})", sub))
    return rows


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
    return [(label, _fmt(raw.get(k), f), _fmt(enh.get(k), f)) for k, label, f in spec]


def _fmt(value: Any, spec: str = ".2f") -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return "-" if value in (None, "") else str(value)
    return format(value, spec) if math.isfinite(value) else "-"


def _flatten(d: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out += _flatten(v, key + ".")
        else:
            out.append((key, v))
    return out


def _settings_rows(settings: Mapping[str, Any], absolute_paths: bool) -> list[tuple[str, str]]:
    rows = []
    for k, v in _flatten(settings):
        if isinstance(v, str):
            v = display_path(v, absolute_paths)
        elif v is None:
            v = "-"
        rows.append((k, str(v)))
    return rows


def _title(summary: Mapping[str, Any], absolute_paths: bool) -> str:
    traj = str(summary.get("settings", {}).get("input", {}).get("trajectory") or "")
    if not traj:
        return ""
    return (
        display_path(traj, absolute_paths)
        if absolute_paths
        else traj.replace("\\", "/").split("/")[-1]
    )


def page_context(
    records: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
    assets: Mapping[str, Mapping[str, str]],
    plots: Sequence[Mapping[str, str]],
    absolute_paths: bool = False,
) -> dict[str, Any]:
    """Everything the template shows (plain data; the template autoescapes it)."""
    n = len(records)
    counts = summary.get("counts", {})
    stats = summary.get("statistics", {})
    err = stats.get("corner_error_px", {})
    gate = summary.get("gate", {})
    from pgt_check.report.paths import disagreement, path_comparison

    columns = table_columns(records)
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
    extra = {}
    for r in records:
        detail = str(r.get("error_detail") or "")
        if detail:
            detail = redact_text(detail, absolute_paths)
            if len(detail) > MAX_DETAIL_CHARS:
                detail = "…" + detail[-MAX_DETAIL_CHARS:]
            extra[str(r["frame_id"])] = {"error_detail": detail}
    inspect = [str(f) for f in select_detail_frames(records)]
    data = {
        "columns": columns,
        "rows": rows,
        "assets": {str(k): dict(v) for k, v in assets.items()},
        "extra": extra,
        "inspect": inspect,
        "kinds": list(ASSET_KINDS),
        "kind_labels": KIND_LABELS,
        "page_size": PAGE_SIZE,
    }
    auc = stats.get("auc") or {}
    timing = [
        (
            k,
            f"{_fmt(v.get('median_s'), '.3f')} / {_fmt(v.get('p90_s'), '.3f')} / "
            f"{_fmt(v.get('total_s'), '.1f')}",
        )
        for k, v in (summary.get("timing") or {}).items()
        if isinstance(v, Mapping)
    ]
    run_info = []
    for key, label, spec in (
        ("trajectory_format", "trajectory format", None),
        ("shading", "shading", None),
        ("setup_s", "setup [s]", ".2f"),
        ("wall_time_s", "wall time [s]", ".1f"),
        ("fingerprint", "measurement fingerprint", None),
        ("version", "pgt-check version", None),
    ):
        if summary.get(key) is not None:
            v = summary[key]
            run_info.append((label, _fmt(v, spec) if spec else str(v)))
    offset = stats.get("systematic_offset") or {}
    comparison = summary.get("raw_vs_enhanced")
    if not isinstance(comparison, Mapping):
        comparison = path_comparison(records)
    show_comparison = has_enhanced_path(records)
    return {
        "comparison": comparison_rows(comparison) if show_comparison else [],
        "n_disagree": int(comparison.get("frames_disagree") or 0) if show_comparison else 0,
        "shared_errors": shared_error_rows(summary),
        "title": _title(summary, absolute_paths),
        "gate_passed": bool(gate.get("passed")),
        "gate_explanation": str(gate.get("explanation", "")),
        "n_frames": n,
        "verdicts": [
            {
                "name": v,
                "count": counts.get(v, 0),
                "fraction": f"{counts.get(v, 0) / n:.1%}" if n else "-",
            }
            for v in ("PASS", "FAIL", "UNVERIFIABLE")
        ],
        "threshold": _fmt(summary.get("threshold_px"), ".1f"),
        "err_stats": " / ".join(_fmt(err.get(k)) for k in ("median", "p90", "max")) + " px",
        "auc": ", ".join(f"{k}: {_fmt(v, '.3f')}" for k, v in auc.items())
        if isinstance(auc, Mapping)
        else "",
        "unverifiable_reasons": sorted(
            (stats.get("unverifiable_reasons") or {}).items(), key=lambda kv: -kv[1]
        ),
        "input_warnings": [
            redact_text(str(w), absolute_paths) for w in (summary.get("warnings") or [])
        ],
        "offset_message": str(offset.get("message", "")),
        "offset_systematic": bool(offset.get("systematic")),
        "run_info": run_info,
        "plots": list(plots),
        "n_detail": len(inspect),
        "n_with_assets": sum(1 for f in inspect if f in data["assets"]),
        "columns": columns,
        "settings": _settings_rows(summary.get("settings") or {}, absolute_paths),
        "timing": timing,
        "versions": sorted((str(k), str(v)) for k, v in (summary.get("versions") or {}).items()),
        "data_json": script_json(data),
    }


def _environment():
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("pgt_check.report", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def _static(name: str) -> str:
    return resources.files("pgt_check.report").joinpath("static", name).read_text(encoding="utf-8")


def render_html(context: Mapping[str, Any]) -> str:
    template = _environment().get_template("report.html.j2")
    return template.render(**context, css=_static("report.css"), js=_static("report.js"))


def build_report(
    out_dir: str | Path,
    records: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
    assets: Mapping[str, Mapping[str, str]] | None = None,
    absolute_paths: bool = False,
) -> Path:
    """Write ``report.html`` (+ plots as PNG in ``assets/``) and ``junit.xml`` into ``out_dir``.

    records: judged records (``verdict``, ``reason``, ``threshold_px`` set); summary: as written
    to summary.json; assets: ``{frame_id: {kind: relative path}}`` from ``write_frame_assets``
    (stored as ``assets/index.json``), or None to use the index already in ``out_dir`` (as
    ``pgt-check report`` does). Only assets whose files exist are referenced. Absolute paths of
    this machine are shortened unless ``absolute_paths``. Returns the path of report.html.
    """
    from pgt_check.report.files import atomic_write_text
    from pgt_check.report.junit import junit_xml_text
    from pgt_check.report.plots import write_plots

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if assets is None:
        assets = load_assets_index(out_dir)
    else:
        assets = existing_assets(out_dir, {str(k): v for k, v in assets.items()})
        write_assets_index(out_dir, assets)
    known = {str(r["frame_id"]) for r in records}
    assets = {k: v for k, v in assets.items() if k in known}
    plots = write_plots(records, summary, out_dir)
    context = page_context(records, summary, assets, plots, absolute_paths)
    # the measurement store exists in real runs (written by the runner, not by the writers)
    context["has_records"] = (out_dir / "records.jsonl").is_file()
    html = render_html(context)
    path = out_dir / REPORT_NAME
    atomic_write_text(path, html)
    atomic_write_text(
        out_dir / JUNIT_NAME,
        junit_xml_text(records, summary, lambda p: display_path(p, absolute_paths)),
    )
    logger.info(
        "wrote %s and %s (%d frames, %d with images)", path, JUNIT_NAME, len(records), len(assets)
    )
    return path
