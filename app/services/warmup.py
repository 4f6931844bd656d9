"""Start-up preparation of the process, before ``/readyz`` says the server is ready: every numba
kernel a scene request runs compiled (or loaded from numba's on-disk cache), and the objects
start-up made frozen out of the garbage collector's full collections.

Numba compiles a kernel on its first call. With an empty cache (a new machine, a new image,
changed code) the first concept-level scene after a start took 12.3 s and the first
feature-level one 1.25 s here, while ``/readyz`` already answered 200 after 2.0 s: a robot's
first scenes would time out against a server that said it was ready. So the start-up runs a
small scene of each level (concepts as names and as a probability map, features, raw payloads)
through the functions a request runs — perception, the concept webs, Eq. 6 feedback, the online
Incremental-LDA update with its growth checks, fold-in inference — on a throwaway model that is
never stored. The arrays have the dtypes and layouts of a request's, so the specialisations
compiled are the ones requests use.

Prototypes are fitted with k-means here, not RGNG: RGNG runs only in ``/fit``, which is no
latency path, and compiling it would lengthen every cold start.

The freeze: after start-up the process holds ≈ 270,000 objects the cyclic garbage collector
tracks (the modules of numpy, scipy, librosa, numba and the web stack, compiled kernels, the
models loaded), and a full collection walks them all: 128 ms right after start-up here, a
stall of every request in the process. Full collections are rare while serving (in a process
serving through TestClient, 2,000 feature-level scenes left 287 more tracked objects and caused none), but fits,
new models and filling caches bring them on. ``gc.freeze()`` moves start-up's objects to the
permanent generation, which collections skip: the same 2,000 scenes then caused 3 full
collections of at most 2.4 ms. The cost: cyclic garbage among frozen objects is never
collected (reference counting still frees the rest), e.g. the cycles of a model loaded at
start-up and deleted later; objects made after start-up are not frozen.
"""

from __future__ import annotations

import base64
import functools
import gc
import logging
import time

import numpy as np

from app.schemas.scenes import SceneCreate
from app.services.perception import Perception, analyse_objects, in_context
from core.concept_web import ConceptWeb
from core.context.feedback import PAPER_SIGMA
from core.context.incremental import IncrementalLDA
from core.features.layout import EFFECT_SIZE, ENTITY_SIZE
from core.prototypes.prototypes import fit_prototypes
from sim.world import World

logger = logging.getLogger("contextweb")

#: Scenes learned by the throwaway model: more than one, so that its growth checks run.
WARM_UP_SCENES = 3


@functools.cache
def warm_up_kernels() -> float:
    """Run scenes of every level through a throwaway model, once per process (compiled kernels
    stay in the process: a second app, as in the tests, finds them there); the seconds it took."""
    started = time.perf_counter()
    world = World.paper(0)
    perception = _throwaway_perception(world)
    incremental_lda = IncrementalLDA(world.vocabulary.concepts, seed=0)
    body = SceneCreate.model_validate(_scene(world))
    for _ in range(WARM_UP_SCENES):
        analysis = analyse_objects(perception, body.objects, "warm-up")
        analysis = in_context(perception, incremental_lda, analysis, sigma=PAPER_SIGMA, seed=0)
        incremental_lda.learn_scene(analysis.words)
    incremental_lda.infer_scene(analysis.words, seed=0)
    seconds = time.perf_counter() - started
    logger.info("kernels warmed up in %.1f s", seconds)
    return seconds


@functools.cache
def freeze_start_up_objects() -> int:
    """Collect, then freeze what is left out of future collections (once per process); the
    number of objects frozen."""
    gc.collect()
    gc.freeze()
    frozen = gc.get_freeze_count()
    logger.info("%d start-up objects frozen out of the garbage collector's collections", frozen)
    return frozen


def _throwaway_perception(world: World) -> Perception:
    """Prototypes (k-means, on random vectors) and a concept web fitted on the paper world's labels."""
    rng = np.random.default_rng(0)
    train = world.train_objects
    behaviours = [behaviour for obj in train for behaviour in obj.behaviours]
    prototypes = fit_prototypes(
        world.vocabulary,
        rng.normal(size=(len(train), ENTITY_SIZE)),
        [[obj.noun, *obj.adjectives] for obj in train],
        rng.normal(size=(len(behaviours), EFFECT_SIZE)),
        behaviours,
        method="kmeans",
    )
    web = ConceptWeb.fit(world.vocabulary, [[obj.noun, *obj.adjectives, *obj.behaviours] for obj in train])
    return Perception(world.vocabulary, prototypes, web)


def _scene(world: World) -> dict:
    """A scene body with an object at each level (raw clouds small: extraction is not what is warmed)."""
    obj = world.test_objects[0]
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(200, 3))
    sphere = 0.04 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + np.array([0.0, 0.3, 0.04])
    cloud = base64.b64encode(sphere.astype("<f4").tobytes()).decode()
    moved = base64.b64encode((sphere - [0.1, 0.0, 0.0]).astype("<f4").tobytes()).decode()
    sound = rng.uniform(-0.5, 0.5, 1600).tolist()
    finger = np.linspace(0.0, 1.0, 50).tolist()
    return {
        "objects": [
            {"concepts": [obj.noun, *obj.adjectives, *obj.behaviours]},
            {"concepts": {obj.noun: 0.8, obj.adjectives[0]: 0.6}},
            {
                "features": {
                    "entity": rng.normal(size=ENTITY_SIZE).tolist(),
                    "effects": {"move_left": rng.normal(size=EFFECT_SIZE).tolist()},
                }
            },
            {
                "raw": {
                    "look": {"points": cloud},
                    "interactions": [
                        {"behaviour": "move_left", "before": {"points": cloud}, "after": {"points": moved}},
                        {
                            "behaviour": "shake",
                            "before": {"points": cloud},
                            "after": {"points": cloud},
                            "audio": {"samples": sound, "sample_rate": 16_000},
                        },
                        {
                            "behaviour": "grasp",
                            "before": {"points": cloud},
                            "after": {"points": cloud},
                            "finger": {"haptic": finger, "proprioceptive": finger},
                        },
                    ],
                }
            },
        ]
    }
