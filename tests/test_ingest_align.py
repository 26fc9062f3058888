"""The alignment rules of the importers, on known inputs and as properties."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from soilocp.ingest.align import NS, Stream, align, in_time_order


def _lnds_length(a: list[int]) -> int:
    best = [1] * len(a)
    for i in range(len(a)):
        for j in range(i):
            if a[j] <= a[i]:
                best[i] = max(best[i], best[j] + 1)
    return max(best, default=0)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-50, 50), max_size=40))
def test_in_time_order_keeps_a_longest_non_decreasing_run(a):
    keep = in_time_order(np.array(a, dtype=np.int64))
    kept = [x for x, k in zip(a, keep) if k]
    assert kept == sorted(kept)
    assert len(kept) == _lnds_length(a)


def test_align_holds_last_value_up_to_max_age_then_skips():
    fast = Stream("fast", np.arange(0, 100) * NS // 100, {"a": np.arange(100.0)}, max_age=0.01)
    # slow at 10 Hz with one message missing (t = 0.5 s)
    t_slow = np.array([0, 1, 2, 3, 4, 6, 7, 8, 9]) * NS // 10
    slow = Stream("slow", t_slow, {"b": t_slow / NS}, max_age=0.15)
    al = align([fast, slow], 100.0)
    # ticks 0..99 (fast ends at 0.99 s + 0.01 s); slow at 0.4 s is fresh up to 0.55 s, stale until 0.6 s
    assert list(al.seq) == [*range(0, 56), *range(60, 101)]
    assert al.skipped == {"stale slow (older than 0.15 s)": 4}
    i = list(al.seq).index(60)  # tick 60: the 0.6 s message
    assert al.values["b"][i] == 0.6 and al.values["a"][list(al.seq).index(12)] == 12.0
    assert al.values["b"][list(al.seq).index(19)] == 0.1  # held
