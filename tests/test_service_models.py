"""Models: create, list, get and delete through the API, each independent of the others."""

from __future__ import annotations

from functools import partial

from fastapi.testclient import TestClient

from tests.conftest import FAST_HYPERPARAMETERS, two_processes
from tests.faults import at_once


def test_create_get_list_and_delete(client: TestClient) -> None:
    created = client.post(
        "/v1/models", json={"name": "kitchen robot", "seed": 3, "hyperparameters": {"priors": {"alpha": 0.5}}}
    )
    assert created.status_code == 201
    model = created.json()
    assert model["hyperparameters"]["priors"] == {"alpha": 0.5, "xi": 0.1}
    assert model["hyperparameters"]["k_rule"]["name"] == "scenes"
    assert (model["context_count"], model["vocabulary_size"], model["scene_count"]) == (1, 29, 0)
    assert model["vocabulary"]["nouns"] == ["box", "ball", "cylinder", "cup", "plate", "tool"]
    other = client.post("/v1/models", json={"name": "workshop robot"}).json()
    assert [m["id"] for m in client.get("/v1/models").json()] == [model["id"], other["id"]]
    assert client.get(f"/v1/models/{model['id']}").json() == model

    assert client.delete(f"/v1/models/{model['id']}").status_code == 204
    missing = client.get(f"/v1/models/{model['id']}")
    assert missing.status_code == 404
    assert missing.json() == {
        "error": "model_not_found",
        "detail": f"no model {model['id']!r}",
        "field": "path.model_id",
    }
    assert [m["id"] for m in client.get("/v1/models").json()] == [other["id"]]


def test_models_learn_independently(client: TestClient) -> None:
    first, second = (
        client.post("/v1/models", json={"name": name, "hyperparameters": FAST_HYPERPARAMETERS}).json()["id"]
        for name in ("a", "b")
    )
    client.post(f"/v1/models/{first}/scenes", json={"objects": [{"concepts": ["cup", "spoon"]}]})
    assert client.get(f"/v1/models/{first}").json()["scene_count"] == 1
    assert client.get(f"/v1/models/{first}").json()["vocabulary_size"] == 30
    assert client.get(f"/v1/models/{second}").json()["scene_count"] == 0
    assert client.get(f"/v1/models/{second}").json()["vocabulary_size"] == 29


def test_a_custom_vocabulary_and_bad_hyperparameters(client: TestClient) -> None:
    vocabulary = {"nouns": ["mug", "pan"], "adjective_pairs": [["hot", "cold"]], "verbs": ["stir"]}
    model = client.post("/v1/models", json={"name": "cook", "vocabulary": vocabulary}).json()
    assert model["vocabulary"] == vocabulary and model["vocabulary_size"] == 5

    duplicate = client.post("/v1/models", json={"name": "x", "vocabulary": {**vocabulary, "verbs": ["mug"]}})
    assert duplicate.status_code == 422 and duplicate.json()["field"] == "vocabulary"
    burn_in = client.post(
        "/v1/models",
        json={"name": "x", "hyperparameters": {"sampler": {"inference_sweeps": 5, "inference_burn_in": 5}}},
    )
    assert burn_in.status_code == 422 and burn_in.json()["field"] == "hyperparameters.sampler.inference_burn_in"
    negative = client.post("/v1/models", json={"name": "x", "hyperparameters": {"priors": {"alpha": -1}}})
    assert negative.status_code == 422 and negative.json()["field"] == "hyperparameters.priors.alpha"
    unknown = client.post("/v1/models", json={"name": "x", "hyperparameters": {"priors": {"gamma": 1}}})
    assert unknown.status_code == 422 and unknown.json()["field"] == "hyperparameters.priors.gamma"
    misplaced = client.post("/v1/models", json={"name": "x", "hyperparameters": {"sampler": {}, "tau": 0.1}})
    assert misplaced.status_code == 422 and misplaced.json()["field"] == "hyperparameters.tau"


def test_the_paper_rule_is_selectable_and_likelihood_is_refused_naming_the_field(client: TestClient) -> None:
    paper = {"name": "paper", "hyperparameters": {"k_rule": {"name": "paper", "tau": 0.05}}}
    model = client.post("/v1/models", json=paper).json()
    assert model["hyperparameters"]["k_rule"] == {
        "name": "paper", "tau": 0.05, "delta": 0.05, "max_contexts": 10, "birth_window": 100,
        "birth_check_interval": 25, "novelty_window": 20, "scene_prior_strength": 1.0,
    }  # fmt: skip
    for hyperparameters in ({"k_rule": {"name": "likelihood"}}, {"k_selection": "likelihood"}):
        refused = client.post("/v1/models", json={"name": "x", "hyperparameters": hyperparameters})
        assert refused.status_code == 422 and refused.json()["field"] == "hyperparameters.k_rule"
        assert "experiments/baselines/likelihood_rule.py" in refused.json()["detail"]
    wrong_group = client.post(
        "/v1/models", json={"name": "x", "hyperparameters": {"k_rule": {"name": "scenes", "tau": 0.05}}}
    )
    assert wrong_group.status_code == 422 and wrong_group.json()["field"] == "hyperparameters.k_rule.tau"


def test_the_deprecated_flat_body_is_accepted_and_answered_nested(client: TestClient) -> None:
    """Today's flat body keeps working: each setting lands in its group, and the settings the
    chosen rule does not have (the retired likelihood rule's, another rule's) are dropped."""
    flat = {"alpha": 0.5, "sweeps": 12, "birth_check_interval": 200, "likelihood_samples": 2, "tau": 0.2}
    model = client.post("/v1/models", json={"name": "flat", "hyperparameters": flat}).json()
    nested = client.post(
        "/v1/models",
        json={
            "name": "nested",
            "hyperparameters": {
                "priors": {"alpha": 0.5}, "sampler": {"sweeps": 12}, "k_rule": {"birth_check_interval": 200},
            },
        },
    ).json()  # fmt: skip
    assert model["hyperparameters"] == nested["hyperparameters"]
    assert model["hyperparameters"]["priors"]["alpha"] == 0.5 and "tau" not in model["hyperparameters"]["k_rule"]
    paper = client.post("/v1/models", json={"name": "p", "hyperparameters": {"k_selection": "paper", "tau": 0.2}})
    assert paper.json()["hyperparameters"]["k_rule"]["tau"] == 0.2
    bad = client.post("/v1/models", json={"name": "x", "hyperparameters": {"alpha": -1}})
    assert bad.status_code == 422 and bad.json()["field"] == "hyperparameters.priors.alpha"


def test_a_keyed_creation_retried_answers_its_model_and_a_changed_body_is_refused(client: TestClient) -> None:
    body = {"name": "keyed", "seed": 4, "hyperparameters": FAST_HYPERPARAMETERS}
    first = client.post("/v1/models", json=body, headers={"Idempotency-Key": "create-7f3a"})
    assert first.status_code == 201 and "idempotent-replayed" not in first.headers, first.text
    model_id = first.json()["id"]
    scene = {"objects": [{"concepts": ["cup", "hard", "round"]}]}
    assert client.post(f"/v1/models/{model_id}/scenes", json=scene).status_code == 201

    again = client.post("/v1/models", json=body, headers={"Idempotency-Key": "create-7f3a"})
    assert again.status_code == 201 and again.headers["idempotent-replayed"] == "true", again.text
    assert again.json()["id"] == model_id and again.json()["scene_count"] == 1  # the model as it is now

    changed = client.post("/v1/models", json={**body, "seed": 5}, headers={"Idempotency-Key": "create-7f3a"})
    assert changed.status_code == 422, changed.text
    assert changed.json()["error"] == "idempotency_key_reused" and changed.json()["field"] == "header.Idempotency-Key"
    bad_key = client.post("/v1/models", json=body, headers={"Idempotency-Key": "two words"})
    assert bad_key.status_code == 422 and "Idempotency-Key" in bad_key.json()["field"], bad_key.text

    keyless = [client.post("/v1/models", json=body).json()["id"] for _ in range(2)]
    assert len({model_id, *keyless}) == 3  # without a key every creation is a new model
    listed = [model["id"] for model in client.get("/v1/models").json()]
    assert sorted(listed) == sorted([model_id, *keyless])


def test_one_key_created_at_once_on_two_processes_makes_one_model(database_url: str) -> None:
    """Two processes, two threads each, create with one key at the same moment, 10 times: every
    answer is a 201 naming the same model (a later insert meets the key's unique index, is undone
    by its savepoint, and answers the stored model), and one model per key is stored."""
    with two_processes(database_url) as (first, second):
        for round_ in range(10):
            body = {"name": f"race {round_}", "hyperparameters": FAST_HYPERPARAMETERS}
            headers = {"Idempotency-Key": f"race-{round_}"}
            answers = at_once(
                [partial(app.post, "/v1/models", json=body, headers=headers) for app in (first, second, first, second)]
            )
            assert all(answer.status_code == 201 for answer in answers), [answer.text for answer in answers]
            assert len({answer.json()["id"] for answer in answers}) == 1, [answer.json() for answer in answers]
            assert sum(answer.headers.get("idempotent-replayed") == "true" for answer in answers) == 3
        names = [model["name"] for model in second.get("/v1/models").json()]
        assert sorted(names) == sorted(f"race {round_}" for round_ in range(10))
