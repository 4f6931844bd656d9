"""The robot-side client of the Contextweb service (docs/bridge.md).

Its own distribution (bridge/pyproject.toml): ``pip install ./bridge`` installs it with httpx
and pydantic only (``websockets`` with the ``stream`` extra, imported when a stream is
opened), so a robot does not install the service, numba, numpy or SQLAlchemy.
``bridge.tools`` (the replay of folders, ROS bags and yarp logs) is in the distribution too but needs
numpy and the file readers: ``pip install './bridge[bags]'``; nothing here imports it.
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
    InvalidRecordingError,
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
    "InvalidRecordingError",
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
