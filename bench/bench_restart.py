"""Restart-to-ready, storage and latency of one model as its corpus grows (issue 17, goals 1-3).

For each size (``--sizes 10000,100000,1000000``; default 10k and 100k) a trained
paper-world model on a fresh SQLite database learns that many concept-level
scenes IN-PROCESS through the service's own code (``prepare_scene`` and
``learn_scene`` of app/services/scenes.py, the same rows, checkpoints and
compressed answers as over HTTP; 500 scenes a transaction, to build fast), then:

- ``restart_s``: a real ``contextweb serve`` started on that database, until
  ``/readyz`` answers 200 (bench_service.Server), against an empty database
  and against a 1,000-scene one in the same run;
- ``bytes_per_scene``: the database file's size (after a WAL checkpoint) over
  the scenes, with each table's and index's share from SQLite's ``dbstat``;
- ``load_s`` / ``load_from_batches_s``: the model's load in-process (``load_runtime``, one
  snapshot) from its checkpoint and the token batches since, and from every token batch (the
  checkpoint row removed: the worst tail's cost at that size; only while no batch was compacted,
  else None: then the batches alone no longer hold the corpus);
- ``memory_per_scene``: the serving process's RSS once ready, minus the RSS
  of the empty database's server, over the scenes;
- ``p50/p99``: 300 further scenes posted over HTTP (one lean client) to the
  big model and to the 1,000-scene one.

``--synthetic=1000000x78,1000000x20`` adds the model part of a start on synthetic corpora of
that many scenes and tokens a scene (4 contexts, the paper's 29 concepts, each scene's tokens
mostly in its context), where building the corpus through the service would take hours here:
the checkpoint's bytes, its packing and writing (what the checkpointing scene pays), reading
and unpacking, and the
model built from it (``stored_incremental_lda``, no tail) with its memory (tracemalloc).

Results go to bench/results/restart.json.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy import text

from app.main import create_app
from app.registry import load_runtime, stored_incremental_lda
from app.schemas.scenes import SceneCreate
from app.services import scenes as scene_service
from app.settings import Settings
from bench.bench_service import LatencySummary, LeanClient, Server, _summary, concept_scenes
from sim.world import World
from storage.database import create_database_engine, create_session_makers, snapshot
from storage.migrations import upgrade_to_head
from storage.models import IncrementalLdaCheckpoint
from storage.repositories import incremental_lda as lda_repository
from storage.repositories import models as model_repository
from tests.conftest import synthetic_training_objects

RESULTS = Path(__file__).resolve().parent / "results"
DEFAULT_SIZES = (10_000, 100_000)
REFERENCE_SIZE = 1_000
BATCH = 500
LATENCY_SCENES = 300


def _migrated(url: str) -> str:
    """``url`` after what ``contextweb migrate`` does (the app refuses a database not at head)."""
    engine = create_database_engine(url)
    try:
        upgrade_to_head(engine)
    finally:
        engine.dispose()
    return url


def _settings(url: str) -> Settings:
    values: dict[str, Any] = {"database_url": url, "environment": "development", "write_key": None, "read_key": None}
    return Settings(**values)


def build(
    path: Path, size: int, pool: list[dict[str, Any]], *, training_seed: int = 1, keyed: bool = False
) -> tuple[str, float]:
    """A database at ``path`` with one trained model (on the synthetic training objects of
    ``training_seed``) that has learned ``size`` scenes, each with a 32-character Idempotency-Key
    (as the bridge's) if ``keyed``; (model id, seconds)."""
    url = f"sqlite:///{path}"
    world = World.paper(0)
    with TestClient(create_app(_settings(_migrated(url)))) as client:
        model_id = client.post("/v1/models", json={"name": "month", "seed": 0}).json()["id"]
        training = {"objects": synthetic_training_objects(world, seed=training_seed)}
        client.post(f"/v1/models/{model_id}/training-objects", json=training).raise_for_status()
        client.post(f"/v1/models/{model_id}/fit", json={}).raise_for_status()
        state = client.app_state["contextweb"]
        model = state.registry.get(model_id)
        bodies = [SceneCreate.model_validate(body) for body in pool]
        started = time.perf_counter()
        learned = 0
        while learned < size:
            checkpoints = []
            with model.writer.transaction(state.write_sessions, state.registry) as write:
                for i in range(min(BATCH, size - learned)):
                    if i:
                        write.version += 1  # one version per scene, as the service gives them
                    key = f"{learned:032x}" if keyed else None
                    read = scene_service.read_scene(model, bodies[learned % len(bodies)], key)
                    prepared = scene_service.prepare_scene(model, read)
                    scene = scene_service.learn_scene(write.session, model, write.version, prepared, key, write.locked)
                    checkpoints += [scene.checkpoint] if scene.checkpoint is not None else []
                    learned += 1
                write.version_saved = True
            for checkpoint in checkpoints:  # after the commit, as the service stores them
                scene_service.store_checkpoint(state.write_sessions, model_id, checkpoint)
            if learned % 50_000 < BATCH:
                print(f"  {learned:,} scenes in {time.perf_counter() - started:.0f} s", flush=True)
        seconds = time.perf_counter() - started
    return model_id, seconds


def storage(path: Path, scenes: int) -> dict[str, Any]:
    engine = create_database_engine(f"sqlite:///{path}")
    try:
        with engine.connect() as connection:
            connection.execute(text("PRAGMA wal_checkpoint(TRUNCATE)"))
            rows = connection.execute(text("SELECT name, SUM(pgsize) FROM dbstat GROUP BY name")).all()
    finally:
        engine.dispose()
    size = path.stat().st_size
    return {
        "database_bytes": size,
        "bytes_per_scene": round(size / max(scenes, 1), 1),
        "bytes_per_scene_by_object": {
            name: round(n / max(scenes, 1), 1) for name, n in sorted(rows, key=lambda r: -r[1])
        },
    }


def load_seconds(path: Path, model_id: str) -> dict[str, float | None]:
    """In-process load of the model from its checkpoint, then (checkpoint row removed) from its batches."""
    engine = create_database_engine(f"sqlite:///{path}")
    read, _ = create_session_makers(engine)
    times: dict[str, float | None] = {}
    try:
        with snapshot(read) as session:
            whole = lda_repository.compacted_version(session, model_id) == 0
        for name in ("load_s", "load_from_batches_s"):
            if name == "load_from_batches_s" and not whole:
                times[name] = None
                continue
            with snapshot(read) as session:
                started = time.perf_counter()
                row = model_repository.get_model(session, model_id)
                assert row is not None
                load_runtime(session, row)
                times[name] = round(time.perf_counter() - started, 3)
            with engine.begin() as connection:
                connection.execute(text("DELETE FROM incremental_lda_checkpoint"))
    finally:
        engine.dispose()
    return times


def synthetic_load(scenes: int, tokens_per_scene: int, contexts: int = 4) -> dict[str, float]:
    """The model part of a start on a synthetic checkpoint (see the module's docstring)."""
    rng = np.random.default_rng(0)
    names = list(World.paper(0).vocabulary.concepts)
    scene_context = rng.integers(0, contexts, scenes)
    words = ((rng.integers(0, 12, (scenes, tokens_per_scene)) + scene_context[:, None] * 5) % len(names)).ravel()
    drawn = rng.integers(0, contexts, (scenes, tokens_per_scene))
    assignments = np.where(rng.random((scenes, tokens_per_scene)) < 0.9, scene_context[:, None], drawn).ravel()
    n_kw = np.zeros((contexts, len(names)), dtype=np.int64)
    np.add.at(n_kw, (assignments, words), 1)
    saved = lda_repository.StoredCheckpoint(
        version=scenes,
        context_count=contexts,
        word_count=len(names),
        words=words.astype(np.int32),
        contexts=assignments.astype(np.int32),
        doc_offsets=(np.arange(scenes + 1) * tokens_per_scene).astype(np.int32),
    )
    del words, assignments, drawn
    directory = tempfile.TemporaryDirectory(prefix="bench_restart_synthetic_")
    engine = create_database_engine(f"sqlite:///{directory.name}/checkpoint.sqlite3")  # its table's round trip
    _, write = create_session_makers(engine)
    try:
        with write() as session:
            session.execute(text("CREATE TABLE model (id VARCHAR(32) PRIMARY KEY)"))
            session.execute(text("INSERT INTO model VALUES ('synthetic')"))
            IncrementalLdaCheckpoint.__table__.create(session.connection())
            started = time.perf_counter()
            lda_repository.save_checkpoint(session, "synthetic", saved)
            save_s = time.perf_counter() - started
            del saved
            started = time.perf_counter()
            checkpoint = lda_repository.load_checkpoint(session, "synthetic")
            load_s = time.perf_counter() - started
            blob_bytes = session.execute(text("SELECT length(arrays) FROM incremental_lda_checkpoint")).scalar_one()
    finally:
        engine.dispose()
        directory.cleanup()
    entries = np.array([(k, w, n_kw[k, w]) for k in range(contexts) for w in range(len(names))], dtype=np.int64)
    stored = lda_repository.StoredStart(
        word_names=names,
        word_kinds=[None] * len(names),
        checkpoint=checkpoint,
        tail=lda_repository.ReplayedTokens.none(scenes * tokens_per_scene),
        count_entries=entries,
        scene_count=scenes,
        context_count=contexts,
        state={"rng_state": np.random.default_rng(1).bit_generator.state},
        version=scenes,
    )
    tracemalloc.start()
    started = time.perf_counter()
    model = stored_incremental_lda(stored, {})
    build_s = time.perf_counter() - started
    memory, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    del model
    return {
        "checkpoint_bytes": blob_bytes,
        "checkpoint_bytes_per_scene": round(blob_bytes / scenes, 1),
        "pack_and_write_s": round(save_s, 2),
        "read_and_unpack_s": round(load_s, 2),
        "build_model_s": round(build_s, 2),
        "model_memory_per_scene": round(memory / scenes, 1),
        "peak_bytes": peak,
    }


def serve(path: Path, log: Path) -> tuple[Server, float, int]:
    started = time.perf_counter()
    server = Server(f"sqlite:///{path}", log)
    seconds = time.perf_counter() - started
    return server, seconds, _rss(server.process.pid)


def _rss(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    return 0


def latency(server: Server, model_id: str, scenes: list[dict[str, Any]]) -> LatencySummary:
    client = LeanClient(server.port)
    try:
        return _summary(client.post_all(model_id, scenes))
    finally:
        client.close()


def main() -> dict:
    sizes: tuple[int, ...] = DEFAULT_SIZES
    synthetic: list[tuple[int, int]] = []
    for arg in sys.argv[1:]:
        if arg.startswith("--sizes="):
            sizes = tuple(int(size) for size in arg.split("=", 1)[1].split(",") if size)
        if arg.startswith("--synthetic="):
            synthetic = [(int(a), int(b)) for a, b in (item.split("x") for item in arg.split("=", 1)[1].split(","))]
    world = World.paper(0)
    pool = concept_scenes(world, 2_000, seed=7)
    later = concept_scenes(world, LATENCY_SCENES, seed=8)
    result: dict[str, Any] = {"sizes": {}, "synthetic": {}}
    for scenes, tokens in synthetic:
        load_figures = synthetic_load(scenes, tokens)
        result["synthetic"][f"{scenes}x{tokens}"] = load_figures
        print(f"synthetic {scenes:,} scenes x {tokens} tokens: {load_figures}", flush=True)
    if not sizes:
        return _write(result)
    with tempfile.TemporaryDirectory(prefix="bench_restart_") as directory:
        work = Path(directory)
        log = work / "servers.log"
        empty = work / "empty.sqlite3"
        _migrated(f"sqlite:///{empty}")
        server, seconds, empty_rss = serve(empty, log)
        server.stop()
        result["empty"] = {"restart_s": round(seconds, 2), "rss_bytes": empty_rss}
        print(f"empty database: ready in {seconds:.2f} s, RSS {empty_rss / 2**20:.0f} MiB", flush=True)

        for size in (REFERENCE_SIZE, *sizes):
            path = work / f"corpus_{size}.sqlite3"
            print(f"building {size:,} scenes in-process", flush=True)
            model_id, build_seconds = build(path, size, pool)
            figures: dict[str, Any] = {"build_s": round(build_seconds, 1), **storage(path, size)}
            server, seconds, rss = serve(path, log)
            try:
                figures["restart_s"] = round(seconds, 2)
                figures["rss_bytes"] = rss
                figures["memory_per_scene"] = round((rss - empty_rss) / size, 1)
                figures["latency"] = latency(server, model_id, later)
            finally:
                server.stop()
            figures |= load_seconds(path, model_id)
            result["sizes"][str(size)] = figures
            lat = figures["latency"]
            print(
                f"{size:>9,} scenes: built in {build_seconds:.0f} s; ready in {seconds:.2f} s "
                f"(empty {result['empty']['restart_s']:.2f} s); {figures['bytes_per_scene']:.0f} B/scene "
                f"({', '.join(f'{k} {v:.0f}' for k, v in list(figures['bytes_per_scene_by_object'].items())[:5])}); "
                f"memory {figures['memory_per_scene']:.0f} B/scene; load in-process {figures['load_s']:.2f} s "
                f"(from every batch {figures['load_from_batches_s']} s); "
                f"p50 {lat['median_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms",
                flush=True,
            )
            path.unlink()
    return _write(result)


def _write(result: dict[str, Any]) -> dict[str, Any]:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "restart.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
