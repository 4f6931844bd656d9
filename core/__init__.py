"""Contextweb's pure algorithms: no web, no database.

Subpackages follow the paper (Çelikkanat et al., "Learning Context on a Humanoid
Robot using Incremental Latent Dirichlet Allocation"):

- ``core.vocabulary`` and ``core.world``: the concepts and the synthetic iCub world (§II);
- ``core.features``: sensor payloads to the entity/effect vectors of Table III;
- ``core.prototypes`` and ``core.concept_web``: concepts and the MRF web (§III, Appendix);
- ``core.context``: Incremental-LDA and context feedback (§IV);
- ``core.planning``: context-pruned planning (§V-E);
- ``core.experiments``: the paper's experiments, one module each.
"""
