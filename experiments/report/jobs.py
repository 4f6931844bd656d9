"""Running the report's jobs: every experiment of :data:`experiments.EXPERIMENTS` with the defaults of
its own parser (what ``contextweb experiment NAME`` would run), and §V-F's running times."""

from __future__ import annotations

import argparse
import importlib
import json
import time
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import experiments
from core.errors import InvalidInputError
from experiments.report.claim import Status, Summary, Verdict
from experiments.report.claims import CLAIMS
from experiments.report.claims.running_times import RUNNING_TIMES, running_times


@dataclass
class JobResult:
    name: str
    folder: Path
    summary: Summary | None = None
    error: str | None = None
    seconds: float = 0.0
    #: Wall-clock start (epoch seconds): files older than this in ``folder`` are from an earlier run.
    started: float = field(default_factory=time.time)


@dataclass
class ReportResult:
    page: Path
    jobs: dict[str, JobResult]
    verdicts: dict[str, Verdict] = field(default_factory=dict)

    @property
    def failed(self) -> dict[str, str]:
        """Jobs that failed and claims that could not be judged, with the error."""
        jobs = {name: job.error for name, job in self.jobs.items() if job.error is not None}
        return jobs | {name: v.reason for name, v in self.verdicts.items() if v.status is Status.NOT_RUN}

    @property
    def ok(self) -> bool:
        return not self.failed


def error_text(exception: BaseException) -> str:
    where = traceback.extract_tb(exception.__traceback__)[-1:] if exception.__traceback__ else []
    at = f" (at {Path(where[0].filename).name}:{where[0].lineno})" if where else ""
    return f"{type(exception).__name__}: {exception}{at}".replace("\n", " ")


def experiment_args(name: str, out: Path, quick: bool, seed: int) -> tuple[Any, argparse.Namespace]:
    """The experiment's module and the arguments ``contextweb experiment NAME`` would give it by default."""
    module = importlib.import_module(experiments.EXPERIMENTS[name])
    parser = argparse.ArgumentParser(prog=f"contextweb experiment {name}")
    module.add_arguments(parser)
    args = parser.parse_args([])
    args.out, args.json, args.quick, args.seed = out, False, quick, seed
    return module, args


def run_job(name: str, folder: Path, quick: bool, seed: int, bench_results: Path) -> JobResult:
    job = JobResult(name, folder)
    start = time.perf_counter()
    try:
        if name == RUNNING_TIMES:
            job.summary = running_times(bench_results, seed)
        elif name not in experiments.EXPERIMENTS:
            raise LookupError(f"experiment {name!r} is not registered in experiments.EXPERIMENTS")
        else:
            module, args = experiment_args(name, folder, quick, seed)
            folder.mkdir(parents=True, exist_ok=True)
            job.summary = module.run(args)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "summary.json").write_text(json.dumps(job.summary, indent=2) + "\n", encoding="utf-8")
    except Exception as exception:  # noqa: BLE001 — one failed experiment must not lose the others' results
        job.error = error_text(exception)
    job.seconds = time.perf_counter() - start
    return job


def job_names(only: Sequence[str] | None) -> list[str]:
    every = list(dict.fromkeys([*experiments.EXPERIMENTS, *(claim.job for claim in CLAIMS)]))
    if only is None:
        return every
    unknown = [name for name in only if name not in every]
    if unknown:
        raise InvalidInputError("only", f"unknown job(s) {', '.join(unknown)}; known: {', '.join(every)}")
    return [name for name in every if name in only]
