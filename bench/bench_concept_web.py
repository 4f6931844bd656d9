"""Speed of the concept web (``python -m bench.bench_concept_web [--quick]``).

The web is the paper's: 29 concepts over 19 variables, learned from the 45
training objects of Tables I–II (``sim.world``). Perceptions are noisy readings
of the 60 objects (truth 0.8, rest 0.2, Gaussian noise 0.1, every behaviour
applied), so that our loopy BP and the reference solve the very same MRF.

- ours: median wall time of one ``ConceptWeb.infer`` call (sum-product marginals
  and max-product MAP, validation included), and per object in ``infer_many``;
- reference, measured in the same run: pgmpy 1.1's ``BeliefPropagation`` (exact
  junction-tree inference) on the same graph and factors, split into building the
  ``DiscreteMarkovNetwork`` and querying every variable's marginal;
- accuracy: the largest |P_ours(c) - P_exact(c)| over the reference's perceptions,
  and for one hard case (nouns perceived, every verb sent as a neutral 0.5).

The paper reports 1,395 ms for the convergence of one concept web. Writes
``bench/results/concept_web.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

from bench import RESULTS
from core.concept_web import ConceptWeb
from core.concept_web.reference import exact_variable_marginals, pgmpy_network
from core.paper_timings import WEB_CONVERGENCE_MS
from core.vocabulary import paper_vocabulary
from sim.world import TRAIN, WorldConfig, make_objects

PAPER_MILLISECONDS = WEB_CONVERGENCE_MS[0]


def perceptions_of(objects: list[list[str]], rng: np.random.Generator) -> np.ndarray:
    """One noisy perception per object: its concepts near 0.8, the others near 0.2."""
    concepts = paper_vocabulary().concepts
    truth = np.array([np.isin(concepts, names) for names in objects])
    return np.clip(np.where(truth, 0.8, 0.2) + rng.normal(0.0, 0.1, truth.shape), 0.0, 1.0)


def time_calls(work: Callable[[np.ndarray], object], inputs: np.ndarray, calls: int) -> list[float]:
    """Wall time in µs of ``calls`` calls of ``work``, cycling through ``inputs``."""
    times = []
    for i in range(calls):
        start = time.perf_counter_ns()
        work(inputs[i % len(inputs)])
        times.append((time.perf_counter_ns() - start) / 1e3)
    return times


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer calls and one reference run")
    args = parser.parse_args(sys.argv[1:])
    calls, reference_runs = (300, 1) if args.quick else (3000, 3)

    vocabulary = paper_vocabulary()
    world_objects = make_objects(WorldConfig.paper(), seed=0)
    objects = [[*o.concepts, *o.behaviours] for o in world_objects]
    training = [names for names, o in zip(objects, world_objects) if o.split == TRAIN]
    web = ConceptWeb.fit(vocabulary, training)
    perceptions = perceptions_of(objects, np.random.default_rng(0))

    web.infer_many(perceptions)  # compile / load the kernels before timing
    ours = time_calls(web.infer, perceptions, calls)
    batch = np.tile(perceptions, (max(1, calls // len(perceptions)), 1))
    start = time.perf_counter()
    batch_results = web.infer_many(batch)
    per_object_in_batch = (time.perf_counter() - start) / len(batch) * 1e6

    hard = np.full(len(vocabulary), 0.5)
    hard[: len(vocabulary.nouns)] = 0.05
    hard[vocabulary.index("cup")] = 0.95
    build, query, errors = [], [], []
    for perception in [*perceptions[:: max(1, len(perceptions) // reference_runs)][:reference_runs], hard]:
        potentials = web.potentials(perception)
        start = time.perf_counter()
        network = pgmpy_network(potentials)
        middle = time.perf_counter()
        exact = exact_variable_marginals(potentials, network)
        end = time.perf_counter()
        build.append((middle - start) * 1e6)
        query.append((end - middle) * 1e6)
        errors.append(
            float(np.abs(web.infer(perception).probabilities - exact[web.concept_variable, web.concept_state]).max())
        )

    ours_median = statistics.median(ours)
    pgmpy_median = statistics.median(b + q for b, q in zip(build, query))
    result = {
        "web": {
            "concepts": len(vocabulary.concepts),
            "variables": len(web.variable_names),
            "variable_edges": len(web.potentials(hard).variable_edges),
            "concept_edges": len(web.edges),
            "training_objects": web.n_objects,
            "beta": web.beta,
        },
        "calls": calls,
        "ours_median_us": ours_median,
        "ours_p10_us": float(np.percentile(ours, 10)),
        "ours_p90_us": float(np.percentile(ours, 90)),
        "ours_infer_many_per_object_us": per_object_in_batch,
        "iterations_median": statistics.median(r.iterations for r in batch_results),
        "all_converged": all(r.converged for r in batch_results),
        "pgmpy_runs": len(build),
        "pgmpy_median_us": pgmpy_median,
        "pgmpy_build_median_us": statistics.median(build),
        "pgmpy_query_median_us": statistics.median(query),
        "speed_ratio_pgmpy_over_ours": pgmpy_median / ours_median,
        "max_abs_error_vs_exact_realistic": max(errors[:-1]),
        "max_abs_error_vs_exact_neutral_verbs": errors[-1],
        "paper_ms": PAPER_MILLISECONDS,
        "speed_ratio_paper_over_ours": PAPER_MILLISECONDS * 1e3 / ours_median,
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "concept_web.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    lines = {
        "ours (infer, one object)": f"{ours_median:10.1f} µs median (p10 {result['ours_p10_us']:.1f}, "
        f"p90 {result['ours_p90_us']:.1f})",
        "ours (infer_many)": f"{per_object_in_batch:10.1f} µs mean per object",
        "pgmpy BeliefPropagation": f"{pgmpy_median:10.1f} µs median of {len(build)} "
        f"(build {result['pgmpy_build_median_us']:.0f}, query {result['pgmpy_query_median_us']:.0f})",
        "speed ratio pgmpy / ours": f"{result['speed_ratio_pgmpy_over_ours']:10.0f}x "
        f"(paper's 1,395 ms / ours: {result['speed_ratio_paper_over_ours']:.0f}x)",
        "max |ours - exact|": f"{result['max_abs_error_vs_exact_realistic']:.4f} realistic, "
        f"{errors[-1]:.4f} neutral verbs",
    }
    for name, text in lines.items():
        print(f"{name:>24}: {text}")
    return result


if __name__ == "__main__":
    main()
