"""Retries as an httpx transport: backoff with jitter, ``Retry-After``, a cap.

:class:`RetryTransport` wraps the real transport, so every request the
:class:`bridge.Client` sends goes through one retry policy and the client's
methods stay free of loops. What is retried:

* a connection that failed before the request was sent (refused, connect
  timeout): always, since the service never saw it;
* any other transport failure (read timeout, reset mid-answer) and the answers
  429 and 5xx: only for a request that is safe to repeat: an idempotent method,
  a request carrying an ``Idempotency-Key`` (the service answers a repeat with
  the stored result, so a retried scene is never counted twice), or one the
  client marked with the ``retry_safe`` extension (inference and planning,
  which change nothing on the service).

Delays double from ``initial_delay`` up to ``max_delay`` and are multiplied by a
uniform factor in [1 - jitter, 1]: robots that lost the service at the same
moment then come back spread out instead of in one burst, while the floor keeps
them from retrying in a tight loop. A ``Retry-After`` header (seconds or an HTTP
date) replaces the computed delay, still capped at ``max_delay`` so one bad
header cannot park a robot for an hour.
"""

from __future__ import annotations

import logging
import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from email.utils import parsedate_to_datetime

import httpx

logger = logging.getLogger("bridge")

IDEMPOTENT_METHODS = frozenset({"GET", "HEAD", "OPTIONS", "PUT", "DELETE"})
IDEMPOTENCY_HEADER = "Idempotency-Key"
RETRY_SAFE = "retry_safe"
#: Request extension overriding the policy's ``max_retries`` for one request (a probe wants one try).
MAX_RETRIES = "max_retries"
RETRY_STATUSES = frozenset({429, 500, 502, 503, 504})
_NOT_SENT = (httpx.ConnectError, httpx.ConnectTimeout)


@dataclass(frozen=True)
class RetryPolicy:
    """How many times and how long to wait: ``max_retries`` retries after the first try."""

    max_retries: int = 5
    initial_delay: float = 0.25
    max_delay: float = 8.0
    jitter: float = 0.5

    def __post_init__(self) -> None:
        if self.max_retries < 0:
            raise ValueError("max_retries must be >= 0")
        if not 0 < self.initial_delay <= self.max_delay:
            raise ValueError("need 0 < initial_delay <= max_delay")
        if not 0 <= self.jitter <= 1:
            raise ValueError("jitter must be in [0, 1]")

    def backoff(self, attempt: int, rng: random.Random) -> float:
        """Delay before retry number ``attempt`` (0-based), jittered."""
        ceiling = min(self.max_delay, self.initial_delay * 2 ** min(attempt, 32))
        return ceiling * (1.0 - self.jitter * rng.random())


def retry_after_seconds(response: httpx.Response) -> float | None:
    """The ``Retry-After`` header as seconds, or None when absent or unreadable."""
    value = response.headers.get("Retry-After")
    if value is None:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return max(0.0, (when - datetime.now(UTC)).total_seconds())


def is_retry_safe(request: httpx.Request) -> bool:
    return (
        request.method in IDEMPOTENT_METHODS
        or IDEMPOTENCY_HEADER in request.headers
        or bool(request.extensions.get(RETRY_SAFE))
    )


class RetryTransport(httpx.BaseTransport):
    """An httpx transport that retries ``wrapped`` under a :class:`RetryPolicy`."""

    def __init__(
        self,
        wrapped: httpx.BaseTransport,
        policy: RetryPolicy | None = None,
        *,
        seed: int | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.wrapped = wrapped
        self.policy = policy or RetryPolicy()
        self._rng = random.Random(seed)
        self._sleep = sleep

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        safe = is_retry_safe(request)
        max_retries = int(request.extensions.get(MAX_RETRIES, self.policy.max_retries))
        attempt = 0
        while True:
            try:
                response = self.wrapped.handle_request(request)
            except httpx.TransportError as error:
                if attempt >= max_retries or not (safe or isinstance(error, _NOT_SENT)):
                    raise
                delay = self.next_delay(attempt)
                logger.info(
                    "%s %s failed (%r); retry %d in %.2fs", request.method, request.url, error, attempt + 1, delay
                )
            else:
                if response.status_code not in RETRY_STATUSES or not safe or attempt >= max_retries:
                    return response
                delay = self._delay_for(response, attempt)
                response.close()
                logger.info(
                    "%s %s -> %d; retry %d in %.2fs",
                    request.method,
                    request.url,
                    response.status_code,
                    attempt + 1,
                    delay,
                )
            self._sleep(delay)
            attempt += 1

    def next_delay(self, attempt: int) -> float:
        """The jittered backoff before retry ``attempt`` (also used to reconnect a stream)."""
        return self.policy.backoff(attempt, self._rng)

    def _delay_for(self, response: httpx.Response, attempt: int) -> float:
        requested = retry_after_seconds(response)
        if requested is None:
            return self.next_delay(attempt)
        return min(requested, self.policy.max_delay)

    def close(self) -> None:
        self.wrapped.close()
