"""Contextweb's pure algorithms: no web, no database.

Subpackages follow the paper (Çelikkanat et al., "Learning Context on a Humanoid
Robot using Incremental Latent Dirichlet Allocation"):

- ``core.vocabulary``: the concepts (§III), read from the paper's world file in ``core/data``;
- ``core.features``: sensor payloads to the entity/effect vectors of Table III;
- ``core.prototypes`` and ``core.concept_web``: concepts and the MRF web (§III, Appendix);
- ``core.context``: Incremental-LDA and context feedback (§IV);
- ``core.planning``: context-pruned planning (§V-E).

The synthetic iCub world is the top-level ``sim`` package and the paper's
experiments the top-level ``experiments`` package; ``core`` imports neither.
"""
