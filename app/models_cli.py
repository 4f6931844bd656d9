"""``contextweb models check [ID]`` and ``contextweb models repair ID``: the stored models against their invariants.

``check`` prints one line per model, ``<id> <name>: ok`` or the problems indented
below it; it exits 0 when every model checked is sound, 1 when any has a problem
and 2 for an unknown ID. ``ok`` means the storage invariants hold, every stored answer and
kept token batch reads back, and a server's own load accepts the model (docs/operations.md,
"Damaged storage"); a model the database cannot read is a problem of its own, not the end of
the check. ``repair`` rebuilds a model's counts from its scenes and
token assignments (storage.repositories.consistency), prints what changed, checks
the model again and exits 0 when it is sound afterwards. Both read the database
of ``CONTEXTWEB_DATABASE_URL`` (the server's), which must be at the head revision (else exit 75,
as ``serve`` and ``keys``), and may be served meanwhile: each model is
checked in one snapshot (``storage.database.snapshot``), so a scene committed during the check
is not taken for damage, and a repair bumps the model's version, so serving processes reload it.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session, sessionmaker

from app.errors import is_storage_damage, is_storage_failure, storage_failure_reason
from app.registry import load_runtime
from app.settings import Settings
from storage.database import snapshot
from storage.migrations import sessions_at_head
from storage.repositories import consistency
from storage.repositories import models as model_repository
from storage.unit_of_work import unit_of_work

SOUND = 0
PROBLEMS = 1
UNKNOWN_MODEL = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    check = actions.add_parser("check", help="check stored models against the storage invariants (all without ID)")
    check.add_argument("model_id", nargs="?", metavar="ID", help="the model to check (default: every model)")
    check.set_defaults(handler=run_check)
    repair = actions.add_parser("repair", help="rebuild a model's counts from its scenes and token assignments")
    repair.add_argument("model_id", metavar="ID", help="the model to repair")
    repair.set_defaults(handler=run_repair)


@contextmanager
def _session_makers() -> Iterator[tuple[sessionmaker[Session], sessionmaker[Session]]]:
    settings = Settings()  # a database not at the head revision: one line and exit 75, not a false "ok"
    with sessions_at_head(settings.resolved_database_url, sqlite_synchronous=settings.sqlite_synchronous) as makers:
        yield makers


def _model_name(session: Session, model_id: str) -> str | None:
    return dict(model_repository.stored_models(session)).get(model_id)


def _print_result(model_id: str, name: str, problems: list[consistency.Problem]) -> None:
    if not problems:
        print(f"{model_id} {name}: ok")
        return
    print(f"{model_id} {name}: {len(problems)} problem{'s' if len(problems) > 1 else ''}")
    for problem in problems:
        print(f"  {problem.message}")
    if all(problem.repairable for problem in problems):
        print(f"  (all repairable: contextweb models repair {model_id})")
    else:
        print(
            "  (not repairable from the rows: what is damaged is stored as it was sent, not derived; restore a backup)"
        )


def run_check(args: argparse.Namespace) -> int:
    """Check one model or all; 0 when all are sound, 1 when any has a problem, 2 for an unknown ID."""
    with _session_makers() as (read, _write):
        with snapshot(read) as session:
            models = model_repository.stored_models(session)
        if args.model_id is not None:
            models = [(model_id, name) for model_id, name in models if model_id == args.model_id]
            if not models:
                print(f"contextweb models check: no model with id {args.model_id!r}", file=sys.stderr)
                return UNKNOWN_MODEL
        exit_code = SOUND
        for model_id, name in models:
            problems = _problems(read, model_id)
            _print_result(model_id, name, problems)
            if problems:
                exit_code = PROBLEMS
        if not models:
            print("no models stored")
    return exit_code


def run_repair(args: argparse.Namespace) -> int:
    """Repair one model, then check it again; 0 when it is sound afterwards, 2 for an unknown ID."""
    model_id = args.model_id
    with _session_makers() as (read, write):
        with read() as session:
            name = _model_name(session, model_id)
        if name is None:
            print(f"contextweb models repair: no model with id {model_id!r}", file=sys.stderr)
            return UNKNOWN_MODEL
        try:
            with unit_of_work(write) as session:
                changes = consistency.repair_model(session, model_id)
        except consistency.UnrepairableModelError as error:
            print(f"{model_id} {name}: not repaired, nothing changed; these problems cannot be repaired from the rows:")
            for problem in error.problems:
                print(f"  {problem}")
            return PROBLEMS
        except Exception as error:
            if is_storage_failure(error) and not is_storage_damage(error):
                raise
            print(f"{model_id} {name}: not repaired, nothing changed; its rows cannot be read: {_reason(error)}")
            return PROBLEMS
        problems = _problems(read, model_id)
        if not changes and problems:  # what only a server's load or a read found: nothing repair mends
            print(f"{model_id} {name}: not repaired, nothing changed; these problems cannot be repaired from the rows:")
            for found in problems:
                print(f"  {found.message}")
            return PROBLEMS
        if changes:
            print(f"{model_id} {name}: repaired")
            for change in changes:
                print(f"  {change}")
        else:
            print(f"{model_id} {name}: nothing to repair")
    _print_result(model_id, name, problems)
    return PROBLEMS if problems else SOUND


def _problems(read: sessionmaker[Session], model_id: str) -> list[consistency.Problem]:
    """The model's problems in one snapshot: the storage invariants, then, if they all hold, whether
    the server's own load accepts it (its stored vocabulary, hyperparameters, training objects and
    fit), so that ``ok`` means a server would serve it. A model the database cannot read at all
    (a damaged page) is one problem, and the other models are still checked."""
    try:
        with snapshot(read) as session:
            problems = consistency.find_problems(session, model_id)
            return problems or _load_problems(session, model_id)
    except Exception as error:
        if is_storage_failure(error) and not is_storage_damage(error):
            raise  # the database is not answering: no model can be checked
        return [consistency.Problem(f"cannot be read: {_reason(error)}", repairable=False)]


def _load_problems(session: Session, model_id: str) -> list[consistency.Problem]:
    row = model_repository.get_model(session, model_id)
    if row is None:
        return []
    try:
        load_runtime(session, row)
    except Exception as error:
        if is_storage_failure(error) and not is_storage_damage(error):
            raise
        return [consistency.Problem(f"a server cannot load it: {_reason(error)}", repairable=False)]
    return []


def _reason(error: BaseException) -> str:
    if isinstance(error, DBAPIError):
        return storage_failure_reason(error)
    field_name = getattr(error, "field", None)
    where = f" ({field_name})" if field_name else ""
    return f"{type(error).__name__}{where}: {getattr(error, 'problem', None) or error}"
