"""World files of the simulator (``<name>_world.json``), read with :func:`load_world_file`.

The paper's world (``paper``: Tables I, II, IV and VI) is the library's data and lives in
``core/data``; files here are the simulator's only (``generic``: the themes of the generic
worlds). :func:`load_world_file` looks here first, then in ``core/data``, so a world is
named the same wherever its file lives.
"""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

from core.vocabulary import load_world_file as load_core_world_file


def load_world_file(name: str = "paper") -> dict[str, Any]:
    """The raw dictionary of the world file ``name``: ``sim/data/<name>_world.json``, else ``core/data``'s."""
    own = resources.files(__name__).joinpath(f"{name}_world.json")
    if own.is_file():
        return json.loads(own.read_text(encoding="utf-8"))
    return load_core_world_file(name)
