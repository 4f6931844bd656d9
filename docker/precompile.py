"""Compile every numba kernel the service runs into ``NUMBA_CACHE_DIR``, at image build time.

The Dockerfile runs this in its final stage, as the service's user and on the installed
sources, so a new container loads compiled kernels from the image instead of compiling them
on its first start (how long that takes: docs/benchmarks.md). It drives the real app in-process, on a
throwaway SQLite database, through every route that runs numba: both prototype fits (k-means
and RGNG), scenes at the concepts, features and raw levels (learned and inferred, enough of
them for the growth checks to run), the three planners and the contexts. Numba compiles a
kernel per argument types on its first call; calling the routes, not the kernels, is what
makes the compiled specialisations the ones requests use.

numba keys its cache on the source files (path, size and modification time) and on the CPU:
a container on a host whose CPU differs from the build host's compiles again on its first
start, into the same directory (docs/deployment.md says how to build a portable image).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
from fastapi.testclient import TestClient

from app.serve import serving_app
from app.settings import Settings
from sim.robot import scene_objects, training_object
from sim.world import World
from storage.database import create_database_engine
from storage.migrations import upgrade_to_head

#: Scenes per level: enough for the growth checks to run.
SCENES_PER_LEVEL = 4
MAX_POINTS = 300


def precompile() -> float:
    """Run the routes once; the seconds it took."""
    started = time.perf_counter()
    world = World.paper(0)
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as directory:
        settings = Settings(
            database_url=f"sqlite:///{Path(directory) / 'precompile.sqlite3'}",
            write_key=None,
            environment="development",
        )
        engine = create_database_engine(settings.resolved_database_url)
        upgrade_to_head(engine)  # as `contextweb migrate`
        engine.dispose()
        with TestClient(serving_app(settings)) as client:  # the warm-up's kernels too, as `contextweb serve`
            for level, method in (("features", "rgng"), ("raw", "kmeans")):
                model = _checked(client.post("/v1/models", json={"name": f"precompile-{method}"}))["id"]
                objects = [
                    training_object(obj, world.record(obj, rng), level, rng, MAX_POINTS).model_dump(mode="json")
                    for obj in world.train_objects
                ]
                for start in range(0, len(objects), 8):
                    batch = {"objects": objects[start : start + 8]}
                    _checked(client.post(f"/v1/models/{model}/training-objects", json=batch))
                _checked(client.post(f"/v1/models/{model}/fit", json={"method": method}))
                for level_of_scene in ("concepts", "features", "raw"):
                    for scene in world.scenes(SCENES_PER_LEVEL, seed=1):
                        body = {
                            "objects": [
                                obj.model_dump(mode="json", exclude_none=True)
                                for obj in scene_objects(world, scene, level_of_scene, rng, MAX_POINTS)
                            ]
                        }
                        _checked(client.post(f"/v1/models/{model}/scenes", json=body))
                    _checked(client.post(f"/v1/models/{model}/infer", json=body))
                for mode in ("paper", "bfs", "astar"):
                    plan = {"object": "cup", "start": 8, "goal": 5, "obstacles": {"plate": 3}, "mode": mode}
                    _checked(client.post(f"/v1/models/{model}/plans", json=plan))
                _checked(client.get(f"/v1/models/{model}/contexts"))
        with TestClient(serving_app(settings)) as client:  # a start with stored models: the load's kernels
            _checked(client.get("/v1/models"))
    return time.perf_counter() - started


def _checked(response: httpx.Response) -> dict:
    if response.status_code >= 400:
        raise SystemExit(f"precompile: {response.request.method} {response.request.url.path}: {response.text}")
    return response.json()


if __name__ == "__main__":
    print(f"precompile: every kernel compiled in {precompile():.1f} s", file=sys.stderr)
