"""Stored answers and scene rows (issue 17, goal 2): bytes per answer, per scene row, and their CPU time.

Two paper-world models learn concept-level scenes in-process through the service's own code
(``bench_restart.build``: the same scene rows and compressed answers as over HTTP, fresh SQLite):

- model A (training objects seed 1, scenes seed 7), on whose answers format 2's preset dictionary
  was trained (``--train-dictionary=PATH`` trains one the same way and writes it to PATH: needs
  ``backports.zstd``, which the ``bags`` extra installs; format 2's is frozen, see
  storage/compression.py);
- model B (training objects seed 5, scenes seed 11), held out: every figure below is measured on
  its answers, so the dictionary is not judged on the answers it was made from.

Figures: the answer's JSON and each way of storing it (mean bytes; CPU time to compress and to
decompress one, median of ``REPEATS`` passes over all answers); the scene row's columns (mean
``length()`` in SQLite) and the pages of the scene table and its indexes per scene (``dbstat``),
for scenes posted without an Idempotency-Key and (``keyed_scene_row``, the same scenes again)
with one of 32 characters, as the bridge sends.
Results go to bench/results/answers.json.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sqlalchemy import text

from bench import RESULTS
from bench.bench_restart import build
from bench.bench_service import concept_scenes
from sim.world import World
from storage import compression
from storage.database import create_database_engine

TRAINING_SCENES = 1_000
HELD_OUT_SCENES = 300
REPEATS = 5
SCENE_COLUMNS = (
    "model_id",
    "id",
    "idempotency_key",
    "request_hash",
    "context_count",
    "map_context",
    "context_posterior",
    "answer_zlib",
    "created_at",
)


def learned_answers(path: Path, scenes: int, training_seed: int, scene_seed: int, *, keyed: bool = False) -> list[str]:
    """The stored answers of a model that learned ``scenes`` concept-level scenes (database at ``path``;
    each scene with an Idempotency-Key if ``keyed``)."""
    pool = concept_scenes(World.paper(0), scenes, seed=scene_seed)
    build(path, scenes, pool, training_seed=training_seed, keyed=keyed)
    engine = create_database_engine(f"sqlite:///{path}")
    try:
        with engine.connect() as connection:
            rows = connection.execute(text("SELECT answer_zlib FROM scene ORDER BY id")).scalars().all()
    finally:
        engine.dispose()
    return [compression.decompress_answer(bytes(row)) for row in rows]


def train_dictionary(answers: list[str]) -> bytes:
    """A preset dictionary for deflate: zstd's dictionary trainer (COVER) picks the answers' most
    frequent segments; the last 32 KiB (deflate's window) of a 64 KiB dictionary are kept."""
    from backports import zstd  # the bags extra; only to make a dictionary, never to store

    trained = zstd.train_dict([answer.encode() for answer in answers], 65_536)
    return trained.dict_content[-32_768:]


def _deflate(dictionary: bytes | None, level: int) -> Callable[[str], bytes]:
    def compress(answer: str) -> bytes:
        compressor = zlib.compressobj(level, zdict=dictionary) if dictionary else zlib.compressobj(level)
        return bytes([0]) + compressor.compress(answer.encode()) + compressor.flush()

    return compress


def _cpu_us(function: Callable[[Any], Any], items: list[Any]) -> float:
    """Median over ``REPEATS`` passes of the CPU time of ``function`` per item, in µs."""
    times = []
    for _ in range(REPEATS):
        started = time.process_time()
        for item in items:
            function(item)
        times.append((time.process_time() - started) / len(items))
    return round(1e6 * statistics.median(times), 1)


def answer_formats(answers: list[str]) -> dict[str, Any]:
    """Mean bytes of each way to store the answers, and the stored format's CPU times."""
    ways: dict[str, Callable[[str], bytes]] = {
        "plain_zlib_6": _deflate(None, 6),
        "format_1_zlib_6": _deflate(compression.ANSWER_DICTIONARY_1, 6),
        "format_2_zlib_6": _deflate(compression.ANSWER_DICTIONARY_2, 6),
        "format_2_zlib_9": _deflate(compression.ANSWER_DICTIONARY_2, 9),
    }
    result: dict[str, Any] = {"json_bytes": round(statistics.mean(len(answer.encode()) for answer in answers), 1)}
    for name, compress in ways.items():
        result[f"{name}_bytes"] = round(statistics.mean(len(compress(answer)) for answer in answers), 1)
    stored = [compression.compress_answer(answer) for answer in answers]
    result["stored_bytes"] = round(statistics.mean(map(len, stored)), 1)
    result["stored_format"] = stored[0][0]
    result["compress_cpu_us"] = _cpu_us(compression.compress_answer, answers)
    result["decompress_cpu_us"] = _cpu_us(compression.decompress_answer, stored)
    result["format_1_compress_cpu_us"] = _cpu_us(ways["format_1_zlib_6"], answers)
    result["format_2_unprimed_compress_cpu_us"] = _cpu_us(ways["format_2_zlib_6"], answers)
    result["format_2_zlib_9_compress_cpu_us"] = _cpu_us(ways["format_2_zlib_9"], answers)
    return result


def scene_row(path: Path, scenes: int) -> dict[str, Any]:
    """Mean bytes of each column of the scene rows, and the scene table's and indexes' pages per scene."""
    engine = create_database_engine(f"sqlite:///{path}")
    try:
        with engine.connect() as connection:
            connection.execute(text("PRAGMA wal_checkpoint(TRUNCATE)"))
            lengths = ", ".join(f"COALESCE(AVG(LENGTH({column})), 0)" for column in SCENE_COLUMNS)
            means = connection.execute(text(f"SELECT {lengths} FROM scene")).one()
            pages = connection.execute(
                text(
                    "SELECT dbstat.name, SUM(pgsize) FROM dbstat JOIN sqlite_schema AS s ON s.name = dbstat.name "
                    "WHERE s.tbl_name = 'scene' GROUP BY dbstat.name"
                )
            ).all()
    finally:
        engine.dispose()
    columns = {column: round(float(mean), 1) for column, mean in zip(SCENE_COLUMNS, means, strict=True)}
    return {
        "column_bytes": columns,
        "columns_total_bytes": round(sum(columns.values()), 1),
        "pages_bytes_per_scene": {name: round(size / scenes, 1) for name, size in sorted(pages)},
    }


def main() -> dict[str, Any]:
    target = next((arg.split("=", 1)[1] for arg in sys.argv[1:] if arg.startswith("--train-dictionary=")), None)
    with tempfile.TemporaryDirectory(prefix="bench_answers_") as directory:
        work = Path(directory)
        if target is not None:
            training = learned_answers(work / "a.sqlite3", TRAINING_SCENES, training_seed=1, scene_seed=7)
            Path(target).write_bytes(train_dictionary(training))
            print(f"dictionary trained on {len(training)} answers written to {target}", flush=True)
        held_out, keyed = work / "b.sqlite3", work / "b_keyed.sqlite3"
        answers = learned_answers(held_out, HELD_OUT_SCENES, training_seed=5, scene_seed=11)
        learned_answers(keyed, HELD_OUT_SCENES, training_seed=5, scene_seed=11, keyed=True)
        result = {
            "answers": answer_formats(answers),
            "scene_row": scene_row(held_out, HELD_OUT_SCENES),
            "keyed_scene_row": scene_row(keyed, HELD_OUT_SCENES),
        }
    print(json.dumps(result, indent=2), flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "answers.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
