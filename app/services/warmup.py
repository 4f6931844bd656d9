"""Start-up preparation of the process, before ``/readyz`` says the server is ready: every numba
kernel a scene request runs compiled (or loaded from numba's on-disk cache), and the objects
start-up made frozen out of the garbage collector's full collections.

Numba compiles a kernel on its first call. With an empty cache (a new machine, a new image,
changed code) the first scenes after a start took seconds while ``/readyz`` already answered
200 (the figures: docs/benchmarks.md): a robot's first scenes would time out against a server
that said it was ready. So the start-up runs a
small scene of each level (concepts as names and as a probability map, features, raw payloads)
through the functions a request runs — perception, the concept webs, Eq. 6 feedback, the online
Incremental-LDA update with its growth checks, fold-in inference — on a throwaway model that is
never stored. The arrays have the dtypes and layouts of a request's, so the specialisations
compiled are the ones requests use. The labels come from a small recorded file
(``app/data/warmup_scenes.json``, written by ``python -m sim.record_warmup`` from the simulated
paper world): the service never imports the simulator.

Prototypes are fitted with k-means here, not RGNG: RGNG runs only in ``/fit``, which is no
latency path, and compiling it would lengthen every cold start.

The freeze: after start-up the process holds hundreds of thousands of objects the cyclic
garbage collector tracks (the modules of numpy, scipy, librosa, numba and the web stack,
compiled kernels), and a full collection walks them all, a stall of every request in the
process. Full collections are rare while serving, but fits, new models and filling caches
bring them on. ``gc.freeze()`` moves start-up's objects to the permanent generation, which
collections skip (the stalls before and after: docs/benchmarks.md). ``contextweb serve``
runs both (app/serve.py, ``serving_app``), not the app factory, before the app loads its
models. The cost: cyclic garbage among frozen objects is never collected (reference counting
still frees the rest); objects made later, the loaded models among them, are not frozen.
"""

from __future__ import annotations

import base64
import functools
import gc
import json
import logging
import time
from importlib import resources
from importlib.resources.abc import Traversable
from typing import Any

import numpy as np

from app.schemas.scenes import SceneCreate
from app.services.perception import Perception, analyse_objects, in_context
from core.concept_web import ConceptWeb
from core.context.feedback import PAPER_SIGMA
from core.context.incremental import IncrementalLDA
from core.features.layout import EFFECT_SIZE, ENTITY_SIZE
from core.prototypes.prototypes import fit_prototypes
from core.vocabulary import Vocabulary

logger = logging.getLogger("contextweb")

#: Scenes learned by the throwaway model: with ``birth_check_interval=1`` scenes 1 and 2 run the
#: scheduled growth checks and scene 3 the novelty test (``LDAState.scene_novelty``) that decides
#: the others, so every kernel of an online update is compiled.
WARM_UP_SCENES = 3
#: The recorded labels the warm-up replays (``python -m sim.record_warmup`` writes it).
WARM_UP_FILE: Traversable = resources.files("app") / "data" / "warmup_scenes.json"


@functools.cache
def warm_up_kernels() -> float:
    """Run scenes of every level through a throwaway model, once per process (compiled kernels
    stay in the process: a second app, as in the tests, finds them there); the seconds it took."""
    started = time.perf_counter()
    record = json.loads(WARM_UP_FILE.read_text(encoding="utf-8"))
    perception = _throwaway_perception(record)
    incremental_lda = IncrementalLDA(perception.vocabulary.concepts, seed=0, birth_check_interval=1)
    body = SceneCreate.model_validate(_scene(record))
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


def _throwaway_perception(record: dict[str, Any]) -> Perception:
    """Prototypes (k-means, on random vectors) and a concept web fitted on the recorded labels."""
    rng = np.random.default_rng(0)
    vocabulary = Vocabulary.from_dict(record["vocabulary"])
    train = record["training_objects"]
    applicable: dict[str, list[str]] = record["behaviours"]
    behaviours = [behaviour for obj in train for behaviour in applicable[obj["noun"]]]
    prototypes = fit_prototypes(
        vocabulary,
        rng.normal(size=(len(train), ENTITY_SIZE)),
        [[obj["noun"], *obj["adjectives"]] for obj in train],
        rng.normal(size=(len(behaviours), EFFECT_SIZE)),
        behaviours,
        method="kmeans",
    )
    web = ConceptWeb.fit(vocabulary, [[obj["noun"], *obj["adjectives"], *applicable[obj["noun"]]] for obj in train])
    return Perception(vocabulary, prototypes, web)


def _scene(record: dict[str, Any]) -> dict:
    """A scene body with an object at each level (raw clouds small: extraction is not what is warmed)."""
    obj = record["scene_object"]
    noun, adjectives, behaviours = obj["noun"], obj["adjectives"], record["behaviours"][obj["noun"]]
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(200, 3))
    sphere = 0.04 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + np.array([0.0, 0.3, 0.04])
    cloud = base64.b64encode(sphere.astype("<f4").tobytes()).decode()
    moved = base64.b64encode((sphere - [0.1, 0.0, 0.0]).astype("<f4").tobytes()).decode()
    sound = rng.uniform(-0.5, 0.5, 1600).tolist()
    finger = np.linspace(0.0, 1.0, 50).tolist()
    return {
        "objects": [
            {"concepts": [noun, *adjectives, *behaviours]},
            {"concepts": {noun: 0.8, adjectives[0]: 0.6}},
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
