"""The paper's experiments, one module each.

Every module exposes ``add_arguments(parser)`` (its own options beyond the
common ``--out``, ``--json``, ``--quick`` and ``--seed``) and
``run(args) -> dict``, which writes its CSV and PNG files into ``args.out`` and
returns a JSON-serialisable summary (the headline numbers the paper reports).
The CLI (``contextweb experiment NAME``) and the report both go through
:data:`EXPERIMENTS`.
"""

from __future__ import annotations

#: Experiment name -> module path. Modules import lazily: numba compiles on first use.
EXPERIMENTS: dict[str, str] = {
    "contexts": "core.experiments.contexts",
    "convergence": "core.experiments.convergence",
    "mixed": "core.experiments.mixed",
    "recognition": "core.experiments.recognition",
    "planning": "core.experiments.planning",
    "sigma": "core.experiments.sigma",
    "noise": "core.experiments.noise",
    "raw-vs-web": "core.experiments.raw_vs_web",
}
