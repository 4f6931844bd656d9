"""Record the service's warm-up scene file (``app/data/warmup_scenes.json``) from the simulated paper world.

At start-up the service runs a small scene of every level through a throwaway model so that no
request compiles a numba kernel (:mod:`app.services.warmup`). It replays this file instead of
building a :class:`~sim.world.World`, so the service never imports the simulator. The file holds
what the warm-up took from the world: the vocabulary, the training objects' labels (noun and
adjectives), the behaviours applicable to each noun (Table II) and one test object for the scene.

Regenerate after changing the paper world: ``python -m sim.record_warmup``.
``tests/test_service_warmup.py`` checks that the committed file is what this gives for its seed.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sim.world import World, WorldObject

#: Seed of the recorded world.
WARM_UP_SEED = 0
#: Where the service reads the file (``app.services.warmup.WARM_UP_FILE``).
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "app" / "data" / "warmup_scenes.json"


def _labels(obj: WorldObject) -> dict[str, Any]:
    return {"noun": obj.noun, "adjectives": list(obj.adjectives)}


def warm_up_record(seed: int = WARM_UP_SEED) -> dict[str, Any]:
    """The paper world of ``seed`` as the warm-up uses it: its vocabulary, the training objects'
    labels, each noun's behaviours and the first test object."""
    world = World.paper(seed)
    objects = [*world.train_objects, world.test_objects[0]]
    return {
        "source": f"python -m sim.record_warmup: the paper world, seed {seed}",
        "seed": seed,
        "vocabulary": world.vocabulary.to_dict(),
        "behaviours": {obj.noun: list(obj.behaviours) for obj in objects},
        "training_objects": [_labels(obj) for obj in world.train_objects],
        "scene_object": _labels(world.test_objects[0]),
    }


def render(record: dict[str, Any]) -> str:
    """The file's text: a line per entry and per training object, so a change to the world reads as a small diff."""
    lines = [f"  {json.dumps(key)}: {json.dumps(value)}" for key, value in record.items() if key != "training_objects"]
    objects = ",\n".join(f"    {json.dumps(obj)}" for obj in record["training_objects"])
    lines.append(f'  "training_objects": [\n{objects}\n  ]')
    return "{\n" + ",\n".join(lines) + "\n}\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.record_warmup", description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=WARM_UP_SEED, help="seed of the recorded world")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="where the file goes")
    args = parser.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(render(warm_up_record(args.seed)), encoding="utf-8")
    print(f"warm-up scenes written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
