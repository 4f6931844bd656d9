"""Keyed writes (Idempotency-Key): the request's digest, and the check a retry must pass.

Scenes, model creations and training batches store the SHA-256 of their validated body beside
their key; a later request under the same key is a retry only if its digest is the same
(docs/api.md: "same body" means the same request after validation).
"""

from __future__ import annotations

import hashlib

from pydantic import BaseModel

from app.errors import IdempotencyKeyReused


def request_digest(idempotency_key: str | None, body: BaseModel) -> bytes | None:
    """The SHA-256 digest (32 bytes) of ``body`` as validated (field order and whitespace do not
    count), which a keyed request stores; None without a key (nothing is stored)."""
    return None if idempotency_key is None else hashlib.sha256(body.model_dump_json().encode()).digest()


def check_retry(idempotency_key: str, stored_digest: bytes | None, request_hash: bytes | None) -> None:
    """A request under a key already stored must carry the stored body: else 422 ``idempotency_key_reused``."""
    if stored_digest != request_hash:
        raise IdempotencyKeyReused(idempotency_key)
