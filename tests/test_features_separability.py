"""Entity features e of the synthetic world's objects separate the nouns (§II-A, §II-C, Fig. 13 "perceptual").

A nearest-centroid noun classifier on standardised features is the plainest
prototype method (§III-A uses prototypes too): if it cannot tell the six nouns
apart from e, no later stage can. Measured with World.paper(seed=0): 15 of 15
test objects right (seeds 1 and 2: 15/15 and 14/15).

The bar is 9 of 15 (0.6). The strongest naive rule, always answering the most
common test noun (box, 4 of 15), is right 27% of the time; a classifier that is
right that often per object reaches 9 of 15 with probability 0.007 (binomial), so
passing shows the features carry the noun, while leaving room for the simulator's
physics to change.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.features.extract import entity_features
from sim.world import World

pytestmark = pytest.mark.slow


def _entity_matrix(objects: tuple, recordings: dict) -> tuple[np.ndarray, np.ndarray]:
    rows = []
    for obj in objects:
        recording = recordings[obj.object_id]
        rows.append(entity_features(recording.look, recording.audio, recording.finger))
    return np.array(rows), np.array([obj.noun for obj in objects])


def test_nearest_noun_centroid_on_entity_features_recognises_most_test_objects() -> None:
    world = World.paper(seed=0)
    assert (len(world.train_objects), len(world.test_objects)) == (45, 15)
    recordings = world.recordings(seed=0)
    train, train_nouns = _entity_matrix(world.train_objects, recordings)
    test, test_nouns = _entity_matrix(world.test_objects, recordings)

    mean, scale = train.mean(axis=0), train.std(axis=0)
    scale[scale == 0.0] = 1.0  # a feature constant over the training objects carries no noun
    nouns = np.unique(train_nouns)
    centroids = np.array([((train - mean) / scale)[train_nouns == noun].mean(axis=0) for noun in nouns])
    distances = np.linalg.norm(((test - mean) / scale)[:, None, :] - centroids[None], axis=2)
    accuracy = float(np.mean(nouns[distances.argmin(axis=1)] == test_nouns))

    print(f"nearest-centroid noun accuracy on the 15 test objects: {accuracy:.3f}")
    assert accuracy >= 0.6
