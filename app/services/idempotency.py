"""Keyed writes (Idempotency-Key): the request's digest, and the check a retry must pass.

Scenes, model creations and training batches store the SHA-256 of their validated body beside
their key; a later request under the same key is a retry only if its digest is the same
(docs/api.md: "same body" means the same request after validation).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import TypeVar

from pydantic import BaseModel
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.errors import IdempotencyKeyReused

Created = TypeVar("Created")


def request_digest(idempotency_key: str | None, body: BaseModel) -> bytes | None:
    """The SHA-256 digest (32 bytes) of ``body`` as validated (field order and whitespace do not
    count), which a keyed request stores; None without a key (nothing is stored)."""
    return None if idempotency_key is None else hashlib.sha256(body.model_dump_json().encode()).digest()


def check_retry(idempotency_key: str, stored_digest: bytes | None, request_hash: bytes | None) -> None:
    """A request under a key already stored must carry the stored body: else 422 ``idempotency_key_reused``."""
    if stored_digest != request_hash:
        raise IdempotencyKeyReused(idempotency_key)


def create_once(
    session: Session,
    idempotency_key: str | None,
    create: Callable[[], Created],
    earlier: Callable[[str], Created | None],
) -> Created:
    """``create()`` once per ``idempotency_key``: a keyed request first asks ``earlier(key)`` for what
    an earlier request under the key made (its answer, or an error it raises; None when there is
    none), and only then creates, in a savepoint. Two requests racing on one key on two processes
    meet at the key's unique index: the later one's insert is undone with its savepoint and it is
    answered ``earlier(key)``. An integrity error that is not that race (no earlier row under the key)
    is raised. Without a key, ``create()`` runs as it is, with no savepoint to pay for."""
    if idempotency_key is None:
        return create()
    answered = earlier(idempotency_key)
    if answered is not None:
        return answered
    try:
        with session.begin_nested():
            return create()
    except IntegrityError:
        answered = earlier(idempotency_key)
        if answered is None:  # another constraint: not a race on the key
            raise
        return answered
