"""Speed of Incremental-LDA (``python -m bench.bench_context [--quick]``).

- **Sampler throughput** (tokens × sweeps per second) of our collapsed Gibbs
  sweep against tomotopy's ``LDAModel`` (``workers=1``, priors fixed:
  ``optim_interval=0``) and the ``lda`` package, on the same synthetic corpora
  drawn from an LDA generative model: a small-vocabulary one like the paper's
  (29 concepts, K = 3, scenes of 20–40 tokens), a medium one (500 words, K = 20,
  documents of 50–100 tokens) and a large one (2,000 words, K = 50, documents of
  100 tokens). Ours with each sweep kernel (``LDAState.sweep(kernel=...)``: dense,
  lanes, sparse) and with the one :func:`core.context.lda.sweep_kernel` chooses
  for the corpus's K. Initialisation is excluded: tomotopy is timed after
  ``train(0)``, ``lda`` as the difference between two fits of different lengths,
  ours after a first sweep. Ours (each kernel) and tomotopy are timed in turn,
  ``--repeats`` times (each chain goes on from where it was), and each figure is the
  median over the repeats, each ratio the median of the repeats' ratios: by wall
  clock, and by CPU time (which leaves out the time other processes held this
  shared machine's cores), with the CPU-time ratio's range over the repeats.
- **Kernel crossover**: the three sweep kernels on one corpus shape (1,000 words,
  documents of 50–100 tokens) for K from 8 to 600, after 20 dense sweeps, each
  kernel's best of 7 single sweeps by CPU time, interleaved: where
  ``sweep_kernel``'s thresholds come from.
- **Context detection** of a 5-object scene of the paper's world
  (``IncrementalLDA.infer_scene``, fold-in with its default sweeps) by a model
  fitted on 50 scenes, median over many calls, against the paper's 209.82 ms and
  against tomotopy's ``infer`` on the same scenes: with a new seed per call, and with
  one seed for every call, as the service calls it (``seed=model.seed``), whose random
  numbers are then memoised (:class:`core.context.lda.SeededUniforms`).
- **Online update** (``learn_scene``) with 1,000 and with 100,000 scenes already
  learned: median (the usual update) and mean (with the periodic growth checks,
  amortised). The two models are built by Algorithm 1 (K = 3) with the default
  hyperparameters, as the service runs them, then learn the same new scenes,
  interleaved; the ratio of medians must stay below 1.5. (Built with 5 sweeps, as
  before 2026-12-07, the fit had not converged: the growth checks of the first
  updates then opened contexts the world does not have, K 4 at 1,000 scenes and 6 at
  100,000, which slowed every later update and added checks to the mean.)
  A copy of each model learns the first new scenes before timing, so that the kernels
  its updates call are loaded (a kernel's first call loads it from numba's cache, ≈ 30
  ms, otherwise counted in one update and in the mean). Times by wall clock and by this
  process's CPU time (which leaves out the time other processes held the cores: on a
  loaded machine, preemptions of a few ms land in a few updates and in the wall mean),
  with the growth checks run and K after.

Writes ``bench/results/context.json``.
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import logging
import os
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import lda
import numpy as np
import tomotopy as tp

from bench import RESULTS
from core.context import IncrementalLDA, LDAState
from core.context.lda import SWEEP_KERNELS, sweep_kernel
from core.paper_timings import CONTEXT_DETECTION_MS
from sim.world import WorldConfig, generate_scenes

PAPER_DETECTION_MS = CONTEXT_DETECTION_MS[0]
WARM_UPDATES = 3
ALPHA, XI = 0.1, 0.1


def synthetic_corpus(
    n_docs: int, vocab_size: int, n_topics: int, length: tuple[int, int], seed: int
) -> list[np.ndarray]:
    """Documents drawn from LDA's generative model (sparse topics, α = 0.1 per document)."""
    rng = np.random.default_rng(seed)
    cumulative = np.cumsum(rng.dirichlet(np.full(vocab_size, 0.05), size=n_topics), axis=1)
    docs = []
    for _ in range(n_docs):
        theta = rng.dirichlet(np.full(n_topics, ALPHA))
        z = rng.choice(n_topics, size=int(rng.integers(length[0], length[1] + 1)), p=theta)
        words = np.empty(z.shape[0], dtype=np.int32)
        for k in np.unique(z):
            words[z == k] = np.searchsorted(cumulative[k], rng.random(int((z == k).sum())) * cumulative[k, -1])
        docs.append(words)
    return docs


def timed(work: Callable[[], object]) -> tuple[float, float]:
    """Seconds ``work()`` took: wall clock, and CPU time of this process (all its threads). On
    a shared machine the CPU time leaves out the time other processes held the cores."""
    wall, cpu = time.perf_counter(), time.process_time()
    work()
    return time.perf_counter() - wall, time.process_time() - cpu


def ours_state(docs: list[np.ndarray], vocab_size: int, n_topics: int) -> tuple[LDAState, np.random.Generator]:
    """Our chain on ``docs``, every z drawn uniformly, and its generator."""
    words = np.concatenate(docs)
    offsets = np.concatenate([[0], np.cumsum([len(d) for d in docs])]).astype(np.int32)
    state = LDAState.from_arrays(ALPHA, XI, vocab_size, n_topics, words, np.zeros_like(words), offsets)
    rng = np.random.default_rng(0)
    state.initialize_randomly(rng)
    return state, rng


def tomotopy_model(docs: list[np.ndarray], n_topics: int) -> tp.LDAModel:
    """tomotopy's chain on ``docs``, initialised (``train(0)``), priors fixed."""
    model = tp.LDAModel(k=n_topics, alpha=ALPHA, eta=XI, seed=0)
    for doc in docs:
        model.add_doc([f"w{w}" for w in doc])
    model.optim_interval = 0
    model.train(0, workers=1)
    return model


def sampler_throughput(
    docs: list[np.ndarray], vocab_size: int, n_topics: int, sweeps: int, repeats: int
) -> dict[str, list[tuple[float, float]]]:
    """Tokens × sweeps per second (wall clock, CPU time) of ``sweeps`` sweeps of each of our kernels
    and of tomotopy (``workers=1``), timed in turn ``repeats`` times, by kernel and ``"tomotopy"``."""
    work = sum(len(d) for d in docs) * sweeps
    chains = {kernel: ours_state(docs, vocab_size, n_topics) for kernel in SWEEP_KERNELS}
    for kernel, (state, rng) in chains.items():
        state.sweep(rng, kernel=kernel)
    model = tomotopy_model(docs, n_topics)
    runs: dict[str, list[tuple[float, float]]] = {name: [] for name in [*SWEEP_KERNELS, "tomotopy"]}
    for _ in range(repeats):
        for kernel, (state, rng) in chains.items():
            wall, cpu = timed(functools.partial(state.sweep, rng, sweeps, kernel=kernel))
            runs[kernel].append((work / wall, work / cpu))
        wall, cpu = timed(functools.partial(model.train, sweeps, workers=1))
        runs["tomotopy"].append((work / wall, work / cpu))
    return runs


def throughput_row(
    runs: dict[str, list[tuple[float, float]]], chosen: str, tokens: int, lda_package: float
) -> dict[str, Any]:
    """Medians over the repeats of each throughput and of each ratio to tomotopy in the same repeat."""
    tomotopy = runs["tomotopy"]

    def ratios(kernel: str, clock: int) -> list[float]:
        return [ours[clock] / reference[clock] for ours, reference in zip(runs[kernel], tomotopy, strict=True)]

    def median(kernel: str, clock: int) -> float:
        return statistics.median(run[clock] for run in runs[kernel])

    chosen_cpu = ratios(chosen, 1)
    return {
        "tokens": tokens,
        "repeats": len(tomotopy),
        "kernel": chosen,
        "ours_tokens_sweeps_per_s": median(chosen, 0),
        **{f"{kernel}_tokens_sweeps_per_s": median(kernel, 0) for kernel in SWEEP_KERNELS},
        **{f"ratio_{kernel}_over_tomotopy": statistics.median(ratios(kernel, 0)) for kernel in SWEEP_KERNELS},
        **{f"ratio_{kernel}_over_tomotopy_cpu_time": statistics.median(ratios(kernel, 1)) for kernel in SWEEP_KERNELS},
        "tomotopy_tokens_sweeps_per_s": median("tomotopy", 0),
        "tomotopy_tokens_sweeps_per_s_cpu_time": median("tomotopy", 1),
        "lda_package_tokens_sweeps_per_s": lda_package,
        "ratio_ours_over_tomotopy": statistics.median(ratios(chosen, 0)),
        "ratio_ours_over_tomotopy_cpu_time": statistics.median(chosen_cpu),
        "ratio_ours_over_tomotopy_cpu_time_min": min(chosen_cpu),
        "ratio_ours_over_tomotopy_cpu_time_max": max(chosen_cpu),
        "ratio_ours_over_lda_package": median(chosen, 0) / lda_package,
    }


def lda_package_throughput(docs: list[np.ndarray], vocab_size: int, n_topics: int, sweeps: int) -> float:
    counts = np.zeros((len(docs), vocab_size), dtype=np.int64)
    for d, doc in enumerate(docs):
        np.add.at(counts[d], doc, 1)

    def fit(iterations: int) -> float:
        start = time.perf_counter()
        lda.LDA(n_topics=n_topics, n_iter=iterations, alpha=ALPHA, eta=XI, random_state=0, refresh=10**9).fit(counts)
        return time.perf_counter() - start

    short, long = fit(sweeps), fit(2 * sweeps)
    return sum(len(d) for d in docs) * sweeps / (long - short) if long > short else float("nan")


def kernel_crossover(contexts: tuple[int, ...], n_docs: int, vocab_size: int = 1_000) -> dict[str, dict[str, Any]]:
    """Tokens per CPU second of one sweep with each kernel, from the same state, for each K."""
    rows: dict[str, dict[str, Any]] = {}
    for n_topics in contexts:
        docs = synthetic_corpus(n_docs, vocab_size, n_topics, (50, 100), 5)
        words = np.concatenate(docs)
        offsets = np.concatenate([[0], np.cumsum([len(d) for d in docs])]).astype(np.int32)
        start = LDAState.from_arrays(ALPHA, XI, vocab_size, n_topics, words, np.zeros_like(words), offsets)
        rng = np.random.default_rng(0)
        start.initialize_randomly(rng)
        start.sweep(rng, 20, kernel="dense")
        states = {
            kernel: LDAState.from_arrays(ALPHA, XI, vocab_size, n_topics, words, start.assignments.copy(), offsets)
            for kernel in SWEEP_KERNELS
        }
        best = dict.fromkeys(SWEEP_KERNELS, float("inf"))
        for _ in range(7):
            for kernel, state in states.items():
                best[kernel] = min(best[kernel], timed(functools.partial(state.sweep, rng, kernel=kernel))[1])
        rows[str(n_topics)] = {kernel: words.shape[0] / seconds for kernel, seconds in best.items()}
        rows[str(n_topics)]["chosen"] = sweep_kernel(n_topics)
    return rows


def median_us(work: Callable[[int], object], calls: int) -> float:
    times = []
    for i in range(calls):
        start = time.perf_counter_ns()
        work(i)
        times.append((time.perf_counter_ns() - start) / 1e3)
    return statistics.median(times)


def detection(calls: int) -> dict[str, float]:
    config = WorldConfig.paper()
    training = [scene.tokens() for scene in generate_scenes(config, 50, 1)]
    model = IncrementalLDA(seed=0).fit(training)
    scenes = [scene.tokens() for scene in generate_scenes(config, 50, 2, objects_per_scene=5)]
    model.infer_scene(scenes[0])
    ours = median_us(lambda i: model.infer_scene(scenes[i % len(scenes)], seed=i), calls)
    ours_one_seed = median_us(lambda i: model.infer_scene(scenes[i % len(scenes)], seed=0), calls)
    reference = tp.LDAModel(k=model.n_contexts, alpha=ALPHA, eta=XI, seed=0)
    for scene in training:
        reference.add_doc(scene)
    reference.optim_interval = 0
    reference.train(200, workers=1)
    iterations = model.hyperparameters.sampler.inference_sweeps
    documents = [reference.make_doc(scene) for scene in scenes]
    tomotopy = median_us(
        lambda i: reference.infer(documents[i % len(documents)], iterations=iterations, workers=1), calls
    )
    return {
        "scene_tokens_mean": float(np.mean([len(s) for s in scenes])),
        "ours_median_us": ours,
        "ours_one_seed_median_us": ours_one_seed,
        "speed_ratio_tomotopy_over_ours_one_seed": tomotopy / ours_one_seed,
        "tomotopy_infer_median_us": tomotopy,
        "paper_ms": PAPER_DETECTION_MS,
        "speed_ratio_paper_over_ours": PAPER_DETECTION_MS * 1e3 / ours,
        "speed_ratio_tomotopy_over_ours": tomotopy / ours,
    }


def online(sizes: tuple[int, ...], updates: int) -> dict[str, dict[str, float]]:
    """learn_scene times of models holding ``sizes`` scenes, the same new scenes given to each
    model in turn (interleaved, so that a change of machine load hits every size alike)."""
    config = WorldConfig.paper()
    new_scenes = [scene.tokens() for scene in generate_scenes(config, updates, 99)]
    models = {}
    for size in sizes:
        learned = [scene.tokens() for scene in generate_scenes(config, size, 3)]
        models[size] = IncrementalLDA(seed=0).fit(learned, n_contexts=3)
    for model in models.values():  # a copy meets the same updates first: the kernels load before timing
        for scene in copy.deepcopy(new_scenes[:WARM_UPDATES]):
            copy.deepcopy(model).learn_scene(scene)
    times: dict[int, list[float]] = {size: [] for size in sizes}
    cpu: dict[int, list[float]] = {size: [] for size in sizes}
    checks: dict[int, int] = dict.fromkeys(sizes, 0)
    for scene in new_scenes:
        for size, model in models.items():
            start, start_cpu = time.perf_counter_ns(), time.process_time_ns()
            checks[size] += model.learn_scene(scene).growth_checked
            cpu[size].append((time.process_time_ns() - start_cpu) / 1e3)
            times[size].append((time.perf_counter_ns() - start) / 1e3)
    return {
        str(size): {
            "median_us": statistics.median(t),
            "mean_us": statistics.mean(t),
            "median_cpu_us": statistics.median(cpu[size]),
            "mean_cpu_us": statistics.mean(cpu[size]),
            "growth_checks": checks[size],
            "contexts_after": models[size].n_contexts,
        }
        for size, t in times.items()
    }


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller corpora and fewer calls")
    parser.add_argument("--repeats", type=int, default=None, help="timings of each sampler (5; --quick: 3)")
    args = parser.parse_args(sys.argv[1:])
    if args.repeats is not None and args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    logging.getLogger("lda").setLevel(logging.WARNING)
    sweeps, large_docs, calls, updates = (10, 2_000, 100, 100) if args.quick else (10, 20_000, 1_000, 500)
    repeats = args.repeats or (3 if args.quick else 5)
    corpora = {
        "small (29 words, K=3)": (synthetic_corpus(2_000, 29, 3, (20, 40), 0), 29, 3),
        "medium (500 words, K=20)": (synthetic_corpus(large_docs // 2, 500, 20, (50, 100), 2), 500, 20),
        "large (2000 words, K=50)": (synthetic_corpus(large_docs, 2_000, 50, (100, 100), 1), 2_000, 50),
    }
    throughput: dict[str, dict[str, Any]] = {}
    for name, (docs, vocab_size, n_topics) in corpora.items():
        runs = sampler_throughput(docs, vocab_size, n_topics, sweeps, repeats)
        lda_package = lda_package_throughput(docs, vocab_size, n_topics, 10)
        throughput[name] = throughput_row(runs, sweep_kernel(n_topics), int(sum(len(d) for d in docs)), lda_package)
    crossover = kernel_crossover(
        (10, 12, 50, 600) if args.quick else (8, 10, 12, 16, 32, 50, 128, 300, 400, 600), 4_000
    )
    sizes = (1_000, 10_000) if args.quick else (1_000, 100_000)
    updates_by_size = online(sizes, updates)
    medians = [updates_by_size[str(size)]["median_us"] for size in sizes]
    result: dict[str, Any] = {
        "throughput": throughput,
        "kernel_crossover_tokens_per_cpu_s": crossover,
        "detection_5_objects": detection(calls),
        "online_update": updates_by_size,
        "online_median_ratio_largest_over_smallest": medians[-1] / medians[0],
        "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0],
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "context.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    for name, row in throughput.items():
        print(
            f"{name:>26}: ours ({row['kernel']}) {row['ours_tokens_sweeps_per_s'] / 1e6:6.1f} M tok·sweep/s, "
            f"tomotopy {row['tomotopy_tokens_sweeps_per_s'] / 1e6:6.1f} M ({row['ratio_ours_over_tomotopy']:.2f}x; "
            f"CPU time {row['ratio_ours_over_tomotopy_cpu_time']:.2f}x, {row['ratio_ours_over_tomotopy_cpu_time_min']:.2f}"
            f"-{row['ratio_ours_over_tomotopy_cpu_time_max']:.2f} over {row['repeats']} repeats), "
            f"lda {row['lda_package_tokens_sweeps_per_s'] / 1e6:6.1f} M ({row['ratio_ours_over_lda_package']:.2f}x)"
        )
        print(
            f"{'':>26}  by kernel: "
            + ", ".join(
                f"{kernel} {row[f'{kernel}_tokens_sweeps_per_s'] / 1e6:.1f} M "
                f"({row[f'ratio_{kernel}_over_tomotopy']:.2f}x; CPU time {row[f'ratio_{kernel}_over_tomotopy_cpu_time']:.2f}x)"
                for kernel in SWEEP_KERNELS
            )
        )
    for contexts, row in crossover.items():
        fastest = max(SWEEP_KERNELS, key=lambda kernel: row[kernel])
        print(
            f"{'kernels at K=' + contexts:>26}: "
            + ", ".join(f"{kernel} {row[kernel] / 1e6:.1f} M" for kernel in SWEEP_KERNELS)
            + f" per CPU s (fastest {fastest}, chosen {row['chosen']})"
        )
    found = result["detection_5_objects"]
    print(
        f"{'context of a 5-object scene':>26}: {found['ours_median_us']:.1f} µs median "
        f"(paper {PAPER_DETECTION_MS} ms: {found['speed_ratio_paper_over_ours']:.0f}x; "
        f"tomotopy infer {found['tomotopy_infer_median_us']:.1f} µs); one seed, as the service calls it: "
        f"{found['ours_one_seed_median_us']:.1f} µs ({found['speed_ratio_tomotopy_over_ours_one_seed']:.1f}x tomotopy)"
    )
    for size, row in updates_by_size.items():
        print(
            f"{'online update, ' + size + ' scenes':>26}: {row['median_us']:.1f} µs median, {row['mean_us']:.1f} µs mean "
            f"(CPU time {row['median_cpu_us']:.1f} / {row['mean_cpu_us']:.1f} µs; {row['growth_checks']} growth checks, "
            f"K = {row['contexts_after']})"
        )
    print(f"{'median ratio':>26}: {result['online_median_ratio_largest_over_smallest']:.2f} (must be < 1.5)")
    return result


if __name__ == "__main__":
    main()
