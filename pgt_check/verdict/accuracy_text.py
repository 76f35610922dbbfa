"""The run's accuracy statement in plain sentences (``accuracy_sentences``: for a dataset paper,
the CLI and the report) and the number formats the accuracy gate's messages share with them.

Split out of ``verdict.accuracy``, which re-exports ``accuracy_sentences``. This module imports
nothing from it (``accuracy`` imports this one, and an import back would be a cycle): the
statement comes in as ``verdict.accuracy.RunAccuracy``, read by attribute only.
"""

from __future__ import annotations

from typing import Any


def _fmt(v: float | None, digits: int = 3) -> str:
    return "?" if v is None else f"{v:.{digits}g}"


def _need(x: float | None, y: float | None) -> str:
    parts = ([f"{x:g} deg"] if x is not None else []) + (
        [f"{y:g} scene units"] if y is not None else []
    )
    return " / ".join(parts)


def _bound_sentences(acc: Any) -> list[str]:
    """How many frames are verified to within what, and the bounds' percentiles (``acc``: a
    ``RunAccuracy``)."""
    if acc.n_bounded == 0:
        return [
            f"None of the {acc.n_frames} frames has absolute evidence for a per-frame accuracy "
            "bound (their verdicts rest on reprojected references or nothing)."
        ]
    how = {
        "required": "the required accuracy",
        "p90_pass": "the 90th percentile of the PASS frames' bounds",
    }.get(acc.within_from, "the 90th percentile of the bounds; no frame PASSes")
    r, t, p = acc.rotation_bound_deg, acc.translation_bound, acc.effect_bound_px
    return [
        f"{acc.n_within} of {acc.n_frames} frames are verified to within "
        f"{_fmt(acc.within_deg)} deg and {_fmt(acc.within_units)} scene units at 95 % "
        f"confidence ({how}; {acc.n_bounded} frames have absolute evidence for a bound).",
        f"Per-frame 95 % bounds: median {_fmt(r.p50)} deg / {_fmt(t.p50)} units "
        f"({_fmt(p.p50)} px), 90th percentile {_fmt(r.p90)} deg / {_fmt(t.p90)} units "
        f"({_fmt(p.p90)} px).",
    ]


def _shared_sentence(s: Any) -> str:
    """One shared error's size with its intervals (``s``: a ``SharedSize``, not similarity)."""
    ci_r = f" (95 % {_fmt(s.rotation_deg_ci[0])}-{_fmt(s.rotation_deg_ci[1])})" if (
        s.rotation_deg_ci) else ""
    ci_t = f" (95 % {_fmt(s.translation_ci[0])}-{_fmt(s.translation_ci[1])})" if (
        s.translation_ci) else ""
    ci_p = f" (95 % {_fmt(s.effect_px_ci[0])}-{_fmt(s.effect_px_ci[1])})" if (
        s.effect_px_ci) else ""
    parts = ([f"{_fmt(s.rotation_deg)} deg{ci_r}"] if s.rotation_deg is not None else [])
    parts += [f"{_fmt(s.translation)} scene units{ci_t}"] if s.translation is not None else []
    parts += [f"{_fmt(s.effect_px)} px{ci_p}"] if s.effect_px is not None else []
    if s.from_px:
        return (
            f"Largest drift along the trajectory ({s.status}): {_fmt(s.effect_px)} px"
            f"{ci_p}, as large as {_fmt(s.rotation_deg)} deg of rotation alone or "
            f"{_fmt(s.translation)} scene units of translation alone."
        )
    return f"Shared {s.check} error ({s.status}): " + ", ".join(parts) + "."


def _limits_sentence(lim: Any) -> str:
    """The run's detection limits (``lim``: a ``DetectionLimits`` with ``frame_px``)."""
    return (
        f"Detection limits of this run: a single frame's error is flagged above about "
        f"{_fmt(lim.frame_deg, 2)} deg or {_fmt(lim.frame_units, 2)} scene units "
        f"({_fmt(lim.frame_px, 3)} px)"
        + (
            f"; an error shared by all frames above about {_fmt(lim.shared_deg, 2)} deg or "
            f"{_fmt(lim.shared_units, 2)} scene units ({_fmt(lim.shared_px, 3)} px)"
            if lim.shared_px is not None
            else (f"; an error shared by all frames: {lim.shared_note}" if lim.shared_note
                  else "")
        )
        + f"; one frame cannot tell {_fmt(lim.noise_deg, 2)} deg / "
        f"{_fmt(lim.noise_units, 2)} units from zero (median bootstrap noise)."
    )


def accuracy_sentences(acc: Any) -> list[str]:
    """Plain sentences with the numbers (for a dataset paper, the CLI and the report); ``acc``:
    a ``verdict.accuracy.RunAccuracy``."""
    out = _bound_sentences(acc)
    for s in acc.shared:
        if s.check == "similarity":
            continue
        out.append(_shared_sentence(s))
    lim = acc.limits
    if lim.frame_px is not None:
        out.append(_limits_sentence(lim))
    if acc.gate_passed is not None:
        out.append(("Accuracy gate passed: " if acc.gate_passed else "Accuracy gate FAILED: ")
                   + acc.gate_explanation.removeprefix("accuracy: ") + ".")
    return out
