"""Who is calling: API keys, their roles and model scopes, and the closing of revoked keys' streams.

Two kinds of keys (docs/api.md, "Keys"):

- **Environment keys**, the bootstrap keys: ``CONTEXTWEB_WRITE_KEY`` is an admin key of every
  model (it can create the stored keys), ``CONTEXTWEB_READ_KEY`` a read key of every model.
  They change only by a restart and cannot be revoked. Keys are checked only when the write
  key is set; without it every request is allowed, as :data:`OPEN`.
- **Stored keys**, one per robot or dashboard: ``cw_<lookup id>_<secret>``, created by
  ``POST /v1/keys`` or ``contextweb keys create``, with a role and a model scope.

A stored key is stored as the SHA-256 of the whole key, never the key. A slow KDF (scrypt,
argon2) protects secrets a person chose, which an attacker holding the hashes could guess;
the secret here is 256 random bits from :mod:`secrets`, which no guessing reaches, and a slow
KDF would only add its tens of milliseconds to every request. The request's key is found by
its lookup id (one primary-key read) and its digest compared with :func:`hmac.compare_digest`.
No cache: the per-request read is what makes a revocation take effect on the very next
request on every process (docs/operations.md gives its cost).

Scope: a key scoped to models answers 404 ``model_not_found`` for any other model, exactly
as for a model that does not exist, so it cannot learn which other models exist; a key's
role is checked after its scope. Creating a model needs a write key of every model (a scoped
key could not use the model it created) or an admin key; admin keys are never scoped, since
they can create keys of any scope.
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import logging
import re
import secrets
from collections.abc import Collection
from dataclasses import dataclass
from typing import get_args

import anyio
from pydantic import SecretStr
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker
from starlette.websockets import WebSocket

from app.errors import Forbidden, ModelNotFound
from app.schemas.keys import Role
from app.settings import Settings
from app.stream import CLOSE_UNAUTHORIZED, StreamHub
from storage.repositories import api_keys as api_key_repository

logger = logging.getLogger("contextweb")

ROLES: tuple[Role, ...] = get_args(Role)
"""In increasing order of rights: each role can do everything the previous ones can."""
_STORED_KEY = re.compile(r"cw_([0-9a-f]{16})_([A-Za-z0-9_-]{43})")
#: The subprotocol a browser's websocket offers, with ``key.<key>``, to send its key without a header.
STREAM_SUBPROTOCOL = "contextweb"
_KEY_SUBPROTOCOL = "key."
#: How often each process asks the database which of its open streams' keys were revoked. With the
#: query and the close this keeps the documented "closed within 1 s" with room to spare.
REVOCATION_CHECK_SECONDS = 0.3


@dataclass(frozen=True)
class Principal:
    """The caller of a request: a stored key (``key_id``), an environment key or open access."""

    key_id: str | None
    """The stored key's lookup id; None for an environment key or open access (never revoked)."""
    name: str
    role: Role
    model_ids: frozenset[str] | None = None
    """The models the key may use; None: every model."""

    def can(self, role: Role) -> bool:
        return ROLES.index(self.role) >= ROLES.index(role)

    def covers(self, model_id: str) -> bool:
        return self.model_ids is None or model_id in self.model_ids


OPEN = Principal(None, "open access (no CONTEXTWEB_WRITE_KEY)", "admin")
BOOTSTRAP_ADMIN = Principal(None, "CONTEXTWEB_WRITE_KEY", "admin")
BOOTSTRAP_READ = Principal(None, "CONTEXTWEB_READ_KEY", "read")


@dataclass(frozen=True)
class NewKey:
    """A freshly generated stored key: what the database keeps, and the key itself (shown once)."""

    key_id: str
    key: str
    prefix: str
    secret_hash: str


def generate_key() -> NewKey:
    """``cw_<16 hex: lookup id>_<43 characters: 256 random bits>``; only the characters of an HTTP token,
    so the key also travels as a websocket subprotocol."""
    key_id = secrets.token_hex(8)
    key = f"cw_{key_id}_{secrets.token_urlsafe(32)}"
    return NewKey(key_id=key_id, key=key, prefix=key[: len(key_id) + 8], secret_hash=_digest(key.encode()).hex())


def _digest(presented: bytes) -> bytes:
    return hashlib.sha256(presented).digest()


def _matches(presented: bytes, configured: SecretStr | None) -> bool:
    """Constant-time comparison on bytes (any header value, even one that is not ASCII)."""
    return configured is not None and hmac.compare_digest(presented, configured.get_secret_value().encode("utf-8"))


async def authenticate(settings: Settings, sessions: sessionmaker[Session], key: str | None) -> Principal | None:
    """The caller presenting ``key``, or None for no valid key. Environment keys cost no database
    read (and no thread hop); a stored key costs one primary-key read on a worker thread."""
    if not settings.auth_enabled:
        return OPEN
    if not key:  # an empty key never matches, whatever is configured
        return None
    presented = key.encode("utf-8", "surrogateescape")
    if _matches(presented, settings.write_key):
        return BOOTSTRAP_ADMIN
    if _matches(presented, settings.read_key):
        return BOOTSTRAP_READ
    stored = _STORED_KEY.fullmatch(key)
    if stored is None:
        return None
    return await anyio.to_thread.run_sync(find_stored_key, sessions, stored.group(1), presented)


def find_stored_key(sessions: sessionmaker[Session], key_id: str, presented: bytes) -> Principal | None:
    """The stored key ``key_id`` if ``presented`` is it and it is not revoked."""
    with sessions() as session:
        row = api_key_repository.get_api_key(session, key_id)
    if row is None or row.revoked_at is not None:
        return None
    if not hmac.compare_digest(bytes.fromhex(row.secret_hash), _digest(presented)):
        return None
    scope = None if row.model_ids is None else frozenset(row.model_ids)
    return Principal(key_id=row.id, name=row.name, role=row.role, model_ids=scope)  # type: ignore[arg-type]


def authorise(principal: Principal, role: Role, model_id: str | None) -> None:
    """Refuse ``principal`` a route that needs ``role`` on ``model_id`` (None: a route of no one model)."""
    if model_id is not None and not principal.covers(model_id):
        raise ModelNotFound(model_id)  # the same answer as for a model that does not exist
    if not principal.can(role):
        raise Forbidden(f"a {principal.role} key cannot use a {role} route")
    if model_id is None and role != "read" and principal.model_ids is not None:
        raise Forbidden("a key scoped to models cannot create models: use a write key of every model")


def websocket_key(websocket: WebSocket) -> str | None:
    """The stream's key: the ``X-API-Key`` header, else a ``key.<key>`` subprotocol (browsers cannot
    set headers), else the legacy ``api_key`` query parameter (redacted from the access log)."""
    header = websocket.headers.get("X-API-Key")
    if header:
        return header
    for subprotocol in websocket.scope.get("subprotocols", ()):
        if subprotocol.startswith(_KEY_SUBPROTOCOL):
            return subprotocol[len(_KEY_SUBPROTOCOL) :]
    return websocket.query_params.get("api_key")


def stream_subprotocol(websocket: WebSocket) -> str | None:
    """The subprotocol to accept: ``contextweb`` when offered (never the one carrying the key, which
    the response would echo back)."""
    return STREAM_SUBPROTOCOL if STREAM_SUBPROTOCOL in websocket.scope.get("subprotocols", ()) else None


async def close_revoked_streams(hub: StreamHub, sessions: sessionmaker[Session]) -> None:
    """Forever (the lifespan cancels it): every :data:`REVOCATION_CHECK_SECONDS`, one query for the
    keys of this process's open streams; the streams of a revoked key are closed with 4401. While the
    database does not answer the streams stay open (the HTTP routes refuse the key's requests
    anyway), and the failure is logged once."""
    failing = False
    while True:
        await asyncio.sleep(REVOCATION_CHECK_SECONDS)
        key_ids = hub.stream_key_ids_now()
        if not key_ids:
            continue
        try:
            revoked = await anyio.to_thread.run_sync(_revoked_keys, sessions, key_ids)
        except SQLAlchemyError as error:
            if not failing:
                logger.warning("cannot check the open streams' keys: %s", type(error).__name__)
            failing = True
            continue
        failing = False
        for key_id in revoked:
            hub.close_key_now(key_id, CLOSE_UNAUTHORIZED, "API key revoked")


def _revoked_keys(sessions: sessionmaker[Session], key_ids: Collection[str]) -> set[str]:
    with sessions() as session:
        return api_key_repository.revoked_among(session, key_ids)
