"""Running the report's jobs: every experiment of :data:`experiments.EXPERIMENTS` with the defaults of
its own parser (what ``contextweb experiment NAME`` would run) at each seed, its ablations
(:data:`ABLATIONS`), and §V-F's running times; in parallel processes (:func:`run_jobs`)."""

from __future__ import annotations

import argparse
import importlib
import json
import multiprocessing
import os
import time
import traceback
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

import experiments
from core.errors import InvalidInputError
from experiments import context_scenes, documents
from experiments.report.claim import Status, Summary, Verdict
from experiments.report.claims import CLAIMS
from experiments.report.claims.running_times import RUNNING_TIMES, running_times
from sim.world import DEFAULT_WORLD

#: The report's seeds unless told otherwise (``--seeds``): five, none of them the tests'.
DEFAULT_SEEDS: tuple[int, ...] = (0, 1, 2, 3, 4)

#: Ablation name -> the experiment options it changes from the headline protocol (the hard world,
#: documents perceived). A claim lists the ablations shown beside it (``Claim.ablations``).
ABLATIONS: dict[str, dict[str, str]] = {
    "easy": {"world": "easy"},
    "labels": {"documents": "labels"},
}


@dataclass
class JobResult:
    name: str
    folder: Path
    seed: int = 0
    ablation: str | None = None
    summary: Summary | None = None
    error: str | None = None
    seconds: float = 0.0
    #: Wall-clock start (epoch seconds): files older than this in ``folder`` are from an earlier run.
    started: float = field(default_factory=time.time)


@dataclass
class ReportResult:
    page: Path
    #: Job label (``NAME`` or ``NAME@ABLATION``) -> its run at each seed, in seed order.
    jobs: dict[str, list[JobResult]]
    verdicts: dict[str, Verdict] = field(default_factory=dict)
    #: Claim name -> ablation -> verdict over the seeds.
    ablation_verdicts: dict[str, dict[str, Verdict]] = field(default_factory=dict)

    @property
    def failed(self) -> dict[str, str]:
        """Jobs that failed (at any seed) and claims that could not be judged, with the error."""
        jobs = {
            label: next(run.error for run in runs if run.error is not None)
            for label, runs in self.jobs.items()
            if any(run.error is not None for run in runs)
        }
        return jobs | {name: v.reason for name, v in self.verdicts.items() if v.status is Status.NOT_RUN}

    @property
    def ok(self) -> bool:
        return not self.failed


def error_text(exception: BaseException) -> str:
    where = traceback.extract_tb(exception.__traceback__)[-1:] if exception.__traceback__ else []
    at = f" (at {Path(where[0].filename).name}:{where[0].lineno})" if where else ""
    return f"{type(exception).__name__}: {exception}{at}".replace("\n", " ")


def job_label(name: str, ablation: str | None) -> str:
    return name if ablation is None else f"{name}@{ablation}"


def experiment_args(
    name: str, out: Path, quick: bool, seed: int, options: Mapping[str, str] | None = None
) -> tuple[Any, argparse.Namespace]:
    """The experiment's module and the arguments ``contextweb experiment NAME`` would give it by
    default, with ``options`` (an ablation's) changed; an option the experiment lacks is refused."""
    module = importlib.import_module(experiments.EXPERIMENTS[name])
    parser = argparse.ArgumentParser(prog=f"contextweb experiment {name}")
    module.add_arguments(parser)
    args = parser.parse_args([])
    for option, value in (options or {}).items():
        if not hasattr(args, option):
            raise InvalidInputError("ablation", f"experiment {name!r} has no --{option}")
        setattr(args, option, value)
    args.out, args.json, args.quick, args.seed = out, False, quick, seed
    return module, args


def run_job(
    name: str, folder: Path, quick: bool, seed: int, bench_results: Path, ablation: str | None = None
) -> JobResult:
    job = JobResult(name, folder, seed, ablation)
    start = time.perf_counter()
    try:
        if name == RUNNING_TIMES:
            job.summary = running_times(bench_results, seed)
        elif name not in experiments.EXPERIMENTS:
            raise LookupError(f"experiment {name!r} is not registered in experiments.EXPERIMENTS")
        else:
            options = ABLATIONS[ablation] if ablation is not None else None
            module, args = experiment_args(name, folder, quick, seed, options)
            folder.mkdir(parents=True, exist_ok=True)
            job.summary = module.run(args)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "summary.json").write_text(json.dumps(job.summary, indent=2) + "\n", encoding="utf-8")
    except Exception as exception:  # noqa: BLE001 — one failed experiment must not lose the others' results
        job.error = error_text(exception)
    job.seconds = time.perf_counter() - start
    return job


@dataclass(frozen=True)
class JobSpec:
    """One (experiment, ablation, seed) run: its output folder is ``out/LABEL/seed-S``."""

    name: str
    ablation: str | None
    seed: int

    @property
    def label(self) -> str:
        return job_label(self.name, self.ablation)


def job_specs(names: Sequence[str], seeds: Sequence[int]) -> list[JobSpec]:
    """Every named job at every seed, with the ablations its claims show; §V-F's running times
    once (they measure the code, not a world)."""
    specs = []
    for name in names:
        if name == RUNNING_TIMES:
            specs.append(JobSpec(name, None, seeds[0]))
            continue
        ablations = dict.fromkeys(a for claim in CLAIMS if claim.job == name for a in claim.ablations)
        specs += [JobSpec(name, ablation, seed) for ablation in (None, *ablations) for seed in seeds]
    # The headline jobs first: the pool runs in submission order, and the ablations matter less.
    return sorted(specs, key=lambda spec: spec.ablation is not None)


def _run_spec(spec: JobSpec, out: Path, quick: bool, bench_results: Path) -> JobResult:
    job = run_job(spec.name, out / spec.label / f"seed-{spec.seed}", quick, spec.seed, bench_results, spec.ablation)
    if job.summary is not None:
        (job.folder / JOB_FILE).write_text(json.dumps({"seconds": job.seconds}) + "\n", encoding="utf-8")
    return job


#: Beside a job's summary.json: how long it took (read back by ``reuse``).
JOB_FILE = "job.json"


def stored_job(spec: JobSpec, out: Path) -> JobResult | None:
    """The job's result from an earlier run into ``out`` (its summary.json), or None."""
    folder = out / spec.label / f"seed-{spec.seed}"
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    try:
        seconds = float(json.loads((folder / JOB_FILE).read_text(encoding="utf-8"))["seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        seconds = 0.0
    return JobResult(spec.name, folder, spec.seed, spec.ablation, summary, seconds=seconds, started=0.0)


def _world_of(spec: JobSpec) -> str:
    return ABLATIONS.get(spec.ablation or "", {}).get("world", DEFAULT_WORLD)


def _perceive_world(world: str, seed: int, quick: bool) -> None:
    """Extract the features of the world's objects (into ``context_scenes.FEATURE_CACHE``) and perceive them."""
    documents.experiment_documents(world, seed, documents.PERCEIVED, quick)


def run_jobs(
    specs: Sequence[JobSpec],
    out: Path,
    quick: bool,
    bench_results: Path,
    workers: int | None = None,
    reuse: str = "none",
) -> dict[str, list[JobResult]]:
    """Every job in parallel processes (``workers``, default one per core) with a progress bar;
    results by label, each label's runs in seed order. Forked workers see the registry as this
    process has it (a test may register an experiment).

    Two phases: first each (world, seed) the experiments need is recorded, its features extracted
    into ``out/cache`` (``context_scenes.FEATURE_CACHE``) and perceived, once; then every job runs,
    reading the features from there instead of extracting them again (≈ 1 s per object).

    ``reuse``: ``"none"`` runs every job; ``"existing"`` takes the jobs whose summary an earlier run
    left in ``out`` (:func:`stored_job`: an interrupted report resumes) and runs the others;
    ``"only"`` runs nothing, and a job without a stored summary is not run (the page says so)."""
    workers = workers or os.cpu_count() or 1
    context_scenes.FEATURE_CACHE = out / "cache"
    stored = {spec: stored_job(spec, out) for spec in specs} if reuse != "none" else {}
    outcomes: dict[str, Any] = {f"{spec.label} seed {spec.seed}": job for spec, job in stored.items() if job}
    for spec in (spec for spec, job in stored.items() if job is None and reuse == "only"):
        folder = out / spec.label / f"seed-{spec.seed}"
        missing = JobResult(spec.name, folder, spec.seed, spec.ablation, error="no summary stored (--reuse only)")
        outcomes[f"{spec.label} seed {spec.seed}"] = missing
    specs_to_run = [spec for spec in specs if f"{spec.label} seed {spec.seed}" not in outcomes]
    worlds = list(dict.fromkeys((_world_of(s), s.seed) for s in specs_to_run if s.name in experiments.EXPERIMENTS))
    progress = tqdm(total=len(worlds) + len(specs_to_run), desc="report", unit="job")
    phases: list[list[tuple[str, Any, tuple[Any, ...]]]] = [
        [(f"perceive {world} seed {seed}", _perceive_world, (world, seed, quick)) for world, seed in worlds],
        [(f"{spec.label} seed {spec.seed}", _run_spec, (spec, out, quick, bench_results)) for spec in specs_to_run],
    ]
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork")) as pool:
        for phase in phases:
            futures = {pool.submit(work, *arguments): name for name, work, arguments in phase}
            for future in as_completed(futures):
                try:
                    outcomes[futures[future]] = future.result()
                except Exception:  # noqa: BLE001 — a world that fails to perceive fails its jobs, reported there
                    outcomes[futures[future]] = None
                progress.set_postfix_str(futures[future])
                progress.update()
    progress.close()
    results: dict[JobSpec, JobResult] = {spec: outcomes[f"{spec.label} seed {spec.seed}"] for spec in specs}
    grouped: dict[str, list[JobResult]] = {}
    for spec in specs:
        grouped.setdefault(spec.label, []).append(results[spec])
    return grouped


def job_names(only: Sequence[str] | None) -> list[str]:
    every = list(dict.fromkeys([*experiments.EXPERIMENTS, *(claim.job for claim in CLAIMS)]))
    if only is None:
        return every
    unknown = [name for name in only if name not in every]
    if unknown:
        raise InvalidInputError("only", f"unknown job(s) {', '.join(unknown)}; known: {', '.join(every)}")
    return [name for name in every if name in only]
