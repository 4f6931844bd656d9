"""The retry transport and the error parsing, with httpx.MockTransport (no network)."""

from __future__ import annotations

import random
from datetime import UTC, datetime, timedelta
from email.utils import format_datetime

import httpx
import pytest

from bridge.errors import (
    APIStatusError,
    AuthenticationError,
    IdempotencyKeyReusedError,
    InternalServerError,
    InvalidRequestError,
    ModelNotFoundError,
    NotFoundError,
    ServiceNotReadyError,
    error_from_response,
)
from bridge.transport import RetryPolicy, RetryTransport, retry_after_seconds

POLICY = RetryPolicy(max_retries=3, initial_delay=0.5, max_delay=4.0, jitter=0.5)


class Script:
    """A mock service answering from a list of (status, headers) or exceptions, recording each request."""

    def __init__(self, *answers: int | tuple[int, dict[str, str]] | Exception) -> None:
        self.answers = list(answers)
        self.requests: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        answer = self.answers.pop(0) if len(self.answers) > 1 else self.answers[0]
        if isinstance(answer, Exception):
            raise answer
        status, headers = answer if isinstance(answer, tuple) else (answer, {})
        return httpx.Response(status, headers=headers, json={"error": "x", "detail": "y"} if status >= 400 else {})


def _client(script: Script, sleeps: list[float], policy: RetryPolicy = POLICY) -> httpx.Client:
    transport = RetryTransport(httpx.MockTransport(script), policy, seed=1, sleep=sleeps.append)
    return httpx.Client(base_url="http://service", transport=transport)


def test_backoff_doubles_with_jitter_and_stays_under_the_cap() -> None:
    rng = random.Random(0)
    for attempt in range(8):
        ceiling = min(POLICY.max_delay, POLICY.initial_delay * 2**attempt)
        delays = [POLICY.backoff(attempt, rng) for _ in range(200)]
        assert all(ceiling * (1 - POLICY.jitter) <= d <= ceiling for d in delays)
        assert max(delays) - min(delays) > 0.3 * ceiling * POLICY.jitter, "jitter must spread the delays"


def test_get_is_retried_on_5xx_and_connection_errors_then_succeeds() -> None:
    script = Script(httpx.ConnectError("refused"), 503, httpx.ReadTimeout("slow"), 200)
    sleeps: list[float] = []
    response = _client(script, sleeps).get("/v1/models")
    assert response.status_code == 200
    assert len(script.requests) == 4
    assert len(sleeps) == 3 and sleeps[2] > sleeps[0]


def test_retries_are_capped_and_the_last_answer_is_returned() -> None:
    script = Script(500)
    sleeps: list[float] = []
    response = _client(script, sleeps).get("/v1/models")
    assert response.status_code == 500
    assert len(script.requests) == POLICY.max_retries + 1
    assert all(d <= POLICY.max_delay for d in sleeps)


def test_post_without_key_is_not_retried_after_it_may_have_been_received() -> None:
    script = Script(httpx.ReadTimeout("slow"), 200)
    with pytest.raises(httpx.ReadTimeout):
        _client(script, []).post("/v1/models", json={})
    assert len(script.requests) == 1
    assert _client(Script(503, 200), []).post("/v1/models", json={}).status_code == 503


def test_post_is_retried_when_the_connection_was_refused_since_nothing_was_sent() -> None:
    script = Script(httpx.ConnectError("refused"), 201)
    assert _client(script, []).post("/v1/models", json={}).status_code == 201
    assert len(script.requests) == 2


def test_post_with_idempotency_key_is_retried_with_the_same_key() -> None:
    script = Script(httpx.ReadTimeout("slow"), 502, 200)
    response = _client(script, []).post("/v1/models/m/scenes", json={"a": 1}, headers={"Idempotency-Key": "k-1"})
    assert response.status_code == 200
    assert [r.headers["Idempotency-Key"] for r in script.requests] == ["k-1", "k-1", "k-1"]
    assert {r.content for r in script.requests} == {b'{"a":1}'}


def test_retry_after_seconds_is_honoured_and_capped() -> None:
    sleeps: list[float] = []
    _client(Script((429, {"Retry-After": "2"}), (503, {"Retry-After": "600"}), 200), sleeps).get("/x")
    assert sleeps == [2.0, POLICY.max_delay]


def test_retry_after_http_date() -> None:
    later = datetime.now(UTC) + timedelta(seconds=30)
    response = httpx.Response(503, headers={"Retry-After": format_datetime(later, usegmt=True)})
    assert 28 <= retry_after_seconds(response) <= 30
    assert retry_after_seconds(httpx.Response(503, headers={"Retry-After": "soon"})) is None


def test_4xx_is_never_retried() -> None:
    script = Script(422, 200)
    assert _client(script, []).get("/x").status_code == 422
    assert len(script.requests) == 1


def test_policy_refuses_nonsense() -> None:
    with pytest.raises(ValueError, match="max_retries"):
        RetryPolicy(max_retries=-1)
    with pytest.raises(ValueError, match="initial_delay"):
        RetryPolicy(initial_delay=5, max_delay=1)


@pytest.mark.parametrize(
    ("status", "error", "expected"),
    [
        (404, "model_not_found", ModelNotFoundError),
        (404, "not_found", NotFoundError),
        (401, "unauthorized", AuthenticationError),
        (422, "invalid_input", InvalidRequestError),
        (422, "idempotency_key_reused", IdempotencyKeyReusedError),
        (503, "not_ready", ServiceNotReadyError),
        (502, "bad_gateway", InternalServerError),
        (418, "teapot", APIStatusError),
    ],
)
def test_error_body_picks_the_exception_class(status: int, error: str, expected: type[APIStatusError]) -> None:
    response = httpx.Response(status, json={"error": error, "detail": "what went wrong", "field": "objects[0]"})
    parsed = error_from_response(response)
    assert type(parsed) is expected
    assert (parsed.status_code, parsed.error, parsed.detail, parsed.field) == (
        status,
        error,
        "what went wrong",
        "objects[0]",
    )
    assert "objects[0]" in str(parsed)


def test_error_without_json_body_falls_back_on_the_status() -> None:
    parsed = error_from_response(httpx.Response(502, text="<html>bad gateway</html>"))
    assert isinstance(parsed, InternalServerError)
    assert "bad gateway" in parsed.detail
