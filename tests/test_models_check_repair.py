"""``contextweb models check`` and ``repair``: a damaged model is named precisely, its counts are rebuilt
from its scenes and assignments, and what cannot be rebuilt is reported, never papered over."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text, update

from app.cli import main
from storage.database import create_session_makers
from storage.models import IncrementalLdaState
from storage.repositories import incremental_lda as lda_repository
from storage.repositories.consistency import UnrepairableModelError, find_problems, repair_model
from storage.unit_of_work import unit_of_work
from tests.conftest import concept_scenes, stored_problems


@pytest.fixture
def learned_model(client: TestClient, model_id: str) -> str:
    """The test model after 12 learned scenes."""
    for body in concept_scenes(12, seed=4):
        response = client.post(f"/v1/models/{model_id}/scenes", json=body)
        assert response.status_code == 201, response.text
    return model_id


def _execute(engine: Engine, statement: str, **parameters: Any) -> None:
    with engine.begin() as connection:
        connection.execute(text(statement), parameters)


def _one(engine: Engine, statement: str, **parameters: Any) -> Any:
    with engine.connect() as connection:
        return connection.execute(text(statement), parameters).one()


def _repair(engine: Engine, model_id: str) -> list[str]:
    _, write = create_session_makers(engine)
    with unit_of_work(write) as session:
        return repair_model(session, model_id)


def _version(engine: Engine, model_id: str) -> int:
    return _one(engine, "SELECT version FROM incremental_lda_state WHERE model_id = :m", m=model_id).version


def _first_count(engine: Engine, model_id: str) -> Any:
    return _one(
        engine,
        "SELECT context, word_id, count FROM context_word_count WHERE model_id = :m AND count > 0 "
        "ORDER BY context, word_id LIMIT 1",
        m=model_id,
    )


def _tokens(engine: Engine, model_id: str) -> lda_repository.StoredAssignments:
    read, _ = create_session_makers(engine)
    with read() as session:
        return lda_repository.load_assignments(session, model_id)


def _batch_versions(engine: Engine, model_id: str) -> list[int]:
    with engine.connect() as connection:
        rows = connection.execute(
            text("SELECT version FROM token_batch WHERE model_id = :m ORDER BY version"), {"m": model_id}
        )
        return [int(version) for (version,) in rows]


def _damage_batch(
    engine: Engine, model_id: str, version: int, *, scene_id: int | None = None, word: int | None = None
) -> None:
    """Rewrite one stored batch: its scene id, or the word of its first token (packed as the code packs it)."""
    read, _ = create_session_makers(engine)
    with read() as session:
        (batch,) = [
            b for b in lda_repository.load_batches(session, model_id, since_version=version - 1) if b.version == version
        ]
    words = batch.words.astype("int64")
    if word is not None:
        words[0] = word
    _execute(
        engine,
        "UPDATE token_batch SET scene_id = :s, packed = :p WHERE model_id = :m AND version = :v",
        s=batch.scene_id if scene_id is None else scene_id,
        p=lda_repository.pack_batch(words, batch.contexts, batch.moved, batch.moved_contexts),
        m=model_id,
        v=version,
    )


def test_a_sound_model_checks_clean(engine: Engine, model_id: str, learned_model: str) -> None:
    assert stored_problems(engine, learned_model) == []
    scene_count, batches, token_count = _one(
        engine,
        "SELECT (SELECT scene_count FROM incremental_lda_state WHERE model_id = :m), "
        "(SELECT count(*) FROM token_batch WHERE model_id = :m), "
        "(SELECT sum(token_count) FROM token_batch WHERE model_id = :m)",
        m=learned_model,
    )
    assert scene_count == 12 and batches == 12 and token_count == _tokens(engine, learned_model).words.shape[0] > 12


def test_a_model_without_scenes_checks_clean_and_an_unknown_one_does_not(engine: Engine, model_id: str) -> None:
    assert stored_problems(engine, model_id) == []
    assert stored_problems(engine, "nosuchmodel") == ["model 'nosuchmodel' is not stored"]


def test_a_corrupted_count_is_named_and_repaired(engine: Engine, learned_model: str) -> None:
    entry = _first_count(engine, learned_model)
    _execute(
        engine,
        "UPDATE context_word_count SET count = count + 2 WHERE model_id = :m AND context = :k AND word_id = :w",
        m=learned_model,
        k=entry.context,
        w=entry.word_id,
    )
    assert stored_problems(engine, learned_model) == [
        (
            f"context_word_count differs from the token assignments at 1 entry, first (context {entry.context}, "
            f"word {entry.word_id}): stored {entry.count + 2}, tokens {entry.count}"
        )
    ]
    version = _version(engine, learned_model)
    changes = _repair(engine, learned_model)
    assert any(change.startswith("context_word_count: ") and "1 entry differed" in change for change in changes)
    assert changes[-1] == f"incremental_lda_state.version: {version} -> {version + 1}"
    assert stored_problems(engine, learned_model) == []
    assert _version(engine, learned_model) == version + 1
    assert _first_count(engine, learned_model) == entry
    versions = _one(
        engine, "SELECT min(version), max(version) FROM context_word_count WHERE model_id = :m", m=learned_model
    )
    assert tuple(versions) == (version + 1, version + 1)
    assert _repair(engine, learned_model) == []  # sound: nothing written, the version stays
    assert _version(engine, learned_model) == version + 1


def test_repair_rebuilds_missing_counts_and_the_scalar_state(engine: Engine, learned_model: str) -> None:
    entry = _first_count(engine, learned_model)
    _execute(
        engine,
        "DELETE FROM context_word_count WHERE model_id = :m AND context = :k AND word_id = :w",
        m=learned_model,
        k=entry.context,
        w=entry.word_id,
    )
    _execute(
        engine,
        "UPDATE incremental_lda_state SET scene_count = 9, context_count = 0 WHERE model_id = :m",
        m=learned_model,
    )
    stored = _tokens(engine, learned_model)
    total, largest, first = stored.words.shape[0], int(stored.contexts.max()), int(stored.contexts[0])
    count_rows, word_count = _one(
        engine,
        "SELECT (SELECT count(*) FROM context_word_count WHERE model_id = :m), "
        "(SELECT count(*) FROM word WHERE model_id = :m)",
        m=learned_model,
    )
    first_row = _one(
        engine,
        "SELECT context, word_id FROM context_word_count WHERE model_id = :m ORDER BY context, word_id LIMIT 1",
        m=learned_model,
    )
    assert stored_problems(engine, learned_model) == [
        (
            f"context_word_count differs from the token assignments at 1 entry, first (context {entry.context}, "
            f"word {entry.word_id}): stored 0, tokens {entry.count}"
        ),
        "incremental_lda_state.scene_count is 9 but 12 scene rows are stored",
        "incremental_lda_state.context_count is 0, not at least 1",
        (
            f"{total} tokens have a context at or above incremental_lda_state.context_count 0, "
            f"first token 0 (context {first})"
        ),
        (
            f"{count_rows} context_word_count rows name a context or word that does not exist (0 contexts, "
            f"{word_count} words), first (context {first_row.context}, word {first_row.word_id})"
        ),
    ]
    changes = _repair(engine, learned_model)
    assert "incremental_lda_state.scene_count: 9 -> 12" in changes
    assert f"incremental_lda_state.context_count: 0 -> {largest + 1}" in changes
    assert stored_problems(engine, learned_model) == []


def test_repair_keeps_unbacked_entries_as_zeros_and_deletes_impossible_ones(engine: Engine, learned_model: str) -> None:
    """An entry no token backs is rewritten as a 0 at the new version (a process catching up on the rows
    since its version sees it), and a row naming a context that does not exist is deleted."""
    context_count, word_count = _one(
        engine,
        "SELECT context_count, (SELECT count(*) FROM word WHERE model_id = :m) FROM incremental_lda_state "
        "WHERE model_id = :m",
        m=learned_model,
    )
    stored = _tokens(engine, learned_model)
    unused_word = min(set(range(word_count)) - set(stored.words[stored.contexts == 0].tolist()))
    _execute(
        engine,
        "DELETE FROM context_word_count WHERE model_id = :m AND context = 0 AND word_id = :w",
        m=learned_model,
        w=unused_word,
    )
    _execute(
        engine,
        "INSERT INTO context_word_count (model_id, context, word_id, count, version) "
        "VALUES (:m, 0, :w, 5, 0), (:m, 50, 0, 0, 0)",
        m=learned_model,
        w=unused_word,
    )
    assert stored_problems(engine, learned_model) == [
        (
            f"context_word_count differs from the token assignments at 1 entry, first (context 0, word {unused_word}): "
            "stored 5, tokens 0"
        ),
        (
            f"1 context_word_count row names a context or word that does not exist ({context_count} contexts, "
            f"{word_count} words), first (context 50, word 0)"
        ),
    ]
    version = _version(engine, learned_model)
    changes = _repair(engine, learned_model)
    assert changes[0] == (
        f"context_word_count: deleted 1 row naming a context or word that does not exist ({context_count} contexts, "
        f"{word_count} words)"
    )
    assert changes[1].endswith(f"1 entry differed, first (context 0, word {unused_word}): stored 5, tokens 0")
    assert changes[2:] == [f"incremental_lda_state.version: {version} -> {version + 1}"]
    assert tuple(
        _one(
            engine,
            "SELECT count, version FROM context_word_count WHERE model_id = :m AND context = 0 AND word_id = :w",
            m=learned_model,
            w=unused_word,
        )
    ) == (0, version + 1)
    assert (
        _one(engine, "SELECT count(*) FROM context_word_count WHERE model_id = :m AND context = 50", m=learned_model)[0]
        == 0
    )
    assert stored_problems(engine, learned_model) == []


def test_rows_ahead_of_the_models_version_are_named_and_the_version_bumped_above(
    engine: Engine, learned_model: str
) -> None:
    version = _version(engine, learned_model)
    _execute(
        engine,
        "UPDATE token_batch SET version = :v WHERE model_id = :m AND version = :last",
        m=learned_model,
        v=version + 7,
        last=_batch_versions(engine, learned_model)[-1],
    )
    assert stored_problems(engine, learned_model) == [
        (
            f"1 token_batch row written at a version above the model's (incremental_lda_state.version {version}), "
            f"first at version {version + 7}"
        )
    ]
    assert _repair(engine, learned_model)[-1] == f"incremental_lda_state.version: {version} -> {version + 8}"
    assert stored_problems(engine, learned_model) == []


def test_a_token_gap_is_reported_and_not_repaired(engine: Engine, learned_model: str) -> None:
    versions = _batch_versions(engine, learned_model)
    first_token = _one(
        engine,
        "SELECT first_token FROM token_batch WHERE model_id = :m AND version = :v",
        m=learned_model,
        v=versions[6],
    )[0]
    _execute(engine, "DELETE FROM token_batch WHERE model_id = :m AND version = :v", m=learned_model, v=versions[5])
    entry = _first_count(engine, learned_model)
    problems = stored_problems(engine, learned_model)
    gap = next(problem for problem in problems if problem.startswith("token ids have a gap"))
    assert gap == (
        f"token ids have a gap: token_batch at version {versions[6]} starts at token {first_token}, "
        f"but {_tokens_before(engine, learned_model, versions[4])} tokens come before it"
    )
    version = _version(engine, learned_model)
    with pytest.raises(UnrepairableModelError) as raised:
        _repair(engine, learned_model)
    assert gap in raised.value.problems
    assert _version(engine, learned_model) == version  # nothing written, not even the counts
    assert _first_count(engine, learned_model) == entry
    assert stored_problems(engine, learned_model) == problems


def _tokens_before(engine: Engine, model_id: str, version: int) -> int:
    """How many tokens the batches up to ``version`` hold."""
    return _one(
        engine, "SELECT sum(token_count) FROM token_batch WHERE model_id = :m AND version <= :v", m=model_id, v=version
    )[0]


def test_broken_scenes_and_random_state_are_unrepairable(engine: Engine, learned_model: str) -> None:
    versions = _batch_versions(engine, learned_model)
    _damage_batch(engine, learned_model, versions[-1], scene_id=0)
    _damage_batch(engine, learned_model, versions[0], word=999)
    _, write = create_session_makers(engine)
    with unit_of_work(write) as session:
        session.execute(
            update(IncrementalLdaState)
            .where(IncrementalLdaState.model_id == learned_model)
            .values(state={"rng_state": {"bit_generator": "MT19937", "state": {}}})
        )
    read, _ = create_session_makers(engine)
    with read() as session:
        problems = find_problems(session, learned_model)
    word_count = _one(engine, "SELECT count(*) FROM word WHERE model_id = :m", m=learned_model)[0]
    unrepairable = [problem.message for problem in problems if not problem.repairable]
    assert unrepairable[0] == f"1 token has a word id outside the {word_count} stored words, first token 0 (word 999)"
    assert unrepairable[1].startswith("token scene ids decrease at 1 token, first token ")
    assert unrepairable[1].endswith("(scene 0 after scene 10)")
    assert unrepairable[2] == "1 scene without tokens, first scene 11"
    assert unrepairable[3].startswith("incremental_lda_state.state: rng_state is not a PCG64 generator state")
    assert len(unrepairable) == 4
    repairable = [problem.message for problem in problems if problem.repairable]
    assert len(repairable) == 1 and repairable[0].startswith("context_word_count differs")  # the moved word
    with pytest.raises(UnrepairableModelError) as raised:
        _repair(engine, learned_model)
    assert raised.value.problems == unrepairable  # the counts are not rewritten from a damaged corpus either
    assert stored_problems(engine, learned_model) == [problem.message for problem in problems]


def test_a_missing_state_row_is_unrepairable(engine: Engine, learned_model: str) -> None:
    _execute(engine, "DELETE FROM incremental_lda_state WHERE model_id = :m", m=learned_model)
    assert stored_problems(engine, learned_model) == ["incremental_lda_state has no row for the model"]
    with pytest.raises(UnrepairableModelError, match="no row for the model"):
        _repair(engine, learned_model)
    with pytest.raises(LookupError):
        _repair(engine, "nosuchmodel")


# The command line.


def test_models_check_prints_one_line_per_model_and_exits_by_soundness(
    cli_database: str, engine: Engine, client: TestClient, learned_model: str, capsys: pytest.CaptureFixture[str]
) -> None:
    other = client.post("/v1/models", json={"name": "other", "seed": 2}).json()["id"]
    assert main(["models", "check"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"{learned_model} test: ok", f"{other} other: ok"]
    entry = _first_count(engine, learned_model)
    _execute(
        engine,
        "UPDATE context_word_count SET count = 0 WHERE model_id = :m AND context = :k AND word_id = :w",
        m=learned_model,
        k=entry.context,
        w=entry.word_id,
    )
    assert main(["models", "check"]) == 1
    assert capsys.readouterr().out.splitlines() == [
        f"{learned_model} test: 1 problem",
        (
            f"  context_word_count differs from the token assignments at 1 entry, first (context {entry.context}, "
            f"word {entry.word_id}): stored 0, tokens {entry.count}"
        ),
        f"  (all repairable: contextweb models repair {learned_model})",
        f"{other} other: ok",
    ]
    assert main(["models", "check", other]) == 0
    assert capsys.readouterr().out == f"{other} other: ok\n"
    assert main(["models", "check", "nosuchmodel"]) == 2
    assert "no model with id 'nosuchmodel'" in capsys.readouterr().err


def test_models_repair_prints_the_changes_and_the_check_after(
    cli_database: str, engine: Engine, learned_model: str, capsys: pytest.CaptureFixture[str]
) -> None:
    _execute(engine, "UPDATE incremental_lda_state SET scene_count = 3 WHERE model_id = :m", m=learned_model)
    version = _version(engine, learned_model)
    assert main(["models", "repair", learned_model]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"{learned_model} test: repaired"
    assert "  incremental_lda_state.scene_count: 3 -> 12" in lines
    assert f"  incremental_lda_state.version: {version} -> {version + 1}" in lines
    assert lines[-1] == f"{learned_model} test: ok"
    assert main(["models", "repair", learned_model]) == 0
    assert capsys.readouterr().out.splitlines() == [
        f"{learned_model} test: nothing to repair",
        f"{learned_model} test: ok",
    ]
    assert main(["models", "repair", "nosuchmodel"]) == 2
    assert "no model with id 'nosuchmodel'" in capsys.readouterr().err


def test_models_repair_refuses_an_unrepairable_model(
    cli_database: str, engine: Engine, learned_model: str, capsys: pytest.CaptureFixture[str]
) -> None:
    first = _batch_versions(engine, learned_model)[0]
    second_starts = _one(
        engine, "SELECT token_count FROM token_batch WHERE model_id = :m AND version = :v", m=learned_model, v=first
    )[0]
    _execute(engine, "DELETE FROM token_batch WHERE model_id = :m AND version = :v", m=learned_model, v=first)
    version = _version(engine, learned_model)
    assert main(["models", "repair", learned_model]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"{learned_model} test: not repaired, nothing changed")
    assert any(
        line.startswith("  token ids have a gap: token_batch at version ")
        and line.endswith(f"starts at token {second_starts}, but 0 tokens come before it")
        for line in lines
    ), lines
    assert _version(engine, learned_model) == version
    assert main(["models", "check", learned_model]) == 1
