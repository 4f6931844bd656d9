"""One exception class per kind of failure, parsed from the service's error body.

The service answers every failure with ``{"error", "detail", "field"}`` and a
status code (docs/api.md); ``error`` is a kind such as ``model_not_found``.
:func:`error_from_response` turns such a response into the matching class
below, so robot code can ``except ModelNotFoundError`` rather than compare
status codes and strings. Failures that never reached the service are
:class:`APIConnectionError` (and its :class:`APITimeoutError`).
"""

from __future__ import annotations

from typing import Any

import httpx


class ContextwebClientError(Exception):
    """Base of every error the bridge raises."""


class InvalidRecordingError(ContextwebClientError, ValueError):
    """A recording the replay tools (``bridge.tools``) refuse before anything is sent: a mapping file, a bag,
    a yarp log or a payload the service would not accept. ``field`` says where (a file and topic, a mapping
    key), ``problem`` what (for a message: its time)."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


class APIConnectionError(ContextwebClientError):
    """The service could not be reached (refused, reset, DNS, TLS) even after the retries."""

    def __init__(self, message: str, *, request: httpx.Request | None = None) -> None:
        super().__init__(message)
        self.request = request


class APITimeoutError(APIConnectionError):
    """The service did not answer within the client's timeout, even after the retries."""


class APIStatusError(ContextwebClientError):
    """The service answered with an error status; ``error``, ``detail``, ``field`` come from its body."""

    def __init__(self, response: httpx.Response, error: str, detail: Any, field: str | None = None) -> None:
        self.response = response
        self.status_code = response.status_code
        self.error = error
        self.detail = detail
        self.field = field
        where = f" ({field})" if field else ""
        super().__init__(f"{response.status_code} {error}{where}: {detail}")


class AuthenticationError(APIStatusError):
    """401 ``unauthorized``: the ``X-API-Key`` header is missing or unknown."""


class PermissionDeniedError(APIStatusError):
    """403 ``forbidden``: the key is valid but may not do this (the read key on a write route)."""


class NotFoundError(APIStatusError):
    """404: no such route or resource."""


class ModelNotFoundError(NotFoundError):
    """404 ``model_not_found``: no model with this id."""


class SceneNotFoundError(NotFoundError):
    """404 ``scene_not_found``: the model has no scene with this id."""


class ModelNotFittedError(APIStatusError):
    """409 ``model_not_fitted``: post training interactions and fit before this call."""


class PayloadTooLargeError(APIStatusError):
    """413 ``payload_too_large``: the body exceeds the service's limit (send fewer raw points)."""


class InvalidRequestError(APIStatusError):
    """422 ``invalid_input``: the body failed validation; ``field`` names where."""


class IdempotencyKeyReusedError(InvalidRequestError):
    """422 ``idempotency_key_reused``: the key was already used with a different body."""


class RateLimitError(APIStatusError):
    """429: too many requests, still refused after the retries."""


class InternalServerError(APIStatusError):
    """5xx: the service failed, still failing after the retries."""


class ServiceNotReadyError(InternalServerError):
    """503 ``not_ready``: the service is up but cannot serve yet (database, migrations)."""


_BY_ERROR: dict[str, type[APIStatusError]] = {
    "unauthorized": AuthenticationError,
    "forbidden": PermissionDeniedError,
    "not_found": NotFoundError,
    "model_not_found": ModelNotFoundError,
    "scene_not_found": SceneNotFoundError,
    "model_not_fitted": ModelNotFittedError,
    "payload_too_large": PayloadTooLargeError,
    "invalid_input": InvalidRequestError,
    "idempotency_key_reused": IdempotencyKeyReusedError,
    "not_ready": ServiceNotReadyError,
}
_BY_STATUS: dict[int, type[APIStatusError]] = {
    401: AuthenticationError,
    403: PermissionDeniedError,
    404: NotFoundError,
    409: ModelNotFittedError,
    413: PayloadTooLargeError,
    422: InvalidRequestError,
    429: RateLimitError,
}


def error_from_response(response: httpx.Response) -> APIStatusError:
    """The exception for an error response: by the body's ``error`` kind, else by status."""
    response.read()
    try:
        body = response.json()
    except ValueError:
        body = None
    if isinstance(body, dict) and "error" in body:
        error, detail, field = str(body["error"]), body.get("detail"), body.get("field")
    else:
        error, detail, field = response.reason_phrase or "error", response.text, None
    cls = _BY_ERROR.get(error) or _BY_STATUS.get(response.status_code)
    if cls is None:
        cls = InternalServerError if response.status_code >= 500 else APIStatusError
    return cls(response, error, detail, field)
