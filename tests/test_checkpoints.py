"""Checkpoints of the Incremental-LDA corpus (docs/scaling.md, "Checkpoints"): a start reads the latest
checkpoint and the token batches written since, and continues bit for bit like an uninterrupted run; a
checkpoint that disagrees with the batches (all kept: none compacted yet) is named by ``models check``
and rebuilt by ``repair``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text

from app.main import create_app
from storage.compression import pack_arrays, pack_small_arrays, unpack_arrays, unpack_small_arrays
from storage.database import create_database_engine, create_session_makers
from storage.repositories import incremental_lda as lda_repository
from storage.repositories.consistency import check_model, repair_model
from storage.unit_of_work import unit_of_work
from tests.conftest import (
    FAST_HYPERPARAMETERS,
    assert_same_state,
    concept_scenes,
    make_settings,
    memory_state,
    stored_problems,
)

#: Small enough that 24 scenes cross three checkpoints (after scenes 7, 14 and 21) and leave a tail of 3
#: that ends with a scheduled growth check (FAST_HYPERPARAMETERS: after scenes 1, 2, 3, 6, 12, 24, ...),
#: which moves tokens of its window (the last 6 scenes), checkpointed ones included.
INTERVAL = 7
RESTART_AFTER = 24


def _post(client: TestClient, model_id: str, scenes: list[dict]) -> list[dict]:
    """The answers without what differs between two models by design (their id, the time)."""
    answers = []
    for body in scenes:
        response = client.post(f"/v1/models/{model_id}/scenes", json=body)
        assert response.status_code == 201, response.text
        answers.append({k: v for k, v in response.json().items() if k not in ("model_id", "created_at")})
    return answers


def _create(client: TestClient) -> str:
    body = {"name": "robot", "seed": 42, "hyperparameters": FAST_HYPERPARAMETERS}
    return client.post("/v1/models", json=body).json()["id"]


def _start(engine: Engine, model_id: str) -> lda_repository.StoredStart:
    read, _ = create_session_makers(engine)
    with read() as session:
        return lda_repository.load_start(session, model_id)


def test_a_checkpointed_model_restarts_from_checkpoint_and_tail_bit_for_bit(database_url: str) -> None:
    scenes = concept_scenes(RESTART_AFTER + 3, seed=3)
    settings = make_settings(database_url, checkpoint_interval=INTERVAL)
    with TestClient(create_app(settings)) as client:
        uninterrupted = _create(client)
        expected = _post(client, uninterrupted, scenes)
        expected_state = memory_state(client, uninterrupted)
        restarted = _create(client)
        before = _post(client, restarted, scenes[:RESTART_AFTER])

    engine = create_database_engine(database_url)
    try:
        start = _start(engine, restarted)
        assert start.checkpoint is not None and start.checkpoint.scene_count == 21
        tail_scenes = set(start.tail.added[:, 0].tolist())
        assert tail_scenes == {21, 22, 23}, "the 3 scenes after the checkpoint are its tail"
        assert start.tail.moved.size, "tokens of checkpointed scenes reassigned since are in the tail"
        assert start.tail.moved[:, 0].max() < start.checkpoint.token_count
    finally:
        engine.dispose()

    with TestClient(create_app(settings)) as client:
        after = _post(client, restarted, scenes[RESTART_AFTER:])
        state = memory_state(client, restarted)
    assert before + after == expected
    assert max(answer["context_count"] for answer in expected) > 1, "the scenes should make K grow"
    assert_same_state(state, expected_state)


def _corrupt_checkpoint(engine: Engine, model_id: str) -> tuple[int, int]:
    """Move one checkpointed token that was not written since to another context; (token, context)."""
    start = _start(engine, model_id)
    checkpoint = start.checkpoint
    assert checkpoint is not None
    moved_since = set(start.tail.moved[:, 0].tolist())
    token = next(i for i in range(checkpoint.token_count) if i not in moved_since)
    contexts = checkpoint.contexts.copy()
    contexts[token] = (contexts[token] + 1) % checkpoint.context_count
    _, write = create_session_makers(engine)
    with unit_of_work(write) as session:
        lda_repository.save_checkpoint(session, model_id, replace(checkpoint, contexts=contexts))
    return token, int(contexts[token])


def test_models_check_names_a_corrupted_checkpoint_and_repair_rebuilds_it(database_url: str) -> None:
    settings = make_settings(database_url, checkpoint_interval=INTERVAL)
    with TestClient(create_app(settings)) as client:
        model_id = _create(client)
        _post(client, model_id, concept_scenes(13, seed=4))
        sound = memory_state(client, model_id)
    engine = create_database_engine(database_url)
    read, write = create_session_makers(engine)
    try:
        token, _ = _corrupt_checkpoint(engine, model_id)
        with read() as session:
            problems = check_model(session, model_id)
        assert len(problems) == 1 and "incremental_lda_checkpoint" in problems[0], problems
        assert f"context of 1 token, first token {token}" in problems[0]

        with TestClient(create_app(settings)) as client:  # the server starts; this model does not serve
            response = client.get(f"/v1/models/{model_id}/contexts")
            assert response.status_code == 503 and response.json()["error"] == "model_unavailable"

        with unit_of_work(write) as session:
            changes = repair_model(session, model_id)
        assert any("incremental_lda_checkpoint: rebuilt" in change for change in changes), changes
        with read() as session:
            assert check_model(session, model_id) == []

        with engine.begin() as connection:  # a blob that is not a checkpoint at all
            connection.execute(
                text("UPDATE incremental_lda_checkpoint SET arrays = :junk WHERE model_id = :m"),
                {"junk": b"not a checkpoint", "m": model_id},
            )
        with read() as session:
            problems = check_model(session, model_id)
        assert len(problems) == 1 and "cannot be read" in problems[0], problems
        with unit_of_work(write) as session:
            repair_model(session, model_id)
        with read() as session:
            assert check_model(session, model_id) == []
    finally:
        engine.dispose()

    with TestClient(create_app(settings)) as client:  # repaired: it loads, equal to the sound model
        assert_same_state(memory_state(client, model_id), sound)


def test_packed_arrays_round_trip_in_the_narrowest_type_and_damage_is_refused() -> None:
    arrays: dict[str, np.ndarray] = {
        "empty": np.zeros(0, dtype=np.int32),
        "small": np.array([0, 3, 255], dtype=np.int32),
        "words": np.array([0, 256, 70_000], dtype=np.int64),
        "signed": np.array([-1, 5, 2**40], dtype=np.int64),
    }
    unpacked = unpack_arrays(pack_arrays(arrays))
    assert {name: value.dtype for name, value in unpacked.items()} == {
        "empty": np.uint8,
        "small": np.uint8,
        "words": np.uint32,
        "signed": np.int64,
    }
    for name, value in arrays.items():
        assert np.array_equal(unpacked[name].astype(np.int64), value), name
    blob = pack_arrays(arrays)
    for damaged in (blob[: len(blob) // 2], b"junk", bytes(len(blob))):
        with pytest.raises(ValueError):
            unpack_arrays(damaged)


def test_a_server_behind_the_compacted_batches_reloads_and_one_within_an_interval_catches_up(
    database_url: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Two servers on one database: while the first learns 2 intervals' worth of scenes, the batches
    the second needs are deleted by the checkpoints (compaction); on its next request the second
    reloads from the checkpoint instead of catching up, then catches up incrementally from there,
    and its memory equals the writer's bit for bit."""
    settings = make_settings(database_url, checkpoint_interval=INTERVAL)
    scenes = concept_scenes(3 * INTERVAL + 2, seed=5)
    with TestClient(create_app(settings)) as writer, TestClient(create_app(settings)) as follower:
        model_id = _create(writer)
        _post(writer, model_id, scenes[:2])
        assert follower.get(f"/v1/models/{model_id}/contexts").status_code == 200  # follows at version 2 scenes
        _post(writer, model_id, scenes[2 : 2 * INTERVAL + 1])  # checkpoints after scenes 7 and 14: 7 compacted
        engine = create_database_engine(database_url)
        read, _ = create_session_makers(engine)
        with read() as session:
            compacted = lda_repository.compacted_version(session, model_id)
        engine.dispose()
        assert compacted > 0
        with caplog.at_level("INFO", logger="contextweb"):
            assert follower.get(f"/v1/models/{model_id}/contexts").status_code == 200
        assert any("folded into its checkpoint" in record.getMessage() for record in caplog.records)
        assert_same_state(memory_state(follower, model_id), memory_state(writer, model_id))
        caplog.clear()
        _post(writer, model_id, scenes[2 * INTERVAL + 1 :])  # crosses the checkpoint after scene 21
        with caplog.at_level("INFO", logger="contextweb"):
            assert follower.get(f"/v1/models/{model_id}/contexts").status_code == 200
        assert not any("folded into its checkpoint" in record.getMessage() for record in caplog.records)
        assert_same_state(memory_state(follower, model_id), memory_state(writer, model_id))


def test_a_server_far_behind_a_newer_checkpoint_reloads_when_that_is_cheaper_than_replaying(
    database_url: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A follower whose missing versions a newer checkpoint covers, more of them than a reload costs
    (``reload_is_cheaper``: 900 versions, a checkpoint of a few thousand tokens), reloads although the
    batches are all kept (no compaction yet); its memory equals the writer's bit for bit. The same
    follower a few scenes behind that checkpoint later catches up from the batches."""
    interval = 900
    settings = make_settings(database_url, checkpoint_interval=interval)
    scenes = concept_scenes(interval + 10, seed=6)
    with TestClient(create_app(settings)) as writer, TestClient(create_app(settings)) as follower:
        model_id = _create(writer)
        assert follower.get(f"/v1/models/{model_id}/contexts").status_code == 200  # follows before any scene
        _post(writer, model_id, scenes[: interval + 5])  # the checkpoint after scene 900, nothing compacted
        with caplog.at_level("INFO", logger="contextweb"):
            assert follower.get(f"/v1/models/{model_id}/contexts").status_code == 200
        assert any("cheaper than replaying" in record.getMessage() for record in caplog.records)
        assert_same_state(memory_state(follower, model_id), memory_state(writer, model_id))
        caplog.clear()
        _post(writer, model_id, scenes[interval + 5 :])
        with caplog.at_level("INFO", logger="contextweb"):
            assert follower.get(f"/v1/models/{model_id}/contexts").status_code == 200
        assert not any("reloading it from its checkpoint" in record.getMessage() for record in caplog.records)
        assert_same_state(memory_state(follower, model_id), memory_state(writer, model_id))


def test_small_packed_arrays_round_trip_narrow_and_short_and_damage_is_refused() -> None:
    arrays = [np.zeros(0, dtype=np.int64), np.array([0, 3, 255]), np.array([0, 256, 70_000]), np.arange(200) % 3]
    blob = pack_small_arrays(arrays)
    unpacked = unpack_small_arrays(blob)
    assert [array.dtype for array in unpacked] == [np.uint8, np.uint8, np.uint32, np.uint8]
    assert all(np.array_equal(a, b) for a, b in zip(arrays, unpacked, strict=True))
    assert len(blob) < 1 + 1 + 4 * 5 + 3 + 12 + 200, "the repetitive array is deflated"
    assert unpack_small_arrays(pack_small_arrays([np.array([7, 9])]))[0].tolist() == [7, 9]  # stored plain
    for damaged in (blob[: len(blob) // 2], b"junk", bytes(len(blob)), b"", blob + b"\x00"):
        with pytest.raises(ValueError):
            unpack_small_arrays(damaged)
    with pytest.raises(ValueError):
        pack_small_arrays([np.array([-1, 2])])


def _batch(
    version: int, first: int, words: list[int], moved: dict[int, int], scene: int | None = None
) -> lda_repository.StoredBatch:
    """One batch as stored and read back: its new tokens (context 0) and moved tokens."""
    contexts = [0] * len(words)
    return lda_repository.unpack_batch(
        version,
        scene if scene is not None else (version if words else None),
        first,
        len(words),
        lda_repository.pack_batch(
            np.array(words, dtype=np.int64),
            np.array(contexts),
            np.array(sorted(moved)),
            np.array([moved[i] for i in sorted(moved)]),
        ),
    )


def test_replaying_batches_keeps_the_last_context_of_each_token_and_refuses_gaps() -> None:
    batches = [_batch(3, 10, [4, 5], {2: 1}), _batch(4, 12, [6], {2: 2, 11: 1}), _batch(5, 0, [], {0: 1, 12: 2})]
    replayed = lda_repository.replay_batches(batches, 10)
    assert replayed.moved.tolist() == [[0, 1], [2, 2]]  # token 2: moved twice, the last context kept
    assert replayed.added.tolist() == [[3, 4, 0], [3, 5, 1], [4, 6, 2]]  # tokens 11 and 12 added, then moved
    with pytest.raises(lda_repository.DamagedBatchError, match="starts at token 12, but 11 tokens come before it"):
        lda_repository.replay_batches([_batch(3, 12, [4], {})], 11)
    with pytest.raises(lda_repository.DamagedBatchError, match="reassigns token 11, but only 11 tokens exist"):
        lda_repository.replay_batches([_batch(3, 11, [4], {11: 1})], 11)
    with pytest.raises(lda_repository.DamagedBatchError, match="cannot be read"):
        lda_repository.unpack_batch(3, 3, 0, 1, b"junk")
    with pytest.raises(lda_repository.DamagedBatchError, match="its row says 2 tokens"):
        lda_repository.unpack_batch(
            3, 3, 0, 2, lda_repository.pack_batch(np.array([1]), np.array([0]), np.zeros(0), np.zeros(0))
        )


def _checkpoint_row(engine: Engine, model_id: str) -> tuple[int, int] | None:
    """(version, compacted_version) of the model's checkpoint row, or None."""
    with engine.connect() as connection:
        row = connection.execute(
            text("SELECT version, compacted_version FROM incremental_lda_checkpoint WHERE model_id = :m"),
            {"m": model_id},
        ).first()
    return None if row is None else (int(row[0]), int(row[1]))


def _batch_count(engine: Engine, model_id: str) -> int:
    with engine.connect() as connection:
        return int(
            connection.execute(
                text("SELECT count(*) FROM token_batch WHERE model_id = :m"), {"m": model_id}
            ).scalar_one()
        )


def _refuse_checkpoints(engine: Engine) -> None:
    """The database refuses every checkpoint row (a trigger): what a disk too full for the
    checkpoint's megabytes, while a scene's few rows still fit, looks like to the server."""
    statements = (
        [
            (
                "CREATE FUNCTION refuse_checkpoint() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN "
                "RAISE EXCEPTION 'checkpoints refused'; END $$"
            ),
            (
                "CREATE TRIGGER refuse_checkpoint BEFORE INSERT OR UPDATE ON incremental_lda_checkpoint "
                "FOR EACH ROW EXECUTE FUNCTION refuse_checkpoint()"
            ),
        ]
        if engine.dialect.name == "postgresql"
        else [
            f"CREATE TRIGGER refuse_checkpoint_{event.lower()} BEFORE {event} ON incremental_lda_checkpoint "
            "BEGIN SELECT RAISE(ABORT, 'checkpoints refused'); END"
            for event in ("INSERT", "UPDATE")
        ]
    )
    with engine.begin() as connection:
        for statement in statements:
            connection.execute(text(statement))


def _accept_checkpoints(engine: Engine) -> None:
    with engine.begin() as connection:
        if engine.dialect.name == "postgresql":
            connection.execute(text("DROP TRIGGER IF EXISTS refuse_checkpoint ON incremental_lda_checkpoint"))
            connection.execute(text("DROP FUNCTION IF EXISTS refuse_checkpoint()"))
        else:
            for event in ("insert", "update"):
                connection.execute(text(f"DROP TRIGGER IF EXISTS refuse_checkpoint_{event}"))


def test_a_checkpoint_the_database_refuses_leaves_its_scene_acknowledged_and_the_next_one_is_stored(
    database_url: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A checkpoint is stored after its scene's commit, in a transaction of its own: when the
    database refuses it, the scene is still a 201 and stored, nothing is compacted, the log says
    so, and the next interval's checkpoint is stored and compacts as usual. A model restarted
    meanwhile loads from the batches and answers as an uninterrupted twin."""
    scenes = concept_scenes(2 * INTERVAL + 3, seed=8)
    settings = make_settings(database_url, checkpoint_interval=INTERVAL)
    engine = create_database_engine(database_url)
    try:
        with TestClient(create_app(settings)) as client:
            twin = _create(client)
            expected = _post(client, twin, scenes)
            model_id = _create(client)
            _refuse_checkpoints(engine)
            try:
                caplog.set_level("WARNING", logger="contextweb")
                before = _post(client, model_id, scenes[: INTERVAL + 2])  # scene 7 takes a checkpoint: refused
            finally:
                _accept_checkpoints(engine)
            refused = [r.getMessage() for r in caplog.records if "was not stored" in r.getMessage()]
            assert len(refused) == 1 and "checkpoints refused" in refused[0], refused
            assert _checkpoint_row(engine, model_id) is None
            assert stored_problems(engine, model_id) == []
        with TestClient(create_app(settings)) as client:  # a start with no checkpoint: every batch replayed
            after = _post(client, model_id, scenes[INTERVAL + 2 :])  # scene 14 takes the next one
        assert before + after == expected
        version, compacted = _checkpoint_row(engine, model_id) or (0, 0)
        assert version == 2 * INTERVAL and compacted == 0  # nothing older to compact: none was stored
        assert _start(engine, model_id).checkpoint is not None
        assert stored_problems(engine, model_id) == []
    finally:
        _accept_checkpoints(engine)
        engine.dispose()


def test_a_checkpoint_stored_late_never_replaces_a_newer_one_nor_compacts(database_url: str) -> None:
    """Checkpoints are stored after their scenes' commits, so one could arrive after a newer one
    (a stalled thread): it changes nothing, neither the row nor the batches kept."""
    settings = make_settings(database_url, checkpoint_interval=INTERVAL)
    engine = create_database_engine(database_url)
    try:
        with TestClient(create_app(settings)) as client:
            model_id = _create(client)
            _post(client, model_id, concept_scenes(2 * INTERVAL + 1, seed=4))
        row, batches = _checkpoint_row(engine, model_id), _batch_count(engine, model_id)
        assert row == (2 * INTERVAL, INTERVAL)
        newer = _start(engine, model_id).checkpoint
        assert newer is not None
        older = replace(newer, version=INTERVAL)  # what the checkpoint of scene 7 would be, arriving now
        _, write = create_session_makers(engine)
        with unit_of_work(write) as session:
            lda_repository.save_checkpoint(session, model_id, older, compact=True)
        assert _checkpoint_row(engine, model_id) == row and _batch_count(engine, model_id) == batches
        assert stored_problems(engine, model_id) == []
    finally:
        engine.dispose()
