"""The scene feed (app/feed.py): a stream on one process gets the scenes learned on every process.

Two apps on one database in this test process stand for two server processes:
each has its own registry, hub and feed. Every wait is bounded: the websocket
is read on a thread into a queue (:class:`StreamReader`).
"""

from __future__ import annotations

import json
import logging
import queue
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import psycopg
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text
from sqlalchemy.exc import OperationalError
from starlette.websockets import WebSocketDisconnect
from websockets.sync.client import connect

from app.feed import LISTEN_APPLICATION_NAME, SceneFeed
from app.main import create_app
from sim.world import World
from storage.database import create_session_makers
from storage.repositories import feed as feed_repository
from tests.conftest import FAST_HYPERPARAMETERS, concept_scenes, make_settings, synthetic_training_objects
from tests.servers import running_server

pytestmark = pytest.mark.timeout(120)

#: Longest wait for one message, well above the feed's latency (ms on PostgreSQL, 50 ms polls on SQLite).
MESSAGE_SECONDS = 15.0


class StreamReader:
    """A websocket's messages, read on a daemon thread so that every wait of the test is bounded."""

    def __init__(self, ws: Any) -> None:
        self._messages: queue.Queue[dict[str, Any] | BaseException] = queue.Queue()
        threading.Thread(target=self._read, args=(ws,), daemon=True).start()

    def _read(self, ws: Any) -> None:
        while True:
            try:
                self._messages.put(ws.receive_json())
            except BaseException as error:  # noqa: BLE001 - the close (or the session's end) goes to the test
                self._messages.put(error)
                return

    def next(self, timeout: float = MESSAGE_SECONDS) -> dict[str, Any]:
        try:
            message = self._messages.get(timeout=timeout)
        except queue.Empty:
            raise AssertionError(f"no message within {timeout} s") from None
        if isinstance(message, BaseException):
            raise message
        return message

    def until_scenes(self, count: int) -> list[dict[str, Any]]:
        """Every message up to and including the ``count``-th scene event."""
        events: list[dict[str, Any]] = []
        while sum(event["type"] == "scene" for event in events) < count:
            events.append(self.next())
        return events

    def closed(self) -> WebSocketDisconnect:
        """The close that ends the stream (after any events still queued)."""
        with pytest.raises(WebSocketDisconnect) as closed:
            while True:
                self.next()
        return closed.value

    def assert_quiet(self, seconds: float) -> None:
        try:
            message = self._messages.get(timeout=seconds)
        except queue.Empty:
            return
        raise AssertionError(f"unexpected message {message!r}")


@pytest.fixture
def other_client(database_url: str, client: TestClient) -> Iterator[TestClient]:
    """A second app on the same database: another server process."""
    with TestClient(create_app(make_settings(database_url))) as other:
        yield other


@pytest.fixture
def postgres_only(database_url: str) -> None:
    if not database_url.startswith("postgresql"):
        pytest.skip("LISTEN/NOTIFY is PostgreSQL's")


def wait_for(value: Callable[[], Any], what: str, seconds: float = 15.0) -> Any:
    """``value()`` once it is truthy, polled for at most ``seconds``."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if result := value():
            return result
        time.sleep(0.02)
    raise AssertionError(f"waited {seconds} s for {what}")


def scene_feed(client: TestClient) -> SceneFeed:
    return client.app_state["contextweb"].feed


def post_scene(client: TestClient, model_id: str, body: dict) -> dict:
    response = client.post(f"/v1/models/{model_id}/scenes", json=body)
    assert response.status_code == 201, response.text
    return response.json()


def stream_of(client: TestClient, model_id: str) -> Any:
    return client.websocket_connect(f"/v1/models/{model_id}/stream")


def assert_events_match(events: list[dict[str, Any]], answers: list[dict[str, Any]], model_id: str) -> None:
    """``events`` are exactly the scene and context_discovered events of ``answers`` (in scene id order)."""
    expected: list[dict[str, Any]] = []
    for answer in sorted(answers, key=lambda a: a["scene_id"]):
        expected.append(
            {
                "type": "scene",
                "model_id": model_id,
                "scene_id": answer["scene_id"],
                "context_count": answer["context_count"],
                "context_posterior": answer["context_posterior"],
                "map_context": answer["map_context"],
                "map_context_label": answer["map_context_label"],
                "active_concepts": [obj["active_concepts"] for obj in answer["objects"]],
                "created_at": answer["created_at"],
            }
        )
        if answer["context_count"] > answer["previous_context_count"]:
            expected.append(
                {
                    "type": "context_discovered",
                    "model_id": model_id,
                    "scene_id": answer["scene_id"],
                    "context_count": answer["context_count"],
                    "previous_context_count": answer["previous_context_count"],
                }
            )
    assert events == expected


def test_a_stream_gets_the_scenes_of_every_process_once_in_learning_order(
    client: TestClient, other_client: TestClient, model_id: str
) -> None:
    bodies = concept_scenes(35, seed=5)
    before = [post_scene(client, model_id, body) for body in bodies[:5]]
    with stream_of(other_client, model_id) as ws_b, stream_of(client, model_id) as ws_a:
        stream_b, stream_a = StreamReader(ws_b), StreamReader(ws_a)
        hello = {"type": "hello", "model_id": model_id, "context_count": before[-1]["context_count"], "scene_count": 5}
        assert stream_b.next() == hello and stream_a.next() == hello
        answers_a: list[dict] = []
        answers_b: list[dict] = []

        def post_all(poster: TestClient, share: list[dict], answers: list[dict]) -> None:
            answers.extend(post_scene(poster, model_id, body) for body in share)

        # Both processes learn at once (interleaved by the model's lock in the database).
        posters = [
            threading.Thread(target=post_all, args=(client, bodies[5::2], answers_a)),
            threading.Thread(target=post_all, args=(other_client, bodies[6::2], answers_b)),
        ]
        for poster in posters:
            poster.start()
        for poster in posters:
            poster.join(timeout=90)
        answers = answers_a + answers_b
        assert len(answers_a) == len(answers_b) == 15, "every scene should be learned"
        assert sorted(a["scene_id"] for a in answers) == list(range(5, 35))
        assert any(a["context_count"] > a["previous_context_count"] for a in answers), "K should grow"
        for reader in (stream_b, stream_a):
            assert_events_match(reader.until_scenes(30), answers, model_id)
            reader.assert_quiet(0.5)


def test_hello_says_where_the_next_scene_event_starts(
    client: TestClient, other_client: TestClient, model_id: str
) -> None:
    bodies = concept_scenes(9, seed=8)
    for body in bodies[:3]:
        post_scene(client, model_id, body)
    with stream_of(other_client, model_id) as ws:
        early = StreamReader(ws)
        assert early.next()["scene_count"] == 3
        second = [post_scene(client, model_id, body) for body in bodies[3:7]]
        assert_events_match(early.until_scenes(4), second, model_id)
        with stream_of(other_client, model_id) as ws_late:
            late = StreamReader(ws_late)
            hello = late.next()
            assert (hello["scene_count"], hello["context_count"]) == (7, second[-1]["context_count"])
            third = [post_scene(client, model_id, body) for body in bodies[7:]]
            for reader in (early, late):
                assert_events_match(reader.until_scenes(2), third, model_id)


def test_a_fit_on_one_process_is_announced_on_the_others(
    client: TestClient, other_client: TestClient, model_id: str
) -> None:
    objects = synthetic_training_objects(World.paper(0), seed=1)
    assert client.post(f"/v1/models/{model_id}/training-objects", json={"objects": objects}).status_code == 201
    with stream_of(other_client, model_id) as ws:
        reader = StreamReader(ws)
        assert reader.next()["type"] == "hello"
        assert client.post(f"/v1/models/{model_id}/fit", json={"method": "kmeans"}).status_code == 200
        event = reader.next()
        assert event == {"type": "model_fitted", "model_id": model_id, "training_object_count": len(objects)}
        reader.assert_quiet(0.3)


def test_deleting_the_model_on_one_process_closes_its_streams_on_the_others(
    client: TestClient, other_client: TestClient, model_id: str
) -> None:
    with stream_of(other_client, model_id) as ws:
        reader = StreamReader(ws)
        assert reader.next()["type"] == "hello"
        assert client.delete(f"/v1/models/{model_id}").status_code == 204
        closed = reader.closed()
    assert (closed.code, closed.reason) == (1000, "model deleted")
    with pytest.raises(WebSocketDisconnect) as unknown, stream_of(other_client, model_id) as ws:
        ws.receive_json()
    assert unknown.value.code == 4404


def test_a_stream_of_a_model_created_on_another_process_opens(client: TestClient, other_client: TestClient) -> None:
    model_id = other_client.post("/v1/models", json={"name": "made on b"}).json()["id"]
    with stream_of(client, model_id) as ws:
        assert StreamReader(ws).next() == {"type": "hello", "model_id": model_id, "context_count": 1, "scene_count": 0}


def test_the_feed_survives_a_dropped_listen_connection(
    postgres_only: None,
    client: TestClient,
    other_client: TestClient,
    model_id: str,
    engine: Engine,
    caplog: pytest.LogCaptureFixture,
) -> None:
    feed = scene_feed(other_client)
    feed.interval = 60.0  # no fallback read during the test: deliveries come from notifications
    bodies = concept_scenes(4, seed=13)
    with stream_of(other_client, model_id) as ws, caplog.at_level(logging.INFO, logger="contextweb.feed"):
        reader = StreamReader(ws)
        assert reader.next()["scene_count"] == 0
        dropped = wait_for(lambda: feed.listener_backend_pid, "the feed to listen")
        with engine.connect() as connection:
            assert connection.scalar(text("SELECT pg_terminate_backend(:pid)"), {"pid": dropped})
        during = [post_scene(client, model_id, bodies[0])]  # while it is, or may still be, disconnected
        wait_for(lambda: feed.listener_backend_pid not in (None, dropped), "the feed to listen again")
        after = [post_scene(client, model_id, body) for body in bodies[1:]]
        assert_events_match(reader.until_scenes(4), during + after, model_id)
    lost = [r for r in caplog.records if "lost its LISTEN connection" in r.getMessage()]
    assert len(lost) == 1 and lost[0].levelno == logging.WARNING and not lost[0].exc_info, "one line an outage"
    assert any("listens for model changes again" in r.getMessage() for r in caplog.records)


def test_the_feed_outlives_failed_reads(
    client: TestClient, model_id: str, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    failures = {"left": 0}
    read_marks = feed_repository.model_marks

    def failing_marks(session: Any, model_ids: Any) -> Any:
        if failures["left"]:
            failures["left"] -= 1
            raise OperationalError("SELECT", {}, Exception("the database went away"))
        return read_marks(session, model_ids)

    monkeypatch.setattr(feed_repository, "model_marks", failing_marks)
    with stream_of(client, model_id) as ws, caplog.at_level(logging.INFO, logger="contextweb.feed"):
        reader = StreamReader(ws)
        assert reader.next()["scene_count"] == 0
        failures["left"] = 3
        answers = [post_scene(client, model_id, body) for body in concept_scenes(2, seed=4)]
        assert_events_match(reader.until_scenes(2), answers, model_id)
        wait_for(lambda: any("reads the database again" in r.getMessage() for r in caplog.records), "the recovery")
    assert failures["left"] == 0
    failed = [r for r in caplog.records if "cannot read the database" in r.getMessage()]
    assert len(failed) == 1 and not failed[0].exc_info, "one line an outage, no traceback"


def test_a_scene_whose_stored_answer_is_damaged_is_announced_in_its_place_and_the_stream_goes_on(
    client: TestClient, other_client: TestClient, model_id: str, engine: Engine, caplog: pytest.LogCaptureFixture
) -> None:
    """A trigger damages scene 2's stored answer inside the commit of the process that learns it
    (its client still gets the answer it learned): the other process's stream sends a
    ``scene_unreadable`` event in that scene's place, says so in the log, and sends the scenes after
    it (a first version skipped the scene, and the subscriber, waiting for scene 2, took nothing more)."""
    if engine.dialect.name == "postgresql":
        trigger = [
            (
                "CREATE FUNCTION damage_scene_2() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
                "IF NEW.id = 2 THEN NEW.answer_zlib := decode('0200000000', 'hex'); END IF; RETURN NEW; END $$"
            ),
            "CREATE TRIGGER damage_scene_2 BEFORE INSERT ON scene FOR EACH ROW EXECUTE FUNCTION damage_scene_2()",
        ]
    else:
        trigger = [
            (
                "CREATE TRIGGER damage_scene_2 AFTER INSERT ON scene WHEN NEW.id = 2 BEGIN "
                "UPDATE scene SET answer_zlib = X'0200000000' WHERE model_id = NEW.model_id AND id = 2; END"
            )
        ]
    with engine.begin() as connection:
        for statement in trigger:
            connection.execute(text(statement))
    try:
        _damaged_scene_streamed(client, other_client, model_id, caplog)
    finally:  # the test database outlives the test (PostgreSQL's is emptied, not dropped): so must not the trigger
        with engine.begin() as connection:
            connection.execute(
                text(
                    "DROP TRIGGER IF EXISTS damage_scene_2"
                    + (" ON scene" if engine.dialect.name == "postgresql" else "")
                )
            )
            if engine.dialect.name == "postgresql":
                connection.execute(text("DROP FUNCTION IF EXISTS damage_scene_2()"))


def _damaged_scene_streamed(
    client: TestClient, other_client: TestClient, model_id: str, caplog: pytest.LogCaptureFixture
) -> None:
    with stream_of(other_client, model_id) as ws, caplog.at_level(logging.ERROR, logger="contextweb"):
        reader = StreamReader(ws)
        assert reader.next()["scene_count"] == 0
        answers = [post_scene(client, model_id, body) for body in concept_scenes(4, seed=4)]
        events = [event for event in reader.until_scenes(3) if event["type"] in ("scene", "scene_unreadable")]
        assert [(event["type"], event["scene_id"]) for event in events] == [
            ("scene", 0),
            ("scene", 1),
            ("scene_unreadable", 2),
            ("scene", 3),
        ]
        assert "cannot be decompressed" in events[2]["detail"]
        reader.assert_quiet(0.5)
    assert [answer["scene_id"] for answer in answers] == [0, 1, 2, 3], "the learning process answered every scene"
    assert any("scene 2's stored answer is damaged" in record.getMessage() for record in caplog.records)


def test_notify_change_is_sent_at_commit_only(postgres_only: None, engine: Engine) -> None:
    url = engine.url.set(drivername="postgresql").render_as_string(hide_password=False)
    _, sessions = create_session_makers(engine)
    with psycopg.connect(url, autocommit=True) as listener:
        listener.execute(f"LISTEN {feed_repository.CHANNEL}")
        with sessions() as session:
            feed_repository.notify_change(session, "rolled-back")
            session.rollback()
        with sessions() as session:
            feed_repository.notify_change(session, "a")
            assert list(listener.notifies(timeout=0.2)) == [], "nothing before the commit"
            feed_repository.notify_change(session, "b")
            session.commit()
        payloads = [n.payload for n in listener.notifies(timeout=5, stop_after=2)]
    assert payloads == ["a", "b"]


def test_the_feed_listens_only_while_a_stream_is_open(
    postgres_only: None, client: TestClient, model_id: str, engine: Engine
) -> None:
    """No dashboard on the process: no LISTEN connection, so the fleet's scenes wake nothing here.
    The first stream opens it (named in ``pg_stat_activity``), the last one's end closes it."""
    feed = scene_feed(client)

    def listening_backends() -> list[tuple[int, str]]:
        query = text(
            "SELECT pid, query FROM pg_stat_activity WHERE application_name = :name AND datname = current_database()"
        )
        with engine.connect() as connection:
            return [tuple(row) for row in connection.execute(query, {"name": LISTEN_APPLICATION_NAME})]

    bodies = concept_scenes(3, seed=21)
    post_scene(client, model_id, bodies[0])
    assert feed.listener_backend_pid is None
    assert listening_backends() == []
    with stream_of(client, model_id) as ws:
        reader = StreamReader(ws)
        assert reader.next()["scene_count"] == 1
        pid = wait_for(lambda: feed.listener_backend_pid, "the feed to listen")
        assert [backend for backend, _ in listening_backends()] == [pid]
        answer = post_scene(client, model_id, bodies[1])
        scene = reader.until_scenes(1)[-1]
        assert (scene["scene_id"], scene["context_posterior"]) == (answer["scene_id"], answer["context_posterior"])
    wait_for(lambda: feed.listener_backend_pid is None, "the feed to stop listening")
    wait_for(lambda: listening_backends() == [], "the LISTEN backend to end")
    post_scene(client, model_id, bodies[2])
    with stream_of(client, model_id) as ws:  # listens again, from the stored count on
        assert StreamReader(ws).next()["scene_count"] == 3
        wait_for(lambda: feed.listener_backend_pid, "the feed to listen again")


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_two_server_processes_stream_each_others_scenes(database_url: str, tmp_path: Path) -> None:
    """Real ``contextweb serve`` processes: a dashboard on either sees the scenes learned on both."""
    with running_server(database_url, tmp_path, name="a") as a, running_server(database_url, tmp_path, name="b") as b:
        with a.client() as http_a, b.client() as http_b, ExitStack() as streams:
            created = http_a.post("/v1/models", json={"name": "shared", "hyperparameters": FAST_HYPERPARAMETERS})
            model_id = created.json()["id"]
            sockets = [
                streams.enter_context(connect(f"ws://127.0.0.1:{s.port}/v1/models/{model_id}/stream", open_timeout=10))
                for s in (a, b)
            ]
            for ws in sockets:
                assert json.loads(ws.recv(timeout=MESSAGE_SECONDS))["scene_count"] == 0
            answers = []
            for n, body in enumerate(concept_scenes(20, seed=21)):
                response = (http_a, http_b)[n % 2].post(f"/v1/models/{model_id}/scenes", json=body)
                assert response.status_code == 201, response.text
                answers.append(response.json())
            for ws in sockets:
                events: list[dict[str, Any]] = []
                while sum(event["type"] == "scene" for event in events) < len(answers):
                    events.append(json.loads(ws.recv(timeout=MESSAGE_SECONDS)))
                assert_events_match(events, answers, model_id)
        # uvicorn re-raises the SIGTERM once it has shut down; a SIGKILL would mean the shutdown hung.
        assert a.stop() in (0, -signal.SIGTERM) and b.stop() in (0, -signal.SIGTERM)
