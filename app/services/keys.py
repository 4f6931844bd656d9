"""Creating, listing and revoking the stored API keys (app/auth.py has the key format and the checks)."""

from __future__ import annotations

from sqlalchemy.orm import Session

from app.auth import generate_key
from app.errors import InvalidInput, KeyAlreadyCreated, KeyNotFound
from app.schemas.keys import ApiKeyCreate, ApiKeyCreated, ApiKeyRead
from app.services.idempotency import check_retry, create_once, request_digest
from storage.models import ApiKey, utc_now
from storage.repositories import api_keys as api_key_repository


def create_key(session: Session, body: ApiKeyCreate, idempotency_key: str | None = None) -> ApiKeyCreated:
    """A new key; the answer is the only place its secret ever appears.

    The scope's models must exist (a mistyped id would make a key that opens nothing), and an
    admin key cannot be scoped: it could create a key of every model.

    ``idempotency_key``: a retry with the same key and body finds the key that creation made, and,
    as its secret is stored only as a hash, is answered 409 :class:`KeyAlreadyCreated` naming it
    (revoke it and create another) instead of making a second key nobody holds; with another body,
    422 ``idempotency_key_reused``. Two creations racing on one key meet at its unique index.
    """
    request_hash = request_digest(idempotency_key, body)

    def create() -> ApiKeyCreated:
        if body.models is not None:
            if body.role == "admin":
                raise InvalidInput("models", "an admin key is a key of every model: send models null")
            existing = api_key_repository.existing_model_ids(session, body.models)
            for index, model_id in enumerate(body.models):
                if model_id not in existing:
                    raise InvalidInput(f"models[{index}]", f"no model {model_id!r}")
        new = generate_key()
        row = api_key_repository.add_api_key(
            session,
            key_id=new.key_id,
            name=body.name,
            role=body.role,
            model_ids=None if body.models is None else sorted(set(body.models)),
            prefix=new.prefix,
            secret_hash=new.secret_hash,
            idempotency_key=idempotency_key,
            request_hash=request_hash,
        )
        return ApiKeyCreated(**key_read(row).model_dump(), key=new.key)

    def earlier(key: str) -> None:
        """Raise if a key was already created under ``key``: 422 for another body, else 409."""
        stored = api_key_repository.find_by_idempotency_key(session, key)
        if stored is not None:
            check_retry(key, stored.request_hash, request_hash)
            raise KeyAlreadyCreated(key, stored.id)

    return create_once(session, idempotency_key, create, earlier)


def list_keys(session: Session) -> list[ApiKeyRead]:
    """Every key, revoked ones included (with ``revoked_at``), oldest first."""
    return [key_read(row) for row in api_key_repository.list_api_keys(session)]


def revoke_key(session: Session, key_id: str) -> ApiKeyRead:
    """Revoke the key (again: nothing changes); :class:`KeyNotFound` if there is no such key."""
    row = api_key_repository.revoke_api_key(session, key_id, utc_now())
    if row is None:
        raise KeyNotFound(key_id)
    return key_read(row)


def key_read(row: ApiKey) -> ApiKeyRead:
    return ApiKeyRead(
        id=row.id,
        name=row.name,
        role=row.role,
        models=row.model_ids,
        prefix=row.prefix,
        created_at=row.created_at,
        revoked_at=row.revoked_at,
    )
