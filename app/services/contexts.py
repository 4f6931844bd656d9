"""The contexts of a model: top concepts by P(c | χ), distinctive ones by relevance, and how many
scenes each one explains best."""

from __future__ import annotations

import numpy as np
from sqlalchemy.orm import Session

from app.errors import ContextNotFound
from app.registry import ModelRuntime
from app.schemas.contexts import ConceptProbability, ContextLabelRead, ContextRead, ContextsRead, DistinctiveConcept
from storage.repositories import contexts as context_repository


def list_contexts(session: Session, model: ModelRuntime, top: int, relevance_weight: float) -> ContextsRead:
    """Read under the model's lock (waits at most for the update running now), with the labels."""
    labels = context_repository.context_labels(session, model.id)
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
                label=labels.get(k),
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


def label_context(session: Session, model: ModelRuntime, context: int, label: str | None) -> ContextLabelRead:
    """Name one of the model's contexts (None removes the name); 404 for a context it does not have."""
    context_count = model.incremental_lda.n_contexts
    if context >= context_count:
        raise ContextNotFound(model.id, context, context_count)
    context_repository.set_context_label(session, model.id, context, label)
    return ContextLabelRead(model_id=model.id, context=context, label=label)
