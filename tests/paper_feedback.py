"""Fixtures shared by the context-feedback tests (Eq. 6): the paper world, its concept web
fitted on the training objects' labels, and a context model learned from 50 of its scenes.

A plugin of the test suite (``pytest_plugins`` in tests/conftest.py), so these are ordinary
fixtures, requested by name. They live apart from conftest for their paper-world meaning: modules
that define their own ``world`` or ``web`` fixture (another world, another web) override these,
as a module's fixture always overrides a plugin's.
"""

from __future__ import annotations

import pytest

from core.concept_web import ConceptWeb
from core.context import IncrementalLDA
from sim.world import World


@pytest.fixture(scope="module")
def world() -> World:
    return World.paper(seed=0)


@pytest.fixture(scope="module")
def web(world: World) -> ConceptWeb:
    return ConceptWeb.fit(world.vocabulary, [[*obj.concepts, *obj.behaviours] for obj in world.train_objects])


@pytest.fixture(scope="module")
def context_model(world: World) -> IncrementalLDA:
    scenes = world.scenes(50, seed=1, objects=world.train_objects)
    model = IncrementalLDA(seed=0).fit([scene.tokens(with_verbs=True) for scene in scenes])
    assert model.n_contexts == 3
    return model
