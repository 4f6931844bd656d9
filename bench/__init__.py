"""Benchmarks: ``python -m bench`` runs every ``bench/bench_*.py`` module's ``main()``.

Each benchmark times its area against a reference measured in the same run (the
machine is shared, so only ratios travel) and writes a JSON to ``bench/results/``.
"""

from __future__ import annotations

from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
