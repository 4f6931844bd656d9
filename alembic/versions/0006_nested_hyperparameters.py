"""Nested hyperparameters: priors, sampler and K rule, with a schema version.

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-02

A model's ``hyperparameters`` JSON was flat (every setting at the top level, the rule named by
``k_selection``); it becomes ``{"priors": {...}, "sampler": {...}, "k_rule": {"name": ..., ...}}``
(core.context.hyperparameters), and ``model.hyperparameters_version`` says which form a row
holds: 1 flat, 2 nested. Its server default is 1, so a row that a process of an earlier version
writes during a rolling upgrade is labelled as what it is.

Each group keeps the settings a row stored; the settings the row's rule does not have (the
other rule's, which had no effect) are left out. Models stored with ``k_selection =
"likelihood"``, the rule that moved to the experiments (experiments/baselines/likelihood_rule.py),
continue with the default ``scenes`` rule from their stored state: what they learned (K, every
assignment) is kept, their likelihood-only settings are dropped, and each is named in a warning.
The downgrade writes the flat form back (a converted likelihood model stays ``scenes``).

The mapping is written out here, not imported, so that later changes to the code cannot change
what this migration does.
"""

import logging
from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql

from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

JSON = sa.JSON().with_variant(postgresql.JSONB(), "postgresql")
logger = logging.getLogger("alembic.runtime.migration")

PRIORS = ("alpha", "xi")
SAMPLER = ("sweeps", "scene_sweeps", "rejuvenation_tokens", "inference_sweeps", "inference_burn_in")
EVERY_RULE = ("max_contexts", "birth_window", "birth_check_interval", "novelty_window", "scene_prior_strength")
RULES = {
    "scenes": (
        *EVERY_RULE, "partition_scans", "online_partition_scans", "partition_random_starts", "birth_margin",
        "online_birth_margin", "birth_proposals", "delta", "split_scans",
    ),
    "paper": (*EVERY_RULE, "tau", "delta"),
}  # fmt: skip

model = sa.table(
    "model",
    sa.column("id", sa.String(32)),
    sa.column("hyperparameters", JSON),
    sa.column("hyperparameters_version", sa.Integer()),
)


def nested(model_id: str, flat: dict[str, Any]) -> dict[str, Any]:
    """The nested form of a flat row."""
    name = flat.get("k_selection", "scenes")
    if name not in RULES:
        logger.warning(
            "model %s used the K rule %r, which the service no longer offers: it continues with 'scenes'",
            model_id,
            name,
        )
        name = "scenes"
    return {
        "priors": {key: flat[key] for key in PRIORS if key in flat},
        "sampler": {key: flat[key] for key in SAMPLER if key in flat},
        "k_rule": {"name": name, **{key: flat[key] for key in RULES[name] if key in flat}},
    }


def flat(nested_form: dict[str, Any]) -> dict[str, Any]:
    """The flat form of a nested row."""
    rule = dict(nested_form.get("k_rule", {}))
    return {
        **nested_form.get("priors", {}),
        **nested_form.get("sampler", {}),
        "k_selection": rule.pop("name", "scenes"),
        **rule,
    }


def upgrade() -> None:
    with op.batch_alter_table("model") as batch_op:
        batch_op.add_column(sa.Column("hyperparameters_version", sa.Integer(), nullable=False, server_default="1"))
    connection = op.get_bind()
    for row in connection.execute(sa.select(model.c.id, model.c.hyperparameters)).all():
        connection.execute(
            model.update()
            .where(model.c.id == row.id)
            .values(hyperparameters=nested(row.id, dict(row.hyperparameters)), hyperparameters_version=2)
        )


def downgrade() -> None:
    connection = op.get_bind()
    rows = connection.execute(
        sa.select(model.c.id, model.c.hyperparameters).where(model.c.hyperparameters_version == 2)
    ).all()
    for row in rows:
        connection.execute(
            model.update().where(model.c.id == row.id).values(hyperparameters=flat(dict(row.hyperparameters)))
        )
    if connection.dialect.name == "sqlite":
        # Not batch mode: its copy of `model` drops the old table, and the ON DELETE CASCADE of
        # every scene, token and count would empty the database with it. SQLite 3.35+ drops a
        # column in place (Debian 12's is 3.40).
        op.execute("ALTER TABLE model DROP COLUMN hyperparameters_version")
    else:
        op.drop_column("model", "hyperparameters_version")
