"""The report page (experiments.report): a --quick run of the planning experiment, a failing one.

This module doubles as the failing experiment: registered as ``broken``, its
:func:`run` raises as an experiment's bug would.
"""

from __future__ import annotations

import argparse
import json
import os
import re
from pathlib import Path

import pytest

import experiments
from app.cli import main
from core.errors import InvalidInputError
from experiments import report

BROKEN = "broken"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--size", type=int, default=3)


def run(args: argparse.Namespace) -> dict:
    raise RuntimeError(f"simulated failure at size {args.size}")


@pytest.fixture(scope="module")
def bench_results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("bench")
    (folder / "context.json").write_text(json.dumps({"detection_5_objects": {"ours_median_us": 70.0}}))
    (folder / "concept_web.json").write_text(json.dumps({"ours_median_us": 210.0}))
    return folder


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory: pytest.TempPathFactory, bench_results: Path) -> report.ReportResult:
    root = tmp_path_factory.mktemp("report")
    stale = root / "out" / "planning" / "seed-7" / "from_an_earlier_run.png"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"")
    os.utime(stale, (0, 0))
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(experiments.EXPERIMENTS, BROKEN, __name__)
        return report.generate_report(
            root / "out",
            quick=True,
            seeds=[7],
            only=["planning", BROKEN, report.RUNNING_TIMES],
            workers=1,
            page=root / "docs" / "reproduction.md",
            bench_results=bench_results,
        )


def test_page_links_this_runs_figures_copied_beside_it(quick_report: report.ReportResult) -> None:
    page = quick_report.page
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page.read_text(encoding="utf-8"))
    assert links == ["reproduction/planning/planning.png"]
    assert (page.parent / links[0]).is_file()
    assert (page.parent / "reproduction" / "planning" / "median.json").is_file()
    assert (page.parent / "reproduction" / "planning" / "seed-7.json").is_file()
    assert (page.parent.parent / "out" / "planning" / "seed-7" / "summary.json").is_file()


def test_page_has_one_verdict_per_claim_of_the_jobs_run(quick_report: report.ReportResult) -> None:
    text = quick_report.page.read_text(encoding="utf-8")
    assert set(quick_report.verdicts) == {
        "Fig. 15 — planning trees of the two canonical scenarios",
        "Fig. 16 — pruning over random scenarios",
        "§V-F — running times",
    }
    assert (
        "**Verdict: reproduced — at the median: nodes 2,380 (paper 2,380), 156 (paper 156), 820 (paper 820); "
        "holds at 1 of 1 seeds (needs 1)**"
    ) in text
    assert "**Verdict: better — at the median: context detection 0.070 ms vs 209.82 ms" in text
    assert text.count("**Verdict: ") == 3 and text.count("- *Criterion:* ") == 3


def test_a_failed_experiment_is_reported_not_fatal(quick_report: report.ReportResult) -> None:
    assert not quick_report.ok
    assert list(quick_report.failed) == [BROKEN]
    assert quick_report.failed[BROKEN].startswith("RuntimeError: simulated failure at size 3 (at test_report_page.py")
    assert "| `broken` | 7 | " in quick_report.page.read_text(encoding="utf-8")
    assert [run.error for run in quick_report.jobs["planning"]] == [None]


def test_command_line_exits_non_zero_when_a_job_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(experiments.EXPERIMENTS, BROKEN, __name__)
    assert main(["report", "--out", str(tmp_path), "--quick", "--only", BROKEN, "--seeds", "5", "6"]) == 1
    assert "not run (seed 5): RuntimeError: simulated failure" in (tmp_path / "report.md").read_text(encoding="utf-8")


def test_unknown_job_names_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match="only.*unknown job"):
        report.generate_report(tmp_path, only=["no-such-experiment"])


def test_a_report_can_be_judged_again_from_the_summaries_it_stored(
    quick_report: report.ReportResult, bench_results: Path
) -> None:
    """``--reuse only`` runs nothing: the stored summaries give the same verdicts; a seed never run
    is named, and the claim is judged on the seeds that ran."""
    out = quick_report.page.parent.parent / "out"
    again = report.generate_report(
        out,
        quick=True,
        seeds=[7, 8],
        only=["planning", report.RUNNING_TIMES],
        page=out.parent / "again.md",
        bench_results=bench_results,
        reuse="only",
    )
    name = "Fig. 15 — planning trees of the two canonical scenarios"
    assert again.jobs["planning"][0].summary == quick_report.jobs["planning"][0].summary
    assert again.jobs["planning"][1].error == "no summary stored (--reuse only)"
    assert again.verdicts[name].status is quick_report.verdicts[name].status
    assert again.verdicts[name].reason.endswith("(judged on seeds 7; seeds 8 did not run)")
