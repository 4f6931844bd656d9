"""Verdicts over seeds: a claim is judged on the distribution of its numbers over the report's seeds.

The rule (written on the page, :data:`RULE`): a claim holds when its criterion holds

- **at the median**: on the median summary (:func:`median_summary`, every number the median over
  the seeds), and
- **at ⌈0.8 · n⌉ of the n seeds** (:func:`seeds_needed`: 4 of 5, 1 of 1), each seed's own summary
  judged alone.

A criterion's verdict at the median names the numbers it read (medians); the page's tables show each
number as its median with its range over the seeds (:func:`table_over_seeds`).
"""

from __future__ import annotations

import json
import math
import re
import statistics
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from experiments.report.claim import Claim, Status, Summary, Table, Verdict

#: The share of seeds at which a claim must also hold (4 of 5).
SEED_SHARE = 0.8

RULE = (
    f"a claim holds when its criterion holds on the median over the seeds of every number AND at "
    f"⌈{SEED_SHARE:g} · n⌉ of the n seeds (4 of 5), each seed judged alone"
)


def seeds_needed(n_seeds: int) -> int:
    return math.ceil(SEED_SHARE * n_seeds - 1e-9)


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _median(values: Sequence[int | float | None]) -> int | float | None:
    """Median with None read as +∞ ("never", e.g. scenes needed): None if the median is."""
    median = statistics.median(math.inf if v is None else v for v in values)
    if math.isinf(median):
        return None
    if all(isinstance(v, int) for v in values) and float(median).is_integer():
        return int(median)
    return float(median)


def median_summary(summaries: Sequence[Any]) -> Any:
    """Element-wise median of same-shaped JSON summaries: numbers by :func:`_median`, mappings key by
    key, lists of one length item by item; anything else (text, booleans, lists of varying length)
    is the value most seeds share (the first seed's on a tie)."""
    first = summaries[0]
    if all(isinstance(s, dict) for s in summaries) and all(s.keys() == first.keys() for s in summaries):
        return {key: median_summary([s[key] for s in summaries]) for key in first}
    if all(isinstance(s, list) for s in summaries) and len({len(s) for s in summaries}) == 1:
        return [median_summary(list(column)) for column in zip(*summaries, strict=True)]
    if all(s is None or _is_number(s) for s in summaries) and any(_is_number(s) for s in summaries):
        return _median(summaries)
    counts = Counter(json.dumps(s, sort_keys=True) for s in summaries)
    top = max(counts.values())
    return next(s for s in summaries if counts[json.dumps(s, sort_keys=True)] == top)


@dataclass(frozen=True)
class SeedVerdict:
    """A claim over the seeds: the verdict by :data:`RULE`, the verdict at the median, each seed's."""

    verdict: Verdict
    at_median: Verdict
    per_seed: tuple[Verdict, ...]

    @property
    def holding(self) -> int:
        return sum(v.status in (Status.REPRODUCED, Status.BETTER) for v in self.per_seed)

    def seeds_text(self) -> str:
        return f"{self.holding}/{len(self.per_seed)} seeds"


def judge_over_seeds(claim: Claim, summaries: Sequence[Summary], seeds: Sequence[int] | None = None) -> SeedVerdict:
    """:data:`RULE` applied to ``claim``: reproduced (or better, if better at the median) when it holds at
    the median and at :func:`seeds_needed` seeds; otherwise not reproduced, naming which part failed."""
    per_seed = tuple(claim.judge(summary) for summary in summaries)
    seeds = list(seeds) if seeds is not None else list(range(len(summaries)))
    at_median = claim.judge(median_summary(list(summaries)))
    holding = sum(v.status in (Status.REPRODUCED, Status.BETTER) for v in per_seed)
    needed = seeds_needed(len(summaries))
    counted = f"holds at {holding} of {len(summaries)} seeds (needs {needed})"
    median_holds = at_median.status in (Status.REPRODUCED, Status.BETTER)
    if median_holds and holding >= needed:
        verdict = Verdict(at_median.status, f"at the median: {at_median.reason}; {counted}")
    elif median_holds:
        failing = "; ".join(
            f"seed {seed}: {v.reason}"
            for seed, v in zip(seeds, per_seed, strict=True)
            if v.status is Status.NOT_REPRODUCED
        )
        verdict = Verdict(
            Status.NOT_REPRODUCED,
            f"holds at the median but only at {holding} of {len(summaries)} seeds (needs {needed}); failing: {failing}",
        )
    else:
        verdict = Verdict(Status.NOT_REPRODUCED, f"at the median: {at_median.reason}; {counted}")
    return SeedVerdict(verdict, at_median, per_seed)


_NUMBER = re.compile(r"(?<![\w.])-?\d+(?:,\d{3})*(?:\.\d+)?")


def _cell_over_seeds(cells: Sequence[str]) -> str | None:
    """One table cell over the seeds: every number as its median, with [min–max] where it varies;
    None when the seeds' cells differ in more than their numbers."""
    templates = {_NUMBER.sub("#", cell) for cell in cells}
    if len(templates) != 1:
        return None
    numbers = [_NUMBER.findall(cell) for cell in cells]
    pieces = iter(_NUMBER.split(cells[0]))
    out = [next(pieces)]
    for column, text in zip(zip(*numbers, strict=True), pieces, strict=True):
        values = [float(token.replace(",", "")) for token in column]
        decimals = len(column[0].split(".")[1]) if "." in column[0] else 0
        grouped = "," in column[0]
        shown = f"{statistics.median(values):{',' if grouped else ''}.{decimals}f}"
        if min(values) != max(values):
            shown += f" [{min(values):.{decimals}f}–{max(values):.{decimals}f}]"
        out += [shown, text]
    return "".join(out)


def table_over_seeds(claim: Claim, summaries: Sequence[Summary]) -> Table:
    """The claim's table over the seeds: cell by cell :func:`_cell_over_seeds` where every seed's table
    has the same shape; a cell whose text differs beyond its numbers (and a table whose shape
    differs) is the median summary's."""
    at_median = claim.table(median_summary(list(summaries)))
    tables = [claim.table(summary) for summary in summaries]
    shapes = {tuple(len(row) for row in table) for table in tables}
    if len(shapes) != 1 or shapes != {tuple(len(row) for row in at_median)}:
        return at_median
    return [
        [
            _cell_over_seeds([str(table[r][c]) for table in tables]) or str(at_median[r][c])
            for c in range(len(at_median[r]))
        ]
        for r in range(len(at_median))
    ]
