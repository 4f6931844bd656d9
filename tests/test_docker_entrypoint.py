"""The container's entry point and health check, run outside docker (no engine runs here).

The image itself is built by hand (docs/deployment.md); these tests run the same
``docker/entrypoint.sh`` and the Dockerfile's ``HEALTHCHECK`` command against a
temporary SQLite database, and check that compose.yaml's commands are ones the
CLI accepts.
"""

from __future__ import annotations

import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import build_parser
from tests.test_bridge_live import PROJECT, ServiceProcess

DOCKER = PROJECT / "docker"


def _healthcheck_command() -> list[str]:
    """The Dockerfile's ``HEALTHCHECK ... CMD python -c "..."``, as an argument list."""
    text = (DOCKER / "Dockerfile").read_text().replace("\\\n", " ")
    command = re.search(r"^HEALTHCHECK .*?CMD (python .*)$", text, re.MULTILINE)
    assert command is not None, "the Dockerfile has a HEALTHCHECK ... CMD python ..."
    return [sys.executable, *shlex.split(command.group(1))[1:]]


@pytest.mark.slow
def test_entrypoint_migrates_then_serves_and_the_healthcheck_sees_it(tmp_path: Path) -> None:
    service = ServiceProcess(tmp_path, command=["sh", str(DOCKER / "entrypoint.sh")]).start()
    try:
        assert "is at the latest schema" in service.log(), "the entrypoint runs `contextweb migrate` first"
        healthy = subprocess.run(_healthcheck_command(), check=False, env=service.env, capture_output=True, timeout=30)
        assert healthy.returncode == 0, healthy.stderr
    finally:
        service.stop(signal.SIGTERM)
    # `exec`: the server is the process the container engine signals, and it shuts down gracefully.
    assert service.process is not None and f"Finished server process [{service.process.pid}]" in service.log()
    unhealthy = subprocess.run(_healthcheck_command(), check=False, env=service.env, capture_output=True, timeout=30)
    assert unhealthy.returncode != 0


def test_dockerfile_defaults() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    assert re.search(r"^ARG BASE_IMAGE=python:3\.11-slim$", text, re.MULTILINE)
    users = re.findall(r"^USER (\S+)$", text, re.MULTILINE)
    assert users and users[-1] not in ("root", "0")
    assert "curl" not in text.split("HEALTHCHECK", 1)[1]
    final_stage = text.rsplit("\nFROM ", 1)[1]
    # Without a write key the server would bind loopback only, unreachable yet healthy: the image refuses.
    assert "CONTEXTWEB_ENVIRONMENT=production" in final_stage
    # The kernels are compiled into the image by its user, after the sources are in place.
    assert final_stage.index(f"USER {users[-1]}") < final_stage.index("RUN python docker/precompile.py")
    assert "pip install --requirement docker/constraints.txt" in text


def test_the_constraints_pin_every_server_dependency() -> None:
    import tomllib

    from packaging.requirements import Requirement
    from packaging.utils import canonicalize_name

    project = tomllib.loads((DOCKER.parent / "pyproject.toml").read_text())["project"]
    pinned = {}
    for line in (DOCKER / "constraints.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            requirement = Requirement(line)
            (specifier,) = requirement.specifier
            assert specifier.operator == "==", line
            pinned[canonicalize_name(requirement.name)] = specifier.version
    for dependency in project["dependencies"]:
        requirement = Requirement(dependency)
        name = canonicalize_name(requirement.name)
        assert name in pinned, f"{name} is not pinned: run make constraints"
        assert requirement.specifier.contains(pinned[name]), (
            f"{name}=={pinned[name]} is outside {requirement.specifier}"
        )


def test_compose_commands_are_valid_cli_invocations() -> None:
    yaml = pytest.importorskip("yaml")
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = compose["services"]
    simulator = services["simulator"]
    args = build_parser("bridge").parse_args([*simulator["entrypoint"][1:], *simulator["command"]])
    assert (args.command, args.tool, args.url) == ("bridge", "simulate", "http://api:8000")
    assert "postgres" in services["postgres"]["profiles"] and "profiles" not in services["api"]
    assert "contextweb-data:/data" in services["api"]["volumes"]
    postgres_env = dict(
        line.split("=", 1)
        for line in (DOCKER / "postgres.env").read_text().splitlines()
        if line and not line.startswith("#")
    )
    assert postgres_env["COMPOSE_PROFILES"] == "postgres"
    assert postgres_env["CONTEXTWEB_DATABASE_URL"].startswith("postgresql://contextweb:")
