"""Fig. 15: the planning trees of the paper's two canonical scenarios (the ``planning`` experiment's
summary, judged).
"""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, verdict_of

#: Fig. 15 / §V-E: nodes of the breadth-first trees: 13 behaviours unpruned, 5 in the Kitchen, 9 in the Playroom.
PAPER_FIG_15_NODES = {"unpruned_cup_8_to_5": 2380, "kitchen_cup_8_to_5": 156, "playroom_ball_7_to_1": 820}


def judge(summary: Summary) -> Verdict:
    ours = summary["fig_15_paper_counts"]
    text = ", ".join(f"{ours[name]:,} (paper {count:,})" for name, count in PAPER_FIG_15_NODES.items())
    return verdict_of(
        all(ours[name] == count for name, count in PAPER_FIG_15_NODES.items()), f"nodes {text}", f"nodes {text}"
    )


def table(summary: Summary) -> Table:
    return (
        [["scenario", "paper", "ours"]]
        + [
            [name.replace("_", " "), f"{count:,}", f"{summary['fig_15_paper_counts'][name]:,}"]
            for name, count in PAPER_FIG_15_NODES.items()
        ]
        + [
            [f"behaviours kept in the {context}", "", ", ".join(kept)]
            for context, kept in summary["kept_behaviours"].items()
        ]
    )


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Fig. 15",
        title="planning trees of the two canonical scenarios",
        job="planning",
        paper=", ".join(f"{count:,}" for count in PAPER_FIG_15_NODES.values())
        + " nodes (cup 8 → 5 unpruned and in the Kitchen, ball 7 → 1 in the Playroom).",
        criterion="our breadth-first trees have exactly these node counts.",
        judge=judge,
        table=table,
        headline=("Kitchen cup 8 → 5 nodes", lambda s: s["fig_15_paper_counts"]["kitchen_cup_8_to_5"]),
        figures=False,
    ),
)
