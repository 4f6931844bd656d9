"""The one error type that pure code raises for bad input.

Every validation failure names the offending field and the problem, so that the
web layer can turn it into a 4xx body without parsing messages.
"""

from __future__ import annotations


class InvalidInputError(ValueError):
    """Bad input to a core function: ``field`` says where, ``problem`` says what."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")
