"""Bounds on how much one request may make a model hold: its vocabulary and its tokens (docs/api.md, "Limits").

Every distinct concept name a scene brings grows the model's vocabulary W for good: a
column of the K × |W| counts, a row of the database, a term of every sweep over the
concepts. Unbounded, one request could add 16,384 names, and 540,706 names made
``/contexts`` 80 times slower and a restart twice as long (issue 14). Two limits
bound it, both checked before anything is learned:

- ``CONTEXTWEB_MAX_VOCABULARY`` (10,000): |W| of one model, the concepts it was
  created with included. The paper's world has 29 concepts; a robot's recogniser
  with a few thousand labels stays well inside, and at 10,000 every per-concept
  cost stays in milliseconds.
- ``CONTEXTWEB_MAX_NEW_CONCEPTS_PER_SCENE`` (64): new names in one scene. A scene
  of the paper activates about 8 concepts per object and a robot meets new names a
  few at a time; 64 is twice the paper's whole vocabulary, so an honest scene never
  meets it, while a scene at the schema's maximum (64 objects × 256 names) is 256
  times over it. It also stops one client filling the vocabulary in one request.

A model's tokens are bounded too, by the int32 indices they are kept under (``core.context.lda.MAX_TOKENS``,
about two years of a scene every 2 s): a scene that would pass it is refused the same way.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from app.errors import InvalidInput
from app.settings import Settings
from core.errors import InvalidInputError

if TYPE_CHECKING:
    from app.registry import ModelRuntime


@dataclass(frozen=True)
class VocabularyLimits:
    """The two vocabulary limits a model is held to; each :class:`~app.registry.ModelRuntime` carries
    the registry's (set from the settings by the app), so the scene service needs no settings."""

    max_vocabulary: int
    max_new_concepts_per_scene: int

    @classmethod
    def from_settings(cls, settings: Settings) -> VocabularyLimits:
        return cls(settings.max_vocabulary, settings.max_new_concepts_per_scene)

    @classmethod
    def defaults(cls) -> VocabularyLimits:
        """The settings' defaults (for runtimes built outside an app: the CLI, tests)."""
        fields = Settings.model_fields
        return cls(fields["max_vocabulary"].default, fields["max_new_concepts_per_scene"].default)


def check_vocabulary_growth(model: ModelRuntime, words: Sequence[str]) -> None:
    """Raise a 422 on ``objects`` when learning ``words`` would pass one of the model's vocabulary limits.

    Costs one dictionary lookup per distinct word; call it before the model changes (nothing is learned).
    """
    limits = model.vocabulary_limits
    lda = model.incremental_lda
    new_words = lda.unseen_words(words)
    if not new_words:
        return
    if len(new_words) > limits.max_new_concepts_per_scene:
        raise InvalidInput(
            "objects",
            f"the scene would add {len(new_words)} new concepts; the limit per request is "
            f"{limits.max_new_concepts_per_scene} (CONTEXTWEB_MAX_NEW_CONCEPTS_PER_SCENE)",
        )
    size = lda.lda_state.vocab_size
    if size + len(new_words) > limits.max_vocabulary:
        raise InvalidInput(
            "objects",
            f"the scene would add {len(new_words)} new concepts to a vocabulary of {size}; the limit per model "
            f"is {limits.max_vocabulary} concepts (CONTEXTWEB_MAX_VOCABULARY)",
        )


def check_token_room(model: ModelRuntime, words: Sequence[str]) -> None:
    """Raise a 422 on ``objects`` when the model has no room for the scene's tokens
    (:meth:`core.context.lda.LDAState.check_room`); call it before the model changes."""
    try:
        model.incremental_lda.lda_state.check_room(len(words))
    except InvalidInputError as full:
        raise InvalidInput("objects", full.problem) from None
