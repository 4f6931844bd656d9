"""The contexts of a model: top concepts by P(c | χ), distinctive ones by relevance, and how many
scenes each one explains best."""

from __future__ import annotations

import numpy as np

from app.registry import ModelRuntime
from app.schemas.contexts import ConceptProbability, ContextRead, ContextsRead, DistinctiveConcept


def list_contexts(model: ModelRuntime, top: int, relevance_weight: float) -> ContextsRead:
    """Read under the model's lock: waits at most for the update running now."""
    with model.lock:
        lda = model.incremental_lda
        top_concepts = lda.top_concepts(top)
        distinctive = lda.distinctive_concepts(top, relevance_weight)
        posteriors = lda.lda_state.context_given_scene()
        scene_counts = np.bincount(np.argmax(posteriors, axis=1), minlength=lda.n_contexts) if lda.n_scenes else None
        kinds = list(model.word_kinds)
        index = {name: i for i, name in enumerate(lda.vocabulary)}
        context_count, scene_count = lda.n_contexts, lda.n_scenes
    return ContextsRead(
        model_id=model.id,
        context_count=context_count,
        scene_count=scene_count,
        relevance_weight=relevance_weight,
        contexts=[
            ContextRead(
                context=k,
                scene_count=0 if scene_counts is None else int(scene_counts[k]),
                top_concepts=[
                    ConceptProbability(name=name, kind=kinds[index[name]], probability=p) for name, p in concepts
                ],
                distinctive_concepts=[
                    DistinctiveConcept(name=name, kind=kinds[index[name]], probability=p, relevance=relevance)
                    for name, p, relevance in distinctive[k]
                ],
            )
            for k, concepts in enumerate(top_concepts)
        ],
    )
