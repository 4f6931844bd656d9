"""Migration 0006 carries stored flat hyperparameters over to the nested form, on SQLite and PostgreSQL."""

from __future__ import annotations

import importlib.util
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from app.registry import stored_hyperparameters
from core.context import Hyperparameters, ScenesSettings
from core.context.hyperparameters import nest_flat_settings
from core.errors import InvalidInputError
from storage.migrations import upgrade_to_head
from storage.models import JSONType, Model
from tests.conftest import migrate

#: What the service stored before 0006: the full flat dump of every setting (a few changed).
SCENES_ROW: dict[str, Any] = {
    "alpha": 0.2, "xi": 0.1, "k_selection": "scenes", "tau": 0.03, "delta": 0.05, "max_contexts": 10,
    "sweeps": 12, "likelihood_samples": 10, "scene_prior_strength": 1.0, "partition_scans": 25,
    "online_partition_scans": 10, "partition_random_starts": 4, "birth_margin": 0.0, "online_birth_margin": 3.0,
    "growth_z": 0.0, "online_growth_z": 3.0, "birth_proposals": 2, "split_scans": 3, "sample_lag": 5,
    "scene_sweeps": 5, "rejuvenation_tokens": 64, "birth_window": 100, "birth_check_interval": 200,
    "novelty_window": 20, "inference_sweeps": 30, "inference_burn_in": 10,
}  # fmt: skip
PAPER_ROW = {**SCENES_ROW, "k_selection": "paper", "tau": 0.07}
LIKELIHOOD_ROW = {**SCENES_ROW, "k_selection": "likelihood", "growth_z": 1.5, "split_scans": 2}
#: A row written before later settings existed: the missing ones take their defaults.
SHORT_ROW = {"alpha": 0.1, "xi": 0.1, "k_selection": "scenes", "sweeps": 50}
NOW = datetime(2026, 12, 1, tzinfo=UTC)
ROWS = {"scenes": SCENES_ROW, "paper": PAPER_ROW, "likelihood": LIKELIHOOD_ROW, "short": SHORT_ROW}

MODEL = sa.table(
    "model",
    sa.column("id", sa.String(32)),
    sa.column("name", sa.String(200)),
    sa.column("seed", sa.BigInteger()),
    sa.column("sigma", sa.Float()),
    sa.column("hyperparameters", JSONType),
    sa.column("vocabulary", JSONType),
    sa.column("created_at", sa.DateTime(timezone=True)),
    sa.column("updated_at", sa.DateTime(timezone=True)),
)


#: The migration's own module (its file name is not an importable name).
_SPEC = importlib.util.spec_from_file_location(
    "migration_0006", Path(__file__).resolve().parents[1] / "alembic" / "versions" / "0006_nested_hyperparameters.py"
)
assert _SPEC is not None and _SPEC.loader is not None
MIGRATION = importlib.util.module_from_spec(_SPEC)
_SPEC.loader.exec_module(MIGRATION)


def _stored(engine: Engine, with_version: bool) -> dict[str, tuple[dict[str, Any], int | None]]:
    columns = [MODEL.c.id, MODEL.c.hyperparameters]
    if with_version:
        columns.append(sa.column("hyperparameters_version", sa.Integer()))
    with engine.connect() as connection:
        rows = connection.execute(sa.select(*columns).select_from(MODEL)).all()
    return {row[0]: (row[1], row[2] if with_version else None) for row in rows}


def _insert_flat_rows(engine: Engine) -> None:
    """One model per kind of flat row, as a process older than 0006 wrote them."""
    with engine.begin() as connection:
        connection.execute(
            MODEL.insert(),
            [
                {
                    "id": model_id, "name": model_id, "seed": 0, "sigma": 0.5, "hyperparameters": row,
                    "vocabulary": {}, "created_at": NOW, "updated_at": NOW,
                }
                for model_id, row in ROWS.items()
            ],
        )  # fmt: skip


@pytest.fixture
def flat_database(engine: Engine) -> Engine:
    """A database at the revision before 0006 holding one model per kind of flat row."""
    migrate(engine, "downgrade", "0006-1")
    _insert_flat_rows(engine)
    return engine


def test_flat_rows_become_nested_and_load_as_the_same_settings(flat_database: Engine) -> None:
    upgrade_to_head(flat_database)
    stored = _stored(flat_database, with_version=True)
    assert {version for _, version in stored.values()} == {2}
    for model_id in ("scenes", "paper", "short"):  # the migration agrees with the service's flat mapping
        expected = Hyperparameters.from_dict(nest_flat_settings(ROWS[model_id])[0])
        assert Hyperparameters.from_dict(stored[model_id][0]) == expected
    assert stored["paper"][0]["k_rule"]["tau"] == 0.07 and stored["scenes"][0]["sampler"]["sweeps"] == 12
    assert stored["short"][0] == {
        "priors": {"alpha": 0.1, "xi": 0.1},
        "sampler": {"sweeps": 50},
        "k_rule": {"name": "scenes"},
    }


def test_a_likelihood_model_continues_under_the_scenes_rule(flat_database: Engine) -> None:
    upgrade_to_head(flat_database)
    nested, _ = _stored(flat_database, with_version=True)["likelihood"]
    settings = Hyperparameters.from_dict(nested)
    assert isinstance(settings.k_rule, ScenesSettings) and settings.k_rule.split_scans == 2
    assert "growth_z" not in nested["k_rule"] and settings.sampler.sweeps == 12


def test_the_downgrade_writes_the_flat_form_back(flat_database: Engine) -> None:
    upgrade_to_head(flat_database)
    migrate(flat_database, "downgrade", "0006-1")
    stored = _stored(flat_database, with_version=False)
    restored = stored["paper"][0]
    assert restored["k_selection"] == "paper" and restored["tau"] == 0.07 and restored["alpha"] == 0.2
    assert set(restored) == {
        "k_selection",
        "alpha",
        "xi",
        "sweeps",
        "scene_sweeps",
        "rejuvenation_tokens",
        "inference_sweeps",
        "inference_burn_in",
        "max_contexts",
        "birth_window",
        "birth_check_interval",
        "novelty_window",
        "scene_prior_strength",
        "tau",
        "delta",
    }  # fmt: skip  (the scenes rule's and the likelihood rule's settings had no effect and are gone)
    assert stored["likelihood"][0]["k_selection"] == "scenes"
    upgrade_to_head(flat_database)
    assert _stored(flat_database, with_version=True)["paper"][0]["k_rule"]["tau"] == 0.07


def test_a_nested_row_with_the_likelihood_rule_is_refused_naming_the_field() -> None:
    with pytest.raises(InvalidInputError) as error:
        Hyperparameters.from_dict({"k_rule": {"name": "likelihood"}})
    assert error.value.field == "k_rule.name" and "experiments/baselines" in error.value.problem


def test_a_flat_row_written_during_a_rolling_upgrade_loads_as_the_migration_would_carry_it(engine: Engine) -> None:
    """A process older than 0006 still writes flat rows after the upgrade; the column's server
    default marks them as version 1, and the registry reads them as the migration would have."""
    upgrade_to_head(engine)
    _insert_flat_rows(engine)
    with Session(engine) as session:
        rows = {row.id: row for row in session.scalars(sa.select(Model))}
    assert {row.hyperparameters_version for row in rows.values()} == {1}
    read = {model_id: stored_hyperparameters(row) for model_id, row in rows.items()}
    for model_id, flat_row in ROWS.items():
        carried = MIGRATION.nested(model_id, flat_row)  # what migration 0006 writes for the same row
        assert Hyperparameters.from_dict(read[model_id]) == Hyperparameters.from_dict(carried), model_id
    assert read["likelihood"]["k_rule"]["name"] == "scenes" and read["likelihood"]["k_rule"]["split_scans"] == 2
