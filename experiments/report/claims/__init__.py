"""The paper's claims, one module per claim (Fig. 11 and Fig. 11 a–d share the ``contexts`` summary
and one module). Each module holds the paper's numbers for its claim (``PAPER_*``), the criterion's
own thresholds with their reasons, a ``judge`` (summary → :class:`~experiments.report.claim.Verdict`),
a ``table`` (summary → the page's table) and its ``CLAIMS``.

:data:`CLAIMS` is the order of the report's page.
"""

from __future__ import annotations

from experiments.report.claim import Claim
from experiments.report.claims import (
    fig_9,
    fig_10,
    fig_11,
    fig_12,
    fig_13,
    fig_14,
    fig_15,
    fig_16,
    running_times,
    table_vi,
)

CLAIMS: tuple[Claim, ...] = (
    *fig_10.CLAIMS,
    *fig_11.CLAIMS,
    *fig_12.CLAIMS,
    *table_vi.CLAIMS,
    *fig_9.CLAIMS,
    *fig_13.CLAIMS,
    *fig_14.CLAIMS,
    *fig_15.CLAIMS,
    *fig_16.CLAIMS,
    *running_times.CLAIMS,
)
