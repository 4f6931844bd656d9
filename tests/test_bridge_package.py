"""The robot-side client installs on its own: ``pip install ./bridge`` into a fresh venv gives a
working ``bridge.Client`` and none of the server's dependencies (issue 16, item 5); adding the ``bags``
extra gives the replay of ROS bags and yarp logs, which reads real bags (one cut short) in that venv into
the very requests the server's install makes of them, still without the server's packages (issue 18)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim.world import World, WorldConfig
from tests.test_bridge_bags import MAPPING, _small, write_bag

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
                               "rosbags", "mcap", "bridge.tools.bags", "bridge.tools.yarp", "bridge.tools.replay")
                   if _importable(m)],
    "installed": installed,
    "loaded": sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "sqlalchemy", "librosa", "scipy",
                                                                   "core", "app", "storage")),
}))
"""

# The bag replay's reading from the robot's venv: a bag cut short (read with mcap up to its cut: the first
# scene is read, the cut one refused), then the whole bag; each scene's key and a digest of its raw objects
# (the body `contextweb bridge replay` posts).
_READ = """
import hashlib, json, sys
from pathlib import Path
from bridge import InvalidRecordingError
from bridge.tools.bags import BagReplay
from bridge.tools.mapping import parse_mapping

def read(path, mapping):
    scenes, refused = [], None
    with BagReplay(Path(path), parse_mapping(json.loads(mapping))) as bag:
        try:
            for scene in bag.scenes(seed=1, max_points=50):
                body = json.dumps([raw.model_dump(mode="json") for raw in scene.recordings], sort_keys=True)
                scenes.append([scene.key, hashlib.sha256(body.encode()).hexdigest()])
        except InvalidRecordingError as error:
            refused = str(error)
    return {"scenes": scenes, "refused": refused}

if __name__ == "__main__":
    cut, whole, mapping = sys.argv[1:4]
    answer = {"cut": read(cut, mapping), "whole": read(whole, mapping), "modules": sorted(sys.modules)}
    print(json.dumps(answer))
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
    install = _run([str(python), "-m", "pip", "install", "--quiet", "--no-compile", str(source)], tmp_path)
    assert install.returncode == 0, install.stderr[-3000:]
    found = _probe(python, tmp_path)
    assert found["client"] == "bridge.client"
    assert Path(found["file"]).is_relative_to(venv), "the installed copy, not the repository's"
    assert found["importable"] == [], "the robot's install holds the client alone"
    assert "contextweb-bridge" in found["installed"] and {"httpx", "pydantic"} <= set(found["installed"])
    assert not {"numba", "numpy", "sqlalchemy", "librosa", "contextweb"} & set(found["installed"])

    # The bags extra: the replay tools import (numpy, rosbags and the file readers come with them) ...
    install = _run([str(python), "-m", "pip", "install", "--quiet", "--no-compile", f"{source}[bags]"], tmp_path)
    assert install.returncode == 0, install.stderr[-3000:]
    found = _probe(python, tmp_path)
    assert found["importable"] == [
        "numpy", "rosbags", "mcap", "bridge.tools.bags", "bridge.tools.yarp", "bridge.tools.replay",
    ]  # fmt: skip
    assert found["loaded"] == [], "importing the replay tools loads nothing of the server"
    assert not {"numba", "scipy", "sqlalchemy", "librosa", "contextweb"} & set(found["installed"])

    # ... and read real bags, a whole one and one cut short, into exactly the scenes (keys and bodies) and the
    # refusal that the server's install reads from them; those bodies are posted to a service and learned
    # once in tests/test_bridge_bags.py (a service started here would cost more than the rest of this test).
    world = World(WorldConfig.paper(), seed=0)
    rng = np.random.default_rng(3)
    scenes = [[_small(world.record(world.test_objects[0], rng))], [_small(world.record(world.test_objects[5], rng))]]
    bag = write_bag(tmp_path, "mcap", scenes)
    cut = shutil.copytree(bag, tmp_path / "cut" / bag.name)
    data = next(cut.glob("*.mcap"))
    data.write_bytes(data.read_bytes()[: data.stat().st_size * 7 // 10])  # inside the second scene
    (tmp_path / "read_bags.py").write_text(_READ, encoding="utf-8")
    arguments = [str(cut), str(bag), json.dumps(MAPPING)]
    robot = _run([str(python), "-I", str(tmp_path / "read_bags.py"), *arguments], tmp_path)
    assert robot.returncode == 0, robot.stderr[-3000:]
    answer = json.loads(robot.stdout)
    assert not [m for m in answer["modules"] if m.split(".")[0] in SERVER_MODULES]
    # The same reading in the server's install (this repository first on the path, as `python -m` puts it).
    server_env = os.environ | {"PYTHONPATH": str(PROJECT)}
    reading = subprocess.run(
        [sys.executable, str(tmp_path / "read_bags.py"), *arguments],
        cwd=tmp_path, env=server_env, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert reading.returncode == 0, reading.stderr[-3000:]
    server = json.loads(reading.stdout)
    assert answer["cut"] == server["cut"] and answer["whole"] == server["whole"]
    assert len(answer["whole"]["scenes"]) == 2 and answer["whole"]["refused"] is None
    assert answer["cut"]["scenes"] == answer["whole"]["scenes"][:1], "the whole scene before the cut, same key"
    refused = answer["cut"]["refused"]
    assert "is the last one read: the file ends inside a chunk" in refused and "scene 1 (from t = " in refused
