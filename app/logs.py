"""The server's log configuration: uvicorn's own, with API keys redacted from every line.

Browsers cannot set headers on a websocket, so dashboards send their key as the
``api_key`` query parameter, and uvicorn logs each websocket's path with its
query (``"WebSocket /v1/models/…/stream?api_key=…" [accepted]``). The filter
rewrites any ``api_key=`` value before a handler writes the line. It sits on
uvicorn's handlers in the dictConfig that ``contextweb serve`` hands to uvicorn,
so every worker process (``--workers N``) applies it too.
"""

from __future__ import annotations

import copy
import logging
import re
from typing import Any

from uvicorn.config import LOGGING_CONFIG

_API_KEY_IN_QUERY = re.compile(r"(api_key=)[^&\s\"']*", re.IGNORECASE)
REDACTED = "[redacted]"


def redact_keys(text: str) -> str:
    """``text`` with the value of every ``api_key=`` replaced."""
    return _API_KEY_IN_QUERY.sub(rf"\g<1>{REDACTED}", text)


class RedactKeys(logging.Filter):
    """Redacts API keys from a record's message and its string arguments."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact_keys(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact_keys(arg) if isinstance(arg, str) else arg for arg in record.args)
        elif isinstance(record.args, dict):
            record.args = {k: redact_keys(v) if isinstance(v, str) else v for k, v in record.args.items()}
        return True


#: The format of the service's own lines (and every library's but uvicorn's): ``WARNING:     contextweb: …``.
LOG_FORMAT = "%(levelname)s:     %(name)s: %(message)s"


def log_config(level: str = "info") -> dict[str, Any]:
    """uvicorn's default logging configuration with :class:`RedactKeys` on every handler, and the
    root logger at ``level`` writing the service's own lines (``contextweb``, psycopg, …) in
    :data:`LOG_FORMAT`. uvicorn applies it in every worker process: a worker of ``--workers N`` is a
    new interpreter, and without the root logger here it had no handler for the service's lines
    (its start-up lines were lost, and a warning came out bare, without its level)."""
    config = copy.deepcopy(LOGGING_CONFIG)
    config.setdefault("filters", {})["redact_keys"] = {"()": f"{__name__}.RedactKeys"}
    config["formatters"]["contextweb"] = {"format": LOG_FORMAT}
    config["handlers"]["contextweb"] = {
        "class": "logging.StreamHandler",
        "formatter": "contextweb",
        "stream": "ext://sys.stderr",
    }
    for handler in config["handlers"].values():
        handler.setdefault("filters", []).append("redact_keys")
    config["root"] = {"handlers": ["contextweb"], "level": level.upper()}
    return config
