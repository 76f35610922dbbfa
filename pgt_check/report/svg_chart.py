"""Small SVG charts for the HTML report: axes on linear or log scales, lines, points, stacked
bars, bands, reference lines and a legend, written as text.

Why not matplotlib: importing it and drawing the report's figures cost about a second of CPU
per run, a fixed cost as large as checking a few frames (reports/pipeline_timing.md, "report
files"). These charts need no import, write in milliseconds and stay sharp at any zoom.

A ``Chart`` collects marks in data coordinates; ``Chart.svg()`` fixes the limits from them
(or from ``Axis.lo`` / ``Axis.hi``), lays out ticks and returns one ``<svg>`` document;
``hstack`` puts several charts side by side in one document.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape

import numpy as np

FONT_PX = 11
CHAR_WIDTH = 0.6  # mean glyph width / font size: text is laid out without measuring it
MARGIN = {"left": 58, "right": 12, "top": 26, "bottom": 40}
LEGEND_GAP = 10


@dataclass
class Axis:
    """One axis: its label, scale and optional fixed limits (data units)."""

    label: str = ""
    log: bool = False
    integer: bool = False  # ticks at whole numbers only (counts, frame indices)
    lo: float | None = None
    hi: float | None = None


@dataclass
class _Mark:
    kind: str  # line, points, bars, band, hline, vline
    xy: tuple[np.ndarray, ...]
    colour: str
    label: str | None = None
    width: float = 1.0
    dash: str | None = None
    marker: str = "o"
    size: float = 2.5
    opacity: float = 1.0


@dataclass
class Chart:
    """A chart of ``width`` x ``height`` px (the legend, if any, is inside that width)."""

    width: int
    height: int
    title: str = ""
    x: Axis = field(default_factory=Axis)
    y: Axis = field(default_factory=Axis)
    equal_aspect: bool = False
    note: str | None = None  # centred text, e.g. "no frame was measured"
    marks: list[_Mark] = field(default_factory=list)

    # -- marks (data coordinates; non-finite points, and non-positive ones on a log axis, are
    # left out) ---------------------------------------------------------------------------
    def line(self, x, y, colour: str, *, label: str | None = None, width: float = 1.0,
             dash: str | None = None, marker: str | None = None, size: float = 2.0) -> None:
        self.marks.append(_Mark("line", _xy(x, y), colour, label, width, dash,
                                marker or "", size))

    def points(self, x, y, colour: str, *, label: str | None = None, marker: str = "o",
               size: float = 2.5) -> None:
        if marker not in ("o", "x"):
            raise ValueError(f"marker must be 'o' or 'x', got {marker!r}")
        self.marks.append(_Mark("points", _xy(x, y), colour, label, marker=marker, size=size))

    def bars(self, edges, counts, colour: str, *, base=None, label: str | None = None) -> None:
        """Bars between consecutive ``edges`` (K + 1,) of heights ``counts`` (K,), stacked on
        ``base`` (K,) when given."""
        edges = np.asarray(edges, dtype=np.float64)
        counts = np.asarray(counts, dtype=np.float64)
        if edges.ndim != 1 or counts.shape != (len(edges) - 1,):
            raise ValueError(f"bars: {len(edges)} edges need {len(edges) - 1} counts, "
                             f"got shape {counts.shape}")
        base = np.zeros_like(counts) if base is None else np.asarray(base, dtype=np.float64)
        self.marks.append(_Mark("bars", (edges, base, base + counts), colour, label))

    def band(self, x, lo, hi, colour: str, *, label: str | None = None,
             opacity: float = 0.5) -> None:
        x, lo, hi = (np.asarray(a, dtype=np.float64) for a in (x, lo, hi))
        if not (x.shape == lo.shape == hi.shape) or x.ndim != 1:
            raise ValueError("band: x, lo and hi must be 1-D of one length")
        self.marks.append(_Mark("band", (x, lo, hi), colour, label, opacity=opacity))

    def hline(self, y: float, colour: str = "#000", *, label: str | None = None,
              dash: str | None = "5,3", width: float = 1.0) -> None:
        self.marks.append(_Mark("hline", (np.array([y], dtype=np.float64),), colour, label,
                                width, dash))

    def vline(self, x: float, colour: str = "#000", *, label: str | None = None,
              dash: str | None = "5,3", width: float = 1.0) -> None:
        self.marks.append(_Mark("vline", (np.array([x], dtype=np.float64),), colour, label,
                                width, dash))

    # -- layout ---------------------------------------------------------------------------
    def limits(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """((x lo, x hi), (y lo, y hi)) in data units, from the marks and the fixed limits."""
        xs, ys = [], []
        for m in self.marks:
            if m.kind in ("line", "points"):
                xs.append(m.xy[0])
                ys.append(m.xy[1])
            elif m.kind in ("bars", "band"):  # (x or edges, lower, upper)
                xs.append(m.xy[0])
                ys += [m.xy[1], m.xy[2]]
            elif m.kind == "hline":
                ys.append(m.xy[0])
            else:
                xs.append(m.xy[0])
        xl = _range(xs, self.x, pad=not any(m.kind == "bars" for m in self.marks))
        yl = _range(ys, self.y, pad=True)
        if self.equal_aspect:
            xl, yl = _equal_aspect(xl, yl, self._plot_size())
        return xl, yl

    def _legend(self) -> list[_Mark]:
        return [m for m in self.marks if m.label]

    def _legend_width(self) -> int:
        labels = [m.label for m in self._legend()]
        if not labels:
            return 0
        return int(28 + CHAR_WIDTH * (FONT_PX - 1) * max(len(s) for s in labels)) + LEGEND_GAP

    def _plot_size(self) -> tuple[float, float]:
        w = self.width - MARGIN["left"] - MARGIN["right"] - self._legend_width()
        h = self.height - MARGIN["top"] - MARGIN["bottom"]
        if w < 40 or h < 40:
            raise ValueError(f"chart {self.width} x {self.height} px leaves no room to plot")
        return float(w), float(h)

    def body(self, clip_id: str) -> str:
        """The chart's SVG elements (no ``<svg>`` wrapper), clipped with ``clip_id``."""
        (x0, x1), (y0, y1) = self.limits()
        pw, ph = self._plot_size()
        left, top = MARGIN["left"], MARGIN["top"]
        sx = _scale(x0, x1, self.x.log, left, left + pw)
        sy = _scale(y0, y1, self.y.log, top + ph, top)
        out = [f'<clipPath id="{clip_id}"><rect x="{left}" y="{top}" width="{pw:.0f}" '
               f'height="{ph:.0f}"/></clipPath>',
               f'<rect x="{left}" y="{top}" width="{pw:.0f}" height="{ph:.0f}" fill="#fff" '
               'stroke="#444" stroke-width="0.8"/>']
        out += _ticks(x0, x1, self.x, sx, "x", top, top + ph)
        out += _ticks(y0, y1, self.y, sy, "y", left, left + pw)
        out.append(f'<g clip-path="url(#{clip_id})">')
        out += [_draw(m, sx, sy, (left, left + pw, top, top + ph)) for m in self.marks]
        out.append("</g>")
        cx, cy = left + pw / 2, top + ph / 2
        if self.note:
            out.append(_text(cx, cy, self.note, anchor="middle"))
        out.append(_text(left + pw / 2, 16, self.title, anchor="middle", size=FONT_PX + 1,
                         cls="title"))
        out.append(_text(cx, self.height - 6, self.x.label, anchor="middle", cls="xlabel"))
        out.append(f'<text class="ylabel" transform="translate(13,{cy:.1f}) rotate(-90)" '
                   f'text-anchor="middle" font-size="{FONT_PX}">{escape(self.y.label)}</text>')
        out += _legend_items(self._legend(), left + pw + LEGEND_GAP, top + 4)
        return "\n".join(s for s in out if s)

    def svg(self) -> str:
        """This chart as one SVG document."""
        return hstack([self])


def hstack(charts: Sequence[Chart]) -> str:
    """Charts side by side in one SVG document (each keeps its own size)."""
    if not charts:
        raise ValueError("hstack needs at least one chart")
    width, height = sum(c.width for c in charts), max(c.height for c in charts)
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'viewBox="0 0 {width} {height}" font-family="DejaVu Sans, Arial, sans-serif">',
             f'<rect width="{width}" height="{height}" fill="#fff"/>']
    dx = 0
    for i, c in enumerate(charts):
        parts.append(f'<g transform="translate({dx},0)">{c.body(f"plot-area-{i}")}</g>')
        dx += c.width
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


# -- helpers -------------------------------------------------------------------------------
def _xy(x, y) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    y = np.asarray(y, dtype=np.float64).reshape(-1)
    if x.shape != y.shape:
        raise ValueError(f"x and y differ in length: {len(x)} vs {len(y)}")
    return x, y


def _usable(v: np.ndarray, log: bool) -> np.ndarray:
    ok = np.isfinite(v)
    return ok & (v > 0) if log else ok


def _range(values: list[np.ndarray], axis: Axis, pad: bool) -> tuple[float, float]:
    v = np.concatenate([a.reshape(-1) for a in values]) if values else np.zeros(0)
    v = v[_usable(v, axis.log)]
    f = np.log10 if axis.log else (lambda a: a)
    if len(v):
        lo, hi = float(f(v.min())), float(f(v.max()))
    else:
        lo, hi = (0.0, 1.0)
    if hi - lo <= 1e-12 * max(1.0, abs(hi)):
        lo, hi = lo - (0.5 if axis.log else max(1.0, abs(lo) * 0.1)), hi + (
            0.5 if axis.log else max(1.0, abs(hi) * 0.1))
    elif pad:
        d = 0.05 * (hi - lo)
        lo, hi = lo - d, hi + d
    inv = (lambda a: 10.0 ** a) if axis.log else (lambda a: a)
    lo, hi = inv(lo), inv(hi)
    if axis.lo is not None and (not axis.log or axis.lo > 0):
        lo = float(axis.lo)
    if axis.hi is not None:
        hi = float(axis.hi)
    if not hi > lo:
        hi = lo * 10 if axis.log else lo + 1.0
    return lo, hi


def _equal_aspect(xl, yl, size) -> tuple[tuple[float, float], tuple[float, float]]:
    """Widen the range of the axis with more units per pixel so both have the same."""
    (x0, x1), (y0, y1), (pw, ph) = xl, yl, size
    upp = max((x1 - x0) / pw, (y1 - y0) / ph)
    xc, yc = (x0 + x1) / 2, (y0 + y1) / 2
    return (xc - upp * pw / 2, xc + upp * pw / 2), (yc - upp * ph / 2, yc + upp * ph / 2)


def _scale(lo: float, hi: float, log: bool, p0: float, p1: float):
    if log:
        lo, hi = math.log10(lo), math.log10(hi)

    def to_px(v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((np.log10(v) if log else v) - lo) / (hi - lo)
        return p0 + t * (p1 - p0)

    return to_px


def nice_ticks(lo: float, hi: float, log: bool = False, integer: bool = False,
               target: int = 5) -> list[float]:
    """Tick values within [lo, hi]: 1 / 2 / 2.5 / 5 x 10^k steps (whole numbers when
    ``integer``); on a log axis decades, with 2 and 5 between when few decades are shown."""
    if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
        return []
    if log:
        if lo <= 0:
            raise ValueError(f"log axis limits must be positive, got {lo}")
        k0, k1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
        for mults in ((1,), (1, 2, 5), (1, 2, 3, 4, 5, 6, 7, 8, 9)):
            ticks = [m * 10.0 ** k for k in range(k0, k1 + 1) for m in mults]
            ticks = [t for t in ticks if lo * (1 - 1e-9) <= t <= hi * (1 + 1e-9)]
            if len(ticks) >= 3:
                return ticks
        return nice_ticks(lo, hi, integer=integer)
    raw = (hi - lo) / target
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw * (1 - 1e-9))
    if integer:
        step = float(max(1, math.ceil(step)))
    k0, k1 = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
    return [round(k * step, 12) for k in range(k0, k1 + 1)]


def tick_label(v: float) -> str:
    if v == 0:
        return "0"
    if abs(v) >= 1e5 or abs(v) < 1e-3:
        return f"{v:.0e}".replace("e+0", "e").replace("e-0", "e-")
    return f"{v:.4g}"


def _ticks(lo, hi, axis: Axis, to_px, which: str, a0: float, a1: float) -> list[str]:
    out = []
    for t in nice_ticks(lo, hi, axis.log, axis.integer):
        p = float(to_px(t))
        if which == "x":
            out.append(f'<line x1="{p:.1f}" y1="{a1}" x2="{p:.1f}" y2="{a1 + 4}" stroke="#444"/>')
            out.append(_text(p, a1 + 15, tick_label(t), anchor="middle", cls="xtick"))
        else:
            out.append(f'<line x1="{a0 - 4}" y1="{p:.1f}" x2="{a0}" y2="{p:.1f}" stroke="#444"/>')
            out.append(f'<line x1="{a0}" y1="{p:.1f}" x2="{a1}" y2="{p:.1f}" stroke="#eee"/>')
            out.append(_text(a0 - 6, p + 4, tick_label(t), anchor="end", cls="ytick"))
    return out


def _text(x: float, y: float, s: str, anchor: str = "start", size: int = FONT_PX,
          cls: str | None = None) -> str:
    if not s:
        return ""
    c = f' class="{cls}"' if cls else ""
    return (f'<text{c} x="{x:.1f}" y="{y:.1f}" text-anchor="{anchor}" '
            f'font-size="{size}">{escape(s)}</text>')


def _stroke(m: _Mark) -> str:
    dash = f' stroke-dasharray="{m.dash}"' if m.dash else ""
    return f'stroke="{m.colour}" stroke-width="{m.width}"{dash}'


def _path(px: np.ndarray, py: np.ndarray) -> str:
    return " ".join(f"{'M' if i == 0 else 'L'}{a:.1f},{b:.1f}"
                    for i, (a, b) in enumerate(zip(px, py, strict=True)))


def _runs(ok: np.ndarray) -> list[slice]:
    """Runs of consecutive True values (a line breaks at missing points)."""
    idx = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return [slice(a, b) for a, b in zip(idx[::2], idx[1::2], strict=True)]


def _markers(px, py, m: _Mark) -> list[str]:
    r = m.size
    if m.marker == "x":
        return [f'<path d="M{a - r:.1f},{b - r:.1f}L{a + r:.1f},{b + r:.1f}M{a - r:.1f},'
                f'{b + r:.1f}L{a + r:.1f},{b - r:.1f}" stroke="{m.colour}" stroke-width="1.2"/>'
                for a, b in zip(px, py, strict=True)]
    return [f'<circle cx="{a:.1f}" cy="{b:.1f}" r="{r}" fill="{m.colour}"/>'
            for a, b in zip(px, py, strict=True)]


def _draw(m: _Mark, sx, sy, box: tuple[float, float, float, float]) -> str:
    left, right, top, bottom = box
    if m.kind == "hline":
        p = float(sy(m.xy[0][0]))
        return (f'<line x1="{left}" y1="{p:.1f}" x2="{right}" y2="{p:.1f}" {_stroke(m)}/>'
                if math.isfinite(p) else "")
    if m.kind == "vline":
        p = float(sx(m.xy[0][0]))
        return (f'<line x1="{p:.1f}" y1="{top}" x2="{p:.1f}" y2="{bottom}" {_stroke(m)}/>'
                if math.isfinite(p) else "")
    if m.kind == "bars":
        edges, b0, b1 = m.xy
        x, y0, y1 = sx(edges), sy(b0), sy(b1)
        return "".join(
            f'<rect x="{x[i]:.1f}" y="{y1[i]:.1f}" width="{x[i + 1] - x[i]:.1f}" '
            f'height="{y0[i] - y1[i]:.1f}" fill="{m.colour}" stroke="#fff" stroke-width="0.4"/>'
            for i in range(len(b0)) if b1[i] > b0[i] and np.isfinite(x[i:i + 2]).all())
    if m.kind == "band":
        x, lo, hi = (np.asarray(a) for a in (sx(m.xy[0]), sy(m.xy[1]), sy(m.xy[2])))
        ok = np.isfinite(x) & np.isfinite(lo) & np.isfinite(hi)
        polys = []
        for s in _runs(ok):
            d = _path(np.concatenate([x[s], x[s][::-1]]), np.concatenate([hi[s], lo[s][::-1]]))
            polys.append(f'<path d="{d}Z" fill="{m.colour}" fill-opacity="{m.opacity}"/>')
        return "".join(polys)
    px, py = sx(m.xy[0]), sy(m.xy[1])
    ok = np.isfinite(px) & np.isfinite(py)
    if m.kind == "points":
        return "".join(_markers(px[ok], py[ok], m))
    lines = [f'<path d="{_path(px[s], py[s])}" fill="none" {_stroke(m)}/>'
             for s in _runs(ok) if s.stop - s.start > 1]
    if m.marker:
        lines += _markers(px[ok], py[ok], m)
    return "".join(lines)


def _legend_items(items: list[_Mark], x: float, y: float) -> list[str]:
    out = []
    for i, m in enumerate(items):
        cy = y + 8 + 16 * i
        if m.kind == "points":
            sample = _markers(np.array([x + 9]), np.array([cy]), m)[0]
        elif m.kind in ("bars", "band"):
            op = f' fill-opacity="{m.opacity}"' if m.kind == "band" else ""
            sample = (f'<rect x="{x + 2}" y="{cy - 5}" width="14" height="10" '
                      f'fill="{m.colour}"{op}/>')
        else:
            sample = f'<line x1="{x}" y1="{cy}" x2="{x + 18}" y2="{cy}" {_stroke(m)}/>'
        out += [sample, _text(x + 24, cy + 4, m.label or "", size=FONT_PX - 1, cls="legend")]
    return out
