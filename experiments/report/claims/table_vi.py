"""Table VI: the context of pure and mixed scenes (the ``mixed`` experiment's summary, judged)."""

from __future__ import annotations

from typing import Any

import numpy as np

from experiments.report.claim import Claim, Summary, Table, Verdict, number, verdict_of
from sim.world import table_vi_scenes


def _paper_worst_error() -> float:
    """The paper's own worst |predicted − true| proportion in Table VI (0.071: playroom+workshop's
    Workshop, 26.23 % for 1/3), from the paper's data (core/data/paper_world.json)."""
    return max(
        abs(spec.paper_prediction.get(context, 0.0) - spec.mixture.get(context, 0.0))
        for spec in table_vi_scenes()
        for context in {*spec.mixture, *spec.paper_prediction}
    )


#: Table VI: largest |predicted − true| proportion accepted: the paper's own worst error (issue 15:
#: as strict as the paper's table, which is the only evidence of what the paper's model achieves).
#: Proportions are by objects while LDA sees tokens; the table lists both.
TABLE_VI_TOLERANCE = round(_paper_worst_error(), 3)


def _rows(summary: Summary) -> list[dict[str, Any]]:
    return [
        {
            "scene": scene,
            "context": context,
            "true": values["true"].get(context, 0.0),
            "tokens": values["true_by_tokens"].get(context, 0.0),
            "paper": values["paper"].get(context, 0.0),
            "ours": ours,
            "std": values["ours_std"][context],
        }
        for scene, values in summary["scenes"].items()
        for context, ours in values["ours"].items()
    ]


def judge(summary: Summary) -> Verdict:
    rows = _rows(summary)
    errors = [abs(r["ours"] - r["true"]) for r in rows]
    ours_mean, paper_mean = float(np.mean(errors)), float(np.mean([abs(r["paper"] - r["true"]) for r in rows]))
    worst = rows[int(np.argmax(errors))]
    misses = [r for r, e in zip(rows, errors, strict=True) if e > TABLE_VI_TOLERANCE]
    facts = (
        f"every proportion within {max(errors):.2f} of the truth; mean |error| {ours_mean:.3f} "
        f"(the paper's own predictions: {paper_mean:.3f})"
    )
    why = (
        f"{len(misses)} of {len(rows)} proportions off by more than {TABLE_VI_TOLERANCE}, worst "
        f"{worst['scene']} / {worst['context']}: {worst['ours']:.2f} ± {worst['std']:.2f} vs {worst['true']:.2f} "
        f"by objects ({worst['tokens']:.2f} by tokens, which LDA sees); mean |error| {ours_mean:.3f} "
        f"vs the paper's {paper_mean:.3f}"
    )
    return verdict_of(not misses, facts, why, better=ours_mean < paper_mean)


def worst_error(summary: Summary) -> float:
    return max(abs(r["ours"] - r["true"]) for r in _rows(summary))


def table(summary: Summary) -> Table:
    header = ["scene", "context", "true (objects)", "true (tokens)", "paper", "ours (mean ± std)"]
    return [header] + [
        [
            r["scene"],
            r["context"],
            number(r["true"], 2),
            number(r["tokens"], 2),
            number(r["paper"], 4),
            f"{r['ours']:.4f} ± {r['std']:.4f}",
        ]
        for r in _rows(summary)
    ]


def _paper_predictions() -> str:
    """Table VI's mixed-scene predictions, from the paper's data (core/data/paper_world.json)."""
    mixed = [spec for spec in table_vi_scenes() if len(spec.mixture) > 1]
    return "; ".join(
        f"{spec.name}: " + ", ".join(f"{context} {p:.2%}" for context, p in spec.paper_prediction.items())
        for spec in mixed
    )


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Table VI",
        title="context of pure and mixed scenes",
        job="mixed",
        paper=f"pure scenes: 100 % their context; mixed scenes: {_paper_predictions()}.",
        criterion=f"every predicted proportion is within {TABLE_VI_TOLERANCE} (the paper's own worst error) of the "
        "true one (by objects); better if the mean |error| is also below the paper's own.",
        judge=judge,
        table=table,
        ablations=("easy", "labels"),
        headline=("worst |error|", worst_error),
    ),
)
