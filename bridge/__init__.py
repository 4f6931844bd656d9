"""The robot-side client of the Contextweb service (docs/bridge.md).

Importable with httpx, pydantic and the standard library only (``websockets``
is imported when a stream is opened): a robot does not install the service.
``bridge.simulate`` and ``bridge.replay`` are development tools that do import
``core``; nothing here imports them.
"""

from bridge.client import Client, QueuedScene
from bridge.errors import (
    APIConnectionError,
    APIStatusError,
    APITimeoutError,
    AuthenticationError,
    ContextwebClientError,
    IdempotencyKeyReusedError,
    InternalServerError,
    InvalidRequestError,
    ModelNotFittedError,
    ModelNotFoundError,
    NotFoundError,
    PayloadTooLargeError,
    PermissionDeniedError,
    RateLimitError,
    SceneNotFoundError,
    ServiceNotReadyError,
)
from bridge.models import (
    Audio,
    Finger,
    Interaction,
    PointCloud,
    SceneObject,
    TrainingObject,
    Vocabulary,
)
from bridge.queue import OfflineQueue
from bridge.transport import RetryPolicy

__all__ = [
    "APIConnectionError",
    "APIStatusError",
    "APITimeoutError",
    "Audio",
    "AuthenticationError",
    "Client",
    "ContextwebClientError",
    "Finger",
    "IdempotencyKeyReusedError",
    "Interaction",
    "InternalServerError",
    "InvalidRequestError",
    "ModelNotFittedError",
    "ModelNotFoundError",
    "NotFoundError",
    "OfflineQueue",
    "PayloadTooLargeError",
    "PermissionDeniedError",
    "PointCloud",
    "QueuedScene",
    "RateLimitError",
    "RetryPolicy",
    "SceneNotFoundError",
    "SceneObject",
    "ServiceNotReadyError",
    "TrainingObject",
    "Vocabulary",
]
