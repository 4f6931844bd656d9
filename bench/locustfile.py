"""A fleet for Locust: robots posting scenes, dashboards reading and subscribing (issue 18, item 5).

Run it against a running server (``pip install -e '.[load]'`` first)::

    CONTEXTWEB_WRITE_KEY=robot-key CONTEXTWEB_READ_KEY=dash-key \\
    CONTEXTWEB_LOAD_ROBOTS=8 CONTEXTWEB_LOAD_DASHBOARDS=2 CONTEXTWEB_LOAD_SCENE_RATE=1 \\
        locust -f bench/locustfile.py --headless -u 10 -r 5 -t 60s --host http://127.0.0.1:8000 --csv /tmp/run

``-u`` should be the robots plus the dashboards: both classes are spawned in fixed numbers
(Locust's ``fixed_count``), so the environment, not ``-u``, sets the fleet's make-up.

User classes:

- :class:`Robot` posts a scene to its model every ``1 / SCENE_RATE`` s (``constant_pacing``: a
  robot whose answer is slower than that posts as fast as it is answered). Each scene has 2–4
  objects from one of three contexts (the contexts of tests/conftest.py's ``concept_scenes``) and a
  fresh ``Idempotency-Key``. Robot ``r`` posts to model ``r % MODELS``. Every user starts at a
  seeded random phase of its period, so the fleet does not post in lockstep.
- :class:`Dashboard` reads ``/contexts`` and the latest page of ``/scenes`` of model
  ``d % MODELS`` every ``POLL_SECONDS``, and, with ``STREAM=1``, follows its websocket stream.
  Each ``scene`` event is reported as ``WS stream scene`` with the event's lag (arrival minus the
  scene's ``created_at``) as its response time; the socket's opening as ``WS connect``; a close
  as a ``WS close`` failure with its code.

Refusals get their own request names, so that admission pressure (429 ``model_busy``,
``rate_limited``) and storage pressure (503 ``storage_busy``, ``storage_unavailable``, …) are
counted, and timed, apart from the answered requests: ``POST /scenes [429 model_busy]``. Nothing
is retried.

On start, the test creates the models it needs, or reuses those that already have their names
(``<PREFIX>-<i>``); at the ``features`` level it also trains and fits every model not fitted yet.
The server's memory is not in its ``/metrics`` (no process collector): read it on the server's
machine (``ps -o rss``, ``/proc/<pid>/status``).

Environment:

=================================  ===============  ==========================================
variable                           default          meaning
=================================  ===============  ==========================================
``CONTEXTWEB_URL``                 127.0.0.1:8000   the server, when ``--host`` is not given
``CONTEXTWEB_WRITE_KEY``           none             robots' key; also creates the models (it
                                                    must be a write key of every model or an
                                                    admin key)
``CONTEXTWEB_READ_KEY``            the write key    dashboards' key
``CONTEXTWEB_LOAD_ROBOTS``         8                robots
``CONTEXTWEB_LOAD_DASHBOARDS``     2                dashboards
``CONTEXTWEB_LOAD_SCENE_RATE``     1.0              scenes a second per robot
``CONTEXTWEB_LOAD_MODELS``         the robots       models the fleet shares
``CONTEXTWEB_LOAD_LEVEL``          ``concepts``     ``concepts`` or ``features`` (91 + 66 synthetic
                                                    numbers per behaviour; needs a fit)
``CONTEXTWEB_LOAD_POLL_SECONDS``   2.0              seconds between a dashboard's polls
``CONTEXTWEB_LOAD_SCENES_LIMIT``   50               ``limit`` of the ``/scenes`` page
``CONTEXTWEB_LOAD_STREAM``         1                dashboards subscribe to the stream (0: poll only)
``CONTEXTWEB_LOAD_SEED``           0                seeds the models and every user's scenes
``CONTEXTWEB_LOAD_MODEL_PREFIX``   ``locust-fleet`` the models' names
=================================  ===============  ==========================================

Reproducible: model ``i`` has seed ``SEED + i``, and robot ``r`` draws its scenes from
``numpy.random.default_rng([SEED, r])``, so one robot per model on fresh models posts the same
scenes and gets the same answers on every run. Robots sharing a model interleave as the network
lets them, so their models' answers vary from run to run. Idempotency keys carry a token of the
run, so a second run on reused models learns its scenes rather than replaying the first run's.

The websocket client is websocket-client (Apache-2.0), a plain-socket client that Locust's gevent
monkey-patching makes cooperative; it runs in one greenlet per dashboard.
"""

from __future__ import annotations

import json
import logging
import os
import re
import secrets
import time
from datetime import datetime
from itertools import count
from typing import Any, ClassVar

import gevent
import numpy as np
import requests
import websocket
from locust import HttpUser, constant_pacing, events, task
from locust.env import Environment

logger = logging.getLogger("contextweb.locust")

URL = os.environ.get("CONTEXTWEB_URL", "http://127.0.0.1:8000")
WRITE_KEY = os.environ.get("CONTEXTWEB_WRITE_KEY")
READ_KEY = os.environ.get("CONTEXTWEB_READ_KEY") or WRITE_KEY
ROBOTS = int(os.environ.get("CONTEXTWEB_LOAD_ROBOTS", "8"))
DASHBOARDS = int(os.environ.get("CONTEXTWEB_LOAD_DASHBOARDS", "2"))
SCENE_RATE = float(os.environ.get("CONTEXTWEB_LOAD_SCENE_RATE", "1"))
MODELS = int(os.environ.get("CONTEXTWEB_LOAD_MODELS", "0")) or max(ROBOTS, 1)
LEVEL = os.environ.get("CONTEXTWEB_LOAD_LEVEL", "concepts")
POLL_SECONDS = float(os.environ.get("CONTEXTWEB_LOAD_POLL_SECONDS", "2"))
SCENES_LIMIT = int(os.environ.get("CONTEXTWEB_LOAD_SCENES_LIMIT", "50"))
STREAM = os.environ.get("CONTEXTWEB_LOAD_STREAM", "1") not in ("0", "", "false", "no")
SEED = int(os.environ.get("CONTEXTWEB_LOAD_SEED", "0"))
MODEL_PREFIX = os.environ.get("CONTEXTWEB_LOAD_MODEL_PREFIX", "locust-fleet")
if LEVEL not in ("concepts", "features"):
    raise SystemExit(f"CONTEXTWEB_LOAD_LEVEL must be concepts or features, not {LEVEL!r}")

#: The service's own serving setting (bench/bench_service.py's ``SERVING``): growth checks every
#: 200 scenes instead of every 25, as a deployment that learns for long would set.
HYPERPARAMETERS: dict[str, Any] = {"k_rule": {"name": "scenes", "birth_check_interval": 200}}

#: Three contexts of the paper's vocabulary, as in tests/conftest.py's ``CONTEXT_CONCEPTS``; the
#: nouns and verbs also drive the feature-level objects.
CONTEXTS = {
    "kitchen": ["cup", "plate", "hard", "short", "silent", "round", "grasp", "move_left"],
    "playroom": ["ball", "box", "soft", "noisy", "edgy", "thick", "throw", "shake"],
    "workshop": ["tool", "cylinder", "hard", "tall", "thin", "push_left", "knock_down", "drop"],
}

#: Sizes of Table III's entity vector e and effect vector f (core/features/layout.py).
ENTITY_SIZE = 91
EFFECT_SIZE = 66
TRAINING_OBJECTS = 60

ERROR_STATUSES = {429, 503}
RUN_TOKEN = secrets.token_hex(4)


class Fleet:
    """What the test's start learned about the models: their ids and vocabularies, in name order."""

    model_ids: ClassVar[list[str]] = []
    vocabularies: ClassVar[list[dict[str, Any]]] = []


def _headers(key: str | None) -> dict[str, str]:
    return {"X-API-Key": key} if key else {}


def _error_name(response: requests.Response) -> str:
    try:
        return str(response.json().get("error", "?"))
    except ValueError:
        return "no_json_body"


def _settle(response: Any, name: str, expected: int) -> bool:
    """Mark a ``catch_response`` answer: ``expected`` succeeds; 429 and 503 are renamed
    ``<name> [<status> <error>]`` so that they are counted and timed apart; any other status is a
    failure of ``name`` itself."""
    if response.status_code == expected:
        response.success()
        return True
    kind = f"{response.status_code} {_error_name(response)}" if response.status_code else str(response.error)
    if response.status_code in ERROR_STATUSES:
        response.request_meta["name"] = f"{name} [{kind}]"
    response.failure(kind)
    return False


def _random_phase(role: int, number: int, period: float) -> None:
    """Wait a seeded random part of the first period: Locust starts a spawn step's users together,
    and users paced alike would then post in lockstep, every request of a period in one burst."""
    gevent.sleep(np.random.default_rng([SEED, number, role]).uniform(0.0, period))


# --- the synthetic world, for feature-level scenes ---------------------------------------------


class SyntheticPerception:
    """Mean entity vectors per noun and adjective and mean effect vectors per verb, drawn from the
    seed (as tests/conftest.py's ``synthetic_training_objects``): an object's entity vector is the sum
    of its concepts' means plus noise, a behaviour's effect its verb's mean plus noise."""

    def __init__(self, vocabulary: dict[str, Any], seed: int) -> None:
        rng = np.random.default_rng([seed, 1_000_003])
        self.nouns: list[str] = vocabulary["nouns"]
        self.pairs: list[list[str]] = vocabulary["adjective_pairs"]
        self.verbs: list[str] = vocabulary["verbs"]
        adjectives = [a for pair in self.pairs for a in pair]
        self.entity_means = {c: rng.normal(0.0, 1.0, ENTITY_SIZE) for c in self.nouns + adjectives}
        self.effect_means = {v: rng.normal(0.0, 1.0, EFFECT_SIZE) for v in self.verbs}

    def labelled_object(self, rng: np.random.Generator, noun: str, preferred: list[str], verbs: list[str]) -> dict:
        adjectives = [self.adjective(rng, pair, preferred) for pair in self.pairs]
        entity = sum(self.entity_means[c] for c in [noun, *adjectives]) + rng.normal(0.0, 0.1, ENTITY_SIZE)
        effects = {v: (self.effect_means[v] + rng.normal(0.0, 0.05, EFFECT_SIZE)).tolist() for v in verbs}
        return {"noun": noun, "adjectives": adjectives, "features": {"entity": entity.tolist(), "effects": effects}}

    @staticmethod
    def adjective(rng: np.random.Generator, pair: list[str], preferred: list[str]) -> str:
        """The pair's adjective that the context names, else either at random."""
        named = [a for a in pair if a in preferred]
        return named[0] if named else str(rng.choice(pair))

    def training_objects(self, seed: int) -> list[dict]:
        rng = np.random.default_rng([seed, 2])
        return [
            self.labelled_object(rng, str(rng.choice(self.nouns)), [], list(rng.choice(self.verbs, 4, replace=False)))
            for _ in range(TRAINING_OBJECTS)
        ]

    def scene_object(self, rng: np.random.Generator, concepts: list[str]) -> dict:
        nouns = [c for c in concepts if c in self.nouns]
        verbs = [c for c in concepts if c in self.verbs]
        labelled = self.labelled_object(rng, str(rng.choice(nouns)), concepts, verbs)
        return {"features": labelled["features"]}


# --- the test's start: models and fits ----------------------------------------


def _ensure_model(session: requests.Session, host: str, name: str, seed: int, existing: dict[str, dict]) -> dict:
    if name in existing:
        return existing[name]
    response = session.post(f"{host}/v1/models", json={"name": name, "seed": seed, "hyperparameters": HYPERPARAMETERS})
    response.raise_for_status()
    return response.json()


def _ensure_fitted(session: requests.Session, host: str, model: dict, seed: int) -> None:
    if model["prototypes_fitted"]:
        return
    objects = SyntheticPerception(model["vocabulary"], SEED).training_objects(seed)
    session.post(f"{host}/v1/models/{model['id']}/training-objects", json={"objects": objects}).raise_for_status()
    session.post(f"{host}/v1/models/{model['id']}/fit", json={"method": "kmeans"}, timeout=300).raise_for_status()


@events.test_start.add_listener
def create_fleet_models(environment: Environment, **_: Any) -> None:
    host = (environment.host or URL).rstrip("/")
    with requests.Session() as session:
        session.headers.update(_headers(WRITE_KEY))
        listing = session.get(f"{host}/v1/models", timeout=30)
        listing.raise_for_status()
        existing = {model["name"]: model for model in listing.json()}
        models = []
        for i in range(MODELS):
            model = _ensure_model(session, host, f"{MODEL_PREFIX}-{i}", SEED + i, existing)
            if LEVEL == "features":
                _ensure_fitted(session, host, model, SEED + i)
            models.append(model)
    Fleet.model_ids = [model["id"] for model in models]
    Fleet.vocabularies = [model["vocabulary"] for model in models]
    logger.info(
        "fleet: %d robots at %.2f scenes/s on %d %s-level models, %d dashboards (stream %s)",
        ROBOTS, SCENE_RATE, MODELS, LEVEL, DASHBOARDS, "on" if STREAM else "off",
    )  # fmt: skip


# --- the users -----------------------------------------------------------------------------------


class Robot(HttpUser):
    """Posts a scene to its model every ``1 / SCENE_RATE`` seconds."""

    host = URL
    fixed_count = ROBOTS
    weight = 1 if ROBOTS else 0  # with neither, Locust leaves the class out
    wait_time = constant_pacing(1.0 / SCENE_RATE)
    numbers = count()

    def on_start(self) -> None:
        self.number = next(Robot.numbers)
        model = self.number % len(Fleet.model_ids)
        self.model_id = Fleet.model_ids[model]
        self.rng = np.random.default_rng([SEED, self.number])
        self.perception = SyntheticPerception(Fleet.vocabularies[model], SEED) if LEVEL == "features" else None
        self.scenes = count()
        self.client.headers.update(_headers(WRITE_KEY))
        _random_phase(1, self.number, 1.0 / SCENE_RATE)

    def scene(self) -> dict:
        """2–4 objects of one context (tests/conftest.py's ``concept_scenes``), named or measured."""
        concepts = CONTEXTS[list(CONTEXTS)[self.rng.integers(3)]]
        objects = []
        for _ in range(self.rng.integers(2, 5)):
            if self.perception is None:
                objects.append({"concepts": [str(c) for c in self.rng.choice(concepts, size=4, replace=False)]})
            else:
                objects.append(self.perception.scene_object(self.rng, concepts))
        return {"objects": objects}

    @task
    def post_scene(self) -> None:
        key = f"locust-{RUN_TOKEN}-robot{self.number}-{next(self.scenes)}"
        with self.client.post(
            f"/v1/models/{self.model_id}/scenes",
            data=json.dumps(self.scene()),
            headers={"Idempotency-Key": key, "Content-Type": "application/json"},
            name="POST /scenes",
            catch_response=True,
        ) as response:
            _settle(response, "POST /scenes", 201)


class Dashboard(HttpUser):
    """Reads a model's contexts and latest scenes every ``POLL_SECONDS``; follows its stream."""

    host = URL
    fixed_count = DASHBOARDS
    weight = 1 if DASHBOARDS else 0
    wait_time = constant_pacing(POLL_SECONDS)
    numbers = count()

    def on_start(self) -> None:
        self.number = next(Dashboard.numbers)
        self.model_id = Fleet.model_ids[self.number % len(Fleet.model_ids)]
        self.client.headers.update(_headers(READ_KEY))
        self.scene_total = 0
        self.socket: websocket.WebSocket | None = None
        self.follower = gevent.spawn(self.follow_stream) if STREAM else None
        _random_phase(2, self.number, POLL_SECONDS)

    def on_stop(self) -> None:
        if self.follower is not None:
            self.follower.kill()  # before the close, whose echo it would report as a failure
        if self.socket is not None:
            self.socket.close()

    @task
    def poll(self) -> None:
        models = f"/v1/models/{self.model_id}"
        with self.client.get(f"{models}/contexts?top=10", name="GET /contexts", catch_response=True) as response:
            _settle(response, "GET /contexts", 200)
        offset = max(self.scene_total - SCENES_LIMIT, 0)
        with self.client.get(
            f"{models}/scenes?offset={offset}&limit={SCENES_LIMIT}", name="GET /scenes", catch_response=True
        ) as response:
            if _settle(response, "GET /scenes", 200):
                self.scene_total = response.json()["total"]

    def fire(self, name: str, milliseconds: float, length: int, exception: Exception | None = None) -> None:
        self.environment.events.request.fire(
            request_type="WS", name=name, response_time=milliseconds, response_length=length,
            exception=exception, context={},
        )  # fmt: skip

    def follow_stream(self) -> None:
        """Receive the stream's events until the user stops; report each ``scene`` event's lag."""
        url = re.sub(r"^http", "ws", (self.host or URL).rstrip("/")) + f"/v1/models/{self.model_id}/stream"
        start = time.perf_counter()
        try:
            self.socket = websocket.create_connection(url, header=_headers(READ_KEY), timeout=60)
        except (OSError, websocket.WebSocketException) as error:
            self.fire("WS connect", (time.perf_counter() - start) * 1000, 0, error)
            return
        self.fire("WS connect", (time.perf_counter() - start) * 1000, 0)
        self.socket.settimeout(None)  # a quiet model is not an error; uvicorn's pings keep it alive
        while True:
            try:
                opcode, data = self.socket.recv_data()
            except (OSError, websocket.WebSocketException) as error:
                self.fire("WS close", 0, 0, error)
                return
            if opcode == websocket.ABNF.OPCODE_CLOSE:
                code = int.from_bytes(data[:2], "big") if len(data) >= 2 else None
                self.fire(
                    "WS close", 0, len(data), ConnectionError(f"closed {code}: {data[2:].decode(errors='replace')}")
                )
                return
            event = json.loads(data)
            if event["type"] == "scene":
                lag = time.time() - datetime.fromisoformat(event["created_at"]).timestamp()
                self.fire("WS stream scene", lag * 1000, len(data))
