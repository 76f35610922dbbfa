"""report.html (+ plots under assets/) and junit.xml from judged records: stage 3 only reads.

``build_report`` is the entry point. The page is one self-contained file (inline CSS and JS from
this package, no network assets) that opens from disk. The frame table travels as JSON in a
``<script type="application/json">`` block and is rendered by a small vanilla-JS table with
pagination; detail panels are built on demand. All user data (frame ids, file names, reasons,
settings) is autoescaped by jinja2 or inserted with ``textContent`` by the script.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from pgt_check.output_layout import OUTPUTS
from pgt_check.report.assets import (
    ASSET_KINDS,
    existing_assets,
    load_assets_index,
    select_detail_frames,
    write_assets_index,
)
from pgt_check.report.tables import (  # re-exported: callers and tests import them here
    BASE_COLUMNS,
    ENHANCED_COLUMNS,
    OPTIONAL_COLUMNS,
    comparison_rows,
    fmt,
    has_enhanced_path,
    shared_error_rows,
    table_columns,
    table_rows,
    table_value,
)
from pgt_check.report.text import display_path, is_absolute_path, redact_text, script_json

logger = logging.getLogger(__name__)

__all__ = [
    "BASE_COLUMNS", "ENHANCED_COLUMNS", "OPTIONAL_COLUMNS",
    "build_report", "comparison_rows", "display_path", "has_enhanced_path", "is_absolute_path",
    "page_context", "redact_text", "render_html", "script_json", "shared_error_rows",
    "table_columns", "table_rows", "table_value",
]

PAGE_SIZE = 100
#: longest error_detail (e.g. a traceback) carried into the page, characters
MAX_DETAIL_CHARS = 1200

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


def _error_details(
    records: Sequence[Mapping[str, Any]], absolute_paths: bool
) -> dict[str, dict[str, str]]:
    """Per frame id, its ``error_detail`` (paths shortened, at most ``MAX_DETAIL_CHARS``)."""
    extra = {}
    for r in records:
        detail = str(r.get("error_detail") or "")
        if detail:
            detail = redact_text(detail, absolute_paths)
            if len(detail) > MAX_DETAIL_CHARS:
                detail = "…" + detail[-MAX_DETAIL_CHARS:]
            extra[str(r["frame_id"])] = {"error_detail": detail}
    return extra


def _timing_rows(summary: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(stage, "median / p90 / total" seconds) per timed stage."""
    return [
        (
            k,
            f"{fmt(v.get('median_s'), '.3f')} / {fmt(v.get('p90_s'), '.3f')} / "
            f"{fmt(v.get('total_s'), '.1f')}",
        )
        for k, v in (summary.get("timing") or {}).items()
        if isinstance(v, Mapping)
    ]


def _run_info_rows(summary: Mapping[str, Any]) -> list[tuple[str, str]]:
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
            run_info.append((label, fmt(v, spec) if spec else str(v)))
    return run_info


def page_context(
    records: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
    assets: Mapping[str, Mapping[str, str]],
    plots: Sequence[Mapping[str, str]],
    absolute_paths: bool = False,
) -> dict[str, Any]:
    """Everything the template shows (plain data; the template autoescapes it)."""
    n = len(records)
    stats = summary.get("statistics", {})
    err = stats.get("corner_error_px", {})
    columns = table_columns(records)
    inspect = [str(f) for f in select_detail_frames(records)]
    assets_data = {str(k): dict(v) for k, v in assets.items()}
    data = {
        "columns": columns,
        "rows": table_rows(records, columns, absolute_paths),
        "assets": assets_data,
        "extra": _error_details(records, absolute_paths),
        "inspect": inspect,
        "kinds": list(ASSET_KINDS),
        "kind_labels": KIND_LABELS,
        "page_size": PAGE_SIZE,
    }
    return {
        **_comparison_context(records, summary),
        "shared_errors": shared_error_rows(summary),
        **_accuracy_context(summary),
        **_separation_context(summary),
        **_verdict_context(summary, n, stats, err, absolute_paths),
        "run_info": _run_info_rows(summary),
        "plots": list(plots),
        "n_detail": len(inspect),
        "n_with_assets": sum(1 for f in inspect if f in assets_data),
        "columns": columns,
        "settings": _settings_rows(summary.get("settings") or {}, absolute_paths),
        "timing": _timing_rows(summary),
        "versions": sorted((str(k), str(v)) for k, v in (summary.get("versions") or {}).items()),
        "data_json": script_json(data),
    }


def _comparison_context(
    records: Sequence[Mapping[str, Any]], summary: Mapping[str, Any]
) -> dict[str, Any]:
    """The raw-vs-enhanced table, the enhancer's name and the count of frames the two paths
    disagree on (empty when no frame has an enhanced path)."""
    from pgt_check.report.paths import path_comparison

    comparison = summary.get("raw_vs_enhanced")
    if not isinstance(comparison, Mapping):
        comparison = path_comparison(records)
    show_comparison = has_enhanced_path(records)
    settings = summary.get("settings")
    enhance = settings.get("enhance") if isinstance(settings, Mapping) else None
    method = enhance.get("method") if isinstance(enhance, Mapping) else None
    return {
        "comparison": comparison_rows(comparison) if show_comparison else [],
        # which enhancer made the enhanced path (MaRINeR or reprojection), for the table head
        "enhance_method": str(method) if isinstance(method, str) else "",
        "n_disagree": int(comparison.get("frames_disagree") or 0) if show_comparison else 0,
    }


def _verdict_context(
    summary: Mapping[str, Any],
    n: int,
    stats: Mapping[str, Any],
    err: Mapping[str, Any],
    absolute_paths: bool,
) -> dict[str, Any]:
    """The title, the gate, the verdict counts and the run's statistics (``summary`` of ``n``
    frames; ``stats`` its statistics, ``err`` their corner error)."""
    counts = summary.get("counts", {})
    gate = summary.get("gate", {})
    auc = stats.get("auc") or {}
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
        "threshold": fmt(summary.get("threshold_px"), ".1f"),
        "err_stats": " / ".join(fmt(err.get(k)) for k in ("median", "p90", "max")) + " px",
        "auc": ", ".join(f"{k}: {fmt(v, '.3f')}" for k, v in auc.items())
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
    }


def _accuracy_context(summary: Mapping[str, Any]) -> dict[str, Any]:
    """The accuracy section: its sentences and a table of bounds, shared sizes and limits
    (``summary["accuracy"]``, ``pgt_check.verdict.accuracy``)."""
    acc = summary.get("accuracy")
    if not isinstance(acc, Mapping):
        return {"accuracy_sentences": [], "accuracy_rows": [], **_self_test_context({}, str)}

    def g(v: Any) -> str:
        return fmt(v, ".3g") if isinstance(v, (int, float)) else "-"

    def ci(v: Any, c: Any) -> str:
        if isinstance(c, (list, tuple)) and len(c) == 2:
            return f"{g(v)} ({g(c[0])}-{g(c[1])})"
        return g(v)

    rows = []
    r, t, p = (acc.get(k) or {} for k in ("rotation_bound_deg", "translation_bound",
                                          "effect_bound_px"))
    for label, key in (("per-frame bound, median", "p50"), ("per-frame bound, p90", "p90"),
                       ("per-frame bound, max", "max")):
        rows.append((label, g(r.get(key)), g(t.get(key)), g(p.get(key))))
    for e in acc.get("shared") or []:
        label = f"shared: {e.get('check')} ({e.get('status')})"
        rows.append((label, ci(e.get("rotation_deg"), e.get("rotation_deg_ci")),
                     ci(e.get("translation"), e.get("translation_ci")),
                     ci(e.get("effect_px"), e.get("effect_px_ci"))))
    lim = acc.get("limits") or {}
    rows.append(("detection limit: single frame", g(lim.get("frame_deg")),
                 g(lim.get("frame_units")), g(lim.get("frame_px"))))
    rows.append(("detection limit: shared by all frames", g(lim.get("shared_deg")),
                 g(lim.get("shared_units")), g(lim.get("shared_px"))))
    rows.append(("one frame's noise (median)", g(lim.get("noise_deg")),
                 g(lim.get("noise_units")), g(lim.get("noise_px"))))
    return {"accuracy_sentences": [str(x) for x in acc.get("sentences") or []],
            "accuracy_rows": rows, **_self_test_context(summary, g)}


def _separation_context(summary: Mapping[str, Any]) -> dict[str, Any]:
    """Each path's separating power on this run (``summary["path_separation"]``,
    ``pgt_check.verdict.separation``): one row per probed path."""
    sep = summary.get("path_separation")
    if not isinstance(sep, Mapping) or not sep.get("paths"):
        return {"separation_rows": [], "separation_how": "", "separation_barred": 0}

    def g(v: Any) -> str:
        return fmt(v, ".3g") if isinstance(v, (int, float)) else "-"

    rows = []
    for name, p in (sep.get("paths") or {}).items():
        status = {"passed": "separates", "failed": "CANNOT SEPARATE: decides no frame",
                  "not_tested": "not tested (too few frames)"}.get(str(p.get("status")),
                                                                   str(p.get("status")))
        rows.append((str(name), status, f"{p.get('n_higher')} / {p.get('n_frames')}",
                     g(p.get("p_value")), g(p.get("move_px")), g(p.get("median_given_px")),
                     g(p.get("median_moved_px"))))
    return {"separation_rows": rows, "separation_how": str(sep.get("how") or ""),
            "separation_barred": int(sep.get("frames_barred") or 0)}


def _self_test_context(summary: Mapping[str, Any], g: Any) -> dict[str, Any]:
    """The self-test's detection curves next to the stated limits (``summary["self_test"]``,
    ``pgt_check.verdict.self_test``): one row per limit, the share flagged per injected size."""
    st = summary.get("self_test")
    if not isinstance(st, Mapping):
        return {"self_test_sentence": "", "self_test_head": [], "self_test_rows": []}
    ks = [k for k in st.get("multiples") or [] if isinstance(k, (int, float))]
    rows = []
    for c in st.get("curves") or []:
        if not isinstance(c, Mapping):
            continue
        by_k = {p.get("k"): p for p in c.get("points") or [] if isinstance(p, Mapping)}

        def cell(k: float, by_k: Mapping = by_k) -> str:
            p = by_k.get(k)
            return "-" if not p or not p.get("n") else f"{p.get('flagged')}/{p.get('n')}"

        rows.append((
            f"{'single frame' if c.get('test') == 'single_frame' else 'shared'} {c.get('kind')}",
            f"{g(c.get('stated'))} {c.get('unit', '')} ({g(c.get('stated_px'))} px)",
            [cell(0.0), *[cell(k) for k in ks]], g(c.get("k50")), g(c.get("k95")),
            str(c.get("judgement", "")),
        ))
    return {"self_test_sentence": str(st.get("sentence") or ""),
            "self_test_head": ["0x", *[f"{k:g}x" for k in ks]], "self_test_rows": rows}


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
    """Write ``report.html`` (+ plots as SVG in ``assets/``) and ``junit.xml`` into ``out_dir``.

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
    context["has_records"] = (out_dir / OUTPUTS.records).is_file()
    html = render_html(context)
    path = out_dir / OUTPUTS.report_html
    atomic_write_text(path, html)
    atomic_write_text(
        out_dir / OUTPUTS.junit_xml,
        junit_xml_text(records, summary, lambda p: display_path(p, absolute_paths)),
    )
    logger.info(
        "wrote %s and %s (%d frames, %d with images)", path, OUTPUTS.junit_xml, len(records),
        len(assets),
    )
    return path
