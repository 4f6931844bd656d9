"""Queries on the ``api_key`` table: keys are added, listed, read by id and revoked, never deleted."""

from __future__ import annotations

from collections.abc import Collection, Sequence
from datetime import datetime

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from storage.models import ApiKey, Model
from storage.repositories.models import LIVE


def add_api_key(
    session: Session,
    *,
    key_id: str,
    name: str,
    role: str,
    model_ids: list[str] | None,
    prefix: str,
    secret_hash: str,
    idempotency_key: str | None = None,
    request_hash: bytes | None = None,
) -> ApiKey:
    key = ApiKey(
        id=key_id,
        name=name,
        role=role,
        model_ids=model_ids,
        prefix=prefix,
        secret_hash=secret_hash,
        idempotency_key=idempotency_key,
        request_hash=request_hash,
    )
    session.add(key)
    session.flush()
    return key


def find_by_idempotency_key(session: Session, idempotency_key: str) -> ApiKey | None:
    """The key created under ``idempotency_key``, if any (its unique index)."""
    return session.scalars(select(ApiKey).where(ApiKey.idempotency_key == idempotency_key)).first()


def get_api_key(session: Session, key_id: str) -> ApiKey | None:
    """The key with lookup id ``key_id``: one primary-key read (the check of every request)."""
    return session.get(ApiKey, key_id)


def list_api_keys(session: Session) -> Sequence[ApiKey]:
    return session.scalars(select(ApiKey).order_by(ApiKey.created_at, ApiKey.id)).all()


def revoke_api_key(session: Session, key_id: str, revoked_at: datetime) -> ApiKey | None:
    """Revoke the key (a revoked key keeps its first ``revoked_at``); None if there is no such key."""
    session.execute(
        update(ApiKey).where(ApiKey.id == key_id, ApiKey.revoked_at.is_(None)).values(revoked_at=revoked_at)
    )
    return session.get(ApiKey, key_id, populate_existing=True)


def revoked_among(session: Session, key_ids: Collection[str]) -> set[str]:
    """Which of ``key_ids`` are revoked (or gone): one query, for the open websockets' keys."""
    if not key_ids:
        return set()
    live = session.scalars(select(ApiKey.id).where(ApiKey.id.in_(list(key_ids)), ApiKey.revoked_at.is_(None)))
    return set(key_ids) - set(live)


def existing_model_ids(session: Session, model_ids: Collection[str]) -> set[str]:
    """Which of ``model_ids`` are stored models (a key's scope must name existing models)."""
    return set(session.scalars(select(Model.id).where(Model.id.in_(list(model_ids)), LIVE)))
