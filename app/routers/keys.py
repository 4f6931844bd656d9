"""API keys: create, list, revoke; admin keys only (docs/api.md, "Keys")."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, status

from app.deps import AdminAccess, IdempotencyKey, ReadSessionDep, WriteSessionDep
from app.errors import (
    Forbidden,
    IdempotencyKeyReused,
    InvalidInput,
    KeyAlreadyCreated,
    KeyNotFound,
    Unauthorized,
    error_responses,
)
from app.routing import JsonBodyRoute
from app.schemas.keys import ApiKeyCreate, ApiKeyCreated, ApiKeyRead
from app.services import keys as key_service

router = APIRouter(prefix="/v1/keys", tags=["keys"], dependencies=[AdminAccess], route_class=JsonBodyRoute)
_AUTH = (Unauthorized, Forbidden)


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    summary="Create an API key (its secret is in this answer only)",
    responses=error_responses(InvalidInput, IdempotencyKeyReused, KeyAlreadyCreated, *_AUTH),
)
def create_key(body: ApiKeyCreate, session: WriteSessionDep, idempotency_key: IdempotencyKey = None) -> ApiKeyCreated:
    """With an Idempotency-Key, a retry (the same key and body) makes no second key: the secret was in
    the first answer only, so the retry is a 409 `key_already_created` naming the key to revoke."""
    return key_service.create_key(session, body, idempotency_key)


@router.get("", summary="List the API keys (never their secrets)", responses=error_responses(*_AUTH))
def list_keys(session: ReadSessionDep) -> list[ApiKeyRead]:
    return key_service.list_keys(session)


@router.delete(
    "/{key_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    summary="Revoke an API key (at once, on every process; again is a no-op)",
    responses=error_responses(KeyNotFound, *_AUTH),
)
def revoke_key(
    key_id: Annotated[str, Path(description="The key's lookup id.", max_length=32)], session: WriteSessionDep
) -> None:
    key_service.revoke_key(session, key_id)
