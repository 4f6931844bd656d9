"""Start-up preparation: once the server says it is ready, no scene request compiles a numba kernel
or imports a module, and start-up's objects are out of the garbage collector's collections."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from app.services.warmup import WARM_UP_FILE
from sim.record_warmup import render, warm_up_record

PROJECT = Path(__file__).resolve().parents[1]

# Run in a fresh interpreter: in the test process, earlier tests have compiled the kernels already.
# Through a serving process's real start-up (``serving_app``, as ``contextweb serve`` builds it, on
# a migrated database; TestClient runs the lifespan), then a model is trained and
# fitted (that compiles the fit's own kernels), then a scene of every level is learned and one
# is inferred. The script prints what start-up froze and the modules those requests imported,
# then the numba kernels of any module that gained a compiled signature during them.
_SCRIPT = """
import gc, json, sys
import numba
import numpy as np
from fastapi.testclient import TestClient
from app.serve import serving_app
from sim.world import World
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, make_settings, synthetic_training_objects
from tests.servers import migrate


def compiled():
    found = {}
    for name, module in list(sys.modules.items()):
        if module is not None:
            for attribute, value in list(vars(module).items()):
                if isinstance(value, numba.core.dispatcher.Dispatcher):
                    found[f"{name}.{attribute}"] = len(value.signatures)
    return found


world = World.paper(0)
migrate(sys.argv[1])
with TestClient(serving_app(make_settings(sys.argv[1]))) as client:
    model = client.post("/v1/models", json={"name": "w", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
    objects = synthetic_training_objects(world, seed=3)
    assert client.post(f"/v1/models/{model}/training-objects", json={"objects": objects}).status_code == 201
    assert client.post(f"/v1/models/{model}/fit", json={}).status_code == 200
    frozen = gc.get_freeze_count()
    numba_module_frozen = not any(o is numba for o in gc.get_objects())
    before, modules_before = compiled(), set(sys.modules)
    sphere = np.random.default_rng(0).normal(size=(300, 3))
    sphere = 0.04 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + [0.0, 0.3, 0.04]
    moved = {"before": {"points": sphere.tolist()}, "after": {"points": (sphere - [0.1, 0, 0]).tolist()}}
    sound = {"samples": np.random.default_rng(1).uniform(-0.5, 0.5, 8000).tolist(), "sample_rate": 16000}
    shaken = {"behaviour": "shake", **moved, "audio": sound}
    raw = {"look": {"points": sphere.tolist()}, "interactions": [{"behaviour": "move_left", **moved}, shaken]}
    measured = [{"features": objects[0]["features"]}, {"features": objects[1]["features"]}, {"raw": raw}]
    body = {"objects": concept_scenes(1, seed=5)[0]["objects"] + [{"concepts": {"cup": 0.7}}] + measured}
    for _ in range(4):
        assert client.post(f"/v1/models/{model}/scenes", json=body).status_code == 201
    assert client.post(f"/v1/models/{model}/infer", json=body).status_code == 200
    after, imported = compiled(), sorted(set(sys.modules) - modules_before)
print(json.dumps({"frozen": frozen, "numba_module_frozen": numba_module_frozen, "imported": imported}))
print(json.dumps({name: [before.get(name, 0), count] for name, count in after.items() if count != before.get(name, 0)}))
"""


@pytest.mark.slow
def test_after_start_up_no_request_compiles_or_imports_and_start_up_objects_are_frozen(tmp_path: Path) -> None:
    database = f"sqlite:///{tmp_path / 'warm.sqlite3'}"
    run = subprocess.run(
        [sys.executable, "-c", _SCRIPT, database], cwd=PROJECT, capture_output=True, text=True, timeout=280, check=False
    )
    assert run.returncode == 0, run.stderr[-3000:]
    start_up, compiled_by_requests = (json.loads(line) for line in run.stdout.strip().splitlines()[-2:])
    assert compiled_by_requests == {}
    assert start_up["imported"] == []  # librosa, e.g., imports its modules lazily on first use
    assert start_up["frozen"] > 0 and start_up["numba_module_frozen"]


# The service's own start-up in a fresh interpreter: migrate, then build the app as `contextweb serve`
# does (serving_app: the warm-up, then create_app) and start it (TestClient runs the lifespan); print
# every module of the simulator, the experiments and their plotting library that got imported. (tqdm is not checked: librosa's pooch imports it when it
# is installed, as an optional progress bar, and works without it.)
_SERVICE_IMPORTS = """
import json, sys
from fastapi.testclient import TestClient
from app.serve import serving_app
from app.settings import Settings
from storage.database import create_database_engine
from storage.migrations import upgrade_to_head

engine = create_database_engine(sys.argv[1])
upgrade_to_head(engine)  # what `contextweb migrate` does first
engine.dispose()
settings = Settings(
    database_url=sys.argv[1], environment="development", write_key=None, read_key=None, sqlite_synchronous="NORMAL"
)
with TestClient(serving_app(settings)) as client:  # warms up, freezes, then create_app, as `serve` does
    assert client.get("/readyz").status_code == 200
roots = ("sim", "experiments", "matplotlib")
print(json.dumps(sorted(name for name in sys.modules if name.split(".")[0] in roots)))
"""


@pytest.mark.slow
def test_the_service_imports_neither_the_simulator_nor_the_experiments(tmp_path: Path) -> None:
    env = {name: value for name, value in os.environ.items() if not name.startswith("CONTEXTWEB_")}
    database = f"sqlite:///{tmp_path / 'service.sqlite3'}"
    run = subprocess.run(
        [sys.executable, "-c", _SERVICE_IMPORTS, database],
        cwd=PROJECT,
        env=env,
        capture_output=True,
        text=True,
        timeout=280,
        check=False,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []


def test_the_warm_up_file_is_what_the_simulator_records_for_its_seed() -> None:
    """The committed file cannot drift from the world: regenerating it gives the same bytes."""
    committed = WARM_UP_FILE.read_text(encoding="utf-8")
    assert committed == render(warm_up_record(json.loads(committed)["seed"]))
    assert render(warm_up_record(1)) != committed  # the seed matters, so the check above is not vacuous
