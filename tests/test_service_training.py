"""Training, fitting and the feature/raw levels, then planning in context (§V-E) through the API.

The training objects are the paper world's 45 with synthetic feature vectors
(tests/conftest.py, :func:`synthetic_training_objects`): real sensor payloads
take about a second per object to turn into features, which is the raw level's
business; it is exercised here on one small cloud.
"""

from __future__ import annotations

import base64
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from app.deps import write_model
from app.registry import ModelRuntime
from app.schemas.training import FitCreate
from app.services import training as training_service
from app.state import AppState
from core.features.layout import EFFECT_SIZE, ENTITY_SIZE
from sim.world import World
from storage.database import autocommit_reads
from storage.repositories import models as model_repository
from storage.repositories.incremental_lda import stored_version
from tests.conftest import state_and_model, synthetic_training_objects
from tests.test_sqlite_locks import outside_write_lock


@pytest.fixture(scope="module")
def world() -> World:
    return World.paper(0)


@pytest.fixture(scope="module")
def training_objects(world: World) -> list[dict]:
    return synthetic_training_objects(world, seed=1)


def _fit(client: TestClient, model_id: str, objects: list[dict], world: World) -> None:
    added = client.post(f"/v1/models/{model_id}/training-objects", json={"objects": objects})
    assert added.status_code == 201 and added.json() == {"added": 45, "training_object_count": 45}
    fitted = client.post(f"/v1/models/{model_id}/fit", json={"method": "kmeans"})
    assert fitted.status_code == 200, fitted.text
    assert fitted.json()["concept_web_edges"] > 0 and sorted(fitted.json()["behaviours"]) == sorted(
        world.vocabulary.verbs
    )


@pytest.fixture
def fitted_model(client: TestClient, world: World, training_objects: list[dict]) -> tuple[str, list[dict]]:
    """A model trained on the paper world's objects and fitted with k-means prototypes."""
    model_id = client.post("/v1/models", json={"name": "icub", "seed": 4}).json()["id"]
    _fit(client, model_id, training_objects, world)
    return model_id, training_objects


def test_fitting_gives_the_prototype_table_and_perceives_features(
    client: TestClient, fitted_model, world: World
) -> None:
    model_id, objects = fitted_model
    model = client.get(f"/v1/models/{model_id}").json()
    assert model["prototypes_fitted"] and model["concept_web_fitted"] and model["training_object_count"] == 45
    table = client.get(f"/v1/models/{model_id}/prototypes").json()
    assert table["method"] == "kmeans" and len(table["concepts"]) == 29
    lengths = {c["kind"]: len(c["relevance"]) for c in table["concepts"]}
    assert lengths == {"noun": ENTITY_SIZE, "adjective": ENTITY_SIZE, "verb": EFFECT_SIZE}
    assert "cup" in table["table"]

    cups = [o for o in objects if o["noun"] == "cup"][:2]
    answer = client.post(f"/v1/models/{model_id}/infer", json={"objects": [{"features": o["features"]} for o in cups]})
    assert answer.status_code == 200
    for analysed, cup in zip(answer.json()["objects"], cups, strict=True):
        assert analysed["level"] == "features"
        assert (
            max(analysed["perception"], key=lambda c: analysed["perception"][c] if c in world.vocabulary.nouns else -1)
            == "cup"
        )
        assert "cup" in analysed["active_concepts"] and set(cup["adjectives"]) <= set(analysed["active_concepts"])
        assert analysed["web"]["cup"] > 0.9
        assert set(analysed["in_context"]) == set(world.vocabulary.concepts)


def test_context_is_fed_back_by_eq_6(client: TestClient, world: World, training_objects: list[dict]) -> None:
    """σ = 1 is the concept web alone; σ = 0 lets the learned context move the probabilities."""
    scene = {"objects": [{"features": training_objects[0]["features"]}, {"concepts": {"cup": 0.5, "plate": 0.5}}]}
    answers = {}
    for sigma in (1.0, 0.0):
        model_id = client.post("/v1/models", json={"name": f"sigma {sigma}", "sigma": sigma}).json()["id"]
        _fit(client, model_id, training_objects, world)
        for kitchen in world.scenes(6, seed=5, contexts=["kitchen"]):
            client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": kitchen.tokens()}]})
        answers[sigma] = client.post(f"/v1/models/{model_id}/infer", json=scene).json()["objects"]
    for obj in answers[1.0]:
        assert obj["in_context"] == pytest.approx(obj["web"])
    assert answers[0.0][1]["in_context"]["cup"] != pytest.approx(answers[0.0][1]["web"]["cup"], abs=1e-3)


def test_extreme_features_are_a_422_naming_the_object(client: TestClient, fitted_model) -> None:
    model_id, _ = fitted_model
    extreme = {"objects": [{"concepts": ["cup"]}, {"features": {"entity": [1e308] * ENTITY_SIZE}}]}
    response = client.post(f"/v1/models/{model_id}/scenes", json=extreme)
    assert response.status_code == 422 and response.json()["field"] == "objects[1].features"
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 0


def test_a_raw_object_is_extracted_and_perceived(client: TestClient, fitted_model) -> None:
    model_id, _ = fitted_model
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(300, 3))
    sphere = 0.04 * sphere / np.linalg.norm(sphere, axis=1, keepdims=True) + np.array([0.0, 0.3, 0.04])
    encoded = base64.b64encode(sphere.astype("<f4").tobytes()).decode()
    raw = {
        "look": {"points": encoded},
        "interactions": [
            {
                "behaviour": "move_left",
                "before": {"points": encoded},
                "after": {"points": (sphere - [0.1, 0, 0]).tolist()},
            }
        ],
    }
    response = client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"raw": raw}, {"concepts": ["ball"]}]})
    assert response.status_code == 201, response.text
    analysed = response.json()["objects"][0]
    assert analysed["level"] == "raw" and analysed["web"] is not None
    assert sum(
        analysed["perception"][noun] for noun in ("box", "ball", "cylinder", "cup", "plate", "tool")
    ) == pytest.approx(1.0)


def test_raw_values_past_a_sensors_range_are_a_422_naming_the_payload_not_a_500(
    client: TestClient, fitted_model
) -> None:
    """Finite coordinates of 1e200 m overflowed the surface fit's covariance (LinAlgError: a 500), and
    audio samples of 1e20 its float32 spectrum (a 422 on no field of the request): core/payloads.py's bounds."""
    model_id, _ = fitted_model
    cloud = (0.04 * np.random.default_rng(1).normal(size=(300, 3))).tolist()
    far = (np.asarray(cloud) * 1e200).tolist()
    loud = {"samples": (np.sin(np.arange(4_000) / 3.0) * 1e20).tolist(), "sample_rate": 8_000}
    shake = {"behaviour": "shake", "before": {"points": cloud}, "after": {"points": cloud}, "audio": loud}
    for raw, field, bound in (
        ({"look": {"points": far}}, "objects[0].raw.look.points", "±1,000 m"),
        (
            {"look": {"points": cloud}, "interactions": [shake]},
            "objects[0].raw.interactions[0].audio.samples",
            "±2,147,483,648",
        ),
    ):
        response = client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"raw": raw}]})
        assert response.status_code == 422, response.text
        assert response.json()["field"] == field and bound in response.json()["detail"]
    assert client.get(f"/v1/models/{model_id}").json()["scene_count"] == 0


def test_planning_prunes_by_the_learned_context(
    client: TestClient, model_id: str, world: World, training_objects: list[dict]
) -> None:
    """Fig. 15(b): in a kitchen, cups and plates are only grasped and moved: 156 nodes instead of 2,380.

    The kitchen scenes carry their verbs (Table II) and are learned before the fit, so
    the context's P(verb | χ) comes from them alone."""
    for scene in world.scenes(20, seed=2, contexts=["kitchen"]):
        response = client.post(f"/v1/models/{model_id}/scenes", json={"objects": [{"concepts": scene.tokens()}]})
        assert response.status_code == 201
    _fit(client, model_id, training_objects, world)
    kitchen = {
        "objects": [{"concepts": ["cup", "hard", "short", "grasp", "move_left"]}, {"concepts": ["plate", "round"]}]
    }
    request = {"object": "cup", "start": 8, "goal": 5, "scene": kitchen, "mode": "paper"}
    plan = client.post(f"/v1/models/{model_id}/plans", json=request)
    assert plan.status_code == 200, plan.text
    plan = plan.json()
    assert plan["context_source"] == "inferred" and plan["status"] == "solved"
    assert plan["plan"] == ["move_right"] * 3 and plan["positions"] == [8, 7, 6, 5]
    assert plan["unpruned"]["nodes_generated"] == 2380
    assert sorted(plan["kept"]) == ["grasp", "move_backward", "move_forward", "move_left", "move_right"]
    assert plan["nodes_generated"] == 156

    unpruned = client.post(
        f"/v1/models/{model_id}/plans", json={"object": "cup", "start": 8, "goal": 5, "mode": "paper"}
    ).json()
    assert unpruned["context_source"] == "none" and unpruned["pruned"] == [] and unpruned["nodes_generated"] == 2380
    off_table = client.post(f"/v1/models/{model_id}/plans", json={"object": "cup", "start": 8, "goal": 99})
    assert off_table.status_code == 422 and off_table.json()["field"] == "goal"
    too_many = client.post(f"/v1/models/{model_id}/plans", json={"object": "cup", "start": 8, "goal": 5, "context": 99})
    assert too_many.status_code == 422 and too_many.json()["field"] == "context"


def test_training_labels_are_checked(client: TestClient, model_id: str, training_objects: list[dict]) -> None:
    good = training_objects[0]
    url = f"/v1/models/{model_id}/training-objects"
    cases = [
        ({**good, "noun": "spoon"}, "objects[0].noun"),
        ({**good, "adjectives": good["adjectives"][:4]}, "objects[0].adjectives"),
        ({**good, "verbs": {"fly": "grasp"}}, "objects[0].verbs.fly"),
        (
            {**good, "features": {**good["features"], "effects": {"fly": [0.0] * EFFECT_SIZE}}},
            "objects[0].features.effects.fly",
        ),
    ]
    for body, field in cases:
        response = client.post(url, json={"objects": [body]})
        assert response.status_code == 422 and response.json()["field"] == field, response.text
    assert client.post(f"/v1/models/{model_id}/fit", json={}).status_code == 409
    assert client.get(f"/v1/models/{model_id}/prototypes").status_code == 409


def _stored_version(engine: Engine, model_id: str) -> int | None:
    with Session(engine) as session:
        return stored_version(session, model_id)


def test_a_fit_without_any_effect_says_what_is_missing(
    client: TestClient, model_id: str, training_objects: list[dict]
) -> None:
    """It said "the training set is empty" though every object was there, only their effects were not."""
    without_effects = [{**obj, "features": {**obj["features"], "effects": {}}} for obj in training_objects]
    assert client.post(f"/v1/models/{model_id}/training-objects", json={"objects": without_effects}).status_code == 201
    response = client.post(f"/v1/models/{model_id}/fit", json={"method": "kmeans"})
    assert response.status_code == 422
    assert response.json()["field"] == "training.effect_vectors"
    assert response.json()["detail"].startswith("no training object carries an effect (its features' effects")


def test_a_keyed_training_batch_retried_is_answered_again_and_adds_nothing(
    client: TestClient, model_id: str, training_objects: list[dict], engine: Engine
) -> None:
    url = f"/v1/models/{model_id}/training-objects"
    first_batch, second_batch = {"objects": training_objects[:10]}, {"objects": training_objects[10:15]}
    first = client.post(url, json=first_batch, headers={"Idempotency-Key": "batch-1"})
    assert first.status_code == 201 and "idempotent-replayed" not in first.headers, first.text
    assert first.json() == {"added": 10, "training_object_count": 10}
    assert client.post(url, json=second_batch, headers={"Idempotency-Key": "batch-2"}).status_code == 201

    version = _stored_version(engine, model_id)
    again = client.post(url, json=first_batch, headers={"Idempotency-Key": "batch-1"})
    assert again.status_code == 201 and again.headers["idempotent-replayed"] == "true", again.text
    assert _stored_version(engine, model_id) == version  # a replay is no write: other processes need not catch up
    assert again.json() == {"added": 10, "training_object_count": 10}  # the answer as it was given
    changed = client.post(url, json=second_batch, headers={"Idempotency-Key": "batch-1"})
    assert changed.status_code == 422 and changed.json()["error"] == "idempotency_key_reused", changed.text
    assert changed.json()["field"] == "header.Idempotency-Key"
    # The key's reuse is said first, before what is wrong with the body (its rows are computed
    # before the write, its refusal raised only after the key's lookup).
    wrong_noun = {"objects": [{**training_objects[0], "noun": "spaceship"}]}
    reused = client.post(url, json=wrong_noun, headers={"Idempotency-Key": "batch-1"})
    assert reused.status_code == 422 and reused.json()["error"] == "idempotency_key_reused", reused.text
    refused = client.post(url, json=wrong_noun, headers={"Idempotency-Key": "batch-3"})
    assert refused.status_code == 422 and refused.json()["field"] == "objects[0].noun", refused.text
    assert client.get(f"/v1/models/{model_id}").json()["training_object_count"] == 15  # nothing added twice

    keyless = client.post(url, json=first_batch)  # without a key a repeat is a new batch
    assert keyless.json() == {"added": 10, "training_object_count": 25}


def _prepared_fit(state: AppState, model: ModelRuntime) -> training_service.PreparedFit:
    """A fit computed as the fit route computes it: from one read, outside the model's write."""
    with autocommit_reads(state.read_sessions) as session:
        return training_service.prepare_fit(session, model, FitCreate(method="kmeans"))


def test_a_fit_computed_before_its_write_is_stored_only_while_its_objects_are_all_the_models(
    client: TestClient, model_id: str, training_objects: list[dict]
) -> None:
    """The fit route computes outside the model's write; the write stores that fit if no training
    object was added in between, else fits again on all of them: a fit never leaves an object out."""
    state, model = state_and_model(client, model_id)
    first, later = training_objects, training_objects[:5]  # every concept first; then 5 objects more
    assert client.post(f"/v1/models/{model_id}/training-objects", json={"objects": first}).status_code == 201

    current = _prepared_fit(state, model)
    stored = write_model(state, model, lambda s: training_service.fit(s, model, FitCreate(method="kmeans"), current))
    assert stored == current.answer and stored.training_object_count == 45
    assert model.writer.fitted is current.fitted  # stored as computed, not fitted again

    stale = _prepared_fit(state, model)
    assert client.post(f"/v1/models/{model_id}/training-objects", json={"objects": later}).status_code == 201
    stored = write_model(state, model, lambda s: training_service.fit(s, model, FitCreate(method="kmeans"), stale))
    assert stored.training_object_count == 50 and model.writer.fitted is not stale.fitted
    # What was stored is the fit of all 50 objects, the one a fit from scratch gives.
    fresh = _prepared_fit(state, model)
    assert (fresh.prototypes_state, fresh.concept_web_state) != (stale.prototypes_state, stale.concept_web_state)
    with state.read_sessions() as session:
        row = model_repository.get_model(session, model_id)
        assert row is not None
        assert (row.prototypes, row.concept_web) == (fresh.prototypes_state, fresh.concept_web_state)


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_a_fit_is_computed_without_sqlites_write_lock(
    client: TestClient, database_url: str, model_id: str, training_objects: list[dict]
) -> None:
    """A fit's computation (seconds on a large training set) reads only: on SQLite it runs while
    another connection holds the database's one write lock, which every model's writes share."""
    state, model = state_and_model(client, model_id)
    assert client.post(f"/v1/models/{model_id}/training-objects", json={"objects": training_objects}).status_code == 201
    with outside_write_lock(Path(database_url.removeprefix("sqlite:///"))):
        prepared = _prepared_fit(state, model)
    assert prepared.object_count == 45
    fitted = client.post(f"/v1/models/{model_id}/fit", json={"method": "kmeans"})
    assert fitted.status_code == 200 and fitted.json() == prepared.answer.model_dump(mode="json")
