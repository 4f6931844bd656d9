"""§V-F: the running times of context detection and of a concept web's convergence (the report's own
``running-times`` job: read from ``python -m bench``'s results, else measured here).
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from core.concept_web import ConceptWeb
from core.context import IncrementalLDA
from core.paper_timings import CONTEXT_DETECTION_MS, WEB_CONVERGENCE_MS
from core.vocabulary import paper_vocabulary
from experiments.report.claim import Claim, Summary, Table, Verdict, verdict_of
from sim.world import WorldConfig, generate_scenes, make_objects

#: §V-F: mean ± standard deviation over 10 runs (non-optimised code, i5 desktop), milliseconds.
PAPER_DETECTION_MS = CONTEXT_DETECTION_MS
PAPER_WEB_MS = WEB_CONVERGENCE_MS
#: §V-F: standard deviations of the paper's runs that separate "as fast" from faster or slower.
TIME_STDS = 3.0

#: The report's own job (not an experiment): §V-F's running times.
RUNNING_TIMES = "running-times"
#: Where ``python -m bench`` writes its results.
BENCH_RESULTS = Path(__file__).resolve().parents[3] / "bench" / "results"
#: Calls timed per operation when the report measures the running times itself.
TIMED_CALLS = 100


def _median_ms(work: Callable[[int], object], calls: int) -> float:
    times = []
    for i in range(calls):
        start = time.perf_counter()
        work(i)
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def measure_running_times(seed: int, calls: int = TIMED_CALLS) -> Summary:
    """Median milliseconds of context detection (``IncrementalLDA.infer_scene`` on 5-object scenes,
    model fitted on 50 pure scenes) and of one concept web's convergence (``ConceptWeb.infer`` on
    noisy perceptions: each object's concepts near 0.8, the others near 0.2), as ``bench`` measures them."""
    config = WorldConfig.paper()
    model = IncrementalLDA(seed=seed).fit([scene.tokens() for scene in generate_scenes(config, 50, seed)])
    scenes = [scene.tokens() for scene in generate_scenes(config, calls, seed + 1, objects_per_scene=5)]
    model.infer_scene(scenes[0])
    vocabulary = paper_vocabulary()
    configurations = [[*obj.concepts, *obj.behaviours] for obj in make_objects(config, seed)]
    web = ConceptWeb.fit(vocabulary, configurations)
    truth = np.array([np.isin(vocabulary.concepts, names) for names in configurations])
    rng = np.random.default_rng(seed)
    perceptions = np.clip(np.where(truth, 0.8, 0.2) + rng.normal(0.0, 0.1, truth.shape), 0.0, 1.0)
    web.infer(perceptions[0])
    return {
        "context_detection_ms": _median_ms(lambda i: model.infer_scene(scenes[i], seed=i), calls),
        "web_convergence_ms": _median_ms(lambda i: web.infer(perceptions[i % len(perceptions)]), calls),
        "source": f"measured by the report (median of {calls} calls)",
    }


def _display(path: Path) -> str:
    """``path`` relative to the repository when inside it (the committed page names no machine's folders)."""
    root = BENCH_RESULTS.parents[1]
    return path.resolve().relative_to(root).as_posix() if path.resolve().is_relative_to(root) else str(path)


def running_times(bench_results: Path, seed: int) -> Summary:
    """§V-F's two times from ``python -m bench``'s results if both are there, else measured now."""
    try:
        context = json.loads((bench_results / "context.json").read_text(encoding="utf-8"))
        web = json.loads((bench_results / "concept_web.json").read_text(encoding="utf-8"))
        return {
            "context_detection_ms": context["detection_5_objects"]["ours_median_us"] / 1e3,
            "web_convergence_ms": web["ours_median_us"] / 1e3,
            "source": f"{_display(bench_results)}/context.json and concept_web.json (python -m bench)",
        }
    except (OSError, KeyError, TypeError, ValueError):
        return measure_running_times(seed)


_TIMES = {"context_detection_ms": PAPER_DETECTION_MS, "web_convergence_ms": PAPER_WEB_MS}


def judge(summary: Summary) -> Verdict:
    ratios = {key: mean / summary[key] for key, (mean, _) in _TIMES.items()}
    slower = [key for key, (mean, std) in _TIMES.items() if summary[key] > mean + TIME_STDS * std]
    faster = all(summary[key] < mean - TIME_STDS * std for key, (mean, std) in _TIMES.items())
    text = ", ".join(
        f"{key.removesuffix('_ms').replace('_', ' ')} {summary[key]:.3f} ms vs {_TIMES[key][0]} ms "
        f"({ratios[key]:,.0f}× {'faster' if ratios[key] >= 1 else 'slower'})"
        for key in _TIMES
    )
    return verdict_of(not slower, text, text, better=faster)


def table(summary: Summary) -> Table:
    return (
        [["operation", "paper (mean ± std, i5 desktop)", "ours (median)"]]
        + [
            [key.removesuffix("_ms").replace("_", " "), f"{mean} ± {std} ms", f"{summary[key]:.3f} ms"]
            for key, (mean, std) in _TIMES.items()
        ]
        + [["source", "", summary["source"]]]
    )


CLAIMS: tuple[Claim, ...] = (
    Claim(
        reference="§V-F",
        title="running times",
        job=RUNNING_TIMES,
        paper=f"context detection {PAPER_DETECTION_MS[0]} ± {PAPER_DETECTION_MS[1]} ms, concept-web convergence "
        f"{PAPER_WEB_MS[0]} ± {PAPER_WEB_MS[1]} ms (10 runs, i5 desktop).",
        criterion=f"neither median exceeds the paper's mean + {TIME_STDS:g} std; better if both are below "
        f"mean − {TIME_STDS:g} std.",
        judge=judge,
        table=table,
        headline=("context detection ms", lambda s: s["context_detection_ms"]),
    ),
)
