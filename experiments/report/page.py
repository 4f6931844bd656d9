"""The report's Markdown page: a verdict table (with the ablations beside each claim), a job table,
then one section per claim with the paper's numbers, the criterion, our table over the seeds and
the first seed's figures."""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from experiments.report.claim import Claim, Status, Summary, Table, Verdict
from experiments.report.jobs import JobResult, ReportResult, error_text, job_label
from experiments.report.seeds import RULE, SeedVerdict, judge_over_seeds, median_summary, table_over_seeds


def markdown_table(rows: Table) -> list[str]:
    header, *body = ([cell.replace("|", "\\|") for cell in row] for row in rows)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(row) + " |" for row in body]


def summaries(runs: Sequence[JobResult]) -> list[Summary] | str:
    """The summaries of the seeds that ran, or the first error when none did."""
    ran = [run.summary for run in runs if run.summary is not None]
    if not ran:
        return f"seed {runs[0].seed}: {runs[0].error or 'no summary'}"
    return ran


def evaluate(claim: Claim, runs: Sequence[JobResult]) -> tuple[SeedVerdict | None, Verdict, Table | None]:
    """The claim over the seeds of ``runs`` that ran (:data:`~experiments.report.seeds.RULE`) and its
    table; the verdict names the seeds that did not run (the job table has their errors)."""
    found = summaries(runs)
    if isinstance(found, str):
        return None, Verdict(Status.NOT_RUN, found), None
    try:
        ran = [run for run in runs if run.summary is not None]
        judged = judge_over_seeds(claim, found, [run.seed for run in ran])
        missing = [str(run.seed) for run in runs if run.summary is None]
        if missing:
            note = f" (judged on seeds {', '.join(str(r.seed) for r in ran)}; seeds {', '.join(missing)} did not run)"
            judged = replace(judged, verdict=replace(judged.verdict, reason=judged.verdict.reason + note))
        return judged, judged.verdict, table_over_seeds(claim, found)
    except (KeyError, IndexError, TypeError, ValueError) as exception:
        return None, Verdict(Status.NOT_RUN, f"the {claim.job} summary cannot be judged: {error_text(exception)}"), None


def headline_text(claim: Claim, runs: Sequence[JobResult]) -> str:
    """The claim's headline number: median [min–max] over the seeds."""
    found = summaries(runs)
    if claim.headline is None or isinstance(found, str):
        return "—"
    _, read = claim.headline
    values = [read(summary) for summary in found]
    known = [v for v in values if v is not None]
    median = median_summary(values)
    text = f"{median:.4g}" if median is not None else "never"
    if known and min(known) != max(known):
        text += f" [{min(known):.4g}–{max(known):.4g}]"
    return text


def link(page_dir: Path, target: Path) -> str:
    return Path(os.path.relpath(target, page_dir)).as_posix()


#: Seconds of file-system timestamp granularity tolerated when telling this run's figures from older ones.
_CLOCK_SLACK = 2.0


def publish(label: str, runs: Sequence[JobResult], figures_dir: Path) -> tuple[list[Path], Path | None]:
    """Copy the PNGs the first seed wrote in this run next to the page, with every seed's summary
    (``seed-S.json``) and the median summary (``median.json``)."""
    target = figures_dir / label
    first = runs[0]
    fresh = [
        path for path in sorted(first.folder.glob("*.png")) if path.stat().st_mtime >= first.started - _CLOCK_SLACK
    ]
    ran = [run for run in runs if run.summary is not None]
    if fresh or ran:
        target.mkdir(parents=True, exist_ok=True)
    pngs = []
    for source in fresh:
        destination = target / source.name
        if source.resolve() != destination.resolve():
            shutil.copyfile(source, destination)
        pngs.append(destination)
    for run in ran:
        (target / f"seed-{run.seed}.json").write_text(json.dumps(run.summary, indent=2) + "\n", encoding="utf-8")
    median = None
    if ran:
        median = target / "median.json"
        median.write_text(json.dumps(median_summary([run.summary for run in ran]), indent=2) + "\n", encoding="utf-8")
    return pngs, median


def claim_section(
    claim: Claim,
    result: ReportResult,
    table: Table | None,
    judged: SeedVerdict | None,
    published: tuple[list[Path], Path | None],
    page_dir: Path,
) -> list[str]:
    runs = result.jobs[claim.job]
    verdict = result.verdicts[claim.name]
    pngs, median = published
    lines = [f"## {claim.reference} — {claim.title}", "", f"**Verdict: {verdict.line()}**", ""]
    lines += [f"- *Paper:* {claim.paper}", f"- *Criterion:* {claim.criterion}"]
    seeds = ", ".join(str(run.seed) for run in runs)
    if median is not None:
        seconds = sum(run.seconds for run in runs)
        lines.append(
            f"- *Ours:* `{claim.job}` at seeds {seeds} in {seconds:.1f} s of CPU; the median of every number in "
            f"[median.json]({link(page_dir, median)}), each seed's beside it"
        )
    if judged is not None:
        lines.append(
            "- *Per seed:* "
            + "; ".join(
                f"{run.seed}: {v.status.value}"
                for run, v in zip([r for r in runs if r.summary is not None], judged.per_seed, strict=True)
            )
        )
    for ablation, ablated in result.ablation_verdicts.get(claim.name, {}).items():
        lines.append(f"- *Ablation `{ablation}`:* {ablated.line()}")
    lines.append("")
    if table is not None:
        lines += ["Median over the seeds [range where it varies]:", "", *markdown_table(table), ""]
    for name in claim.texts if runs[0].summary is not None else ():
        path = runs[0].folder / name
        if path.exists():
            lines += [
                f"Ours (seed {runs[0].seed}), `{name}`:",
                "",
                "```",
                path.read_text(encoding="utf-8").rstrip(),
                "```",
                "",
            ]
    for png in pngs if claim.figures else ():
        lines += [f"![{claim.reference}: {png.stem} (seed {runs[0].seed})]({link(page_dir, png)})", ""]
    return lines


def _ablation_cell(result: ReportResult, claim: Claim, ablation: str) -> str:
    verdict = result.ablation_verdicts.get(claim.name, {}).get(ablation)
    if verdict is None:
        return ""
    runs = result.jobs[job_label(claim.job, ablation)]
    return f"{verdict.status.value}; {headline_text(claim, runs)}"


def render_page(
    result: ReportResult, claims: list[Claim], sections: list[list[str]], quick: bool, seeds: Sequence[int]
) -> str:
    size = "--quick sizes" if quick else "default sizes"
    ablations = list(dict.fromkeys(a for claim in claims for a in claim.ablations))
    lines = [
        "# Reproduction report",
        "",
        (
            f"Generated by `contextweb report` (seeds {', '.join(map(str, seeds))}, {size}): every experiment of "
            "`experiments.EXPERIMENTS` is run at every seed, and each claim of the paper is checked against its "
            "summaries by the criterion written beside it (`experiments/report/claims/`). Verdicts: *reproduced*, "
            "*better* (the criterion holds and we beat the paper's own number), *not reproduced — why*, "
            "*not run: error*."
        ),
        "",
        f"**Rule over seeds:** {RULE}. Numbers are medians over the seeds, [min–max] where they vary.",
        "",
        (
            "The headline protocol is the paper's: the `hard` world (docs/world.md) and LDA documents made of the "
            "active concepts of the perceived concept webs of recorded objects (Table V). Ablations: `easy` (the "
            "easy world) and `labels` (documents made of the objects' true labels)."
        ),
        "",
        *markdown_table(
            [["claim", "verdict", "headline (median [range])", *(f"ablation `{a}`" for a in ablations)]]
            + [
                [
                    claim.name,
                    result.verdicts[claim.name].line(),
                    (f"{claim.headline[0]}: " if claim.headline else "") + headline_text(claim, result.jobs[claim.job]),
                    *(_ablation_cell(result, claim, a) for a in ablations),
                ]
                for claim in claims
            ]
        ),
        "",
        *markdown_table(
            [["job", "seeds", "CPU seconds", "status"]]
            + [
                [
                    f"`{label}`",
                    ", ".join(str(run.seed) for run in runs),
                    f"{sum(run.seconds for run in runs):.1f}",
                    next((f"not run (seed {run.seed}): {run.error}" for run in runs if run.error is not None), "ok"),
                ]
                for label, runs in result.jobs.items()
            ]
        ),
        "",
    ]
    for section in sections:
        lines += section
    return "\n".join(lines).rstrip() + "\n"
