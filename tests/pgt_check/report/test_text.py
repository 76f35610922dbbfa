"""Text made safe for the report page (``report/text.py``): absolute paths shortened, in paths
and inside free text, and JSON that cannot end its ``<script>`` block."""

from __future__ import annotations

import json

import pytest

from pgt_check.report.text import display_path, is_absolute_path, redact_text, script_json


@pytest.mark.parametrize(
    ("path", "absolute"),
    [
        ("/home/a/x.jpg", True),
        ("C:\\data\\x.jpg", True),
        ("\\\\server\\share\\x", True),
        ("images/x.jpg", False),
        ("x.jpg", False),
        ("", False),
    ],
)
def test_is_absolute_path(path, absolute):
    assert is_absolute_path(path) is absolute


def test_display_path_keeps_the_last_two_components_of_absolute_paths():
    assert display_path("/home/alice/scans/img/0001.jpg") == "…/img/0001.jpg"
    assert display_path("C:\\Users\\bob\\img\\0001.jpg") == "…/img/0001.jpg"
    assert display_path("/x.jpg") == "…/x.jpg"
    assert display_path("/") == "…"
    assert display_path("img/0001.jpg") == "img/0001.jpg"  # relative: as given
    assert display_path("/home/alice/x.jpg", absolute_paths=True) == "/home/alice/x.jpg"


def test_redact_text_shortens_paths_inside_free_text():
    tb = 'File "/home/alice/venv/lib/pgt_check/run.py", line 3\nOSError: /data/secret/a.png'
    out = redact_text(tb)
    assert "/home/alice" not in out and "/data/secret" not in out
    assert '"…/pgt_check/run.py"' in out and "OSError: …/secret/a.png" in out
    assert redact_text("ratio 3/4 and http://x.org/a") == "ratio 3/4 and http://x.org/a"
    assert redact_text(tb, absolute_paths=True) == tb
    assert redact_text("") == ""


def test_script_json_cannot_end_the_script_block():
    obj = {"a": "</script><!-- & \u2028\u2029", "n": [1, None]}
    text = script_json(obj)
    assert "<" not in text and ">" not in text and "&" not in text
    assert "\u2028" not in text and "\u2029" not in text
    assert json.loads(text) == obj  # still the same JSON
    with pytest.raises(ValueError):
        script_json({"x": float("nan")})
