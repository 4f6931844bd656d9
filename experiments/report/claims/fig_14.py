"""Fig. 14: recognition under artificial noise (the ``noise`` experiment's summary, judged)."""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, number, verdict_of
from experiments.report.claims.fig_9 import PAPER_SIGMA


def judge(summary: Summary) -> Verdict:
    column = summary["sigmas"].index(PAPER_SIGMA)
    noise, perception = summary["noise_levels"], summary["perception_accuracy"]
    context = [row[column] for row in summary["in_context_accuracy"]]
    worse = [(q, c, p) for q, c, p in zip(noise, context, perception, strict=True) if c < p]
    gains = [c - p for c, p in zip(context, perception, strict=True)]
    facts = (
        f"at σ = {PAPER_SIGMA}, context-enhanced accuracy ≥ prototypes' at all {len(noise)} noise levels "
        f"(gain {min(gains):+.3f} to {max(gains):+.3f})"
    )
    why = f"at σ = {PAPER_SIGMA}, context-enhanced below prototypes at " + ", ".join(
        f"noise {q:.0%} ({c:.3f} vs {p:.3f})" for q, c, p in worse
    )
    return verdict_of(not worse, facts, why)


def table(summary: Summary) -> Table:
    column = summary["sigmas"].index(PAPER_SIGMA)
    rows = [["noise", "prototypes", "concept web", f"in context σ={PAPER_SIGMA}", "best σ", "in context, best σ"]]
    for i, noise in enumerate(summary["noise_levels"]):
        in_context = summary["in_context_accuracy"][i]
        rows.append(
            [
                f"{noise:.0%}",
                number(summary["perception_accuracy"][i]),
                number(summary["concept_web_accuracy"][i]),
                number(in_context[column]),
                str(summary["best_sigma_per_noise"][i]),
                number(max(in_context)),
            ]
        )
    return rows


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Fig. 14",
        title="recognition under artificial noise",
        job="noise",
        paper="context-enhanced webs stay accurate as noise (10–90 %) grows while prototype predictions degrade "
        "(15 trials).",
        criterion=f"at σ = {PAPER_SIGMA}, the context-enhanced accuracy is ≥ the prototypes' at every noise level.",
        judge=judge,
        table=table,
    ),
)
