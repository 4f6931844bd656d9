"""Verdicts over seeds (experiments.report.seeds): the median summary, the 4-of-5 rule, tables over seeds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from core.errors import InvalidInputError
from experiments.report import RUNNING_TIMES, Status
from experiments.report.claims import fig_13
from experiments.report.jobs import ABLATIONS, experiment_args, job_specs
from experiments.report.seeds import (
    judge_over_seeds,
    median_summary,
    seeds_needed,
    table_over_seeds,
)
from tests.test_report_verdicts import _recognition as recognition_summary


def test_seeds_needed_is_four_of_five_and_every_one_of_few() -> None:
    assert [seeds_needed(n) for n in (1, 2, 3, 4, 5, 10)] == [1, 2, 3, 4, 4, 8]


def test_median_summary_takes_numbers_item_by_item_never_as_infinity_and_text_by_majority() -> None:
    summaries: list[dict[str, Any]] = [
        {"a": 1, "b": [0.1, 2.0], "never": None, "name": "x", "kept": ["p"]},
        {"a": 3, "b": [0.3, 1.0], "never": 4, "name": "y", "kept": ["p", "q"]},
        {"a": 2, "b": [0.2, 3.0], "never": None, "name": "y", "kept": ["p"]},
    ]
    assert median_summary(summaries) == {"a": 2, "b": [0.2, 2.0], "never": None, "name": "y", "kept": ["p"]}
    assert median_summary([{"n": 4}, {"n": 5}]) == {"n": 4.5}
    assert median_summary([{"n": 3}]) == {"n": 3}


def _recognition(perception: float, web: float, context: float) -> dict[str, Any]:
    return recognition_summary((perception, web, context, context))


def test_a_claim_must_hold_at_the_median_and_at_four_of_five_seeds() -> None:
    good, bad = _recognition(0.6, 0.7, 0.8), _recognition(0.8, 0.7, 0.6)
    holds = judge_over_seeds(fig_13.CLAIMS[0], [good, good, good, good, bad], seeds=[10, 11, 12, 13, 14])
    assert holds.verdict.status is not Status.NOT_REPRODUCED and holds.holding == 4
    assert "holds at 4 of 5 seeds (needs 4)" in holds.verdict.reason
    three = judge_over_seeds(fig_13.CLAIMS[0], [good, good, good, bad, bad], seeds=[10, 11, 12, 13, 14])
    assert three.verdict.status is Status.NOT_REPRODUCED
    assert "only at 3 of 5 seeds" in three.verdict.reason and "seed 13:" in three.verdict.reason


def test_tables_over_seeds_show_the_median_and_the_range_where_it_varies() -> None:
    summaries = [_recognition(0.6, 0.7, x) for x in (0.8, 0.9, 0.85)]
    table = table_over_seeds(fig_13.CLAIMS[0], summaries)
    assert table[1][1] == "0.600"
    assert table[3][1] == "0.850 [0.800–0.900]"


def test_jobs_run_every_seed_headline_first_with_their_claims_ablations_and_running_times_once() -> None:
    specs = job_specs(["mixed", RUNNING_TIMES], [5, 6])
    assert [(s.label, s.seed) for s in specs] == [
        ("mixed", 5),
        ("mixed", 6),
        (RUNNING_TIMES, 5),
        ("mixed@easy", 5),
        ("mixed@easy", 6),
        ("mixed@labels", 5),
        ("mixed@labels", 6),
    ]
    _, args = experiment_args("mixed", Path("out"), True, 5, ABLATIONS["labels"])
    assert (args.documents, args.world, args.seed) == ("labels", "hard", 5)
    with pytest.raises(InvalidInputError, match="no --documents"):
        experiment_args("raw-vs-web", Path("out"), True, 5, ABLATIONS["labels"])
