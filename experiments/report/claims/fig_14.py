"""Fig. 14: recognition under artificial noise (the ``noise`` experiment's summary, judged)."""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, number, verdict_of
from experiments.report.claims.fig_9 import PAPER_SIGMA

#: Fig. 14's "stays accurate": the context-enhanced accuracy must stay above this at every noise level
#: (10–90 %). The paper gives no number for Fig. 14; it calls the system "quite resilient under
#: increasing artificial noise", able to "correct individual wrong predictions using the majority
#: vote", and in §V-B calls confidences "of over 50 %" "sufficient for correct decision making".
#: So: more than half of the noun and adjective decisions right at every noise level — a majority
#: of right decisions, the paper's own bar for a usable decision.
ACCURACY_FLOOR = 0.5


def in_context_at_paper_sigma(summary: Summary) -> list[float]:
    column = summary["sigmas"].index(PAPER_SIGMA)
    return [row[column] for row in summary["in_context_accuracy"]]


def lowest_in_context(summary: Summary) -> float:
    return min(in_context_at_paper_sigma(summary))


def judge(summary: Summary) -> Verdict:
    noise, perception = summary["noise_levels"], summary["perception_accuracy"]
    context = in_context_at_paper_sigma(summary)
    worse = [(q, c, p) for q, c, p in zip(noise, context, perception, strict=True) if c < p]
    low = [(q, c) for q, c in zip(noise, context, strict=True) if not c > ACCURACY_FLOOR]
    gains = [c - p for c, p in zip(context, perception, strict=True)]
    facts = (
        f"at σ = {PAPER_SIGMA}, context-enhanced accuracy ≥ prototypes' at all {len(noise)} noise levels "
        f"(gain {min(gains):+.3f} to {max(gains):+.3f}) and above {ACCURACY_FLOOR} (lowest {min(context):.3f})"
    )
    reasons = []
    if worse:
        reasons.append(
            "below the prototypes at " + ", ".join(f"noise {q:.0%} ({c:.3f} vs {p:.3f})" for q, c, p in worse)
        )
    if low:
        reasons.append(
            f"not above the floor {ACCURACY_FLOOR} at " + ", ".join(f"noise {q:.0%} ({c:.3f})" for q, c in low)
        )
    return verdict_of(not reasons, facts, f"at σ = {PAPER_SIGMA}, context-enhanced " + "; ".join(reasons))


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
        criterion=f"at σ = {PAPER_SIGMA}, the context-enhanced accuracy is ≥ the prototypes' and above "
        f"{ACCURACY_FLOOR} (a majority of right decisions, the paper's bar for a usable decision) at every noise level.",
        judge=judge,
        table=table,
        headline=("lowest in-context accuracy", lowest_in_context),
    ),
)
