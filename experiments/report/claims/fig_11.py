"""Fig. 11: Incremental-LDA stops at the right number of contexts, and Fig. 11 a–d's |C_low| and H̃
against K (the ``contexts`` experiment's summary, judged).
"""

from __future__ import annotations

from experiments.report.claim import Claim, Summary, Table, Verdict, share, verdict_of

#: Fig. 11 / §V-A: the world's contexts, found "by the |D| = 3 scenes mark", over 10 test sets.
PAPER_CONTEXTS = 3
PAPER_MIN_SCENES = 3
#: Fig. 11: share of test sets that must stop at the right K (the paper shows 10 of 10 as means ± std).
STOP_SHARE = 0.9


def _hits(summary: Summary, key: str, rule: str) -> tuple[int, int]:
    found, present = summary["stop_k"][key][rule], summary["stop_k"][key]["present"]
    return sum(f == p for f, p in zip(found, present, strict=True)), len(found)


def _paper_world_counts(summary: Summary) -> list[int]:
    return sorted(int(n) for n in summary["fig11"] if int(n) >= PAPER_MIN_SCENES)


def hits_at_paper_scenes(summary: Summary) -> float:
    """Test sets stopping at the contexts present at |D| = 3."""
    return _hits(summary, f"paper@{PAPER_MIN_SCENES}", "scenes")[0]


def judge_stop(summary: Summary) -> Verdict:
    counts = _paper_world_counts(summary)
    hits = {n: _hits(summary, f"paper@{n}", "scenes") for n in counts}
    every = {n: _hits(summary, f"paper-all@{n}", "scenes") for n in counts if f"paper-all@{n}" in summary["stop_k"]}
    missed = {f"|D| = {n}": h for n, h in hits.items() if h[0] < STOP_SHARE * h[1]}
    missed |= {f"|D| = {n} (every context present)": h for n, h in every.items() if h[0] < STOP_SHARE * h[1]}
    paper_rule = ", ".join(f"|D| = {n}: {share(*_hits(summary, f'paper@{n}', 'paper'))}" for n in counts)
    facts = "stops at the contexts present in " + ", ".join(f"{share(*h)} (|D| = {n})" for n, h in hits.items())
    if every:
        facts += "; at K = 3 where every context is present in " + ", ".join(
            f"{share(*h)} (|D| = {n})" for n, h in every.items()
        )
    why = (
        "stops at the contexts present in only "
        + ", ".join(f"{share(*h)} test sets at {where}" for where, h in missed.items())
        + f"; the paper's rule (grow while C_low ≠ ∅): {paper_rule}"
    )
    return verdict_of(bool(counts) and not missed, facts, why)


def judge_curves(summary: Summary) -> Verdict:
    counts = _paper_world_counts(summary)
    at_k = PAPER_CONTEXTS - 1
    curves = {n: summary["fig11"][str(n)] for n in counts}
    c_low = {n: curve["c_low"]["mean"][at_k] for n, curve in curves.items()}
    argmin = {n: curve["k_of_min_entropy"] for n, curve in curves.items()}
    facts = f"|C_low| = 0 and minimum H̃ at K = {PAPER_CONTEXTS} for |D| = {', '.join(map(str, counts))}"
    reasons = []
    if any(c_low.values()):
        reasons.append(
            f"mean |C_low| at K = {PAPER_CONTEXTS}: " + ", ".join(f"{c_low[n]:g} (|D| = {n})" for n in counts)
        )
    if any(k != PAPER_CONTEXTS for k in argmin.values()):
        reasons.append(
            "minimum H̃ at "
            + ", ".join(
                f"K = {argmin[n]:g} (|D| = {n}: {curves[n]['entropy']['mean'][int(argmin[n]) - 1]:.3f} vs "
                f"{curves[n]['entropy']['mean'][at_k]:.3f} nats at K = {PAPER_CONTEXTS})"
                if argmin[n] != PAPER_CONTEXTS
                else f"K = {argmin[n]} (|D| = {n})"
                for n in counts
            )
        )
    return verdict_of(bool(counts) and not reasons, facts, "; ".join(reasons))


def table_stops(summary: Summary) -> Table:
    """Per world and |D|: test sets stopping at the contexts present, by each K rule."""
    rules = ("scenes", "likelihood", "paper")
    rows = [
        [
            "world @ scenes",
            "contexts present",
            "K found (default)",
            "right (default: scene evidence)",
            "right (token birth move)",
            "right (paper rule)",
        ]
    ]
    for key, stops in summary["stop_k"].items():
        rows.append(
            [
                key,
                " ".join(map(str, stops["present"])),
                " ".join(map(str, stops["scenes"])),
                *(share(*_hits(summary, key, rule)) for rule in rules),
            ]
        )
    return rows


def table_curves(summary: Summary) -> Table:
    """Per |D|: mean ± std of |C_low| and of H̃ at each forced K."""
    ks = range(1, len(next(iter(summary["fig11"].values()))["c_low"]["mean"]) + 1)
    rows = [["scenes |D|", *(f"K={k}: |C_low|, H̃" for k in ks), "argmin H̃"]]
    for n, curves in summary["fig11"].items():
        c_low, entropy = curves["c_low"], curves["entropy"]
        cells = (
            f"{c_low['mean'][k]:g} ± {c_low['std'][k]:g}, {entropy['mean'][k]:.3f} ± {entropy['std'][k]:.3f}"
            for k in range(len(ks))
        )
        rows.append([n, *cells, str(curves["k_of_min_entropy"])])
    return rows


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="Fig. 11",
        title="Incremental-LDA stops at the right number of contexts",
        job="contexts",
        paper=f"with |D| ≥ {PAPER_MIN_SCENES} scenes Incremental-LDA stops adding contexts at K = {PAPER_CONTEXTS} "
        "(10 test sets per |D|).",
        criterion=f"for every |D| ≥ {PAPER_MIN_SCENES}, the default K rule stops at the number of contexts present "
        f"in the test set's scenes (K = {PAPER_CONTEXTS} once all are present) in ≥ {STOP_SHARE:.0%} of the test sets.",
        judge=judge_stop,
        table=table_stops,
        ablations=("easy", "labels"),
        headline=(f"right K at |D| = {PAPER_MIN_SCENES} (of 10)", hits_at_paper_scenes),
    ),
    Claim(
        reference="Fig. 11 a–d",
        title="|C_low| and H̃ against K",
        job="contexts",
        paper=f"for |D| ≥ {PAPER_MIN_SCENES}, |C_low| is positive until K = {PAPER_CONTEXTS} and 0 from there; H̃ is "
        f"lowest at K = {PAPER_CONTEXTS}.",
        criterion=f"for every |D| ≥ {PAPER_MIN_SCENES}, the mean |C_low| at K = {PAPER_CONTEXTS} is 0 and the mean H̃ "
        f"is lowest at K = {PAPER_CONTEXTS}.",
        judge=judge_curves,
        table=table_curves,
        ablations=("easy", "labels"),
        figures=False,
    ),
)
