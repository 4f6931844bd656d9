"""The robot-side client installs on its own: ``pip install ./bridge`` into a fresh venv gives a
working ``bridge.Client`` and none of the server's dependencies (issue 16, item 5); adding the ``bags``
extra gives the replay of ROS bags and yarp logs, which replays a real bag into a real service from
that venv, still without the server's packages (issue 18)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest

from sim.world import World, WorldConfig
from tests.conftest import synthetic_training_objects
from tests.test_bridge_bags import MAPPING, _small, write_bag
from tests.test_bridge_live import WRITE_KEY, ServiceProcess

PROJECT = Path(__file__).resolve().parents[1]
SERVER_MODULES = ("numba", "sqlalchemy", "librosa", "scipy", "core", "app", "storage")

# Run by the fresh venv's interpreter, isolated (-I: no repository on sys.path, no user site).
_PROBE = """
import importlib, importlib.metadata, json, sys
import bridge

def _importable(module):
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True

installed = sorted(d.metadata["Name"].lower() for d in importlib.metadata.distributions())
print(json.dumps({
    "client": bridge.Client.__module__,
    "file": bridge.__file__,
    "importable": [m for m in ("numba", "numpy", "sqlalchemy", "librosa", "scipy", "core", "app", "storage",
                               "rosbags", "bridge.tools.bags", "bridge.tools.yarp", "bridge.tools.replay")
                   if _importable(m)],
    "installed": installed,
    "loaded": sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "sqlalchemy", "librosa", "scipy",
                                                                   "core", "app", "storage")),
}))
"""

# The replay of a bag from the robot's venv: the library call behind `contextweb bridge replay`.
_REPLAY = """
import sys
from pathlib import Path
from bridge import Client
from bridge.tools.bags import replay_bag
from bridge.tools.mapping import parse_mapping
import json
url, key, model_id, bag, mapping = sys.argv[1:6]
with Client(url, key) as client:
    for _ in range(2):  # the second run is a restart: every scene answered from its key
        answers = replay_bag(client, model_id, Path(bag), parse_mapping(json.loads(mapping)))
print(json.dumps({"scenes": [a.scene_id for a in answers], "modules": sorted(sys.modules)}))
"""


def _run(command: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=600, check=False)


def _probe(python: Path, cwd: Path) -> dict:
    import json

    probe = _run([str(python), "-I", "-c", _PROBE], cwd)
    assert probe.returncode == 0, probe.stderr[-3000:]
    return json.loads(probe.stdout)


@pytest.mark.slow
def test_pip_install_bridge_gives_the_client_and_none_of_the_server(tmp_path: Path) -> None:
    import json

    # A copy: pip builds in the source tree (build/, *.egg-info), which is the developer's checkout.
    source = shutil.copytree(PROJECT / "bridge", tmp_path / "bridge", ignore=shutil.ignore_patterns("__pycache__"))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    install = _run([str(python), "-m", "pip", "install", "--quiet", str(source)], tmp_path)
    assert install.returncode == 0, install.stderr[-3000:]
    found = _probe(python, tmp_path)
    assert found["client"] == "bridge.client"
    assert Path(found["file"]).is_relative_to(venv), "the installed copy, not the repository's"
    assert found["importable"] == [], "the robot's install holds the client alone"
    assert "contextweb-bridge" in found["installed"] and {"httpx", "pydantic"} <= set(found["installed"])
    assert not {"numba", "numpy", "sqlalchemy", "librosa", "contextweb"} & set(found["installed"])

    # The bags extra: the replay tools import (numpy, rosbags and the file readers come with them) ...
    install = _run([str(python), "-m", "pip", "install", "--quiet", f"{source}[bags]"], tmp_path)
    assert install.returncode == 0, install.stderr[-3000:]
    found = _probe(python, tmp_path)
    assert found["importable"] == ["numpy", "rosbags", "bridge.tools.bags", "bridge.tools.yarp", "bridge.tools.replay"]
    assert found["loaded"] == [], "importing the replay tools loads nothing of the server"
    assert not {"numba", "scipy", "sqlalchemy", "librosa", "contextweb"} & set(found["installed"])

    # ... and replay a real bag into a real service, twice: each scene is learned once.
    world = World(WorldConfig.paper(), seed=0)
    rng = np.random.default_rng(3)
    scenes = [[_small(world.record(world.test_objects[0], rng))], [_small(world.record(world.test_objects[5], rng))]]
    bag = write_bag(tmp_path, "mcap", scenes)
    service = ServiceProcess(tmp_path).start()
    try:
        headers = {"X-API-Key": WRITE_KEY}
        model_id = httpx.post(f"{service.url}/v1/models", json={"name": "robot", "seed": 5}, headers=headers).json()[
            "id"
        ]
        objects = {"objects": synthetic_training_objects(world, seed=1)}
        httpx.post(f"{service.url}/v1/models/{model_id}/training-objects", json=objects, headers=headers, timeout=60)
        fit = httpx.post(
            f"{service.url}/v1/models/{model_id}/fit", json={"method": "kmeans"}, headers=headers, timeout=60
        )
        assert fit.status_code == 200, fit.text
        arguments = [service.url, WRITE_KEY, model_id, str(bag), json.dumps(MAPPING)]
        replayed = _run([str(python), "-I", "-c", _REPLAY, *arguments], tmp_path)
        assert replayed.returncode == 0, replayed.stderr[-3000:]
        answer = json.loads(replayed.stdout)
        assert answer["scenes"] == [0, 1]
        assert not [m for m in answer["modules"] if m.split(".")[0] in SERVER_MODULES]
        model = httpx.get(f"{service.url}/v1/models/{model_id}", headers=headers).json()
        assert model["scene_count"] == 2
    finally:
        service.stop()
