"""``contextweb keys create|list|revoke``: the stored API keys, on the database of ``CONTEXTWEB_DATABASE_URL``.

For the first keys of a deployment, and for an operator without an admin key at hand. The
database must be migrated (``contextweb migrate``, which may run before the server ever started;
otherwise the command refuses, exit 75). ``create`` prints the key on stdout, alone on its line, and nothing
else there (its description goes to stderr), so ``KEY=$(contextweb keys create …)`` works;
the key is not stored and cannot be shown again. ``revoke`` exits 2 for an unknown id. A
server reads keys per request, so a revocation holds on its next request.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy.orm import Session, sessionmaker

from app.auth import ROLES
from app.errors import InvalidInput, KeyNotFound
from app.schemas.keys import ApiKeyCreate, ApiKeyRead
from app.services import keys as key_service
from app.settings import Settings
from storage.migrations import sessions_at_head
from storage.unit_of_work import unit_of_work

DONE = 0
REFUSED = 1
UNKNOWN_KEY = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    create = actions.add_parser("create", help="create a key and print it (once)")
    create.add_argument("--name", required=True, help="who holds the key (a robot, a dashboard)")
    create.add_argument("--role", required=True, choices=ROLES, help="read < write < admin")
    create.add_argument(
        "--model", dest="models", action="append", metavar="ID", help="a model the key may use (repeat; none: all)"
    )
    create.set_defaults(handler=run_create)
    actions.add_parser("list", help="list the keys (never their secrets)").set_defaults(handler=run_list)
    revoke = actions.add_parser("revoke", help="revoke a key: refused on its next request, on every server")
    revoke.add_argument("key_id", metavar="KEY_ID", help="the key's id (as `keys list` shows it)")
    revoke.set_defaults(handler=run_revoke)


@contextmanager
def _write_sessions() -> Iterator[sessionmaker[Session]]:
    settings = Settings()
    with sessions_at_head(settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous) as makers:
        yield makers[1]


def _describe(key: ApiKeyRead) -> str:
    models = "all models" if key.models is None else ",".join(key.models)
    revoked = f"revoked {key.revoked_at:%Y-%m-%d %H:%M:%S}Z" if key.revoked_at else "active"
    return f"{key.id}  {key.prefix}…  {key.role:<5}  {revoked:<28}  {key.name}  ({models})"


def run_create(args: argparse.Namespace) -> int:
    """Create a key; 1 when the input is refused (an unknown model, an admin key with models)."""
    try:
        body = ApiKeyCreate(name=args.name, role=args.role, models=args.models)
        with _write_sessions() as sessions, unit_of_work(sessions) as session:
            created = key_service.create_key(session, body)
    except (InvalidInput, ValueError) as error:
        print(f"contextweb keys create: {error}", file=sys.stderr)
        return REFUSED
    print(_describe(created), file=sys.stderr)
    print(created.key)
    return DONE


def run_list(_args: argparse.Namespace) -> int:
    with _write_sessions() as sessions, sessions() as session:
        keys = key_service.list_keys(session)
    for key in keys:
        print(_describe(key))
    if not keys:
        print("no keys stored")
    return DONE


def run_revoke(args: argparse.Namespace) -> int:
    try:
        with _write_sessions() as sessions, unit_of_work(sessions) as session:
            revoked = key_service.revoke_key(session, args.key_id)
    except KeyNotFound as error:
        print(f"contextweb keys revoke: {error}", file=sys.stderr)
        return UNKNOWN_KEY
    print(_describe(revoked))
    return DONE
