"""Stored answers: format 2 is written and read back byte for byte; format 1 rows keep decoding."""

from __future__ import annotations

import hashlib
import json
import zlib
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from storage.compression import (
    _PAPER_CONCEPTS_1,
    ANSWER_DICTIONARY_2,
    compress_answer,
    decompress_answer,
)

#: A row as format 1 stored it: written by storage/compression.py at commit 13dbd74 (before format 2).
FORMAT_1_ROW = bytes.fromhex(
    "0178bb41c3554943a96973d1ab5aecd5a5b1012a3001569de6b158ab4a25efc37b923352151ecd98aa540b0050d82394"
)
FORMAT_1_ANSWER = (
    '{"model_id":"m","scene_id":0,"context_posterior":[0.30000000000000004,0.7],"map_context_label":"Küche ☕"}'
)


def _answer(seed: int) -> str:
    """A concept-level answer's shape with rounded probabilities (what format 2 was made for)."""
    rng = np.random.default_rng(seed)

    def stage() -> dict[str, float]:
        return dict(zip(_PAPER_CONCEPTS_1, np.round(rng.random(len(_PAPER_CONCEPTS_1)), 6).tolist(), strict=True))

    objects = [
        {"level": "concepts", "active_concepts": ["cup"], "perception": stage(), "web": stage(), "in_context": stage()}
        for _ in range(5)
    ]
    answer = {"model_id": "ab" * 16, "scene_id": seed, "context_posterior": [0.25, 0.75], "objects": objects}
    return json.dumps(answer, separators=(",", ":"))


def test_format_1_rows_written_before_format_2_still_decode() -> None:
    assert decompress_answer(FORMAT_1_ROW) == FORMAT_1_ANSWER


@pytest.mark.parametrize("answer", ["", "{}", FORMAT_1_ANSWER, _answer(0), "é" * 70_000])
def test_answers_are_stored_in_format_2_and_read_back_byte_for_byte(answer: str) -> None:
    stored = compress_answer(answer)
    assert stored[0] == 2
    assert decompress_answer(stored) == answer
    fresh = zlib.compressobj(level=6, zdict=ANSWER_DICTIONARY_2)  # the primed compressor's copy changes nothing
    assert stored[1:] == fresh.compress(answer.encode()) + fresh.flush()


def test_the_format_2_dictionary_is_frozen() -> None:
    # Stored answers decode with it: a better dictionary needs a new format byte (storage/compression.py).
    assert len(ANSWER_DICTIONARY_2) == 32_768
    assert hashlib.sha256(ANSWER_DICTIONARY_2).hexdigest() == (
        "1db17084dfeae0ced09acdf919921b55745b93aa02e554f1d64224979490da2d"
    )


def test_threads_compress_answers_at_once() -> None:
    answers = [_answer(seed) for seed in range(40)]
    with ThreadPoolExecutor(4) as pool:
        stored = list(pool.map(compress_answer, answers))
    assert [decompress_answer(blob) for blob in stored] == answers


@pytest.mark.parametrize("stored", [b"", b"\x00abc", b"\x03" + FORMAT_1_ROW[1:]])
def test_an_unknown_format_is_refused(stored: bytes) -> None:
    with pytest.raises(ValueError, match="unknown stored answer format"):
        decompress_answer(stored)
