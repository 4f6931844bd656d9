"""Fig. 9: the strength σ of contextual feedback (the ``sigma`` experiment's summary, judged)."""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, number, verdict_of

#: Fig. 9: the interval of σ depicted as maximising l̂ (Eq. 7).
PAPER_BEST_SIGMA = (0.4, 0.5)
#: §IV-D / Fig. 14: the σ of Eq. 6 the paper settles on.
PAPER_SIGMA = 0.5


def judge(summary: Summary) -> Verdict:
    sigmas, curve, accuracy = summary["sigmas"], summary["log_likelihood"], summary["overall_accuracy"]
    best = summary["best_sigma"]
    low, high = PAPER_BEST_SIGMA
    at_paper = curve[sigmas.index(PAPER_SIGMA)]
    facts = f"l̂ peaks at σ = {best} (l̂ = {max(curve):.3f})"
    leaning = "the concept web" if best > high else "the context"
    why = (
        f"l̂ peaks at σ = {best} (l̂ = {max(curve):.3f} vs {at_paper:.3f} at σ = {PAPER_SIGMA}): Eq. 6 gains by "
        f"leaning on {leaning} more than the paper did; alone, the web (σ = 1) decides {accuracy[-1]:.0%} of the "
        f"nouns and adjectives right and the context (σ = 0) {accuracy[0]:.0%}"
    )
    return verdict_of(low <= best <= high, facts, why)


def table(summary: Summary) -> Table:
    best = summary["best_sigma"]
    return [["σ", "l̂ (Eq. 7)", "l̂ with verbs", "l̂ in-context webs", "accuracy of P*"]] + [
        [
            f"**{sigma}**" if sigma == best else str(sigma),
            *(
                number(summary[key][i])
                for key in (
                    "log_likelihood",
                    "log_likelihood_with_verbs",
                    "log_likelihood_in_context_web",
                    "overall_accuracy",
                )
            ),
        ]
        for i, sigma in enumerate(summary["sigmas"])
    ]


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Fig. 9",
        title="strength of contextual feedback σ",
        job="sigma",
        paper=f"l̂ (Eq. 7) is maximal for σ in [{PAPER_BEST_SIGMA[0]}, {PAPER_BEST_SIGMA[1]}]; the paper uses "
        f"σ = {PAPER_SIGMA}.",
        criterion=f"the σ maximising l̂ lies in [{PAPER_BEST_SIGMA[0]}, {PAPER_BEST_SIGMA[1]}].",
        judge=judge,
        table=table,
        headline=("best σ", lambda s: s["best_sigma"]),
    ),
)
