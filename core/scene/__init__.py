"""One scene through the paper's pipeline (Fig. 6(b)): payloads → features → perception (Eq. 1) →
concept webs (Eqs. 2–4) → active concepts (the LDA document, Table V) → Eq. 6 in context.

The service (app/services/perception.py translates its requests) and the experiments use it:
:func:`perceive_scene` and :func:`scene_in_context` for a scene, :func:`perceived_concepts` for the
document words of one recorded object.
"""

from core.scene.evidence import ObjectEvidence, ObjectLevel, measured_evidence, named_evidence
from core.scene.pipeline import (
    SETTLED_WEBS_CACHED,
    MeasuredObject,
    NamedObject,
    PerceivedObject,
    PerceivedScene,
    Perception,
    SceneObject,
    SettledWebs,
    perceive_scene,
    perceived_concepts,
    scene_in_context,
)

__all__ = [
    "SETTLED_WEBS_CACHED",
    "MeasuredObject",
    "NamedObject",
    "ObjectEvidence",
    "ObjectLevel",
    "PerceivedObject",
    "PerceivedScene",
    "Perception",
    "SceneObject",
    "SettledWebs",
    "measured_evidence",
    "named_evidence",
    "perceive_scene",
    "perceived_concepts",
    "scene_in_context",
]
