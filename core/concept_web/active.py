"""Which concepts of an object are active: its words in the scene's LDA document (Table V).

The paper's document of a scene is the active concepts of its objects' concept
webs. Here an object's active concepts are its **MAP concepts that carry
evidence** (:func:`active_concepts`):

- the noun and the adjectives of every pair the object was perceived with (a
  measured object: always; an object named at the concept level: the groups it
  was named in, see ``core.scene``);
- the verbs whose behaviour was applied to it (:func:`carries_evidence`).

A verb that was not applied is only the web's prediction of an affordance from
the noun. Counting it would repeat the noun's vote once per predicted behaviour
(a box-like object would add 13 verbs against a cup's 5) and let one
misperceived object outvote the rest of the scene; the paper leaves this open
(Table V lists the verbs the robot tried). The same rule gives the document of
step 1 and the in-context documents of Eq. 6's loop (``core.context.feedback``)
and the service's and the experiments' documents (``core.scene``).

Without a fitted web the MAP configuration is read off the perception itself
(:func:`perception_map`).
"""

from __future__ import annotations

import numpy as np

from core.vocabulary import Vocabulary

#: A verb is active without a web when its perceived probability is at least this.
ACTIVE_PROBABILITY = 0.5


def carries_evidence(vocabulary: Vocabulary, applied: np.ndarray) -> np.ndarray:
    """Which concepts of measured objects carry evidence: every noun and adjective (they are
    perceived), and the verbs whose behaviour was applied.

    ``applied`` is (..., n_verbs) in ``vocabulary.verbs`` order; the mask is (..., n_concepts)
    in ``vocabulary.concepts`` order.
    """
    applied = np.asarray(applied, dtype=bool)
    entity = np.ones((*applied.shape[:-1], len(vocabulary.nouns) + len(vocabulary.adjectives)), dtype=bool)
    return np.concatenate([entity, applied], axis=-1)


def active_concepts(map_configuration: np.ndarray, evidence: np.ndarray) -> np.ndarray:
    """Table V: the object's words in the scene's LDA document, as a mask over the concepts: its MAP
    concepts (a settled web's ``map_configuration``, or :func:`perception_map`) that carry
    ``evidence`` (:func:`carries_evidence` for a measured object). Works row-wise on
    (n_objects, n_concepts) arrays."""
    return np.asarray(map_configuration, dtype=bool) & evidence


def perception_map(vocabulary: Vocabulary, probabilities: np.ndarray) -> np.ndarray:
    """The MAP configuration of the perception P(c) alone, for a model without a concept web: the
    most probable noun, the more probable adjective of each pair (the first on a tie), and the verbs
    at ≥ ``ACTIVE_PROBABILITY``."""
    probabilities = np.asarray(probabilities, dtype=np.float64)
    configuration = np.zeros(len(vocabulary), dtype=bool)
    n_nouns, n_adjectives = len(vocabulary.nouns), len(vocabulary.adjectives)
    configuration[int(np.argmax(probabilities[:n_nouns]))] = True
    firsts = np.arange(n_nouns, n_nouns + n_adjectives, 2)
    first_wins = probabilities[firsts] >= probabilities[firsts + 1]
    configuration[np.where(first_wins, firsts, firsts + 1)] = True
    configuration[n_nouns + n_adjectives :] = probabilities[n_nouns + n_adjectives :] >= ACTIVE_PROBABILITY
    return configuration
