"""The reproduction report (``contextweb report``): every experiment, one Markdown page, computed verdicts.

:func:`generate_report` runs each experiment of :data:`experiments.EXPERIMENTS`
at every seed (default 0–4) into ``out/NAME/seed-S/`` with the defaults of its own
parser (what ``contextweb experiment NAME`` would run; ``quick`` for tests), and
the ablations its claims show beside them into ``out/NAME@ABLATION/seed-S/``, in
parallel processes; takes the §V-F running times, and writes one page. For each
claim of the paper the page shows the paper's numbers, ours (a table of medians
and ranges over the seeds, the first seed's figures), the criterion, and a
verdict computed from the experiment's summaries by the rule of ``seeds.py``
(at the median and at 4 of 5 seeds):

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
- ``jobs.py``: running the experiments (and their ablations) at every seed, in parallel;
- ``seeds.py``: the rule over seeds, median summaries and tables over the seeds;
- ``page.py``: the Markdown page;
- this module: the assembler (:func:`generate_report`) and the command line.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from core.errors import InvalidInputError
from experiments.report.claim import Claim, Status, Verdict
from experiments.report.claims import CLAIMS
from experiments.report.claims.running_times import BENCH_RESULTS, RUNNING_TIMES
from experiments.report.jobs import DEFAULT_SEEDS, ReportResult, job_label, job_names, job_specs, run_jobs
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
    seeds: Sequence[int] = DEFAULT_SEEDS,
    only: Sequence[str] | None = None,
    page: Path | None = None,
    bench_results: Path = BENCH_RESULTS,
    workers: int | None = None,
    reuse: str = "none",
) -> ReportResult:
    """Run the jobs (every experiment at every seed with its claims' ablations, and
    :data:`RUNNING_TIMES` once; or ``only`` those) into ``out/LABEL/seed-S/`` in ``workers``
    processes (default one per core), judge every claim over the seeds (``seeds.RULE``) and write
    the page: ``page`` (figures and summaries copied beside it, into a folder named after it:
    ``docs/reproduction.md`` → ``docs/reproduction/``) or ``out/report.md``."""
    if not seeds:
        raise InvalidInputError("seeds", "needs at least one seed")
    names = job_names(only)
    page = page or out / "report.md"
    figures_dir = page.parent / page.stem if page != out / "report.md" else out / "page"
    specs = job_specs(names, list(seeds))
    results = ReportResult(page, run_jobs(specs, out, quick, bench_results, workers, reuse))
    claims = [claim for claim in CLAIMS if claim.job in results.jobs]
    sections = []
    for claim in claims:
        judged, verdict, table = evaluate(claim, results.jobs[claim.job])
        results.verdicts[claim.name] = verdict
        results.ablation_verdicts[claim.name] = {
            ablation: evaluate(claim, results.jobs[job_label(claim.job, ablation)])[1]
            for ablation in claim.ablations
            if job_label(claim.job, ablation) in results.jobs
        }
        published = publish(claim.job, results.jobs[claim.job], figures_dir)
        sections.append(claim_section(claim, results, table, judged, published, page.parent))
    for label, runs in results.jobs.items():
        if label not in (job_label(c.job, a) for c in claims for a in c.ablations):
            continue
        publish(label, runs, figures_dir)
    for name in (name for name in results.jobs if all(claim.job != name.split("@")[0] for claim in CLAIMS)):
        runs = results.jobs[name]
        pngs, _ = publish(name, runs, figures_dir)
        failed = next((run for run in runs if run.error is not None), None)
        status = "ran" if failed is None else f"not run (seed {failed.seed}): {failed.error}"
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
    page.write_text(render_page(results, claims, sections, quick, list(seeds)), encoding="utf-8")
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
    parser.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=list(DEFAULT_SEEDS),
        help="seeds every experiment runs at (default 0 1 2 3 4); claims are judged over them",
    )
    parser.add_argument("--workers", type=int, default=None, help="parallel processes (default: one per core)")
    parser.add_argument(
        "--reuse",
        choices=("none", "existing", "only"),
        default="none",
        help="take the summaries an earlier run left in OUT: 'existing' runs the missing jobs (resume), "
        "'only' runs none and reports the missing ones as not run",
    )
    parser.add_argument(
        "--only",
        nargs="+",
        metavar="JOB",
        default=None,
        help=f"run only these jobs (experiment names, {RUNNING_TIMES})",
    )


def run(args: argparse.Namespace) -> int:
    """Write the report; exit status 1 if any job failed."""
    result = generate_report(
        args.out, args.quick, args.seeds, args.only, args.page, workers=args.workers, reuse=args.reuse
    )
    for title, verdict in result.verdicts.items():
        print(f"{title}: {verdict.line()}")
    print(f"report: {result.page}")
    return 0 if result.ok else 1
