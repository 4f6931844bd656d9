"""Repositories: every database query lives here, one module per aggregate."""

from __future__ import annotations

from typing import Any

from sqlalchemy import CursorResult, Result


def rowcount(result: Result[*tuple[Any, ...]]) -> int:
    """The rows an UPDATE, DELETE or INSERT matched: ``Session.execute`` types every result as a Result."""
    assert isinstance(result, CursorResult)
    return result.rowcount
