"""The numba kernels the tests use beyond the service's warm-up, compiled once before the workers start.

``tests/conftest.py`` fills numba's on-disk cache in xdist's controller with the service's warm-up
(``app.services.warmup.warm_up_kernels``). The tests also run kernels that no request runs: RGNG
(``/fit`` with its default method and the experiments), the batch Incremental-LDA fit with its
growth steps, the sweeps for many contexts (lanes, sparse) and the plain LBP entry point. With a cold
cache (a fresh clone, as in CI) each of the three workers compiled those on its own, ≈ 30 s of CPU
for RGNG alone on the 2-core machine. :func:`compile_kernels_beyond_the_warm_up` runs each once, on
small inputs of the dtypes the tests pass, in a process of its own beside the warm-up (which uses
one core), so that the workers find them in the cache.
"""

from __future__ import annotations

import numpy as np

from core.concept_web import ConceptWeb, loopy_belief_propagation
from core.context import IncrementalLDA
from core.context.lda import LANES_FROM_CONTEXTS, LDAState
from core.features.layout import EFFECT_SIZE, ENTITY_SIZE
from core.prototypes import fit_prototypes
from sim.world import World


def compile_kernels_beyond_the_warm_up() -> None:
    """Run every kernel family the warm-up leaves out, once (results are discarded)."""
    rng = np.random.default_rng(0)
    world = World.paper(seed=0)
    vocabulary, train = world.vocabulary, world.train_objects
    behaviours = [verb for obj in train for verb in obj.behaviours]
    fit_prototypes(
        vocabulary,
        rng.normal(size=(len(train), ENTITY_SIZE)),
        [list(obj.concepts) for obj in train],
        rng.normal(size=(len(behaviours), EFFECT_SIZE)),
        behaviours,
        method="rgng",
    )
    web = ConceptWeb.fit(vocabulary, [[*obj.concepts, *obj.behaviours] for obj in train])
    loopy_belief_propagation(web.potentials(np.full(len(vocabulary.concepts), 0.5)))
    scenes = [scene.tokens() for scene in world.scenes(30, seed=1)]
    model = IncrementalLDA(seed=0).fit(scenes)  # Algorithm 2: growth by scene partitions, counts
    model.grow_context()  # a forced start: scene-level split passes
    IncrementalLDA(seed=0, k_selection="paper").fit(scenes)  # the paper's rule: C_low
    state = model.lda_state
    state.conditional_entropy()
    LDAState.from_arrays(state.alpha, state.xi, state.vocab_size, state.n_contexts, state.words,
                         state.assignments, state.doc_offsets)  # fmt: skip
    words = rng.integers(0, 29, size=400).astype(np.int32)
    for kernel in ("dense", "lanes", "sparse"):
        state = LDAState(0.1, 0.1, 29, LANES_FROM_CONTEXTS)
        for start in range(0, 400, 20):
            state.append_document(words[start : start + 20])
        state.initialize_randomly(rng)
        state.sweep(rng, 1, kernel=kernel)
