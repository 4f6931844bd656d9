"""Fig. 16: pruning over random planning scenarios (the ``planning`` experiment's summary, judged)."""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, verdict_of


def judge(summary: Summary) -> Verdict:
    reduction = {context: values["reduction"] for context, values in summary["median_nodes"]["paper"].items()}
    kitchen, playroom, workshop = (reduction.get(c) for c in ("kitchen", "playroom", "workshop"))
    holds = (
        kitchen is not None
        and playroom is not None
        and workshop is not None
        and kitchen > playroom > 0
        and workshop == 0
    )
    facts = f"median reduction of the breadth-first tree over {summary['scenarios']:,} scenarios: " + ", ".join(
        f"{c} {r:.0%}" for c, r in reduction.items()
    )
    return verdict_of(holds, facts, facts)


def table(summary: Summary) -> Table:
    rows = [["mode", "context", "median nodes unpruned", "median nodes pruned", "median reduction"]]
    for mode, contexts in summary["median_nodes"].items():
        for context, values in contexts.items():
            rows.append(
                [mode, context, f"{values['unpruned']:g}", f"{values['pruned']:g}", f"{values['reduction']:.0%}"]
            )
    return rows


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Fig. 16",
        title="pruning over random scenarios",
        job="planning",
        paper="over 10,000 random scenarios the Kitchen is pruned more than the Playroom; the Workshop is not pruned.",
        criterion="in the paper's breadth-first tree, median node reduction Kitchen > Playroom > 0 and Workshop = 0.",
        judge=judge,
        table=table,
        headline=("Kitchen median reduction", lambda s: s["median_nodes"]["paper"]["kitchen"]["reduction"]),
    ),
)
