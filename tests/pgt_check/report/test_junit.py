from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest
from report_testdata import HOSTILE_NAME, XSD, judged, synthetic_measurements, validate

from pgt_check.report.junit import junit_xml_text, xml_text
from pgt_check.report.outputs import build_summary


def test_xsd_is_used_when_xmlschema_is_installed():
    xmlschema = pytest.importorskip("xmlschema")
    schema = xmlschema.XMLSchema(str(XSD))
    bad = '<testsuites><testsuite name="x" tests="1"><testcase name="a"/></testsuite></testsuites>'
    assert not schema.is_valid(bad)


def test_junit_one_case_per_frame_and_valid(config):
    records = judged(synthetic_measurements(60), config)
    summary = build_summary(records, config)
    text = junit_xml_text(records, summary)
    validate(text)
    root = ET.fromstring(text)
    suite = root.find("testsuite")
    cases = [c for c in suite.findall("testcase") if c.get("classname") == "pgt-check.frames"]
    assert [c.get("name") for c in cases] == [r["frame_id"] for r in records]
    counts = summary["counts"]
    gate_failed = not summary["gate"]["passed"]
    assert int(suite.get("tests")) == len(records) + 1  # the frames and the gate
    assert (int(suite.get("failures")) == counts["FAIL"] + gate_failed
            == len(suite.findall("testcase/failure")))
    assert (
        int(suite.get("skipped"))
        == counts["UNVERIFIABLE"]
        == len(suite.findall("testcase/skipped"))
    )
    by_name = {c.get("name"): c for c in cases}
    for r in records:
        case = by_name[r["frame_id"]]
        if r["verdict"] == "FAIL":
            assert case.find("failure").get("message") == r["reason"]
        elif r["verdict"] == "UNVERIFIABLE":
            assert r["reason"] in case.find("skipped").get("message")
        else:
            assert case.find("failure") is None and case.find("skipped") is None
    assert HOSTILE_NAME in by_name  # escaped by the XML writer, read back verbatim


def test_junit_display_path_hides_absolute_paths(config):
    from pgt_check.report.html import display_path

    records = judged(synthetic_measurements(10), config)
    text = junit_xml_text(records, build_summary(records, config), display_path)
    assert "/home/alice" not in text
    assert "frame-000004.color.jpg" in text


def test_xml_text_removes_control_characters():
    assert xml_text("a\x00b\x1bc\td") == "a\ufffdb\ufffdc\td"
    text = junit_xml_text(
        [{"frame_id": "f\x01", "verdict": "PASS", "reason": ""}],
        {"counts": {"PASS": 1}, "gate": {"passed": True}},
    )
    validate(text)


def test_empty_run_is_valid():
    text = junit_xml_text([], {"counts": {}, "gate": {"passed": False, "explanation": "no frames"}})
    validate(text)


@pytest.mark.parametrize("passed", [True, False])
def test_the_gate_is_a_testcase_so_junit_alone_is_red_when_the_gate_fails(passed):
    """A gate that fails for a run-level reason with no FAIL frame (inputs changed, too many
    UNVERIFIABLE, --require-accuracy) still shows as a failure in junit.xml."""
    summary = {"counts": {"PASS": 2},
               "gate": {"passed": passed, "explanation": "inputs changed: mesh.glb"}}
    text = junit_xml_text([{"frame_id": "a", "verdict": "PASS", "reason": ""},
                           {"frame_id": "b", "verdict": "PASS", "reason": ""}], summary)
    validate(text)
    suite = ET.fromstring(text).find("testsuite")
    gate = [c for c in suite.findall("testcase") if c.get("name") == "gate"]
    assert len(gate) == 1 and gate[0].get("classname") == "pgt-check.run"
    assert int(suite.get("tests")) == 3
    if passed:
        assert gate[0].find("failure") is None and suite.get("failures") == "0"
    else:
        assert "inputs changed: mesh.glb" in gate[0].find("failure").get("message")
        assert suite.get("failures") == "1"
