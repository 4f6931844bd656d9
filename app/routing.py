"""The route class of every router: JSON request bodies whose objects repeat a key are refused.

RFC 8259 §4 leaves an object with a repeated name to the parser, and Python's keeps the last
value: ``{"cup": 0.2, "cup": 0.9}`` would be learned as 0.9 without a word, and a body read one way
by a proxy or a client library and another way here. FastAPI parses a JSON body with
``Request.json()``; :class:`JsonBodyRoute` hands its endpoints a request whose parse refuses a
repeated key, as a JSON syntax error: a 422 on ``body`` that names the key (app/errors.py).
FastAPI's documented way to change how a body is read ("Custom Request and APIRoute class").
The check is an ``object_pairs_hook`` in the standard parser, which stays the C scanner
(≈ 2.5 µs more on a 1.2 kB concept scene, docs/benchmarks.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Coroutine
from typing import Any

from fastapi import Request, Response
from fastapi.routing import APIRoute

NO_POSITION = -1
"""The character offset a repeated key's error gives FastAPI, which locates every JSON syntax
error at one: the parser's hook sees an object's pairs, not where they were."""


class RepeatedKey(ValueError):
    """An object of the body gives one key twice."""

    def __init__(self, key: str) -> None:
        super().__init__(key)
        self.key = key


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``' ``object_pairs_hook``: the object, or :class:`RepeatedKey`."""
    result = dict(pairs)
    if len(result) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise RepeatedKey(key)
            seen.add(key)
    return result


class JsonBodyRequest(Request):
    """A request whose JSON body is parsed refusing repeated keys."""

    async def json(self) -> Any:
        if not hasattr(self, "_json"):
            body = await self.body()
            try:
                self._json = json.loads(body, object_pairs_hook=unique_keys)
            except RepeatedKey as repeated:
                message = f"the key {json.dumps(repeated.key)} appears twice in one object"
                raise json.JSONDecodeError(message, "", NO_POSITION) from None
        return self._json


class JsonBodyRoute(APIRoute):
    """Every router's ``route_class``: its endpoints get a :class:`JsonBodyRequest`."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def with_json_body_request(request: Request) -> Response:
            return await handler(JsonBodyRequest(request.scope, request.receive))

        return with_json_body_request
