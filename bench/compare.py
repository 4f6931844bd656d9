"""Compare this checkout's scene throughput with another commit's: bench_scaling's workload, in ABBA order.

    python -m bench.compare REF [--backend postgresql|sqlite] [--workers N] [--rounds R] [--scenes N]

Server A runs the commit ``REF`` (a temporary ``git worktree``), server B this checkout's
working tree; each on its own database (PostgreSQL ``contextweb_compare_a`` / ``_b``, or a
SQLite file each) with the same 8 trained models, both up for the whole run. Then rounds of
bench_scaling's throughput measure (8 clients on 8 models, one keep-alive connection each;
``_spread``) alternate between them in ABBA order: A B, B A, A B, ... On this shared machine the
speed drifts within minutes, and an AB order credits that drift to whichever runs second; a
change measured so on 2026-12-07 looked 8.7 % faster, and 9 % slower in ABBA order
(docs/benchmarks.md). Only the comparison means something: scenes/s of a slow hour are not a
result (bench_scaling is).

Prints each round and, for A and B, the median scenes/s and CPU a scene, and in how many pairs
B was ahead. Nothing is written to bench/results: this is a tool for deciding a change, whose
figures go into the commit message and docs/benchmarks.md's hand-measured table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from bench.bench_scaling import CLIENTS, ScalingServer, _spread, trained_models, training_features
from bench.bench_service import BIRTH_CHECK_INTERVAL, PROJECT, _fresh_postgres, concept_scenes, training_objects
from sim.world import World


def rounds_order(rounds: int) -> list[tuple[str, str]]:
    """ABBA order: (A, B) in even rounds, (B, A) in odd ones."""
    return [("A", "B") if number % 2 == 0 else ("B", "A") for number in range(rounds)]


def pairs_won(a: list[float], b: list[float]) -> int:
    """In how many rounds B's figure was above A's."""
    return sum(second > first for first, second in zip(a, b, strict=True))


def summary(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Median scenes/s and CPU a scene (ms, by group) of one side's rounds."""
    cpu = [row["cpu_ms_per_scene"] for row in rows]
    return {
        "scenes_per_second": round(statistics.median(row["scenes_per_second"] for row in rows), 1),
        **{f"{group}_ms": round(statistics.median(item[group] for item in cpu), 3) for group in ("server", "total")},
        "cores_busy": round(statistics.median(item["cores_busy"] for item in cpu), 2),
    }


def main() -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ref", help="the commit server A runs (B runs this working tree)")
    parser.add_argument("--backend", default="postgresql", choices=["postgresql", "sqlite"])
    parser.add_argument("--workers", type=int, default=2, help="--workers of each server (default 2)")
    parser.add_argument("--rounds", type=int, default=4, help="rounds of A and B each (default 4)")
    parser.add_argument("--scenes", type=int, default=2_400, help="scenes a round, over the 8 clients")
    args = parser.parse_args(sys.argv[1:])
    folder = Path(tempfile.mkdtemp(prefix="contextweb-compare-"))
    base = folder / "base"
    subprocess.run(["git", "worktree", "add", "--detach", str(base), args.ref], cwd=PROJECT, check=True)
    servers: dict[str, tuple[ScalingServer, list[str], str | None]] = {}
    try:
        world = World.paper(0)
        train = training_objects(world, training_features(world))
        warmup = concept_scenes(world, BIRTH_CHECK_INTERVAL, seed=1)
        scenes = concept_scenes(world, args.scenes, seed=2)
        parts = [scenes[i::CLIENTS] for i in range(CLIENTS)]
        for name, project in (("A", base), ("B", PROJECT)):
            if args.backend == "postgresql":
                url = _fresh_postgres(f"contextweb_compare_{name.lower()}")
                if url is None:
                    raise SystemExit("PostgreSQL is not reachable")
                database: str | None = url.rsplit("/", 1)[1]
            else:
                url, database = f"sqlite:///{folder / name}.sqlite3", None
            server = ScalingServer(url, folder / f"{name}.log", args.workers, project=project)
            models: list[str] = []
            servers[name] = (server, models, database)  # stopped in ``finally`` even if training fails
            models.extend(trained_models(server, train))
            _spread([(server, model) for model in models], [warmup] * CLIENTS)
        results: dict[str, list[dict[str, Any]]] = {"A": [], "B": []}
        for number, order in enumerate(rounds_order(args.rounds)):
            for name in order:
                server, models, database = servers[name]
                figures = _spread([(server, model) for model in models], parts, database)
                results[name].append(figures)
                cpu = figures["cpu_ms_per_scene"]
                print(
                    f"round {number} {name}: {figures['scenes_per_second']:.1f} scenes/s, CPU {cpu['total']:.2f} ms "
                    f"a scene (server {cpu['server']:.2f}), cores busy {cpu['cores_busy']:.2f}",
                    flush=True,
                )
    finally:
        for server, _, _ in servers.values():
            server.stop()
        subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=PROJECT, check=False)
    speeds = {name: [row["scenes_per_second"] for row in rows] for name, rows in results.items()}
    outcome = {
        "ref": args.ref,
        "backend": args.backend,
        "workers": args.workers,
        "A": summary(results["A"]),
        "B": summary(results["B"]),
        "b_ahead_in_pairs": f"{pairs_won(speeds['A'], speeds['B'])} of {args.rounds}",
    }
    print(json.dumps(outcome, indent=2))
    return outcome


if __name__ == "__main__":
    main()
