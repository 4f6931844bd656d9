"""The models' Prometheus metrics: what a scrape shows, the bounded labels, and the Grafana dashboard's queries."""

from __future__ import annotations

import json
import re
from pathlib import Path

from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from app.main import create_app
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, make_settings

DASHBOARD = Path(__file__).resolve().parents[1] / "docker" / "monitoring" / "grafana" / "dashboards" / "contextweb.json"


def _samples(client: TestClient) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    text = client.get("/metrics").text
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }


def _value(samples: dict, name: str, **labels: str) -> float | None:
    return samples.get((name, tuple(sorted(labels.items()))))


def test_a_scrape_shows_each_models_scenes_contexts_and_updates(database_url: str) -> None:
    with TestClient(create_app(make_settings(database_url))) as client:
        model_id = client.post("/v1/models", json={"name": "m", "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        scenes = concept_scenes(7, seed=2)
        for scene in scenes:
            assert client.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201
        model = client.get(f"/v1/models/{model_id}").json()
        with client.websocket_connect(f"/v1/models/{model_id}/stream") as stream:
            stream.receive_json()  # the hello: subscribed
            samples = _samples(client)
        assert _value(samples, "contextweb_model_scenes", model=model_id) == 7
        assert _value(samples, "contextweb_model_contexts", model=model_id) == model["context_count"]
        assert _value(samples, "contextweb_model_vocabulary", model=model_id) == model["vocabulary_size"]
        assert _value(samples, "contextweb_model_stream_subscribers", model=model_id) == 1
        assert _value(samples, "contextweb_model_writes_admitted", model=model_id) == 0
        checked = _value(samples, "contextweb_scene_update_seconds_count", model=model_id, growth_check="true") or 0
        unchecked = _value(samples, "contextweb_scene_update_seconds_count", model=model_id, growth_check="false") or 0
        # FAST_HYPERPARAMETERS check growth after each of the first 3 scenes, then every 3rd: scenes 1, 2, 3, 6.
        assert (checked, unchecked) == (4, 3)
        # A replay is no new update.
        key = {"Idempotency-Key": "again"}
        client.post(f"/v1/models/{model_id}/scenes", json=scenes[0], headers=key)
        client.post(f"/v1/models/{model_id}/scenes", json=scenes[0], headers=key)
        samples = _samples(client)
        assert _value(samples, "contextweb_scene_update_seconds_count", model=model_id, growth_check="false") == 4

        assert client.delete(f"/v1/models/{model_id}").status_code == 204
        assert not [key for key in _samples(client) if ("model", model_id) in key[1]]


def test_model_labels_are_bounded(database_url: str) -> None:
    with TestClient(create_app(make_settings(database_url, metrics_max_models=2))) as client:
        ids = [client.post("/v1/models", json={"name": f"m{i}"}).json()["id"] for i in range(4)]
        for model_id in ids:
            client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": ["cup", "hard"]}]})
        samples = _samples(client)
        labelled = {dict(labels)["model"] for name, labels in samples if name == "contextweb_model_scenes"}
        assert len(labelled) == 3 and "_other" in labelled
        assert _value(samples, "contextweb_model_scenes", model="_other") == 2  # two models, one scene each


def test_every_series_the_grafana_dashboard_queries_exists(database_url: str) -> None:
    dashboard = json.loads(DASHBOARD.read_text())
    queried = {
        name
        for panel in dashboard["panels"]
        for target in panel["targets"]
        for name in re.findall(r"\b(contextweb_\w+|http_\w+)", target["expr"])
    }
    assert len(queried) >= 8
    with TestClient(create_app(make_settings(database_url))) as client:
        model_id = client.post("/v1/models", json={"name": "m"}).json()["id"]
        client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": ["cup"]}]})
        exposed = {name for name, _labels in _samples(client)}
    assert queried <= exposed, queried - exposed
