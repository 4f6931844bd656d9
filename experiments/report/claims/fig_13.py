"""Table VII / Fig. 13: object recognition by perception, the concept web and in context (the
``recognition`` experiment's summary, judged).

The criterion is the paper's words (§V-D, Table VII, Fig. 13): the concept web "can correct certain
mistakes of the perception-only assessment, while also boosting confidences"; context then gives "an
improvement of performance" and lets the system "revise and correct its previous judgments". So, on
the mean accuracy over nouns and adjectives, the web is strictly above perception and in context
strictly above the web (a tie is no improvement); context corrects more nouns than it breaks (counted
against perception alone); and the mean probability of the correct noun rises from perception to the
web to in context (Table VII's confidences rise to ≈ 100 %).

"In context" is the paper's Eq. 6 (a linear pool, σ = 0.5); the verdict is on it. The logarithmic
pool (``in_context_log``, docs/feedback.md "The hard world") is the documented improvement, judged by
the same criterion beside it: the verdict line says whether it would pass.
"""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, number, verdict_of

#: Table VII: perception-only confidence of the top noun of the three example objects.
PAPER_TABLE_VII_NOUN_CONFIDENCES = (0.43, 0.29, 0.26)

_PAPER_CONTEXT, _LOG_CONTEXT = "in_context", "in_context_log"
_RECOGNITION_METHODS = ("perception", "concept_web", _PAPER_CONTEXT, _LOG_CONTEXT)
_NAMES = {"perception": "perception", "concept_web": "web", _PAPER_CONTEXT: "Eq. 6", _LOG_CONTEXT: "log pool"}


def _failures(summary: Summary, context: str) -> list[str]:
    """What breaks the criterion with ``context`` as the in-context method (empty: it holds)."""
    accuracy = {m: summary[m]["overall_accuracy"] for m in ("perception", "concept_web", context)}
    truth = {m: summary["noun_confidence"][m]["mean_true_noun"] for m in ("perception", "concept_web", context)}
    changes = summary["noun_changes"][context]
    failures = []
    if not accuracy["concept_web"] > accuracy["perception"]:
        failures.append(f"web accuracy {accuracy['concept_web']:.3f} ≯ perception {accuracy['perception']:.3f}")
    if not accuracy[context] > accuracy["concept_web"]:
        failures.append(f"{_NAMES[context]} accuracy {accuracy[context]:.3f} ≯ web {accuracy['concept_web']:.3f}")
    if not changes["corrected"] > changes["broken"]:
        failures.append(
            f"{_NAMES[context]} corrects {number(changes['corrected'], 1)} nouns and breaks "
            f"{number(changes['broken'], 1)}"
        )
    if not truth["concept_web"] > truth["perception"]:
        failures.append(f"P(true noun) web {truth['concept_web']:.3f} ≯ perception {truth['perception']:.3f}")
    if not truth[context] > truth["concept_web"]:
        failures.append(f"P(true noun) {_NAMES[context]} {truth[context]:.3f} ≯ web {truth['concept_web']:.3f}")
    return failures


def judge(summary: Summary) -> Verdict:
    accuracy = {m: summary[m]["overall_accuracy"] for m in _RECOGNITION_METHODS if m in summary}
    truth = {m: v["mean_true_noun"] for m, v in summary["noun_confidence"].items()}
    changes = summary["noun_changes"][_PAPER_CONTEXT]
    paper, log = _failures(summary, _PAPER_CONTEXT), _failures(summary, _LOG_CONTEXT)
    facts = (
        f"mean accuracy perception {accuracy['perception']:.3f} < web {accuracy['concept_web']:.3f} < "
        f"Eq. 6 {accuracy[_PAPER_CONTEXT]:.3f}; Eq. 6 corrects {number(changes['corrected'], 1)} nouns, breaks "
        f"{number(changes['broken'], 1)}; P(true noun) {truth['perception']:.3f} → {truth['concept_web']:.3f} → "
        f"{truth[_PAPER_CONTEXT]:.3f}"
    )
    log_text = "the log pool passes too" if not log else "the log pool fails too: " + "; ".join(log)
    if not paper:
        return verdict_of(True, f"{facts}; {log_text}", "")
    log_text = (
        f"the log pool would pass (accuracy {accuracy[_LOG_CONTEXT]:.3f}, P(true noun) {truth[_LOG_CONTEXT]:.3f})"
        if not log
        else "the log pool would not pass either: " + "; ".join(log)
    )
    return verdict_of(False, facts, "Eq. 6 (the paper's rule): " + "; ".join(paper) + f"; {log_text}")


def gain(summary: Summary) -> float:
    """Eq. 6's overall accuracy minus perception's."""
    return float(summary[_PAPER_CONTEXT]["overall_accuracy"] - summary["perception"]["overall_accuracy"])


def table(summary: Summary) -> Table:
    rows = [
        [
            "method",
            "nouns",
            "adjectives",
            "nouns + adjectives",
            "mean P(true noun)",
            "top noun < 0.5",
            "nouns corrected / broken",
        ]
    ]
    for method in (m for m in _RECOGNITION_METHODS if m in summary):
        confidence = summary["noun_confidence"][method]
        changes = summary["noun_changes"].get(method)
        rows.append(
            [
                method.replace("_", " ") + (" (Eq. 6, the paper's)" if method == _PAPER_CONTEXT else ""),
                *(number(summary[method][key]) for key in ("noun_accuracy", "adjective_accuracy", "overall_accuracy")),
                number(confidence["mean_true_noun"]),
                f"{confidence['share_top_below_half']:.0%}",
                "—" if changes is None else f"{changes['corrected']:g} / {changes['broken']:g}",
            ]
        )
    return rows


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Table VII / Fig. 13",
        title="object recognition: perception, concept web, in context",
        job="recognition",
        paper="the concept web corrects some perception errors and raises confidences to ~100 %; context improves "
        "further and corrects judgments over the 15 test objects (Table VII: perception-only top-noun confidences "
        + ", ".join(f"{c:.0%}" for c in PAPER_TABLE_VII_NOUN_CONFIDENCES)
        + ").",
        criterion="mean accuracy over nouns and adjectives: concept web > perception and in context (Eq. 6, σ = 0.5) > "
        "concept web, strictly; in context corrects more nouns than it breaks (against perception); the mean "
        "probability of the true noun rises: perception < web < in context. The log pool is judged beside it.",
        judge=judge,
        table=table,
        texts=("table_vii.txt",),
        ablations=("easy", "labels"),
        headline=("Eq. 6 − perception accuracy", gain),
    ),
)
