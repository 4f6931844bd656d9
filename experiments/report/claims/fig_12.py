"""Fig. 12: context from the concept web against context from raw features (the ``raw-vs-web``
experiment's summary, judged).
"""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, number, scene_count, verdict_of

#: Fig. 12 / §V-B: the concept web settles "at as few as 3-5 scenes"; raw features need 50.
PAPER_WEB_SCENES = (3, 5)
PAPER_RAW_SCENES = 50
#: Fig. 12 (d): "even for the worst parameter settings" the concept web gives over 50 %.
PAPER_GRID_FLOOR = 0.5


def judge(summary: Summary) -> Verdict:
    needed = summary["scenes_to_exceed_half"]
    web = needed["concept_web"]
    raw = {name: n for name, n in needed.items() if name.startswith("raw")}
    before_raw = web is not None and all(n is None or web < n for n in raw.values())
    worst = summary["grid_worst"]["concept_web"]
    holds = web is not None and web <= PAPER_WEB_SCENES[1] and before_raw and worst > PAPER_GRID_FLOOR
    raw_text = ", ".join(f"{name.replace('_', ' ')}: {scene_count(n)}" for name, n in raw.items())
    facts = (
        f"the concept web exceeds 0.5 from {scene_count(web)} (raw — {raw_text}); its worst α–ξ score is {worst:.2f}"
    )
    return verdict_of(holds, facts, facts, better=web is not None and web < PAPER_WEB_SCENES[0])


def table(summary: Summary) -> Table:
    counts = summary["scene_counts"]
    rows = [["input", *(scene_count(n) for n in counts), "exceeds 0.5 from", "worst α–ξ score"]]
    for name, values in summary["score_by_scenes"].items():
        needed = summary["scenes_to_exceed_half"][name]
        worst = summary["grid_worst"].get(name)
        rows.append(
            [
                name.replace("_", " "),
                *(number(v, 2) for v in values),
                scene_count(needed),
                number(worst, 2),
            ]
        )
    return rows


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Fig. 12",
        title="context from the concept web vs from raw features",
        job="raw-vs-web",
        paper=f"the concept web settles at {PAPER_WEB_SCENES[0]}–{PAPER_WEB_SCENES[1]} scenes, raw features need "
        f"{PAPER_RAW_SCENES} (and at most 10 bins); the web's worst α–ξ setting stays above {PAPER_GRID_FLOOR}.",
        criterion="the concept web's mean probability of the true context exceeds 0.5 by "
        f"{PAPER_WEB_SCENES[1]} scenes and at fewer scenes than every raw input, and its worst α–ξ score exceeds "
        f"{PAPER_GRID_FLOOR}; better if it needs fewer than {PAPER_WEB_SCENES[0]} scenes.",
        judge=judge,
        table=table,
    ),
)
