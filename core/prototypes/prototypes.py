"""Concept prototypes (Appendix, Table VIII) and the prototype distance of Eq. 1.

Nouns and adjectives are learned from entity vectors e (91 dims), verbs from
effect vectors f (66 dims). For each concept and feature we take the mean and
the variance over the concept's training instances, cluster the concept's
features in the (mean, variance) plane (RGNG, or k-means as a simpler
alternative) and read a relevance symbol off each cluster's centre:

- ``*`` inconsistent: centre variance above ``inconsistent_variance``;
- ``0`` unaffected (verbs only): centre |mean| below ``unaffected_mean``;
- ``+`` / ``-``: otherwise, by the sign of the centre's mean.

Choices the paper leaves open (docs/prototypes.md gives the reasons at length):

- **Standardisation.** Entity features are z-scored over all training instances,
  so a concept's mean says how far it sits from the population and its variance
  is the share of the population variance left within the concept (1 = the
  concept does not constrain the feature). Effect features are divided, without
  centring, by their pooled within-verb standard deviation: 0 keeps meaning
  "unchanged", a mean is an effect size in units of the behaviours' own
  scatter, and a variance of 1 is the typical scatter of a verb. (Dividing by
  the root mean square over all effects instead let the large changes of drop,
  throw and knock down dwarf every other verb's noise, so the noisy histogram
  bins of the moves became "unaffected" and drowned the position change that
  tells push from move: 36-50 % of the paper world's test effects recognised,
  against 68-70 %.)
  A feature constant over the training set keeps scale 1.
- **Thresholds** (``ENTITY_RULE``, ``VERB_RULE``). Entities: a feature is
  inconsistent when more than half of the population's variance remains inside
  the concept. Verbs: inconsistent above twice the typical within-verb variance;
  unaffected when the mean change is within one typical standard deviation of 0.
- **Small groups.** RGNG's robustness treats a handful of features far from the
  rest (often the few that matter, e.g. the x position for push left) as
  outliers: it neither moves a node towards them nor inserts one there. A feature
  that the MDL test codes as an outlier, or that lies farther than
  ``radius_factor`` robust radii (harmonic average distance of the cluster's
  members) from its centre, is therefore labelled from its own (mean, variance)
  point instead of its centre's.
- **A concept with one instance** has no variance; it borrows the pooled
  within-concept variance of the other concepts of its kind (nouns, adjectives
  or verbs), or 0 when no concept of its kind has two instances.
- **A concept whose every feature is** ``*`` would have an empty sum in Eq. 1;
  its distance then uses all features.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from scipy.cluster.vq import kmeans2

from core.errors import InvalidInputError
from core.features.layout import EFFECT_LAYOUT, EFFECT_SIZE, ENTITY_LAYOUT, ENTITY_SIZE, FeatureLayout
from core.prototypes import _eq1_kernels as eq1_kernels
from core.prototypes.perception import fit_calibration
from core.prototypes.rgng import RGNGParameters, robust_growing_neural_gas
from core.vocabulary import Vocabulary

#: Relevance symbols of Table VIII, indexed by the uint8 codes stored in a PrototypeSet.
RELEVANCE_SYMBOLS = ("+", "-", "*", "0")
POSITIVE, NEGATIVE, IRRELEVANT, UNAFFECTED = range(4)
METHODS = ("rgng", "kmeans")
CALIBRATION_KINDS = ("noun", "adjective", "verb")
#: k of the k-means alternative: one cluster per symbol the kind can take.
KMEANS_CLUSTERS = {False: 3, True: 4}
_CONSTANT_FEATURE = 1e-9


@dataclass(frozen=True)
class RelevanceRule:
    """How a cluster centre (mean, variance) in the standardised plane becomes a symbol."""

    inconsistent_variance: float
    unaffected_mean: float = 0.0
    radius_factor: float = 3.0

    def symbol_codes(self, centres: np.ndarray, allow_unaffected: bool) -> np.ndarray:
        means, variances = centres[:, 0], centres[:, 1]
        codes = np.where(means >= 0.0, POSITIVE, NEGATIVE)
        if allow_unaffected:
            codes = np.where(np.abs(means) < self.unaffected_mean, UNAFFECTED, codes)
        return np.where(variances > self.inconsistent_variance, IRRELEVANT, codes).astype(np.uint8)


#: Entity features are z-scored: variance 1 = the whole population's spread.
ENTITY_RULE = RelevanceRule(inconsistent_variance=0.5)
#: Effect features are in units of the pooled within-verb standard deviation.
VERB_RULE = RelevanceRule(inconsistent_variance=2.0, unaffected_mean=1.0)


def relevance_codes(
    means: np.ndarray,
    variances: np.ndarray,
    *,
    allow_unaffected: bool,
    method: str = "rgng",
    seed: int | np.random.SeedSequence = 0,
    rule: RelevanceRule = ENTITY_RULE,
    rgng_parameters: RGNGParameters | None = None,
) -> np.ndarray:
    """Symbol code of every feature of one concept: cluster the features' (mean, variance)
    points, then label every feature with its cluster centre's symbol (Appendix); with
    RGNG, a feature its centre does not represent (MDL outlier, or beyond
    ``rule.radius_factor`` robust radii) is labelled from its own point."""
    points = np.column_stack([means, variances])
    rng = np.random.default_rng(seed)
    if method == "rgng":
        result = robust_growing_neural_gas(points, seed=rng, parameters=rgng_parameters)
        codes = rule.symbol_codes(result.centres, allow_unaffected)[result.assignment]
        alone = result.outliers | ~result.represented(points, rule.radius_factor)
        codes[alone] = rule.symbol_codes(points[alone], allow_unaffected)
        return codes
    if method == "kmeans":
        centres, assignment = _kmeans(points, KMEANS_CLUSTERS[allow_unaffected], rng)
        return rule.symbol_codes(centres, allow_unaffected)[assignment]
    raise InvalidInputError("method", f"must be one of {METHODS}, got {method!r}")


def _kmeans(points: np.ndarray, k: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """k-means (scipy kmeans2, k-means++ start) in the same unit box RGNG works in."""
    low = points.min(axis=0)
    span = points.max(axis=0) - low
    span[span <= 0.0] = 1.0
    unit = (points - low) / span
    k = min(k, len(np.unique(unit, axis=0)))
    centres, assignment = kmeans2(unit, k, minit="++", seed=rng)
    return centres * span + low, assignment


@dataclass(frozen=True, eq=False)
class PrototypeSet:
    """Learned prototypes of one vocabulary; all state is plain arrays (see :meth:`to_state`).

    Entity rows are the vocabulary's nouns then adjectives (node order); verb rows
    its verbs. Means and variances live in the standardised feature space.
    Treated as immutable: the Eq. 1 constants (:attr:`entity_eq1`, :attr:`verb_eq1`)
    are derived once, on first use, from the arrays as they are then.
    """

    vocabulary: Vocabulary
    method: str
    entity_center: np.ndarray
    entity_scale: np.ndarray
    entity_means: np.ndarray
    entity_variances: np.ndarray
    entity_relevance: np.ndarray
    effect_scale: np.ndarray
    verb_means: np.ndarray
    verb_variances: np.ndarray
    verb_relevance: np.ndarray
    temperatures: dict[str, float]
    biases: dict[str, np.ndarray]

    def __post_init__(self) -> None:
        n_entity = len(self.vocabulary.nouns) + len(self.vocabulary.adjectives)
        n_verbs = len(self.vocabulary.verbs)
        expected = {
            "entity_center": (ENTITY_SIZE,),
            "entity_scale": (ENTITY_SIZE,),
            "effect_scale": (EFFECT_SIZE,),
            "entity_means": (n_entity, ENTITY_SIZE),
            "entity_variances": (n_entity, ENTITY_SIZE),
            "entity_relevance": (n_entity, ENTITY_SIZE),
            "verb_means": (n_verbs, EFFECT_SIZE),
            "verb_variances": (n_verbs, EFFECT_SIZE),
            "verb_relevance": (n_verbs, EFFECT_SIZE),
        }
        for name, shape in expected.items():
            if np.shape(getattr(self, name)) != shape:
                raise InvalidInputError(
                    f"prototypes.{name}", f"must have shape {shape}, got {np.shape(getattr(self, name))}"
                )
        if self.method not in METHODS:
            raise InvalidInputError("prototypes.method", f"must be one of {METHODS}, got {self.method!r}")
        offsets = {
            "noun": len(self.vocabulary.nouns),
            "adjective": len(self.vocabulary.adjective_pairs),
            "verb": n_verbs,
        }
        for kind in CALIBRATION_KINDS:
            value = self.temperatures.get(kind)
            if value is None or not np.isfinite(value) or value <= 0.0:
                raise InvalidInputError(f"prototypes.temperatures.{kind}", f"must be a positive number, got {value!r}")
            bias = self.biases.get(kind)
            if bias is None or np.shape(bias) != (offsets[kind],):
                raise InvalidInputError(f"prototypes.biases.{kind}", f"must have shape ({offsets[kind]},)")

    @property
    def entity_concepts(self) -> tuple[str, ...]:
        return self.vocabulary.nouns + self.vocabulary.adjectives

    @cached_property
    def entity_eq1(self) -> Eq1Prototypes:
        """Eq. 1 constants of the noun and adjective prototypes (derived once: a query pays only the distances)."""
        return Eq1Prototypes.from_relevance(self.entity_means, self.entity_relevance)

    @cached_property
    def verb_eq1(self) -> Eq1Prototypes:
        """Eq. 1 constants of the verb prototypes."""
        return Eq1Prototypes.from_relevance(self.verb_means, self.verb_relevance)

    def distances(self, entity: np.ndarray) -> np.ndarray:
        """D(c, e) of Eq. 1 for every noun and adjective; (91,) -> (n_entity,), (n, 91) -> (n, n_entity)."""
        out = self.entity_eq1.distances(self.standardised_entities(entity))
        return out[0] if np.ndim(entity) == 1 else out

    def effect_distances(self, effect: np.ndarray) -> np.ndarray:
        """D(v, f) of Eq. 1 for every verb; (66,) -> (n_verbs,), (m, 66) -> (m, n_verbs)."""
        out = self.verb_eq1.distances(self.standardised_effects(effect))
        return out[0] if np.ndim(effect) == 1 else out

    def standardised_entities(self, entity: object, field_name: str = "entity") -> np.ndarray:
        """Validated entity vector(s) z-scored as in training: (91,) or (n, 91) -> (n, 91)."""
        return (_feature_rows(entity, ENTITY_SIZE, field_name) - self.entity_center) / self.entity_scale

    def standardised_effects(self, effect: object, field_name: str = "effect") -> np.ndarray:
        """Validated effect vector(s) in units of the pooled within-verb scatter: (66,) or (m, 66) -> (m, 66)."""
        return _feature_rows(effect, EFFECT_SIZE, field_name) / self.effect_scale

    def table(self) -> str:
        """Table VIII: one row per concept, its relevance symbol per feature, blocks spaced."""
        width = max(len(name) for name in self.vocabulary.concepts)
        rows = [
            _symbol_row(name, codes, ENTITY_LAYOUT, width)
            for name, codes in zip(self.entity_concepts, self.entity_relevance)
        ]
        rows += [
            _symbol_row(name, codes, EFFECT_LAYOUT, width)
            for name, codes in zip(self.vocabulary.verbs, self.verb_relevance)
        ]
        legend = f"{'':<{width}}  + positive  - negative  * inconsistent (irrelevant)  0 unaffected; blocks: "
        return "\n".join([legend + " | ".join(name for name, _ in ENTITY_LAYOUT.blocks)] + rows)

    def to_state(self) -> dict[str, Any]:
        """Plain-array state; :meth:`from_state` restores it exactly."""
        state: dict[str, Any] = {"vocabulary": self.vocabulary.to_dict(), "method": self.method}
        state.update({name: np.array(getattr(self, name)) for name in _ARRAY_FIELDS})
        state["temperatures"] = dict(self.temperatures)
        state["biases"] = {kind: np.array(bias) for kind, bias in self.biases.items()}
        return state

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> PrototypeSet:
        missing = [
            name for name in ("vocabulary", "method", "temperatures", "biases", *_ARRAY_FIELDS) if name not in state
        ]
        if missing:
            raise InvalidInputError("prototypes.state", f"missing keys {missing}")
        arrays = {
            name: np.array(state[name], dtype=np.uint8 if name.endswith("relevance") else np.float64)
            for name in _ARRAY_FIELDS
        }
        temperatures = {str(kind): float(value) for kind, value in dict(state["temperatures"]).items()}
        biases = {str(kind): np.array(value, dtype=np.float64) for kind, value in dict(state["biases"]).items()}
        vocabulary = Vocabulary.from_dict(state["vocabulary"])
        return cls(vocabulary, str(state["method"]), temperatures=temperatures, biases=biases, **arrays)


_ARRAY_FIELDS = (
    "entity_center",
    "entity_scale",
    "entity_means",
    "entity_variances",
    "entity_relevance",
    "effect_scale",
    "verb_means",
    "verb_variances",
    "verb_relevance",
)


def format_prototype_table(prototypes: PrototypeSet) -> str:
    """The printable Table VIII of ``contextweb prototypes show``."""
    return prototypes.table()


@dataclass(frozen=True, eq=False)
class Eq1Prototypes:
    """The constants of Eq. 1 for C prototypes over d features (read-only arrays).

    ``weights[c, i]`` is 1.0 for a feature of R_c minus R*_c and 0.0 otherwise (all
    1.0 for a concept without a relevant feature), ``sizes[c]`` their count as a
    float. The distances are a numba loop (``_eq1_kernels``) that reproduces the
    former numpy expression ``sqrt(((z - mu)**2 * weights).sum()) / sizes`` bit for bit;
    its arrays are C-ordered float64, so that it compiles once, then is cached (docs/benchmarks.md).
    """

    means: np.ndarray
    weights: np.ndarray
    sizes: np.ndarray

    @classmethod
    def from_relevance(cls, means: np.ndarray, relevance: np.ndarray) -> Eq1Prototypes:
        relevant = np.asarray(relevance) != IRRELEVANT
        relevant[relevant.sum(axis=1) == 0] = True
        arrays = (
            np.array(means, dtype=np.float64, order="C"),
            relevant.astype(np.float64, order="C"),
            relevant.sum(axis=1).astype(np.float64),
        )
        for array in arrays:
            array.flags.writeable = False
        return cls(*arrays)

    def distances(self, z: np.ndarray) -> np.ndarray:
        """D(c, x) = sqrt(sum over relevant i of (x_i - mu_c^i)^2) / |R_c minus R*_c| for rows z (n, d): (n, C)."""
        return eq1_kernels.eq1_distances(
            np.ascontiguousarray(z, dtype=np.float64), self.means, self.weights, self.sizes
        )


def eq1_distances(z: np.ndarray, means: np.ndarray, relevance: np.ndarray) -> np.ndarray:
    """Eq. 1 for standardised rows z (n, d) against prototype means (C, d): (n, C); a
    concept without a relevant feature uses all of them (:class:`Eq1Prototypes`)."""
    return Eq1Prototypes.from_relevance(means, relevance).distances(z)


def _symbol_row(name: str, codes: np.ndarray, layout: FeatureLayout, width: int) -> str:
    symbols = np.array(RELEVANCE_SYMBOLS)[codes]
    blocks = ["".join(symbols[layout[block]]) for block, _ in layout.blocks]
    return f"{name:<{width}}  " + " ".join(blocks)


def _feature_rows(values: object, size: int, field_name: str) -> np.ndarray:
    """Validate (size,) or (n, size) finite feature vectors and return them as (n, size)."""
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise InvalidInputError(field_name, f"must be numeric ({error})") from None
    if array.ndim not in (1, 2) or array.shape[-1] != size:
        raise InvalidInputError(field_name, f"must have {size} features per vector, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(field_name, "contains NaN or infinite values")
    return array.reshape(-1, size)


def fit_prototypes(
    vocabulary: Vocabulary,
    entity_vectors: np.ndarray,
    entity_concepts: list[list[str]],
    effect_vectors: np.ndarray,
    effect_verbs: list[str],
    *,
    method: str = "rgng",
    seed: int = 0,
    entity_rule: RelevanceRule = ENTITY_RULE,
    verb_rule: RelevanceRule = VERB_RULE,
    rgng_parameters: RGNGParameters | None = None,
) -> PrototypeSet:
    """Learn the 29 prototypes of the Appendix from labelled training instances.

    ``entity_concepts[i]`` lists instance i's noun (exactly one) and adjectives (at
    most one per pair); ``effect_verbs[j]`` is the verb of effect j. Perception
    temperatures and offsets are fitted on the same data (``perception.fit_calibration``).
    """
    if method not in METHODS:
        raise InvalidInputError("method", f"must be one of {METHODS}, got {method!r}")
    entities = _training_matrix(
        entity_vectors, ENTITY_SIZE, "entity_vectors", allow_empty=False, empty="there is no training object"
    )
    effects = _training_matrix(
        effect_vectors,
        EFFECT_SIZE,
        "effect_vectors",
        allow_empty=not vocabulary.verbs,
        empty="no training object carries an effect (its features' effects, or its interactions at the raw "
        f"level), and the vocabulary's {len(vocabulary.verbs)} verbs each need one",
    )
    entity_members = _entity_membership(vocabulary, entity_concepts, len(entities))
    verb_members = _verb_membership(vocabulary, effect_verbs, len(effects))

    entity_center = entities.mean(axis=0)
    entity_scale = _safe_scale(entities.std(axis=0))
    effect_scale = _pooled_within_scale(effects, verb_members)
    z_entities = (entities - entity_center) / entity_scale
    z_effects = effects / effect_scale

    n_nouns = len(vocabulary.nouns)
    noun_stats = _concept_statistics(z_entities, entity_members[:, :n_nouns])
    adjective_stats = _concept_statistics(z_entities, entity_members[:, n_nouns:])
    verb_means, verb_variances = _concept_statistics(z_effects, verb_members)
    entity_means = np.vstack([noun_stats[0], adjective_stats[0]])
    entity_variances = np.vstack([noun_stats[1], adjective_stats[1]])

    seeds = np.random.SeedSequence(seed).spawn(len(vocabulary.concepts))
    entity_seeds, verb_seeds = seeds[: len(entity_means)], seeds[len(entity_means) :]
    entity_relevance = np.array(
        [
            relevance_codes(
                m, v, allow_unaffected=False, method=method, seed=s, rule=entity_rule, rgng_parameters=rgng_parameters
            )
            for m, v, s in zip(entity_means, entity_variances, entity_seeds)
        ],
        dtype=np.uint8,
    ).reshape(entity_means.shape)
    verb_relevance = np.array(
        [
            relevance_codes(
                m, v, allow_unaffected=True, method=method, seed=s, rule=verb_rule, rgng_parameters=rgng_parameters
            )
            for m, v, s in zip(verb_means, verb_variances, verb_seeds)
        ],
        dtype=np.uint8,
    ).reshape(verb_means.shape)

    entity_distances = _leave_one_out(eq1_distances(z_entities, entity_means, entity_relevance), entity_members)
    verb_distances = _leave_one_out(eq1_distances(z_effects, verb_means, verb_relevance), verb_members)
    temperatures, biases = fit_calibration(vocabulary, entity_distances, entity_members, verb_distances, verb_members)
    return PrototypeSet(
        vocabulary,
        method,
        entity_center,
        entity_scale,
        entity_means,
        entity_variances,
        entity_relevance,
        effect_scale,
        verb_means,
        verb_variances,
        verb_relevance,
        temperatures,
        biases,
    )


def _training_matrix(values: object, size: int, field_name: str, *, allow_empty: bool, empty: str) -> np.ndarray:
    """The (n, ``size``) training rows, validated; ``empty`` says what is missing when there are none."""
    array = np.asarray(values, dtype=np.float64) if np.asarray(values).size else np.zeros((0, size))
    if array.ndim != 2:
        raise InvalidInputError(field_name, f"must be an (n, {size}) matrix, got shape {array.shape}")
    if len(array) == 0 and not allow_empty:
        raise InvalidInputError(field_name, empty)
    return _feature_rows(array, size, field_name)


def _entity_membership(vocabulary: Vocabulary, labels: list[list[str]], n: int) -> np.ndarray:
    """(n, n_nouns + n_adjectives) boolean membership; validates one noun, one adjective per pair."""
    if len(labels) != n:
        raise InvalidInputError("entity_concepts", f"has {len(labels)} label lists for {n} entity vectors")
    columns = {name: i for i, name in enumerate(vocabulary.nouns + vocabulary.adjectives)}
    members = np.zeros((n, len(columns)), dtype=bool)
    for row, names in enumerate(labels):
        for name in names:
            if name not in columns:
                raise InvalidInputError(
                    "entity_concepts", f"instance {row}: {name!r} is not a noun or adjective of the vocabulary"
                )
            members[row, columns[name]] = True
        if members[row, : len(vocabulary.nouns)].sum() != 1:
            raise InvalidInputError("entity_concepts", f"instance {row} must have exactly one noun, got {list(names)}")
        pair_counts = members[row, len(vocabulary.nouns) :].reshape(-1, 2).sum(axis=1)
        if np.any(pair_counts > 1):
            raise InvalidInputError("entity_concepts", f"instance {row} has both adjectives of a pair: {list(names)}")
    _require_instances(members, vocabulary.nouns + vocabulary.adjectives, "entity_concepts")
    return members


def _verb_membership(vocabulary: Vocabulary, verbs: list[str], m: int) -> np.ndarray:
    if len(verbs) != m:
        raise InvalidInputError("effect_verbs", f"has {len(verbs)} verbs for {m} effect vectors")
    members = np.zeros((m, len(vocabulary.verbs)), dtype=bool)
    for row, verb in enumerate(verbs):
        if verb not in vocabulary.verbs:
            raise InvalidInputError("effect_verbs", f"effect {row}: {verb!r} is not a verb of the vocabulary")
        members[row, vocabulary.verbs.index(verb)] = True
    _require_instances(members, vocabulary.verbs, "effect_verbs")
    return members


def _require_instances(members: np.ndarray, names: tuple[str, ...], field_name: str) -> None:
    empty = [name for name, count in zip(names, members.sum(axis=0)) if count == 0]
    if empty:
        raise InvalidInputError(field_name, f"no training instance for concept(s) {empty}")


def _safe_scale(scale: np.ndarray) -> np.ndarray:
    return np.where(scale > _CONSTANT_FEATURE, scale, 1.0)


def _pooled_within_scale(effects: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Pooled within-verb standard deviation of each effect feature (root mean square
    when no verb has two effects, 1 without effects)."""
    if len(effects) == 0:
        return np.ones(EFFECT_SIZE)
    dof = len(effects) - members.any(axis=0).sum()
    if dof < 1:
        return _safe_scale(np.sqrt((effects**2).mean(axis=0)))
    labels = members.argmax(axis=1)
    centred = effects - np.array([effects[labels == c].mean(axis=0) for c in range(members.shape[1])])[labels]
    return _safe_scale(np.sqrt((centred**2).sum(axis=0) / dof))


def _concept_statistics(z: np.ndarray, members: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-concept feature means and variances (ddof 1); single-instance concepts borrow
    the pooled within-concept variance of their kind."""
    counts = members.sum(axis=0)
    means = np.array([z[members[:, c]].mean(axis=0) for c in range(members.shape[1])]).reshape(-1, z.shape[1])
    variances = np.zeros_like(means)
    several = counts >= 2
    for c in np.flatnonzero(several):
        variances[c] = z[members[:, c]].var(axis=0, ddof=1)
    if np.any(several):
        pooled = (variances[several] * (counts[several, None] - 1)).sum(axis=0) / (counts[several] - 1).sum()
        variances[~several] = pooled
    return means, variances


def _leave_one_out(distances: np.ndarray, members: np.ndarray) -> np.ndarray:
    """Eq. 1 distances of each training instance with its own concepts' means refitted
    without it: the residual to a leave-one-out mean is n_c / (n_c - 1) times larger."""
    counts = members.sum(axis=0)
    factor = np.where(counts >= 2, counts / np.maximum(counts - 1, 1), 1.0)
    return np.where(members, distances * factor[None, :], distances)
