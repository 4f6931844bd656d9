"""Contexts of scenes: Incremental-LDA (§IV of the paper, Algorithms 1–3, Eqs. 5, 7, 8).

- :class:`IncrementalLDA` learns contexts from scenes given as bags of concept
  names, in batch (:meth:`~IncrementalLDA.fit`) or online
  (:meth:`~IncrementalLDA.learn_scene`, which returns a :class:`SceneUpdate`),
  and answers :meth:`~IncrementalLDA.context_posterior`,
  :meth:`~IncrementalLDA.concept_given_context` and
  :meth:`~IncrementalLDA.top_concepts`;
- :mod:`core.context.metrics`: l̂ of Eq. 7, H̃ of Eq. 8, Dirichlet-multinomial
  log-likelihoods;
- :mod:`core.context.k_selection`: the rules for K, one strategy object per rule
  (``scenes``, the default, and the paper's ``paper``);
- :mod:`core.context.hyperparameters`: the settings, nested by concern (priors, sampler, K rule);
- :mod:`core.context.scene_partition`: the evidence of partitions of the scenes into
  contexts, by which the default rule chooses K;
- :mod:`core.context.lda`: the sampler state and Gibbs sweeps the model is built on.

docs/context.md explains the choices the paper leaves open.
"""

from core.context.hyperparameters import Hyperparameters, Priors, SamplerSettings
from core.context.incremental import ContextModelState, IncrementalLDA, SceneUpdate
from core.context.k_selection import PaperSettings, ScenesSettings, concept_confidence, low_confidence_concepts
from core.context.lda import LDAState
from core.context.metrics import PAPER_RHO, average_log_likelihood, contextual_entropy

__all__ = [
    "PAPER_RHO",
    "ContextModelState",
    "Hyperparameters",
    "IncrementalLDA",
    "LDAState",
    "PaperSettings",
    "Priors",
    "SamplerSettings",
    "SceneUpdate",
    "ScenesSettings",
    "average_log_likelihood",
    "concept_confidence",
    "contextual_entropy",
    "low_confidence_concepts",
]
