"""The robot-side client installs on its own: ``pip install ./bridge`` into a fresh venv gives a
working ``bridge.Client`` and none of the server's dependencies (issue 16, item 5)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PROJECT = Path(__file__).resolve().parents[1]

# Run by the fresh venv's interpreter, isolated (-I: no repository on sys.path, no user site).
_PROBE = """
import importlib.metadata, importlib.util, json
import bridge
installed = sorted(d.metadata["Name"].lower() for d in importlib.metadata.distributions())
print(json.dumps({
    "client": bridge.Client.__module__,
    "file": bridge.__file__,
    "importable": [m for m in ("numba", "numpy", "sqlalchemy", "librosa", "scipy", "core", "app", "storage", "bridge.tools")
                   if importlib.util.find_spec(m) is not None],
    "installed": installed,
}))
"""


@pytest.mark.slow
def test_pip_install_bridge_gives_the_client_and_none_of_the_server(tmp_path: Path) -> None:
    import json

    # A copy: pip builds in the source tree (build/, *.egg-info), which is the developer's checkout.
    source = shutil.copytree(PROJECT / "bridge", tmp_path / "bridge", ignore=shutil.ignore_patterns("__pycache__"))
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    install = subprocess.run(
        [str(python), "-m", "pip", "install", "--quiet", str(source)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert install.returncode == 0, install.stderr[-3000:]
    probe = subprocess.run(
        [str(python), "-I", "-c", _PROBE], cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False
    )
    assert probe.returncode == 0, probe.stderr[-3000:]
    found = json.loads(probe.stdout)
    assert found["client"] == "bridge.client"
    assert Path(found["file"]).is_relative_to(venv), "the installed copy, not the repository's"
    assert found["importable"] == [], "the robot's install holds the client alone"
    assert "contextweb-bridge" in found["installed"] and {"httpx", "pydantic"} <= set(found["installed"])
    assert not {"numba", "numpy", "sqlalchemy", "librosa", "contextweb"} & set(found["installed"])
