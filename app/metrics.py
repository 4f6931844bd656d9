"""Prometheus metrics of the models, beside the per-route ones of the instrumentator (docs/operations.md).

Two kinds, both in the app's own :class:`~prometheus_client.CollectorRegistry`:

- **State, read at scrape time** (:class:`ModelStateCollector`): each model's scenes learned,
  contexts K, vocabulary size, websocket subscribers and writes admitted (the one in progress
  plus those waiting), from the registry's published summaries; nothing is counted twice and
  a deleted model simply stops appearing.
- **Events, counted as they happen** (:class:`ModelEvents`): online updates split by whether
  a growth check (Algorithm 2's inner loop) ran, with their durations, and storage failures.

Cardinality is bounded: the first ``max_models`` model ids a process sees get their own
``model`` label, later ones share ``model="_other"``, so a fleet that creates models without
end cannot grow the series without end. The label of a deleted model is released.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import TYPE_CHECKING

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.registry import Collector

if TYPE_CHECKING:
    from app.admission import Admission
    from app.state import AppState

#: The label of the models beyond :attr:`ModelLabels.max_models`.
OTHER_MODELS = "_other"
#: Online-update durations: a plain update takes tens of µs to ms, a growth check up to seconds.
UPDATE_SECONDS_BUCKETS = (0.0001, 0.0003, 0.001, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0)


class ModelLabels:
    """The ``model`` label of each model id: its own for the first ``max_models``, else ``_other``."""

    def __init__(self, max_models: int) -> None:
        self.max_models = max_models
        self._labels: dict[str, str] = {}
        self._lock = threading.Lock()

    def __call__(self, model_id: str) -> str:
        with self._lock:
            label = self._labels.get(model_id)
            if label is None:
                label = model_id if len(self._labels) < self.max_models else OTHER_MODELS
                self._labels[model_id] = label
            return label

    def release(self, model_id: str) -> str | None:
        """Forget ``model_id`` (deleted); its own label, if it had one."""
        with self._lock:
            label = self._labels.pop(model_id, None)
        return label if label != OTHER_MODELS else None


class ModelEvents:
    """What happens to the models, counted as it happens (thread-safe: prometheus_client locks)."""

    def __init__(self, registry: CollectorRegistry, labels: ModelLabels) -> None:
        self.labels = labels
        self.scene_updates = Histogram(
            "contextweb_scene_update_seconds",
            "Online Incremental-LDA updates of one scene (Algorithm 2's loop body), by whether a growth check ran.",
            ["model", "growth_check"],
            buckets=UPDATE_SECONDS_BUCKETS,
            registry=registry,
        )
        self.storage_errors = Counter(
            "contextweb_storage_errors",
            "Writes the database failed (answered 503 storage_unavailable or storage_busy).",
            ["kind"],
            registry=registry,
        )
        for kind in ("unavailable", "busy"):  # at 0 from the start, so rate() sees the first error
            self.storage_errors.labels(kind)

    def scene_learned(self, model_id: str, seconds: float, growth_checked: bool) -> None:
        self.scene_updates.labels(self.labels(model_id), "true" if growth_checked else "false").observe(seconds)

    def storage_failed(self, kind: str) -> None:
        self.storage_errors.labels(kind).inc()

    def model_deleted(self, model_id: str) -> None:
        label = self.labels.release(model_id)
        if label is None:
            return
        for growth_check in ("true", "false"):
            try:
                self.scene_updates.remove(label, growth_check)
            except KeyError:
                pass


class ModelStateCollector(Collector):
    """Each model's state at scrape time, from the app state the lifespan binds (nothing before)."""

    def __init__(self, labels: ModelLabels) -> None:
        self.labels = labels
        self._bound: tuple[AppState, Admission] | None = None

    def bind(self, state: AppState, admission: Admission) -> None:
        """Read these from now on (the lifespan calls it once the state exists)."""
        self._bound = (state, admission)

    def collect(self) -> Iterator[GaugeMetricFamily]:
        families = {
            name: GaugeMetricFamily(f"contextweb_model_{name}", help_text, labels=["model"])
            for name, help_text in (
                ("scenes", "Scenes the model has learned."),
                ("contexts", "Contexts K the model has discovered."),
                ("vocabulary", "Concepts in the model's vocabulary."),
                ("stream_subscribers", "Websocket subscribers of the model on this process."),
                ("writes_admitted", "Writes to the model in progress or waiting on this process (app/admission.py)."),
            )
        }
        if self._bound is not None:
            state, admission = self._bound
            totals: dict[str, dict[str, float]] = {name: {} for name in families}
            for model in state.registry.all():
                label = self.labels(model.id)
                summary = model.summary
                values: dict[str, float] = {
                    "scenes": summary.scene_count,
                    "contexts": summary.context_count,
                    "vocabulary": summary.vocabulary_size,
                    "stream_subscribers": state.hub.subscriber_count(model.id),
                    "writes_admitted": admission.admitted(model.id),
                }
                for name, value in values.items():
                    totals[name][label] = totals[name].get(label, 0.0) + value
            for name, family in families.items():
                for label, value in totals[name].items():
                    family.add_metric([label], value)
        yield from families.values()


class ModelMetrics:
    """The models' metrics of one app: its events and the collector of its state, in ``registry``."""

    def __init__(self, registry: CollectorRegistry, max_models: int) -> None:
        labels = ModelLabels(max_models)
        self.events = ModelEvents(registry, labels)
        self.state = ModelStateCollector(labels)
        registry.register(self.state)
