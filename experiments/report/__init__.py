"""The reproduction report (``contextweb report``): every experiment, one Markdown page, computed verdicts.

:func:`generate_report` runs each experiment of :data:`experiments.EXPERIMENTS`
into ``out/NAME/`` with the defaults of its own parser (what ``contextweb
experiment NAME`` would run; ``quick`` for tests), takes the §V-F running times,
and writes one page. For each claim of the paper the page shows the paper's
numbers, ours (a table, the experiment's figures), the criterion, and a verdict
computed from the experiment's summary:

- ``reproduced``: the criterion holds;
- ``better``: it holds and our numbers beat the paper's own on the measure the
  criterion names (only where the paper gives such a number);
- ``not reproduced — why``: the measured numbers that break the criterion;
- ``not run: error``: the experiment failed (or is not registered); the rest of
  the page is still written and :attr:`ReportResult.ok` is false.

Layout:

- ``claims/``: one module per claim of the paper (``fig_9`` … ``fig_16``,
  ``table_vi``, ``running_times`` for §V-F). Each holds the paper's numbers
  (``PAPER_*``; for Table VI the data of ``sim.world.table_vi_scenes``), the
  criterion's own thresholds (``*_TOLERANCE``-style constants, each with its
  reason), its ``judge`` and ``table``, and its ``CLAIMS``;
  :data:`~experiments.report.claims.CLAIMS` orders them for the page;
- ``claim.py``: what a claim and a verdict are, and the shared formatting;
- ``jobs.py``: running the experiments and the running-times job;
- ``page.py``: the Markdown page;
- this module: the assembler (:func:`generate_report`) and the command line.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from experiments.report.claim import Claim, Status, Verdict
from experiments.report.claims import CLAIMS
from experiments.report.claims.running_times import BENCH_RESULTS, RUNNING_TIMES
from experiments.report.jobs import ReportResult, job_names, run_job
from experiments.report.page import claim_section, evaluate, link, publish, render_page

__all__ = [
    "CLAIMS",
    "RUNNING_TIMES",
    "Claim",
    "ReportResult",
    "Status",
    "Verdict",
    "add_arguments",
    "generate_report",
    "run",
]


def generate_report(
    out: Path,
    quick: bool = False,
    seed: int = 0,
    only: Sequence[str] | None = None,
    page: Path | None = None,
    bench_results: Path = BENCH_RESULTS,
) -> ReportResult:
    """Run the jobs (every experiment and :data:`RUNNING_TIMES`, or ``only`` those) into
    ``out/NAME/`` and write the page: ``page`` (figures copied beside it, into a folder named
    after it: ``docs/reproduction.md`` → ``docs/reproduction/``) or ``out/report.md``."""
    names = job_names(only)
    page = page or out / "report.md"
    figures_dir = page.parent / page.stem if page != out / "report.md" else out
    results = ReportResult(page, {})
    progress = tqdm(names, desc="report", unit="job")
    for name in progress:
        progress.set_postfix_str(name)
        results.jobs[name] = run_job(name, out / name, quick, seed, bench_results)
    claims = [claim for claim in CLAIMS if claim.job in results.jobs]
    sections = []
    for claim in claims:
        job = results.jobs[claim.job]
        verdict, table = evaluate(claim, job)
        results.verdicts[claim.name] = verdict
        sections.append(claim_section(claim, job, verdict, table, publish(job, figures_dir), page.parent))
    for name in (name for name in results.jobs if all(claim.job != name for claim in CLAIMS)):
        job = results.jobs[name]
        pngs, _ = publish(job, figures_dir)
        status = "ran" if job.error is None else f"not run: {job.error}"
        sections.append(
            [
                f"## `{name}` (no claim of the paper attached)",
                "",
                f"{status}.",
                "",
                *(line for png in pngs for line in (f"![{png.stem}]({link(page.parent, png)})", "")),
            ]
        )
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(render_page(results, claims, sections, quick, seed), encoding="utf-8")
    return results


# --- Command line ---------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("reports"), help="folder for every experiment's output")
    parser.add_argument(
        "--page",
        type=Path,
        default=None,
        help="where the page goes (default OUT/report.md); figures are copied beside it",
    )
    parser.add_argument("--quick", action="store_true", help="every experiment at its --quick size, for tests")
    parser.add_argument("--seed", type=int, default=0, help="seed of every experiment")
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="JOB",
        default=None,
        help=f"run only these jobs (experiment names, {RUNNING_TIMES})",
    )


def run(args: argparse.Namespace) -> int:
    """Write the report; exit status 1 if any job failed."""
    result = generate_report(args.out, args.quick, args.seed, args.only, args.page)
    for title, verdict in result.verdicts.items():
        print(f"{title}: {verdict.line()}")
    print(f"report: {result.page}")
    return 0 if result.ok else 1
