"""junit.xml: one testcase per frame (FAIL = failure, UNVERIFIABLE = skipped with its reason),
then one testcase ``gate`` (classname ``<suite>.run``) that fails when the CI gate failed, so a
CI that reads only junit.xml is red whenever the exit code is 1, also for run-level reasons
(inputs changed, too many UNVERIFIABLE frames, ``--require-accuracy``) with no FAIL frame.

Follows the common Jenkins / Surefire JUnit layout (testsuites > testsuite > properties,
testcase > failure | skipped, system-out), which CI systems (GitLab, GitHub actions, Jenkins,
Azure) display natively.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from typing import Any

#: characters XML 1.0 cannot carry, even escaped
_XML_INVALID = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")


def xml_text(value: Any) -> str:
    """Text safe for an XML attribute or element (control characters replaced by U+FFFD)."""
    return _XML_INVALID.sub("\ufffd", "" if value is None else str(value))


def _fmt(value: Any, spec: str = ".2f") -> str:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return "-" if value in (None, "") else str(value)
    if not math.isfinite(value):
        return "-"
    return format(value, spec)


def _seconds(value: Any) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return f"{max(float(value), 0.0):.3f}"
    return "0.000"


def _frame_text(rec: Mapping[str, Any], path: str) -> str:
    """The frame's line: the error, inliers and matches are those of the path its verdict
    rests on (``decided_by``), named where known."""
    by = f" ({rec['decided_by']} path)" if rec.get("decided_by") else ""
    return (
        f"frame {rec.get('frame_id')} ({path}): corner error "
        f"{_fmt(rec.get('corner_error_px'))} px{by}, threshold {_fmt(rec.get('threshold_px'))} px, "
        f"{_fmt(rec.get('n_inliers'), 'd')} inliers of {_fmt(rec.get('n_matches'), 'd')} matches, "
        f"coverage {_fmt(rec.get('coverage'), '.3f')}"
    ) + _correction_text(rec)


def _correction_text(rec: Mapping[str, Any]) -> str:
    """'; correction 3.50 ± 0.01 deg, 0.2480 ± 0.0010 units (applied)' when one was made."""
    if rec.get("corr_drot_deg") is None:
        return ""
    state = "applied" if rec.get("corr_applied") else f"not applied: {rec.get('corr_reason')}"
    return (
        f"; correction {_fmt(rec.get('corr_drot_deg'), '.3f')} ± "
        f"{_fmt(rec.get('corr_sigma_rot_deg'), '.3f')} deg, {_fmt(rec.get('corr_dt'), '.4f')} ± "
        f"{_fmt(rec.get('corr_sigma_t'), '.4f')} units, corner error after "
        f"{_fmt(rec.get('corr_corner_error_px'))} px ({state})"
    )


def junit_xml_text(
    records: Sequence[Mapping[str, Any]],
    summary: Mapping[str, Any],
    display_path: Callable[[str], str] = str,
    suite_name: str = "pgt-check",
) -> str:
    """The junit.xml document for judged records (``verdict``, ``reason`` per record).

    ``display_path`` maps a record's image_path to what is shown (e.g. without absolute paths).
    """
    n = len(records)
    gate = summary.get("gate", {}) if isinstance(summary.get("gate"), Mapping) else {}
    gate_failed = not gate.get("passed")
    counts = _suite_counts(records, gate_failed)
    root = ET.Element("testsuites", {"name": suite_name, **counts})
    suite = ET.SubElement(root, "testsuite", {"name": suite_name, **counts})
    _add_properties(suite, summary, gate)
    classname = f"{suite_name}.frames"
    for rec in records:
        _add_testcase(suite, rec, classname, display_path)
    case = ET.SubElement(suite, "testcase", {"name": "gate", "classname": f"{suite_name}.run",
                                             "time": "0.000"})
    if gate_failed:
        el = ET.SubElement(case, "failure", {
            "message": xml_text(f"gate FAILED: {gate.get('explanation', '') or 'no gate'}"),
            "type": "GATE"})
        el.text = xml_text(gate.get("explanation", ""))
    so = ET.SubElement(suite, "system-out")
    c = summary.get("counts", {})
    so.text = xml_text(
        f"{n} frames: {c.get('PASS', 0)} PASS, {c.get('FAIL', 0)} FAIL, "
        f"{c.get('UNVERIFIABLE', 0)} UNVERIFIABLE; gate "
        f"{'PASSED' if gate.get('passed') else 'FAILED'}: {gate.get('explanation', '')}"
    )
    ET.indent(root, space=" ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _suite_counts(records: Sequence[Mapping[str, Any]], gate_failed: bool) -> dict[str, str]:
    """The tests / failures / errors / skipped / time attributes of the suite, as text (the
    frames and the gate's testcase)."""
    n_fail = sum(1 for r in records if r.get("verdict") == "FAIL") + int(gate_failed)
    n_skip = sum(1 for r in records if r.get("verdict") == "UNVERIFIABLE")
    total_time = sum(
        float(r["time_s"])
        for r in records
        if isinstance(r.get("time_s"), (int, float)) and math.isfinite(r["time_s"])
    )
    return {
        "tests": str(len(records) + 1),
        "failures": str(n_fail),
        "errors": "0",
        "skipped": str(n_skip),
        "time": _seconds(total_time),
    }


def _add_properties(suite: ET.Element, summary: Mapping[str, Any], gate: Mapping[str, Any]) -> None:
    """Add the suite's <properties> (version, threshold, gate, fingerprint); returns None."""
    props = ET.SubElement(suite, "properties")
    for name, value in (
        ("pgt-check.version", summary.get("version")),
        ("threshold_px", summary.get("threshold_px")),
        ("gate.passed", gate.get("passed")),
        ("gate.explanation", gate.get("explanation")),
        ("fingerprint", summary.get("fingerprint")),
    ):
        if value is not None:
            ET.SubElement(props, "property", {"name": name, "value": xml_text(value)})


def _add_testcase(
    suite: ET.Element,
    rec: Mapping[str, Any],
    classname: str,
    display_path: Callable[[str], str],
) -> None:
    """Add one record's <testcase> (with its failure or skipped element); returns None."""
    path = display_path(str(rec.get("image_path") or ""))
    case = ET.SubElement(
        suite,
        "testcase",
        {
            "name": xml_text(rec.get("frame_id")),
            "classname": classname,
            "time": _seconds(rec.get("time_s")),
        },
    )
    # the correction is in the failure / system-out text (the Surefire schema that CI
    # servers validate against has no per-testcase properties)
    verdict = rec.get("verdict")
    if verdict == "FAIL":
        el = ET.SubElement(
            case, "failure", {"message": xml_text(rec.get("reason") or "FAIL"), "type": "FAIL"}
        )
        el.text = xml_text(_frame_text(rec, path))
    elif verdict == "UNVERIFIABLE":
        ET.SubElement(
            case,
            "skipped",
            {"message": xml_text(f"UNVERIFIABLE: {rec.get('reason') or 'unknown'}")},
        )
    out = ET.SubElement(case, "system-out")
    out.text = xml_text(_frame_text(rec, path))
