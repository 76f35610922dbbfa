"""SVG charts: tick layout, scales, clipping of marks, escaping and well-formed documents."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pgt_check.report.svg_chart import Axis, Chart, hstack, nice_ticks, tick_label

NS = "{http://www.w3.org/2000/svg}"


def _parse(svg: str) -> ET.Element:
    return ET.fromstring(svg)


def _texts(root: ET.Element, cls: str) -> list[str]:
    return [t.text or "" for t in root.iter(f"{NS}text") if t.get("class") == cls]


@pytest.mark.parametrize(("lo", "hi", "integer"), [(0, 10, False), (-3.7, 12.2, False),
                                                   (0.013, 0.021, False), (0, 3, True),
                                                   (0, 2700, True), (1e-9, 1e-8, False)])
def test_linear_ticks_are_round_steps_inside_the_range(lo, hi, integer):
    ticks = nice_ticks(lo, hi, integer=integer)
    assert 3 <= len(ticks) <= 11
    assert all(lo - 1e-12 <= t <= hi + 1e-12 for t in ticks)
    steps = np.diff(ticks)
    assert np.allclose(steps, steps[0])
    mantissa = steps[0] / 10 ** math.floor(math.log10(steps[0]))
    assert any(math.isclose(mantissa, m) for m in (1, 2, 2.5, 5))
    if integer:
        assert all(float(t).is_integer() for t in ticks)


def test_log_ticks_are_decades_or_their_multiples():
    assert nice_ticks(1, 1000, log=True) == [1, 10, 100, 1000]
    few = nice_ticks(1.2, 16, log=True)
    assert few == [2, 5, 10]
    narrow = nice_ticks(3.1, 3.9, log=True)  # inside one decade: linear steps, still in range
    assert len(narrow) >= 2 and all(3.1 <= t <= 3.9 for t in narrow)
    with pytest.raises(ValueError, match="positive"):
        nice_ticks(-1, 10, log=True)
    assert nice_ticks(5, 5) == [] and nice_ticks(math.nan, 1) == []


def test_tick_labels_are_short():
    assert [tick_label(v) for v in (0, 0.25, 2.0, 1500, 2e6, 3e-5)] == [
        "0", "0.25", "2", "1500", "2e6", "3e-5"]


def test_marks_outside_fixed_limits_are_clipped_and_non_finite_left_out():
    c = Chart(500, 300, title="t", x=Axis("x"), y=Axis("y", lo=0.0, hi=1.0))
    c.points([0, 1, 2, np.nan, 3], [0.5, 5.0, np.inf, 0.2, 0.1], "#f00", label="pts")
    root = _parse(c.svg())
    assert len(list(root.iter(f"{NS}circle"))) == 3 + 1  # the inf / nan pairs, + legend sample
    group = next(g for g in root.iter(f"{NS}g") if g.get("clip-path"))
    clip_id = group.get("clip-path")[len("url(#"):-1]
    assert any(cp.get("id") == clip_id for cp in root.iter(f"{NS}clipPath"))
    assert _texts(root, "legend") == ["pts"]
    assert c.limits()[1] == (0.0, 1.0)


def test_log_axis_leaves_out_non_positive_values_and_spans_the_rest():
    c = Chart(500, 300, x=Axis(log=True), y=Axis())
    c.points([0.0, -1.0, 2.0, 200.0], [1, 2, 3, 4], "#000")
    (x0, x1), _ = c.limits()
    assert 0 < x0 < 2.0 and x1 > 200.0
    assert len(list(_parse(c.svg()).iter(f"{NS}circle"))) == 2
    assert {"10", "100"} <= set(_texts(_parse(c.svg()), "xtick"))


def test_equal_aspect_gives_both_axes_the_same_units_per_pixel():
    c = Chart(600, 300, x=Axis(), y=Axis(), equal_aspect=True)
    c.points([0, 1], [0, 10], "#000")
    (x0, x1), (y0, y1) = c.limits()
    pw, ph = c._plot_size()
    assert math.isclose((x1 - x0) / pw, (y1 - y0) / ph)
    assert x0 <= 0 and x1 >= 1 and y0 <= 0 and y1 >= 10


def test_text_is_escaped():
    c = Chart(500, 300, title="<script>alert(1)</script> & co", x=Axis('a"b'), y=Axis("<y>"))
    c.line([0, 1], [0, 1], "#000", label="</svg>")
    svg = c.svg()
    assert "<script>" not in svg and "</svg>" not in svg[:-8]
    root = _parse(svg)
    assert _texts(root, "title") == ["<script>alert(1)</script> & co"]
    assert _texts(root, "legend") == ["</svg>"]


def test_stacked_bars_and_bad_shapes():
    c = Chart(500, 300, x=Axis(), y=Axis(lo=0.0))
    edges = [0, 1, 2, 3]
    c.bars(edges, [1, 0, 2], "#0f0")
    c.bars(edges, [1, 1, 0], "#f00", base=[1, 0, 2])
    rects = [r for r in _parse(c.svg()).iter(f"{NS}rect") if r.get("fill") in ("#0f0", "#f00")]
    assert len(rects) == 4  # zero-height bars are not drawn
    assert c.limits() == ((0.0, 3.0), (0.0, pytest.approx(2.1)))
    with pytest.raises(ValueError, match="counts"):
        c.bars(edges, [1, 2], "#000")
    with pytest.raises(ValueError, match="differ"):
        c.line([0, 1], [0], "#000")
    with pytest.raises(ValueError, match="marker"):
        c.points([0], [0], "#000", marker="*")


def test_an_empty_chart_and_side_by_side_charts_are_valid_documents():
    empty = Chart(400, 250, title="nothing", note="no frame was measured")
    root = _parse(empty.svg())
    assert "no frame was measured" in [t.text for t in root.iter(f"{NS}text")]
    both = _parse(hstack([empty, Chart(300, 250)]))
    assert both.get("width") == "700"
    ids = [cp.get("id") for cp in both.iter(f"{NS}clipPath")]
    assert len(ids) == len(set(ids)) == 2
    with pytest.raises(ValueError, match="no room"):
        Chart(60, 60).svg()
