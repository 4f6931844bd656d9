"""What every K rule shares: the protocol Incremental-LDA calls, the settings of when growth is
checked online, and the checks of a setting's value.

A K rule answers three questions for :class:`core.context.IncrementalLDA` (Algorithm 2):

- *when* to check growth online (:meth:`KRule.growth_window`: the same schedule for every rule,
  docs/context.md "When growth is checked online");
- *whether* K + 1 wins on a window of scenes, and if so how its context starts
  (:meth:`KRule.grow`: the evidence of the candidate K and the decision, one step of
  Algorithm 2's loop);
- how a forced new context starts (:meth:`KRule.open_context`: Algorithm 3's start, for the
  experiments that force K, Figs. 10 and 11).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from core.context.lda import LDAState
from core.errors import InvalidInputError

NOVELTY_MIN_WINDOW = 5
"""Online: the fewest scenes a novelty-triggered growth check decides on (the new scene and the
four before it), even when only the new scene is novel. Each window scene costs the K + 1
partition ≈ 0.6 nats, so this is, in effect, a margin of ≈ 2.6 nats more for a context that one
scene alone announces. Measured over 900 late-context runs and 720 steady streams on seeds
nothing was tuned on (docs/context.md, "When growth is checked online"): a window of 1 found more
late contexts within 5 scenes (92.4 % against 88.3 %) but gave more false births (8.3 % and
6.3 % against 7.2 % and 5.6 %); with 5, false births rise a little against the fixed 20-scene
window (late runs 7.2 against 7.1 %, 7.4 against 6.7 % with a fourth seed set; steady streams 5.6
against 4.6 %) and late contexts found within 5 scenes go from 72.7 to 88.3 %. Not a setting: it
is part of how the trigger reads evidence, like the trigger's zero threshold."""


@dataclass(frozen=True)
class KRuleSettings(ABC):
    """Settings every K rule has: the cap on K and the online growth-check schedule."""

    name: ClassVar[str]

    max_contexts: int = 10
    """K never exceeds this; at the cap growth is simply not proposed any more."""
    birth_window: int = 100
    """Online: scheduled growth checks decide on the last this-many scenes."""
    birth_check_interval: int = 25
    """Online: growth is checked on the last ``birth_window`` scenes after each of the first
    this-many scenes, then after scenes 2, 4, 8, ... times this many (a safety net for contexts
    merged while young, which no single scene announces); besides, novelty triggers checks
    (``novelty_window``; docs/context.md, "When growth is checked online")."""
    novelty_window: int = 20
    """Online: a scene that a fresh context explains better than every existing context held
    before the last this-many scenes (``LDAState.scene_novelty`` > 0) triggers a growth check on
    those of the last this-many scenes, itself included, from the earliest that was novel in the
    same sense (at least :data:`NOVELTY_MIN_WINDOW`; docs/context.md, "When growth is checked online")."""
    scene_prior_strength: float = 1.0
    """Pseudo-counts per concept of the corpus-centred Dirichlet on a context's concepts
    (:func:`core.context.scene_partition.corpus_centred_prior`), with which the novelty trigger
    (and the ``scenes`` rule's evidence) scores a scene's blocks."""

    def __post_init__(self) -> None:
        positive_number(self, "scene_prior_strength")
        for name in ("max_contexts", "birth_window", "birth_check_interval", "novelty_window"):
            integer_at_least(self, name, 1)

    @abstractmethod
    def make_rule(self) -> KRule:
        """The rule these settings configure."""

    def to_dict(self) -> dict[str, Any]:
        """``{"name": ..., <setting>: <value>, ...}``, the stored and API form."""
        return {"name": self.name, **self.__dict__}


class KRule(ABC):
    """A rule for the number of contexts K (Algorithm 2's growth test and Algorithm 3's start)."""

    settings: KRuleSettings

    def growth_window(self, state: LDAState, word_ids: np.ndarray) -> int | None:
        """The first scene of the window that a growth check after learning ``word_ids`` runs on,
        or None for no check (docs/context.md, "When growth is checked online"). Scheduled: after
        each of the first ``birth_check_interval`` scenes and after scenes 2, 4, 8, ... times
        ``birth_check_interval``, on the last ``birth_window`` scenes. On novelty: when a fresh
        context explains the scene better than every context held before the last
        ``novelty_window`` scenes (the ``"scenes"`` rule's block evidence,
        :meth:`LDAState.scene_novelty` > 0), on the scenes since the earliest of those
        ``novelty_window`` that was novel in the same sense, or on the last
        :data:`NOVELTY_MIN_WINDOW` if that is later. Decided before the scene joins: its own tokens
        must not count for the contexts."""
        s = self.settings
        if state.n_contexts >= s.max_contexts:
            return None
        seen = state.n_documents + 1
        periods, rest = divmod(seen, s.birth_check_interval)
        if seen <= s.birth_check_interval or (rest == 0 and periods & (periods - 1) == 0):
            return max(0, seen - s.birth_window)
        first_doc = max(0, seen - s.novelty_window)
        if state.scene_novelty(word_ids, first_doc, s.scene_prior_strength) > 0.0:
            latest_start = max(first_doc, seen - NOVELTY_MIN_WINDOW)
            # Only scenes before latest_start can move the start: the scan stops there.
            earliest = state.first_novel_scene(first_doc, s.scene_prior_strength, stop=latest_start)
            return latest_start if earliest is None else earliest
        return None

    @abstractmethod
    def grow(self, state: LDAState, rng: np.random.Generator, first_doc: int, *, online: bool, sweeps: int) -> bool:
        """One step of Algorithm 2's loop on scenes ``first_doc:``: open context K + 1 if the rule's
        evidence says so (``sweeps`` Gibbs sweeps where the rule samples after a start); True if K grew."""

    @abstractmethod
    def open_context(self, state: LDAState, rng: np.random.Generator) -> None:
        """Algorithm 3's start, whatever :meth:`grow` would decide: open context K + 1 with the
        rule's low-confidence tokens (and each other token with probability δ)."""


def scene_token_mask(state: LDAState, first_doc: int, scene: int) -> np.ndarray:
    """Mask over the tokens of scenes ``first_doc:`` marking those of ``scene``."""
    tokens = state.window_tokens(first_doc)
    offsets = state.doc_offsets
    return (tokens >= offsets[scene]) & (tokens < offsets[scene + 1])


def worst_scene_start(state: LDAState, rng: np.random.Generator, delta: float, split_scans: int) -> None:
    """Algorithm 3's start from the scene explained worst (lowest mean log P(w | s)), followed by
    ``split_scans`` scene-level split passes: :meth:`KRule.open_context` of the rules that seed a
    new context with a scene."""
    low = scene_token_mask(state, 0, int(np.argmin(state.scene_fit(0))))
    state.grow_k_incrementally(low, delta, rng, split_scans=split_scans)


def positive_number(settings: object, name: str) -> None:
    value = getattr(settings, name)
    if isinstance(value, bool) or not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
        raise InvalidInputError(name, f"must be a positive number, got {value!r}")


def non_negative_number(settings: object, name: str) -> None:
    value = getattr(settings, name)
    if isinstance(value, bool) or not (isinstance(value, int | float) and np.isfinite(value) and value >= 0):
        raise InvalidInputError(name, f"must be a number >= 0, got {value!r}")


def probability(settings: object, name: str) -> None:
    value = getattr(settings, name)
    if not (isinstance(value, int | float) and 0.0 <= value <= 1.0):
        raise InvalidInputError(name, f"must lie in [0, 1], got {value!r}")


def integer_at_least(settings: object, name: str, lowest: int) -> None:
    value = getattr(settings, name)
    if not (isinstance(value, int) and not isinstance(value, bool) and value >= lowest):
        raise InvalidInputError(name, f"must be an integer >= {lowest}, got {value!r}")
