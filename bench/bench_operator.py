"""Robots' scenes while an operator trains (``python -m bench.bench_operator [--quick] [--backends sqlite,postgresql]``).

One real ``contextweb serve`` process per database, with 5 trained paper-world models
(bench_service's training set and ``SERVING`` hyperparameters). Four robots (threads, each
its own keep-alive connection) post concept scenes to models 1-4, one model each, with a
20 ms pause after each answer, as robots in the field do; meanwhile, in three phases of the
same length:

- ``baseline``: nobody else writes (the reference, measured in the same run, after a 5 s
  warm-up of the robots that is not measured);
- ``refit``: an operator refits model 0 in a loop (``POST /fit``);
- ``raw_training``: an operator posts model 0 batches of 3 raw training objects in a loop
  (point clouds, sounds and proprioception: their features are extracted by the server).

For each phase: the robots' scenes answered, their latency p50 / p99 / max, the operator's
requests and their median time, and the robots' p50 and p99 as ratios to the baseline's. A
fit or a training batch that held the model's write (on SQLite the database's one write lock)
for its whole computation stopped every model's scenes for that long (docs/scaling.md, "A fit
and a training batch compute before their write"). Every answer must be a 201 (or the
operator's 200 / 201): anything else fails the run.

Writes ``bench/results/operator.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from bench import RESULTS
from bench.bench_scaling import ScalingServer, training_features
from bench.bench_service import SERVING, _fresh_postgres, _trained_model, concept_scenes, training_objects
from sim.robot import training_object
from sim.world import World

ROBOTS = 4
PAUSE_SECONDS = 0.02
RAW_OBJECTS_PER_BATCH = 3
RAW_MAX_POINTS = 2_000
#: Robots posting before the phases, not measured: the models' early growth checks (one after each of
#: their first scenes) and the connections' first requests are behind them.
WARM_UP_SECONDS = 5.0
PHASES = ("baseline", "refit", "raw_training")


def _phase(server: ScalingServer, models: list[str], scenes: list[dict], operator: dict | None, seconds: float) -> dict:
    """The robots posting for ``seconds`` while ``operator`` ({"path", "json"}) posts in a loop (None: nobody)."""
    stop = threading.Event()
    latencies: list[float] = []
    operations: list[float] = []
    failures: list[str] = []
    lock = threading.Lock()

    def robot(model_id: str, part: list[dict]) -> None:
        with httpx.Client(base_url=server.url, timeout=120) as client:
            for body in part:
                if stop.is_set():
                    return
                started = time.perf_counter()
                response = client.post(f"/v1/models/{model_id}/scenes", json=body)
                with lock:
                    latencies.append(time.perf_counter() - started)
                if response.status_code != 201:
                    failures.append(f"scene: {response.status_code} {response.text[:200]}")
                    return
                time.sleep(PAUSE_SECONDS)

    def operate() -> None:
        assert operator is not None
        with httpx.Client(base_url=server.url, timeout=600) as client:
            while not stop.is_set():
                started = time.perf_counter()
                response = client.post(operator["path"], json=operator["json"])
                operations.append(time.perf_counter() - started)
                if response.status_code not in (200, 201):
                    failures.append(f"operator: {response.status_code} {response.text[:200]}")
                    return

    threads = [
        threading.Thread(target=robot, args=(model_id, scenes[i::ROBOTS])) for i, model_id in enumerate(models[1:])
    ]
    if operator is not None:
        threads.append(threading.Thread(target=operate))
    for thread in threads:
        thread.start()
    time.sleep(seconds)
    stop.set()
    for thread in threads:
        thread.join()
    if failures:
        raise RuntimeError(f"refused during the phase: {failures[:3]}")
    ms = np.array(latencies) * 1000
    return {
        "scenes": len(ms),
        "p50_ms": round(float(np.percentile(ms, 50)), 2),
        "p99_ms": round(float(np.percentile(ms, 99)), 2),
        "max_ms": round(float(ms.max()), 1),
        "operator_requests": len(operations),
        "operator_median_s": round(statistics.median(operations), 3) if operations else None,
    }


def run(backend: str, seconds: float, folder: Path) -> dict[str, Any]:
    world = World.paper(0)
    train = training_objects(world, training_features(world))
    if backend == "postgresql":
        url = _fresh_postgres("contextweb_bench_operator")
        if url is None:
            return {"skipped": "PostgreSQL is not reachable"}
    else:
        url = f"sqlite:///{folder / 'operator.sqlite3'}"
    rng = np.random.default_rng(5)
    raw_batch = {
        "objects": [
            training_object(obj, world.record(obj, rng), "raw", rng, RAW_MAX_POINTS).model_dump(
                mode="json", exclude_none=True
            )
            for obj in world.train_objects[:RAW_OBJECTS_PER_BATCH]
        ]
    }
    server = ScalingServer(url, folder / f"{backend}.log")
    try:
        with httpx.Client(base_url=server.url, timeout=300) as client:
            models = [_trained_model(client, train, SERVING) for _ in range(ROBOTS + 1)]
        scenes = concept_scenes(world, 20_000, seed=2)
        operators: dict[str, dict | None] = {
            "baseline": None,
            "refit": {"path": f"/v1/models/{models[0]}/fit", "json": {}},
            "raw_training": {"path": f"/v1/models/{models[0]}/training-objects", "json": raw_batch},
        }
        _phase(server, models, scenes[-2_000:], None, WARM_UP_SECONDS)  # past each model's first growth checks
        phases = {name: _phase(server, models, scenes, operators[name], seconds) for name in PHASES}
    finally:
        server.stop()
    base = phases["baseline"]
    for name in PHASES[1:]:
        phases[name]["p50_over_baseline"] = round(phases[name]["p50_ms"] / base["p50_ms"], 2)
        phases[name]["p99_over_baseline"] = round(phases[name]["p99_ms"] / base["p99_ms"], 2)
    return phases


def main() -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10 s phases instead of 30 s (a smoke run)")
    parser.add_argument("--backends", default="sqlite,postgresql", help="comma-separated: sqlite, postgresql")
    args = parser.parse_args(sys.argv[1:])
    seconds = 10.0 if args.quick else 30.0
    with tempfile.TemporaryDirectory(prefix="contextweb-operator-") as folder:
        results: dict[str, Any] = {
            "robots": ROBOTS,
            "phase_seconds": seconds,
            "raw_objects_per_batch": RAW_OBJECTS_PER_BATCH,
            **{backend: run(backend, seconds, Path(folder)) for backend in args.backends.split(",")},
            "cpu_count": os.cpu_count(),
            "load_average_1min": round(os.getloadavg()[0], 2),
        }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "operator.json").write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))
    return results


if __name__ == "__main__":
    main()
