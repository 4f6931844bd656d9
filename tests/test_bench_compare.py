"""bench/compare.py's bookkeeping: ABBA order and the pairs a change wins (the servers it drives are
the benchmark's own, run by hand)."""

from __future__ import annotations

from bench.compare import pairs_won, rounds_order, summary


def test_rounds_alternate_in_abba_order() -> None:
    assert rounds_order(4) == [("A", "B"), ("B", "A"), ("A", "B"), ("B", "A")]
    runs = [name for pair in rounds_order(6) for name in pair]
    # Each side runs first in half of the rounds, so a steady drift of the machine favours neither.
    assert [runs[2 * i] for i in range(6)].count("A") == 3


def test_pairs_won_counts_the_rounds_where_b_was_ahead() -> None:
    assert pairs_won([383.6, 368.1, 416.6, 386.2], [436.8, 422.2, 435.6, 422.4]) == 4
    assert pairs_won([229.8, 236.5, 231.5, 228.3], [232.3, 236.0, 238.1, 248.1]) == 3
    assert pairs_won([1.0], [1.0]) == 0


def test_summary_takes_medians() -> None:
    rows = [
        {"scenes_per_second": speed, "cpu_ms_per_scene": {"server": server, "total": total, "cores_busy": busy}}
        for speed, server, total, busy in [
            (400.1, 3.5, 4.4, 1.7),
            (420.0, 3.3, 4.2, 1.8),
            (380.0, 3.7, 4.6, 1.6),
            (401.0, 3.4, 4.3, 1.7),
        ]
    ]
    # Medians of an even count are means of the middle two, rounded as the report shows them.
    assert summary(rows) == {"scenes_per_second": 400.6, "server_ms": 3.45, "total_ms": 4.35, "cores_busy": 1.7}
