"""End-to-end speed of the service (``python -m bench.bench_service [--quick] [--backends sqlite,postgresql]``).

For each database, a real ``contextweb serve`` process on loopback with a fresh
database and a trained paper-world model (prototypes and concept web fitted on
the 45 training objects of ``World.paper(0)``, features extracted from their
simulated recordings, clouds decimated to 1,000 points to keep the set-up short):

- ``concepts``: one client posting 5-object scenes at the concept level
  (each object's noun, adjectives and applicable verbs), every scene a durable
  commit (SQLite ``synchronous=FULL``; PostgreSQL's default ``synchronous_commit=on``),
  10,000 timed scenes after a warm-up of ``birth_check_interval`` scenes. The
  client is a plain keep-alive HTTP/1.1 connection (the standard library's
  ``http.client``; the timing includes encoding the body as JSON and reading the
  answer), as lean as a robot's own HTTP stack; ``concepts_httpx`` and
  ``concepts_bridge`` post the next scenes through an ``httpx.Client`` and
  through the robot-side ``bridge.Client`` (idempotency key, retries, the answer
  parsed into pydantic models), whose own costs show beside the server's;
- ``features``: 5 test objects at the feature level (Table III vectors), lean client;
- ``throughput``: 8 concurrent clients, on one model (serialised by its lock)
  and on 8 models (one each, warmed up like the first);
- ``default_hyperparameters``: the concepts series on a model with the core's
  default Incremental-LDA settings (no warm-up), whose growth checks set the tail.

The timed model uses ``birth_check_interval = 200``: under the former default K
rule (``likelihood``) a growth check re-sampled the last ``birth_window`` scenes
hundreds of times (far slower than the ``scenes`` rule's check: docs/benchmarks.md), and the core
checks after each of the first ``birth_check_interval`` scenes (the warm-up), then
every ``birth_check_interval``: every 25 (the default) puts 4 % of the requests
there, every 200 keeps them at 0.5 %, under the p99.

References measured in the same run (the machine is shared; ratios travel):
``fsync_ms``, one 4 KiB write + fsync in the database's folder (the floor of a
durable SQLite commit), ``postgres_commit_ms``, one durable one-row INSERT + COMMIT
on the PostgreSQL server (the floor of a durable PostgreSQL scene: its WAL flush),
and ``pipeline_ms``, the same scenes through the same
perception, concept web, Eq. 6 feedback and Incremental-LDA update in this
process, without HTTP or database. Writes ``bench/results/service.json``.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, TypedDict

import httpx
import numpy as np
from sqlalchemy import create_engine, text

from app.schemas.scenes import SceneCreate
from app.services.perception import Perception, analyse_objects, in_context
from bench import RESULTS
from bridge import Client as BridgeClient
from bridge.models import SceneCreate as BridgeScene
from core.concept_web import ConceptWeb
from core.context.feedback import PAPER_SIGMA
from core.context.hyperparameters import Hyperparameters
from core.context.incremental import IncrementalLDA
from core.features.extract import recording_features
from core.payloads import Interaction, ObjectRecording, PointCloud
from core.prototypes.prototypes import fit_prototypes
from sim.world import World, WorldObject

PROJECT = Path(__file__).resolve().parents[1]
POSTGRES_SERVER = os.environ.get("CONTEXTWEB_BENCH_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432")
POSTGRES_DATABASE = "contextweb_bench"
CLOUD_POINTS = 1_000
OBJECTS_PER_SCENE = 5
CLIENTS = 8
#: Growth checks after each of the first 200 scenes, then at 2x, 4x, ... (docs/context.md), as a
#: deployment that learns for long would set; the API's nested hyperparameters (docs/api.md).
BIRTH_CHECK_INTERVAL = 200
SERVING = {"k_rule": {"name": "scenes", "birth_check_interval": BIRTH_CHECK_INTERVAL}}
TARGETS = {"concepts_median_ms": 5.0, "concepts_p99_ms": 20.0, "features_median_ms": 10.0}


def _decimated(recording: ObjectRecording) -> ObjectRecording:
    def cloud(points: PointCloud) -> PointCloud:
        step = max(1, len(points.points) // CLOUD_POINTS)
        return PointCloud(points.points[::step])

    interactions = tuple(
        Interaction(i.behaviour, cloud(i.before), cloud(i.after), i.audio, i.finger) for i in recording.interactions
    )
    return ObjectRecording(cloud(recording.look), interactions)


def paper_world_features(world: World) -> dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]:
    """Entity and effect vectors of every object of the paper world, from its simulated recordings."""
    return {key: recording_features(_decimated(rec)) for key, rec in world.recordings(seed=0).items()}


def training_objects(world: World, features: dict) -> list[dict[str, Any]]:
    objects = []
    for obj in world.train_objects:
        entity, effects = features[obj.object_id]
        vectors = {behaviour: vector.tolist() for behaviour, vector in effects.items()}
        objects.append(
            {
                "noun": obj.noun,
                "adjectives": list(obj.adjectives),
                "features": {"entity": entity.tolist(), "effects": vectors},
            }
        )
    return objects


def concept_scenes(world: World, count: int, seed: int) -> list[dict[str, Any]]:
    scenes = world.scenes(count, seed=seed, objects_per_scene=OBJECTS_PER_SCENE)
    return [{"objects": [{"concepts": [*obj.concepts, *obj.behaviours]} for obj in scene.objects]} for scene in scenes]


def feature_scenes(world: World, features: dict, count: int, seed: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    pool: list[WorldObject] = list(world.test_objects)

    def feature_object(obj: WorldObject) -> dict[str, Any]:
        entity, effects = features[obj.object_id]
        return {"features": {"entity": entity.tolist(), "effects": {b: v.tolist() for b, v in effects.items()}}}

    return [
        {"objects": [feature_object(pool[i]) for i in rng.choice(len(pool), OBJECTS_PER_SCENE, replace=False)]}
        for _ in range(count)
    ]


def fsync_ms(folder: Path, repeats: int = 50) -> float:
    path = folder / "fsync.probe"
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT)
    try:
        times = []
        for _ in range(repeats):
            os.write(descriptor, b"\0" * 4096)
            start = time.perf_counter()
            os.fsync(descriptor)
            times.append(time.perf_counter() - start)
    finally:
        os.close(descriptor)
        path.unlink()
    return 1000 * statistics.median(times)


def postgres_commit_ms(database_url: str, repeats: int = 50) -> float:
    """Median time of one durable one-row INSERT + COMMIT on the PostgreSQL server (its commit floor:
    a WAL flush with ``synchronous_commit=on``)."""
    engine = create_engine(database_url)
    try:
        with engine.connect() as connection:
            connection.execute(text("CREATE TABLE commit_probe (value integer)"))
            connection.commit()
            times = []
            for value in range(repeats):
                start = time.perf_counter()
                connection.execute(text("INSERT INTO commit_probe VALUES (:value)"), {"value": value})
                connection.commit()
                times.append(time.perf_counter() - start)
            connection.execute(text("DROP TABLE commit_probe"))
            connection.commit()
    finally:
        engine.dispose()
    return 1000 * statistics.median(times)


def pipeline_ms(world: World, train: list[dict], scenes: list[dict], hyperparameters: dict, warmup: int) -> float:
    """Median in-process time of perception + web + Eq. 6 + the online update, no HTTP, no database,
    over the scenes after the first ``warmup`` (those run the model's initial growth checks)."""
    vocabulary = world.vocabulary
    effects = [(vector, behaviour) for obj in train for behaviour, vector in obj["features"]["effects"].items()]
    prototypes = fit_prototypes(
        vocabulary,
        np.array([obj["features"]["entity"] for obj in train]),
        [[obj["noun"], *obj["adjectives"]] for obj in train],
        np.array([vector for vector, _ in effects]),
        [behaviour for _, behaviour in effects],
    )
    web = ConceptWeb.fit(vocabulary, [[o["noun"], *o["adjectives"], *o["features"]["effects"]] for o in train])
    perception = Perception(vocabulary, prototypes, web)
    lda = IncrementalLDA(vocabulary.concepts, seed=0, hyperparameters=Hyperparameters.from_dict(hyperparameters))
    times = []
    for body in scenes:
        start = time.perf_counter()
        analysis = analyse_objects(perception, SceneCreate.model_validate(body).objects, "bench")
        analysis = in_context(perception, lda, analysis, sigma=PAPER_SIGMA, seed=0)
        lda.learn_scene(analysis.words)
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times[warmup:])


class Server:
    """A ``contextweb serve`` process on a free loopback port, stopped by :meth:`stop` (only this one)."""

    def __init__(self, database_url: str, log: Path) -> None:
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            self.port = probe.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        env = {key: value for key, value in os.environ.items() if not key.startswith("CONTEXTWEB_")}
        env |= {
            "CONTEXTWEB_DATABASE_URL": database_url,
            "CONTEXTWEB_PORT": str(self.port),
            "CONTEXTWEB_SQLITE_SYNCHRONOUS": "FULL",
        }
        # As `make run` and the container do: `contextweb migrate`, then `contextweb serve`.
        migrate = [sys.executable, "-m", "app.cli", "migrate"]
        subprocess.run(migrate, cwd=PROJECT, env=env, stdout=log.open("ab"), stderr=subprocess.STDOUT, check=True)
        command = [sys.executable, "-m", "app.cli", "serve", "--log-level", "warning"]
        self.process = subprocess.Popen(command, cwd=PROJECT, env=env, stdout=log.open("ab"), stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and self.process.poll() is None:
            try:
                if httpx.get(f"{self.url}/readyz", timeout=1).status_code == 200:
                    return
            except httpx.TransportError:
                time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"the server did not start; see {log}")

    def stop(self) -> None:
        self.process.terminate()
        try:
            self.process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


class LatencySummary(TypedDict):
    """One series of request latencies, as the JSON result records it."""

    scenes: int
    median_ms: float
    p90_ms: float
    p99_ms: float
    max_ms: float
    scenes_per_second: float
    median_ms_by_tenth: list[float]


def _summary(latencies: list[float]) -> LatencySummary:
    ms = np.array(latencies) * 1000
    return {
        "scenes": len(ms),
        "median_ms": round(float(np.median(ms)), 3),
        "p90_ms": round(float(np.percentile(ms, 90)), 3),
        "p99_ms": round(float(np.percentile(ms, 99)), 3),
        "max_ms": round(float(ms.max()), 3),
        "scenes_per_second": round(len(ms) / float(ms.sum() / 1000), 1),
        # "Sustained": the median of each tenth of the series, in order (a cost that grew with the
        # corpus, as a query scanning every token would, shows as a rising row).
        "median_ms_by_tenth": [round(float(np.median(part)), 3) for part in np.array_split(ms, 10)],
    }


class LeanClient:
    """One keep-alive HTTP/1.1 connection (``http.client``): what the server's answer costs a lean client."""

    def __init__(self, port: int) -> None:
        self._connection = http.client.HTTPConnection("127.0.0.1", port, timeout=60)

    def post_all(self, model_id: str, scenes: list[dict]) -> list[float]:
        path, headers = f"/v1/models/{model_id}/scenes", {"Content-Type": "application/json"}
        latencies = []
        for body in scenes:
            start = time.perf_counter()
            self._connection.request("POST", path, body=json.dumps(body).encode(), headers=headers)
            response = self._connection.getresponse()
            answer = response.read()
            latencies.append(time.perf_counter() - start)
            if response.status != 201:
                raise RuntimeError(f"scene refused: {response.status} {answer[:300]!r}")
        return latencies

    def close(self) -> None:
        self._connection.close()


def _post_with_bridge(url: str, model_id: str, scenes: list[dict]) -> list[float]:
    """The scenes through ``bridge.Client`` (a fresh idempotency key each, the answer parsed)."""
    bodies = [BridgeScene.model_validate(body) for body in scenes]
    latencies = []
    with BridgeClient(url) as client:
        for body in bodies:
            start = time.perf_counter()
            client.scenes.create(model_id, body)
            latencies.append(time.perf_counter() - start)
    return latencies


def _post_all(client: httpx.Client, model_id: str, scenes: list[dict]) -> list[float]:
    latencies = []
    for body in scenes:
        start = time.perf_counter()
        response = client.post(f"/v1/models/{model_id}/scenes", json=body)
        latencies.append(time.perf_counter() - start)
        if response.status_code != 201:
            raise RuntimeError(f"scene refused: {response.status_code} {response.text[:300]}")
    return latencies


def _trained_model(client: httpx.Client, train: list[dict], hyperparameters: dict) -> str:
    model_id = client.post("/v1/models", json={"name": "paper world", "hyperparameters": hyperparameters}).json()["id"]
    client.post(f"/v1/models/{model_id}/training-objects", json={"objects": train}, timeout=120).raise_for_status()
    client.post(f"/v1/models/{model_id}/fit", json={}, timeout=300).raise_for_status()
    return model_id


def _throughput(url: str, model_ids: list[str], scenes: list[dict]) -> dict[str, float]:
    """Scenes per second with one thread per model id (a model id may repeat)."""
    errors: list[BaseException] = []

    def run(model_id: str, part: list[dict]) -> None:
        try:
            with httpx.Client(base_url=url, timeout=60) as client:
                _post_all(client, model_id, part)
        except BaseException as error:  # noqa: BLE001 - reported after the run
            errors.append(error)

    parts = [scenes[i :: len(model_ids)] for i in range(len(model_ids))]
    threads = [threading.Thread(target=run, args=(m, p)) for m, p in zip(model_ids, parts, strict=True)]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.perf_counter() - start
    if errors:
        raise errors[0]
    return {
        "clients": len(model_ids),
        "scenes": len(scenes),
        "seconds": round(elapsed, 2),
        "scenes_per_second": round(len(scenes) / elapsed, 1),
    }


def run_backend(database_url: str, log: Path, data: dict[str, Any], sizes: dict[str, int]) -> dict[str, Any]:
    server = Server(database_url, log)
    try:
        with httpx.Client(base_url=server.url, timeout=60) as client:
            model_id = _trained_model(client, data["train"], SERVING)
            _post_all(client, model_id, data["warmup"])
            lean = LeanClient(server.port)
            try:
                concepts = _summary(lean.post_all(model_id, data["concepts"][: sizes["concepts"]]))
                features = _summary(lean.post_all(model_id, data["features"][: sizes["features"]]))
            finally:
                lean.close()
            other = data["concepts"][sizes["concepts"] :][: sizes["clients"]]
            concepts_httpx = _summary(_post_all(client, model_id, other))
            concepts_bridge = _summary(_post_with_bridge(server.url, model_id, other))
            default = _trained_model(client, data["train"], {})
            default_hyperparameters = _summary(_post_all(client, default, data["concepts"][: sizes["default"]]))
            separate = [_trained_model(client, data["train"], SERVING) for _ in range(CLIENTS)]
        _throughput(server.url, separate, data["warmup"] * CLIENTS)
        throughput = {
            "same_model": _throughput(server.url, [model_id] * CLIENTS, data["concepts"][: sizes["throughput"]]),
            "separate_models": _throughput(server.url, separate, data["concepts"][: sizes["throughput"]]),
        }
    finally:
        server.stop()
    return {
        "concepts": concepts,
        "concepts_httpx": concepts_httpx,
        "concepts_bridge": concepts_bridge,
        "features": features,
        "default_hyperparameters": default_hyperparameters,
        "throughput": throughput,
    }


def _fresh_postgres(database: str = POSTGRES_DATABASE) -> str | None:
    """The URL of ``database``, dropped and created empty; None (saying so) without a server."""
    try:
        admin = create_engine(
            f"{POSTGRES_SERVER}/postgres", isolation_level="AUTOCOMMIT", connect_args={"connect_timeout": 3}
        )
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{database}" WITH (FORCE)'))
            connection.execute(text(f'CREATE DATABASE "{database}"'))
        admin.dispose()
    except Exception as error:  # noqa: BLE001 - no server: the PostgreSQL part is skipped, saying so
        print(f"PostgreSQL not reachable at {POSTGRES_SERVER} ({type(error).__name__}): skipped")
        return None
    return f"{POSTGRES_SERVER}/{database}"


def _report(name: str, result: dict[str, Any], references: dict[str, float]) -> None:
    concepts, features = result["concepts"], result["features"]
    floor, floor_name = (
        (references["postgres_commit_ms"], "one PostgreSQL commit")
        if name == "postgresql"
        else (references["fsync_ms"], "one fsync")
    )
    print(
        f"{name:10s} concepts: median {concepts['median_ms']:.2f} ms, p99 {concepts['p99_ms']:.2f} ms "
        f"({concepts['median_ms'] / references['pipeline_ms']:.1f}x the in-process pipeline, "
        f"{concepts['median_ms'] / floor:.1f}x {floor_name}); "
        f"through httpx {result['concepts_httpx']['median_ms']:.2f} ms, through bridge.Client "
        f"{result['concepts_bridge']['median_ms']:.2f} ms; "
        f"features: median {features['median_ms']:.2f} ms; default hyperparameters p99 "
        f"{result['default_hyperparameters']['p99_ms']:.1f} ms"
    )
    tenths = " ".join(f"{median:.2f}" for median in concepts["median_ms_by_tenth"])
    print(f"{'':10s} concepts median of each tenth of the series, in order: {tenths} ms")
    for kind, figures in result["throughput"].items():
        print(f"{'':10s} {CLIENTS} clients, {kind}: {figures['scenes_per_second']:.0f} scenes/s")


def main() -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a few hundred scenes (a smoke run, not a measurement)")
    parser.add_argument("--backends", default="sqlite,postgresql", help="comma-separated: sqlite, postgresql")
    args = parser.parse_args(sys.argv[1:])
    sizes = (
        {"concepts": 300, "clients": 100, "features": 100, "default": 100, "throughput": 400}
        if args.quick
        else {"concepts": 10_000, "clients": 2_000, "features": 1_000, "default": 1_000, "throughput": 4_000}
    )
    world = World.paper(0)
    started = time.perf_counter()
    features = paper_world_features(world)
    print(f"features of {len(features)} recorded objects in {time.perf_counter() - started:.0f} s")
    train = training_objects(world, features)
    data = {
        "train": train,
        "warmup": concept_scenes(world, BIRTH_CHECK_INTERVAL, seed=1),
        "concepts": concept_scenes(world, max(sizes["concepts"] + sizes["clients"], sizes["throughput"]), seed=2),
        "features": feature_scenes(world, features, sizes["features"], seed=3),
    }
    results: dict[str, Any] = {
        "sizes": sizes,
        "hyperparameters": SERVING,
        "targets_ms": TARGETS,
        "cpus": os.cpu_count(),
    }
    with tempfile.TemporaryDirectory(prefix="contextweb-bench-") as folder:
        references = {
            "fsync_ms": round(fsync_ms(Path(folder)), 3),
            "pipeline_ms": round(
                pipeline_ms(world, train, data["warmup"] + data["concepts"][:300], SERVING, len(data["warmup"])), 3
            ),
        }
        results["references"] = references
        results["load_average_before"] = os.getloadavg()
        for backend in args.backends.split(","):
            url = f"sqlite:///{Path(folder) / 'bench.sqlite3'}" if backend == "sqlite" else _fresh_postgres()
            if url is None:
                continue
            if backend == "postgresql":
                references["postgres_commit_ms"] = round(postgres_commit_ms(url), 3)
            results[backend] = run_backend(url, Path(folder) / f"{backend}.log", data, sizes)
            _report(backend, results[backend], references)
    results["load_average_after"] = os.getloadavg()
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "service.json").write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return results


if __name__ == "__main__":
    main()
