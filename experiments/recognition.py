"""Object recognition (§V-D, Table VII, Fig. 13): perception only vs the concept web.

Protocol:

1. The paper world (sim.world) is recorded; every object's entity vector e and
   the effect vector f of each applied behaviour are extracted
   (core.features.recording_features).
2. Prototypes (Appendix) are fitted on the 45 training objects: nouns and
   adjectives from e, verbs from f (core.prototypes.fit_prototypes).
3. The concept web (§III-B) is fitted on the training objects' concept
   configurations: noun, one adjective per pair, every applicable verb.
4. For every test object, each method of :data:`METHODS` gives per-concept
   probabilities: ``perception`` is the prototype perception of the object
   (core.prototypes.perceive); ``concept_web`` settles the object's web from it.
   A method is a function of the fitted :class:`RecognitionSetup`. ``in_context``
   (§IV-D, Fig. 13's third column) places each test object in a pure-context
   scene with other test objects of its context and takes P*(c) of Eq. 6 from
   the context feedback loop, with a context model learned from scenes of the
   training objects whose documents are the active concepts of their perceived
   webs (``--documents perceived``, the paper's; ``labels`` for the ablation;
   experiments.context_scenes and experiments.documents give the protocol).
5. Noun accuracy of an object = its most probable noun is right (0 or 1);
   adjective accuracy = the fraction of its 5 pairs whose more probable
   adjective is right; overall = the fraction of its 6 noun + adjective
   decisions that are right (Fig. 13 "over all determined noun and adjective
   concepts").

Outputs: results.csv (one row per object and method), recognition.png (Fig. 13's
box plots), table_vii.txt (Table VII for three example objects: the ones where
the methods disagree most, then the first ones) and a summary with the mean
accuracies, the RGNG vs k-means prototype comparison and the paper's claims.

``--quick`` records 3 training objects per noun (plus the fewest more that give
every adjective an instance) and 1 test object per noun.
"""

from __future__ import annotations

import argparse
import csv
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np

from core.concept_web import ConceptWeb
from core.context.feedback import PAPER_POOLING
from core.prototypes import PrototypeSet, fit_prototypes, perceive
from core.prototypes.prototypes import IRRELEVANT
from core.prototypes.prototypes import METHODS as PROTOTYPE_METHODS
from core.scene import Perception
from core.vocabulary import Vocabulary
from experiments import context_scenes, documents
from sim.world import World, WorldObject

#: Random stream of the in-context method's context model and scenes, derived from the world seed.
_IN_CONTEXT_STREAM = 7
QUICK_TRAIN_PER_NOUN = 3
QUICK_TEST_PER_NOUN = 1
EXAMPLES = 3

#: What the paper reports (Fig. 13 and Table VII show the values only graphically / for examples).
PAPER = {
    "figure": "Fig. 13 (15 test objects, box plots of noun and adjective accuracy)",
    "claim": "the concept web corrects some perception errors and raises confidences to ~100%; "
    "context improves further (median accuracy perception <= concept web <= in context)",
    "table_vii_perception_noun_confidences": [0.43, 0.29, 0.26],
}


@dataclass(frozen=True)
class RecognitionSetup:
    """Everything a recognition method may use; ``perception`` and ``applied`` are per test object."""

    world: World
    vocabulary: Vocabulary
    train: tuple[WorldObject, ...]
    test: tuple[WorldObject, ...]
    prototypes: PrototypeSet
    web: ConceptWeb
    perception: np.ndarray
    applied: np.ndarray
    #: The training objects' LDA words for the context model (None: their labels, ``Scene.tokens``).
    train_words: dict[str, tuple[str, ...]] | None = None


#: A method maps the setup to (n_test, n_concepts) probabilities in vocabulary.concepts order.
RecognitionMethod = Callable[[RecognitionSetup], np.ndarray]


def perception_only(setup: RecognitionSetup) -> np.ndarray:
    return setup.perception


def concept_web(setup: RecognitionSetup) -> np.ndarray:
    inferences = setup.web.infer_many(setup.perception, applied=setup.applied)
    return np.array([inference.probabilities for inference in inferences])


def in_context(setup: RecognitionSetup, pooling: str = PAPER_POOLING) -> np.ndarray:
    """P*(c) of Eq. 6 of every test object, interpreted in a pure-context scene (core.context.feedback)."""
    rng = np.random.default_rng([setup.world.seed, _IN_CONTEXT_STREAM])
    model = context_scenes.train_context_model(setup.world, setup.train, rng, words=setup.train_words)
    scenes = context_scenes.pure_context_scenes(setup.world, setup.test, rng)
    eq_6, _ = context_scenes.in_context_probabilities(
        setup.web, model, setup.vocabulary, setup.perception, setup.applied, scenes, pooling=pooling
    )
    return eq_6


def in_context_log(setup: RecognitionSetup) -> np.ndarray:
    """:func:`in_context` with the logarithmic pool instead of Eq. 6's sum (docs/feedback.md, "The hard world")."""
    return in_context(setup, pooling="log")


#: Method name -> function, in the order of Fig. 13's columns.
METHODS: dict[str, RecognitionMethod] = {
    "perception": perception_only,
    "concept_web": concept_web,
    "in_context": in_context,
    "in_context_log": in_context_log,
}

CSV_FIELDS = (
    "object",
    "noun",
    "adjectives",
    "method",
    "noun_accuracy",
    "adjective_accuracy",
    "overall_accuracy",
    "predicted_noun",
    "noun_confidence",
    "true_noun_confidence",
    "predicted_adjectives",
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--prototypes",
        choices=PROTOTYPE_METHODS,
        default="rgng",
        help="how features are clustered into + - * 0 (RGNG as in the paper, or k-means)",
    )
    documents.add_arguments(parser)


def run(args: argparse.Namespace) -> dict[str, Any]:
    world = World.paper(seed=args.seed, difficulty=args.world)
    train, test = experiment_objects(world, args.quick)
    features = context_scenes.object_features(world, train + test, args.seed)
    training = training_data(train, features)
    prototypes = {
        method: fit_prototypes(world.vocabulary, *training, method=method, seed=args.seed)
        for method in PROTOTYPE_METHODS
    }
    chosen = getattr(args, "prototypes", "rgng")
    setup = make_setup(world, train, test, features, prototypes[chosen], args.documents)
    probabilities = {name: method(setup) for name, method in METHODS.items()}
    rows = [
        accuracy_row(setup.vocabulary, obj, name, p[i])
        for name, p in probabilities.items()
        for i, obj in enumerate(test)
    ]
    _write_csv(args.out / "results.csv", rows)
    _plot(args.out / "recognition.png", rows)
    examples = _example_objects(rows, test)
    (args.out / "table_vii.txt").write_text(
        format_table_vii(setup.vocabulary, test, probabilities, examples), encoding="utf-8"
    )
    (args.out / "prototypes.txt").write_text(prototypes[chosen].table() + "\n", encoding="utf-8")
    summary: dict[str, Any] = {name: _mean_accuracies(rows, name) for name in METHODS}
    other = next(method for method in PROTOTYPE_METHODS if method != chosen)
    kmeans_setup = make_setup(world, train, test, features, prototypes[other], documents.LABELS)
    summary.update(
        n_test_objects=len(test),
        n_train_objects=len(train),
        prototypes=chosen,
        temperatures=prototypes[chosen].temperatures,
        verb_accuracy=verb_accuracy(prototypes[chosen], test, features),
        prototype_comparison={
            "label_agreement": label_agreement(prototypes["rgng"], prototypes["kmeans"]),
            "irrelevant_jaccard": irrelevant_jaccard(prototypes["rgng"], prototypes["kmeans"]),
            f"{other}_perception": _mean_accuracies(
                [accuracy_row(setup.vocabulary, obj, "perception", p) for obj, p in zip(test, kmeans_setup.perception)],
                "perception",
            ),
            f"{other}_verb_accuracy": verb_accuracy(prototypes[other], test, features),
        },
        examples=[obj.object_id for obj in examples],
        world=args.world,
        documents=args.documents,
        noun_confidence=_noun_confidences(rows),
        noun_changes=_noun_changes(rows),
        paper=PAPER,
    )
    return summary


def make_setup(
    world: World,
    train: tuple[WorldObject, ...],
    test: tuple[WorldObject, ...],
    features: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]],
    prototypes: PrototypeSet,
    source: str = documents.DEFAULT_SOURCE,
) -> RecognitionSetup:
    """Fit the concept web on the training configurations, perceive every test object, and take the
    training objects' LDA words from ``source`` (``experiments.documents``)."""
    vocabulary = world.vocabulary
    web = ConceptWeb.fit(vocabulary, [[*obj.concepts, *obj.behaviours] for obj in train])
    perception = np.array([perceive(prototypes, *features[obj.object_id]) for obj in test])
    applied = np.array([[verb in features[obj.object_id][1] for verb in vocabulary.verbs] for obj in test])
    train_words = (
        documents.perceived_words(Perception(vocabulary, prototypes, web), train, features)
        if source == documents.PERCEIVED
        else None
    )
    return RecognitionSetup(world, vocabulary, train, test, prototypes, web, perception, applied, train_words)


def experiment_objects(world: World, quick: bool) -> tuple[tuple[WorldObject, ...], tuple[WorldObject, ...]]:
    if not quick:
        return world.train_objects, world.test_objects
    test = tuple(
        obj
        for noun in world.vocabulary.nouns
        for obj in [o for o in world.test_objects if o.noun == noun][:QUICK_TEST_PER_NOUN]
    )
    train = [
        obj
        for noun in world.vocabulary.nouns
        for obj in [o for o in world.train_objects if o.noun == noun][:QUICK_TRAIN_PER_NOUN]
    ]
    for adjective in world.vocabulary.adjectives:
        if not any(adjective in obj.adjectives for obj in train):
            train.append(next(obj for obj in world.train_objects if adjective in obj.adjectives))
    return tuple(train), test


def training_data(
    train: tuple[WorldObject, ...], features: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]]
) -> tuple[np.ndarray, list[list[str]], np.ndarray, list[str]]:
    entities = np.array([features[obj.object_id][0] for obj in train])
    labels = [list(obj.concepts) for obj in train]
    effects = [(verb, effect) for obj in train for verb, effect in features[obj.object_id][1].items()]
    return entities, labels, np.array([effect for _, effect in effects]), [verb for verb, _ in effects]


def _decisions(vocabulary: Vocabulary, probabilities: np.ndarray) -> tuple[str, float, list[tuple[str, float]]]:
    """Most probable noun with its probability, and the more probable adjective of each pair."""
    n_nouns = len(vocabulary.nouns)
    noun = int(np.argmax(probabilities[:n_nouns]))
    firsts = probabilities[n_nouns : n_nouns + len(vocabulary.adjectives) : 2]
    adjectives = [
        (a, float(p)) if p >= 0.5 else (b, float(1.0 - p)) for (a, b), p in zip(vocabulary.adjective_pairs, firsts)
    ]
    return vocabulary.nouns[noun], float(probabilities[noun]), adjectives


def accuracy_row(vocabulary: Vocabulary, obj: WorldObject, method: str, probabilities: np.ndarray) -> dict[str, Any]:
    noun, confidence, adjectives = _decisions(vocabulary, probabilities)
    noun_right = float(noun == obj.noun)
    adjective_right = [name == truth for (name, _), truth in zip(adjectives, obj.adjectives)]
    return {
        "object": obj.object_id,
        "noun": obj.noun,
        "adjectives": " ".join(obj.adjectives),
        "method": method,
        "noun_accuracy": noun_right,
        "adjective_accuracy": float(np.mean(adjective_right)),
        "overall_accuracy": (noun_right + sum(adjective_right)) / (1 + len(adjective_right)),
        "predicted_noun": noun,
        "noun_confidence": round(confidence, 4),
        "true_noun_confidence": round(float(probabilities[vocabulary.nouns.index(obj.noun)]), 4),
        "predicted_adjectives": " ".join(f"{name}:{p:.3f}" for name, p in adjectives),
    }


def _noun_confidences(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Per method: the median top-noun confidence, the share of objects below 0.5 (Table VII's
    perception column has 43 %, 29 %, 26 %), and the mean probability given to the true noun."""
    out = {}
    for method in dict.fromkeys(row["method"] for row in rows):
        chosen = [row for row in rows if row["method"] == method]
        top = np.array([row["noun_confidence"] for row in chosen])
        out[method] = {
            "median_top": float(np.median(top)),
            "share_top_below_half": float(np.mean(top < 0.5)),
            "mean_true_noun": float(np.mean([row["true_noun_confidence"] for row in chosen])),
        }
    return out


def _noun_changes(rows: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per method, against perception alone: test objects whose noun it corrects (perception wrong,
    the method right) and breaks (perception right, the method wrong) — Table VII's rows."""
    right = {(row["method"], row["object"]): row["noun_accuracy"] == 1.0 for row in rows}
    objects = list(dict.fromkeys(row["object"] for row in rows))
    return {
        method: {
            "corrected": sum(right[(method, o)] and not right[("perception", o)] for o in objects),
            "broken": sum(right[("perception", o)] and not right[(method, o)] for o in objects),
        }
        for method in dict.fromkeys(row["method"] for row in rows)
        if method != "perception"
    }


def _mean_accuracies(rows: list[dict[str, Any]], method: str) -> dict[str, float]:
    chosen = [row for row in rows if row["method"] == method]
    return {
        key: float(np.mean([row[key] for row in chosen]))
        for key in ("noun_accuracy", "adjective_accuracy", "overall_accuracy")
    }


def verb_accuracy(prototypes: PrototypeSet, test: tuple[WorldObject, ...], features: dict[str, Any]) -> float:
    """Fraction of the test objects' applied behaviours whose effect is nearest its own verb (Eq. 1)."""
    verbs = prototypes.vocabulary.verbs
    hits = [
        verbs[int(np.argmin(prototypes.effect_distances(effect)))] == verb
        for obj in test
        for verb, effect in features[obj.object_id][1].items()
    ]
    return float(np.mean(hits))


def label_agreement(first: PrototypeSet, second: PrototypeSet) -> float:
    """Fraction of (concept, feature) relevance symbols two prototype sets share."""
    return float(
        np.mean(
            np.concatenate(
                [
                    (first.entity_relevance == second.entity_relevance).ravel(),
                    (first.verb_relevance == second.verb_relevance).ravel(),
                ]
            )
        )
    )


def irrelevant_jaccard(first: PrototypeSet, second: PrototypeSet) -> float:
    """Jaccard agreement of the two sets' irrelevant ('*') (concept, feature) cells."""
    a = np.concatenate([first.entity_relevance.ravel(), first.verb_relevance.ravel()]) == IRRELEVANT
    b = np.concatenate([second.entity_relevance.ravel(), second.verb_relevance.ravel()]) == IRRELEVANT
    union = (a | b).sum()
    return float((a & b).sum() / union) if union else 1.0


def _example_objects(rows: list[dict[str, Any]], test: tuple[WorldObject, ...]) -> list[WorldObject]:
    """Table VII's objects: those whose methods disagree most on overall accuracy, then test order."""
    spread = {
        obj.object_id: np.ptp([row["overall_accuracy"] for row in rows if row["object"] == obj.object_id])
        for obj in test
    }
    order = sorted(range(len(test)), key=lambda i: (-spread[test[i].object_id], i))
    return [test[i] for i in order[:EXAMPLES]]


def format_table_vii(
    vocabulary: Vocabulary,
    test: tuple[WorldObject, ...],
    probabilities: dict[str, np.ndarray],
    examples: list[WorldObject],
) -> str:
    """Table VII: per example object and method, every noun's and the first adjectives' confidences."""
    index = {obj.object_id: i for i, obj in enumerate(test)}
    n_nouns = len(vocabulary.nouns)
    lines = []
    for obj in examples:
        lines.append(f"{obj.object_id}: {obj.noun} {' '.join(obj.adjectives)}")
        for method, p in probabilities.items():
            row = p[index[obj.object_id]]
            nouns = " ".join(f"{name} ({row[i]:.0%})" for i, name in enumerate(vocabulary.nouns))
            adjectives = " ".join(
                f"{a} ({row[n_nouns + 2 * j]:.0%})" for j, (a, _) in enumerate(vocabulary.adjective_pairs)
            )
            lines.append(f"  {method:<12} nouns: {nouns}")
            lines.append(f"  {'':<12} adjectives: {adjectives}")
    return "\n".join(lines) + "\n"


def _write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows(rows)


def _plot(path: Path, rows: list[dict[str, Any]]) -> None:
    """Fig. 13: box plots of per-object accuracies, one box per method, one panel per measure."""
    methods = list(dict.fromkeys(row["method"] for row in rows))
    measures = (
        ("noun_accuracy", "nouns"),
        ("adjective_accuracy", "adjectives"),
        ("overall_accuracy", "nouns + adjectives"),
    )
    figure, axes = plt.subplots(1, len(measures), figsize=(4 * len(measures), 4), sharey=True)
    for axis, (key, title) in zip(axes, measures):
        data = [[row[key] for row in rows if row["method"] == method] for method in methods]
        axis.boxplot(data, sym="*", medianprops={"color": "red"})
        axis.set_xticks(range(1, len(methods) + 1), [method.replace("_", " ") for method in methods])
        axis.set_title(title)
        axis.set_ylim(-0.05, 1.05)
    axes[0].set_ylabel("prediction accuracy")
    figure.suptitle(f"Object recognition over {len({row['object'] for row in rows})} test objects (Fig. 13)")
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)
