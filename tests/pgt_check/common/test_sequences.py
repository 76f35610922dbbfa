"""``common.sequences.evenly_spaced``."""

from __future__ import annotations

from pgt_check.common.sequences import evenly_spaced


def test_evenly_spaced_keeps_ends_and_order() -> None:
    items = list(range(100))
    got = evenly_spaced(items, 12)
    assert len(got) == 12 and got[0] == 0 and got[-1] == 99
    assert got == sorted(set(got))
    steps = [b - a for a, b in zip(got, got[1:], strict=False)]
    assert max(steps) - min(steps) <= 1


def test_short_sequences_and_empty_requests() -> None:
    assert evenly_spaced(["a", "b"], 5) == ["a", "b"]
    assert evenly_spaced(["a", "b"], 0) == [] and evenly_spaced([], 3) == []
    assert evenly_spaced(list(range(10)), 1) == [0]
