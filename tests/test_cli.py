"""The ``contextweb`` command line: every command listed, only the chosen one built."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from app.cli import COMMANDS, build_parser, main


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert name in out


def test_serving_does_not_import_the_experiments() -> None:
    code = (
        "import sys; from app.cli import build_parser; build_parser('serve');"
        "print(sorted(m for m in ('matplotlib', 'experiments.recognition', 'core.context') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_unknown_experiment_is_refused_with_the_known_names(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["experiment", "telepathy"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'telepathy'" in capsys.readouterr().err


def test_experiment_prints_its_json_summary(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["experiment", "mixed", "--quick", "--seed", "7", "--json", "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary == json.loads((tmp_path / "summary.json").read_text())
    assert build_parser("experiment").parse_args(["experiment", "mixed"]).seed == 0


@pytest.mark.parametrize("command", ["migrate", "serve"])
def test_an_unreachable_database_is_one_line_and_exit_69_not_a_traceback(command: str) -> None:
    import socket

    with socket.socket() as closed:  # a port that refuses connections: bound, never listened on
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
        environment = _environment(CONTEXTWEB_DATABASE_URL=f"postgresql://robot:secret@127.0.0.1:{port}/fleet")
        result = subprocess.run(
            [sys.executable, "-m", "app.cli", command],
            capture_output=True,
            text=True,
            env=environment,
            timeout=120,
            check=False,
        )
    assert result.returncode == 69
    assert "Traceback" not in result.stderr and "secret" not in result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith(f"contextweb {command}:")]
    assert len(errors) == 1 and "cannot be reached" in errors[0] and f"127.0.0.1:{port}/fleet" in errors[0]


def test_invalid_settings_are_one_line_each_and_exit_78() -> None:

    environment = _environment(CONTEXTWEB_ENVIRONMENT="production", CONTEXTWEB_PORT="99999")
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", "migrate"],
        capture_output=True,
        text=True,
        env=environment,
        timeout=120,
        check=False,
    )
    assert result.returncode == 78 and "Traceback" not in result.stderr
    assert result.stderr.splitlines() == [
        "contextweb migrate: CONTEXTWEB_PORT: Input should be less than or equal to 65535"
    ], result.stderr


@pytest.mark.parametrize(
    ("url", "problem"),
    [
        ("robot:secret@fleet-db/contextweb", "cannot be read as a database URL"),
        ("mysql://robot:secret@fleet-db/contextweb", "models are stored in PostgreSQL or SQLite, not 'mysql'"),
    ],
)
def test_a_database_url_that_is_not_one_of_ours_is_one_line_and_exit_78(url: str, problem: str) -> None:
    """Not a traceback from SQLAlchemy's parser or a missing MySQL driver; the URL (its password) not echoed."""
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", "serve"],
        capture_output=True,
        text=True,
        env=_environment(CONTEXTWEB_DATABASE_URL=url),
        timeout=120,
        check=False,
    )
    assert result.returncode == 78 and "Traceback" not in result.stderr and "secret" not in result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith("contextweb serve: CONTEXTWEB_DATABASE_URL: ") and problem in line, line


def test_an_empty_database_url_means_the_default() -> None:
    from storage.database import DEFAULT_DATABASE_URL
    from tests.conftest import make_settings

    settings = make_settings("")
    assert settings.database_url is None and settings.resolved_database_url == DEFAULT_DATABASE_URL
    assert settings.scene_threads == 1
    assert make_settings("postgres://robot@fleet-db/contextweb").scene_threads == 2  # postgresql's alias


def test_migrate_needs_no_keys_in_production(tmp_path: Path) -> None:

    url = f"sqlite:///{tmp_path / 'contextweb.sqlite3'}"
    environment = _environment(CONTEXTWEB_ENVIRONMENT="production", CONTEXTWEB_DATABASE_URL=url)
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", "migrate"],
        capture_output=True,
        text=True,
        env=environment,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert "is at the latest schema" in result.stdout


def _previous_revision() -> str:
    from alembic.script import ScriptDirectory

    from storage.migrations import alembic_config

    script = ScriptDirectory.from_config(alembic_config())
    previous = script.get_revision(script.get_current_head()).down_revision
    assert isinstance(previous, str), "the head has one parent"
    return previous


@pytest.mark.parametrize(
    ("command", "revision"),
    [("serve", None), ("serve", "previous"), ("keys", None), ("models", "previous")],
    ids=["empty", "behind", "keys", "models"],
)
def test_a_database_not_at_head_is_refused_with_one_line_and_exit_75(
    tmp_path: Path, command: str, revision: str | None
) -> None:
    """``serve`` (and ``keys``, ``models``) never migrate: they name the two revisions and say what
    to run. ``models check`` on a schema one revision behind said "ok" before, and on an older one
    printed a traceback and exited 1, its code for "problems found" (a drill, 2026-12-07)."""
    from sqlalchemy import inspect

    from alembic import command as alembic_command
    from storage.database import create_database_engine
    from storage.migrations import alembic_config, schema_revisions

    url = f"sqlite:///{tmp_path / 'contextweb.sqlite3'}"
    engine = create_database_engine(url)
    if revision is not None:
        config = alembic_config()
        with engine.begin() as connection:
            config.attributes["connection"] = connection
            alembic_command.upgrade(config, _previous_revision())
    before, head = schema_revisions(engine)
    tables_before = set(inspect(engine).get_table_names())
    argv = {"serve": ["serve"], "keys": ["keys", "list"], "models": ["models", "check"]}[command]
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", *argv],
        capture_output=True,
        text=True,
        env=_environment(CONTEXTWEB_DATABASE_URL=url),
        timeout=120,
        check=False,
    )
    assert result.returncode == 75, result.stderr
    assert "Traceback" not in result.stderr and "warmed up" not in result.stderr, "refused before the warm-up"
    errors = [line for line in result.stderr.splitlines() if line.startswith(f"contextweb {command}:")]
    assert len(errors) == 1, result.stderr
    at = f"at revision {before}" if before else "empty (no revision)"
    assert f"{at}, not at the head revision {head}: run `contextweb migrate`" in errors[0]
    engine.dispose()
    engine = create_database_engine(url)
    assert schema_revisions(engine) == (before, head) and set(inspect(engine).get_table_names()) == tables_before
    engine.dispose()


def test_the_app_factory_refuses_a_database_not_at_head(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    from app.main import create_app
    from storage.migrations import SchemaNotAtHead
    from tests.conftest import make_settings

    with (
        pytest.raises(SchemaNotAtHead, match="contextweb migrate"),
        TestClient(create_app(make_settings(f"sqlite:///{tmp_path / 'contextweb.sqlite3'}"))),
    ):
        pass


def _environment(**settings: str) -> dict[str, str]:
    """This process's environment without the developer's CONTEXTWEB_* settings, plus ``settings``."""
    import os

    return {key: value for key, value in os.environ.items() if not key.startswith("CONTEXTWEB_")} | settings
