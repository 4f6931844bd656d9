"""The paper's running times (§V-F), the one place benchmarks and the report read them from.

Mean and standard deviation over 10 runs of the authors' non-optimised code on an
i5 desktop with 8 GB of RAM, in milliseconds.
"""

from __future__ import annotations

#: Detection of a scene's context with Incremental-LDA: (mean, std) in ms.
CONTEXT_DETECTION_MS: tuple[float, float] = (209.82, 3.38)
#: Convergence of one object's concept web: (mean, std) in ms.
WEB_CONVERGENCE_MS: tuple[float, float] = (1395.22, 15.31)
