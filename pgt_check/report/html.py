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

#: frame-table columns: (key, label, type, digits). type: num | int | str | verdict | bool
BASE_COLUMNS: tuple[tuple[str, str, str, int | None], ...] = (
    ("frame_id", "frame", "str", None),
    ("timestamp", "time", "num", None),
    ("image_path", "image", "str", None),
    ("verdict", "verdict", "verdict", None),
    ("reason", "reason", "str", None),
    ("corner_error_px", "corner err [px]", "num", 2),
    ("threshold_px", "thr [px]", "num", 1),
    ("n_matches", "matches", "int", None),
    ("n_inliers", "inliers", "int", None),
    ("inlier_ratio", "inl. ratio", "num", 3),
    ("coverage", "coverage", "num", 3),
    ("shift_dx_px", "dx [px]", "num", 1),
    ("shift_dy_px", "dy [px]", "num", 1),
    ("zoom", "zoom", "num", 4),
    ("time_s", "time [s]", "num", 2),
)
#: shown only when some record has the key (the enhanced path)
ENHANCED_COLUMNS: tuple[tuple[str, str, str, int | None], ...] = (
    ("enhanced", "enhanced", "bool", None),
    ("corner_error_px_raw", "err raw [px]", "num", 2),
    ("corner_error_px_enhanced", "err enh. [px]", "num", 2),
    ("n_inliers_raw", "inl. raw", "int", None),
    ("n_inliers_enhanced", "inl. enh.", "int", None),
    ("inlier_ratio_raw", "ratio raw", "num", 3),
    ("inlier_ratio_enhanced", "ratio enh.", "num", 3),
    ("enhanced_why", "enhanced why", "str", None),
    ("reference_id", "reference", "str", None),
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
    "blend": "50 % blend render/photo",
    "checker": "checkerboard render/photo",
    "matches": "matches (green inliers, red outliers)",
}

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


def table_columns(records: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    cols = [*BASE_COLUMNS]
    present = set().union(*(r.keys() for r in records)) if records else set()
    cols += [c for c in ENHANCED_COLUMNS if c[0] in present]
    cols += [c for c in CORRECTION_TABLE_COLUMNS if c[0] in present]
    return [{"key": k, "label": lbl, "type": t, "digits": d} for k, lbl, t, d in cols]


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
    columns = table_columns(records)
    rows = []
    for r in records:
        row = []
        for c in columns:
            v = r.get(c["key"])
            if c["key"] == "image_path":
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
    return {
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
    html = render_html(page_context(records, summary, assets, plots, absolute_paths))
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
