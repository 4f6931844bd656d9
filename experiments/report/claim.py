"""What a claim of the paper is, the verdict it gets, and the formatting every claim module shares."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any


class Status(StrEnum):
    REPRODUCED = "reproduced"
    BETTER = "better"
    NOT_REPRODUCED = "not reproduced"
    NOT_RUN = "not run"


@dataclass(frozen=True)
class Verdict:
    status: Status
    reason: str

    def line(self) -> str:
        """The page's verdict line, e.g. "not reproduced — best σ = 0.8 …"."""
        separator = ":" if self.status is Status.NOT_RUN else " —"
        return f"{self.status.value}{separator} {self.reason}"


Summary = dict[str, Any]
Table = list[list[str]]


@dataclass(frozen=True)
class Claim:
    """One claim of the paper, checked against one job's summary."""

    reference: str
    title: str
    job: str
    paper: str
    criterion: str
    judge: Callable[[Summary], Verdict]
    table: Callable[[Summary], Table]
    #: Show the job's PNG figures under this claim (once per job is enough).
    figures: bool = True
    #: Text files of the job's output shown verbatim.
    texts: tuple[str, ...] = ()
    #: Ablations (``experiments.report.jobs.ABLATIONS``) judged by the same criterion beside the headline.
    ablations: tuple[str, ...] = ()
    #: The claim's headline number (its name, and how to read it from a summary), shown on the
    #: page's first table as its median and range over the seeds.
    headline: tuple[str, Callable[[Summary], float | None]] | None = None

    @property
    def name(self) -> str:
        return f"{self.reference} — {self.title}"


def verdict_of(holds: bool, facts: str, why: str, better: bool = False) -> Verdict:
    """Reproduced (or better) with the facts, else not reproduced with why."""
    if not holds:
        return Verdict(Status.NOT_REPRODUCED, why)
    return Verdict(Status.BETTER if better else Status.REPRODUCED, facts)


def number(value: float | None, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def scene_count(count: int | None) -> str:
    return "never" if count is None else f"{count} scene" + ("" if count == 1 else "s")


def share(hits: int, total: int) -> str:
    return f"{hits}/{total}"
