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
    "contexts": "experiments.contexts",
    "convergence": "experiments.convergence",
    "mixed": "experiments.mixed",
    "recognition": "experiments.recognition",
    "planning": "experiments.planning",
    "sigma": "experiments.sigma",
    "noise": "experiments.noise",
    "raw-vs-web": "experiments.raw_vs_web",
}
