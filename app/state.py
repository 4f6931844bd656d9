"""The long-lived objects of one running app, created by the lifespan (app/main.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from app.feed import SceneFeed
from app.metrics import ModelEvents
from app.purge import ModelPurger
from app.registry import ModelRegistry
from app.settings import Settings
from app.storage_health import StorageHealth
from app.stream import StreamHub


@dataclass(eq=False)
class AppState:
    """Engine, session makers, in-memory models, the websocket hub and its feed, and the purger of one app."""

    settings: Settings
    engine: Engine
    read_sessions: sessionmaker[Session]
    write_sessions: sessionmaker[Session]
    registry: ModelRegistry
    hub: StreamHub
    feed: SceneFeed
    purger: ModelPurger
    """Deletes the rows of deleted models, a chunk per transaction (app/purge.py)."""
    metrics: ModelEvents | None = None
    """The models' event metrics (app/metrics.py); None in an app built without them."""
    storage: StorageHealth = field(default_factory=StorageHealth)
    models_loaded: bool = field(default=False)
