"""Incremental-LDA's hyperparameters, nested by concern: the priors of Eq. 5, the sampler, the K rule.

The nested dictionary (:meth:`Hyperparameters.to_dict`) is the form models are stored in and the
API speaks. The flat form of earlier versions (every setting at the top level, the rule named by
``k_selection``) is still accepted (:func:`nest_flat_settings`): the keyword arguments of
:class:`core.context.IncrementalLDA` and, deprecated, the service's request bodies.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from core.context.k_selection import K_RULES, KRuleSettings, ScenesSettings
from core.context.k_selection.base import integer_at_least, positive_number
from core.errors import InvalidInputError

LIKELIHOOD_RULE_MOVED = (
    "'likelihood' is no longer a rule of the service: it is a baseline of the experiments "
    "(experiments/baselines/likelihood_rule.py); use 'scenes' (the default) or 'paper'"
)

#: Settings of the flat form that served only the retired ``likelihood`` rule.
LIKELIHOOD_ONLY_SETTINGS = frozenset({"likelihood_samples", "sample_lag", "growth_z", "online_growth_z"})


@dataclass(frozen=True)
class Priors:
    """The symmetric Dirichlet priors of Eq. 5."""

    alpha: float = 0.1
    """α: prior on a scene's contexts (Eq. 5; §V-B uses 0.1)."""
    xi: float = 0.1
    """ξ: prior on a context's concepts (Eq. 5; §V-B uses 0.1)."""

    def __post_init__(self) -> None:
        positive_number(self, "alpha")
        positive_number(self, "xi")


@dataclass(frozen=True)
class SamplerSettings:
    """How much collapsed Gibbs sampling (Eq. 5) each step gets."""

    sweeps: int = 200
    """Gibbs sweeps after each K-incremental start (batch, or over the growth window)."""
    scene_sweeps: int = 5
    """Online: sweeps over a new scene's tokens."""
    rejuvenation_tokens: int = 64
    """Online: earlier tokens resampled with each of those sweeps (Canini, Shi & Griffiths 2009)."""
    inference_sweeps: int = 30
    """Fold-in sweeps of :meth:`IncrementalLDA.infer_scene`."""
    inference_burn_in: int = 10
    """Of those, the first ones not averaged."""

    def __post_init__(self) -> None:
        for name in ("sweeps", "scene_sweeps", "inference_sweeps"):
            integer_at_least(self, name, 1)
        for name in ("rejuvenation_tokens", "inference_burn_in"):
            integer_at_least(self, name, 0)
        if self.inference_burn_in >= self.inference_sweeps:
            raise InvalidInputError("inference_burn_in", "must be smaller than inference_sweeps")


@dataclass(frozen=True)
class Hyperparameters:
    """Everything that configures an :class:`IncrementalLDA`: priors, sampler, K rule."""

    priors: Priors = field(default_factory=Priors)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    k_rule: KRuleSettings = field(default_factory=ScenesSettings)
    """The rule for K and its own settings (:mod:`core.context.k_selection`)."""

    def to_dict(self) -> dict[str, Any]:
        """``{"priors": {...}, "sampler": {...}, "k_rule": {"name": ..., ...}}``."""
        return {
            "priors": dict(self.priors.__dict__),
            "sampler": dict(self.sampler.__dict__),
            "k_rule": self.k_rule.to_dict(),
        }

    @classmethod
    def from_dict(cls, nested: Mapping[str, Any]) -> Hyperparameters:
        """The inverse of :meth:`to_dict`; missing groups and settings take their defaults.
        Raises InvalidInputError naming the setting as ``group.setting``."""
        if not isinstance(nested, Mapping):
            raise InvalidInputError("hyperparameters", "must be a mapping of priors, sampler and k_rule")
        unknown = sorted(set(nested) - {"priors", "sampler", "k_rule"})
        if unknown:
            raise InvalidInputError(unknown[0], "unknown group (the groups are priors, sampler and k_rule)")
        rule = dict(_group(nested, "k_rule"))
        name = rule.pop("name", ScenesSettings.name)
        if name == "likelihood":
            raise InvalidInputError("k_rule.name", LIKELIHOOD_RULE_MOVED)
        if name not in K_RULES:
            raise InvalidInputError("k_rule.name", f"must be one of {tuple(K_RULES)}, got {name!r}")
        return cls(
            priors=_settings(Priors, "priors", _group(nested, "priors")),
            sampler=_settings(SamplerSettings, "sampler", _group(nested, "sampler")),
            k_rule=_settings(K_RULES[name], "k_rule", rule),
        )

    @classmethod
    def from_flat(cls, **flat: Any) -> Hyperparameters:
        """From the flat form (``alpha=0.1, sweeps=10, k_selection="paper", tau=0.05, ...``);
        a setting the chosen rule does not have is refused."""
        nested, unused = nest_flat_settings(flat)
        if unused:
            rule = nested.get("k_rule", {}).get("name", ScenesSettings.name)
            raise InvalidInputError(unused[0], f"not a setting of the {rule!r} K rule")
        extra = sorted(set(nested) - {"priors", "sampler", "k_rule"})
        if extra:
            raise InvalidInputError(extra[0], "unknown setting")
        return cls.from_dict(nested)


def nest_flat_settings(flat: Mapping[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The nested form of flat settings, and the known settings it leaves out.

    ``k_selection`` becomes ``k_rule.name``; a setting of the priors, of the sampler or of the
    chosen rule goes to its group; a setting of another rule, or of the retired ``likelihood``
    rule (:data:`LIKELIHOOD_ONLY_SETTINGS`), is left out (returned second: it had no effect under
    the chosen rule); an unknown key stays at the top level, for the caller to refuse.
    """
    rest = dict(flat)
    name = rest.pop("k_selection", ScenesSettings.name)
    rule_type = K_RULES.get(name) if isinstance(name, str) else None
    groups: dict[str, tuple[str, ...]] = {
        "priors": _field_names(Priors),
        "sampler": _field_names(SamplerSettings),
        "k_rule": _field_names(rule_type) if rule_type is not None else (),
    }
    nested: dict[str, Any] = {"k_rule": {"name": name}}
    for group, names in groups.items():
        moved = {key: rest.pop(key) for key in names if key in rest}
        if moved:
            nested.setdefault(group, {}).update(moved)
    known = LIKELIHOOD_ONLY_SETTINGS.union(*(_field_names(rule) for rule in K_RULES.values()))
    unused = [key for key in rest if key in known]
    for key in unused:
        del rest[key]
    return {**rest, **nested}, unused


def _field_names(settings_type: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(settings_type))


def _group(nested: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    group = nested.get(name, {})
    if not isinstance(group, Mapping):
        raise InvalidInputError(name, "must be a mapping of settings")
    return group


def _settings(settings_type: type, group: str, values: Mapping[str, Any]) -> Any:
    unknown = sorted(set(values) - set(_field_names(settings_type)))
    if unknown:
        raise InvalidInputError(f"{group}.{unknown[0]}", f"not a setting of {group}")
    try:
        return settings_type(**values)
    except InvalidInputError as error:
        raise InvalidInputError(f"{group}.{error.field}", error.problem) from None
