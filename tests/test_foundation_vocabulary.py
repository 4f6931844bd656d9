"""The vocabulary and the Table III layout are data with invariants of their own."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import InvalidInputError
from core.features.layout import EFFECT_LAYOUT, ENTITY_LAYOUT, VISUAL
from core.payloads import Audio, FingerSeries, PointCloud
from core.vocabulary import ADJECTIVE, NOUN, VERB, Vocabulary, load_world_file, paper_vocabulary


def test_paper_vocabulary_has_the_29_concepts_in_node_order() -> None:
    vocabulary = paper_vocabulary()
    assert len(vocabulary) == 29
    assert vocabulary.kinds.count(NOUN) == 6
    assert vocabulary.kinds.count(ADJECTIVE) == 10
    assert vocabulary.kinds.count(VERB) == 13
    assert vocabulary.concepts[:6] == ("box", "ball", "cylinder", "cup", "plate", "tool")
    assert vocabulary.index("hard") == 6 and vocabulary.index("soft") == 7
    assert vocabulary.opposite("thin") == "thick" and vocabulary.opposite("thick") == "thin"


def test_unknown_concepts_and_malformed_vocabularies_name_the_field() -> None:
    vocabulary = paper_vocabulary()
    with pytest.raises(InvalidInputError, match="concept: unknown concept 'spoon'"):
        vocabulary.index("spoon")
    with pytest.raises(InvalidInputError, match="adjective: 'box' is not an adjective"):
        vocabulary.opposite("box")
    with pytest.raises(InvalidInputError, match="vocabulary: concept names must be unique"):
        Vocabulary(nouns=("box", "hard"), adjective_pairs=(("hard", "soft"),), verbs=())
    with pytest.raises(InvalidInputError, match="vocabulary.adjective_pairs"):
        Vocabulary(nouns=("box",), adjective_pairs=(("hard", "hard"),), verbs=())


def test_vocabulary_round_trips_through_its_dictionary() -> None:
    vocabulary = paper_vocabulary()
    assert Vocabulary.from_dict(vocabulary.to_dict()) == vocabulary


def test_world_file_tables_are_consistent_with_the_vocabulary() -> None:
    world = load_world_file("paper")
    vocabulary = paper_vocabulary()
    assert set(world["noun_adjective_counts"]) == set(vocabulary.nouns)
    assert set(world["applicability"]) == set(vocabulary.nouns)
    for verbs in world["applicability"].values():
        assert set(verbs) <= set(vocabulary.verbs)
    totals = [
        sum(row[a] for a in pair)
        for row in world["noun_adjective_counts"].values()
        for pair in vocabulary.adjective_pairs
    ]
    assert sum(totals) == 60 * 5


def test_table_iii_layout_has_the_papers_positions() -> None:
    # Table III gives 1-based positions; the layout's slices are 0-based.
    expected = {
        "position": (1, 3),
        "dimensions": (4, 6),
        "normal_zenith": (7, 26),
        "normal_azimuth": (27, 46),
        "shape_index": (47, 66),
        "mfcc_range": (67, 79),
        "haptic": (80, 85),
        "proprioceptive": (86, 91),
    }
    for name, (first, last) in expected.items():
        block = ENTITY_LAYOUT[name]
        assert (block.start + 1, block.stop) == (first, last), name
    assert ENTITY_LAYOUT.size == 91 and EFFECT_LAYOUT.size == 66
    assert EFFECT_LAYOUT.slices == {name: ENTITY_LAYOUT[name] for name in EFFECT_LAYOUT.slices}
    assert VISUAL == slice(0, 66)
    assert len(set(ENTITY_LAYOUT.feature_names)) == 91
    assert ENTITY_LAYOUT.feature_names[ENTITY_LAYOUT["haptic"].start] == "haptic.change"


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: PointCloud(np.zeros((0, 3))), "point_cloud.points: is empty"),
        (lambda: PointCloud(np.zeros((4, 2))), r"point_cloud.points: must be \(n, 3\)"),
        (lambda: PointCloud(np.array([[0.0, np.nan, 0.0]])), "point_cloud.points: contains NaN"),
        (lambda: PointCloud([["a", "b", "c"]]), "point_cloud.points: must be numeric"),
        (lambda: Audio(np.zeros(0), 16_000), "audio.samples: is empty"),
        (lambda: Audio(np.zeros(16), 1_000_000), "audio.sample_rate: 1000000 Hz is outside"),
        (lambda: FingerSeries(np.zeros(10), np.zeros(9)), "finger.proprioceptive: length 9 does not match"),
        (lambda: FingerSeries(np.zeros(1), np.zeros(1)), "finger.haptic: needs at least 2 samples"),
    ],
)
def test_payloads_reject_bad_input_naming_the_field(build, message: str) -> None:
    with pytest.raises(InvalidInputError, match=message):
        build()


def test_payloads_normalise_dtypes_without_mutating_the_caller() -> None:
    samples = [0.0, 0.5, -0.5]
    audio = Audio(samples, 16_000)
    assert audio.samples.dtype == np.float32 and samples == [0.0, 0.5, -0.5]
    cloud = PointCloud([[0, 0, 0], [1, 1, 1]])
    assert cloud.points.dtype == np.float64
