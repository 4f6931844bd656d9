"""How bulky values are stored compactly: scene answers and Incremental-LDA checkpoints.

Answers (``scene.answer_zlib``) are the acknowledged ``SceneRead`` JSON, deflated
with a preset dictionary (zlib's ``zdict``): an answer is ~4 KB of JSON whose
keys and concept names repeat in every scene, and a short stream on its own
cannot learn them, so the dictionary holds them once, for every answer. The
stored bytes are a format byte followed by the zlib stream; the format byte
names the dictionary, which therefore never changes once written: a better one
gets a new format byte, and old rows keep decoding with theirs.

- Format 1 (:data:`ANSWER_DICTIONARY_1`): one concept-level answer's skeleton, for
  answers whose probabilities printed with 17 significant digits.
- Format 2 (:data:`ANSWER_DICTIONARY_2`, written since answers are rounded to
  6 decimal places: docs/api.md, "Precision of answers"): 32 KiB of the most frequent
  segments of 1,000 rounded paper-world answers, picked by zstd's dictionary
  trainer (COVER) and used as deflate's preset dictionary
  (``python -m bench.bench_answers --train-dictionary=PATH`` makes one the same way).
  Its content is JSON text: keys, the paper's concepts in order, and the values
  that recur (a concept-level perception's 1.0/0.0, the web's and Eq. 6's usual
  figures). Measured on a held-out model's answers (docs/benchmarks.md, ``answers``):
  40 % smaller than with format 1's dictionary on the same rounded answers. Level
  6 rather than 9: 9 saved 5 % of the bytes for 65 % more CPU (both measured
  loading the dictionary per answer).

Each answer is deflated on its own, in its scene's transaction: blocks of answers
would compress better but tie scenes' rows together.

zlib rather than zstd: it is in the standard library, and zstandard is not a
dependency of the server (zstd with its own trained dictionary would store the
answers smaller still: docs/benchmarks.md).

Checkpoints are numpy arrays in the ``.npy`` format of :func:`numpy.savez`,
each in the smallest integer type that holds it, deflated at level 1: a
checkpoint is written inside a scene's transaction, so speed matters more
than the last percent of size.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

#: Format byte of :data:`ANSWER_DICTIONARY_1`.
_ANSWER_FORMAT_1 = 1

#: The paper's 29 concepts in the vocabulary's order, as answers list them (frozen with the dictionary).
_PAPER_CONCEPTS_1 = [
    "box",
    "ball",
    "cylinder",
    "cup",
    "plate",
    "tool",
    "hard",
    "soft",
    "noisy",
    "silent",
    "tall",
    "short",
    "thin",
    "thick",
    "round",
    "edgy",
    "grasp",
    "push_left",
    "push_right",
    "push_forward",
    "push_backward",
    "move_left",
    "move_right",
    "move_forward",
    "move_backward",
    "drop",
    "throw",
    "knock_down",
    "shake",
]


def _concept_block(key: str, value: str) -> str:
    return f'"{key}":{{' + ",".join(f'"{name}":{value}' for name in _PAPER_CONCEPTS_1) + "}"


#: The preset dictionary of format 1: one concept-level answer's skeleton (keys, the paper's
#: concepts, typical values), most frequent parts last (deflate reaches the dictionary's end with
#: the shortest distances). FROZEN: stored answers decode with it (see the module's docstring).
ANSWER_DICTIONARY_1 = (
    '"perception":null,"web":null,"in_context":null},{"level":"concepts",'
    '{"model_id":"","scene_id":0,"learned":true,"context_count":3,"previous_context_count":3,'
    '"context_posterior":[0.0,0.0,0.0],"map_context":0,"map_context_label":null,"objects":['
    '{"level":"concepts","active_concepts":['
    + ",".join(f'"{name}"' for name in _PAPER_CONCEPTS_1)
    + "],"
    + _concept_block("perception", "0.0")
    + ","
    + _concept_block("web", "0.9999")
    + ","
    + _concept_block("in_context", "0.999")
    + '}],"created_at":"2026-12-02T00:00:00.000000Z"}'
).encode()


#: Format byte of :data:`ANSWER_DICTIONARY_2`, the one :func:`compress_answer` writes.
_ANSWER_FORMAT_2 = 2

#: The preset dictionary of format 2 (see the module's docstring). FROZEN: stored answers decode
#: with it; tests/test_compression.py pins its digest.
ANSWER_DICTIONARY_2 = (Path(__file__).resolve().parent / "data" / "answer_dictionary_2.bin").read_bytes()

#: The dictionary of every format byte that was ever written.
_ANSWER_DICTIONARIES = {_ANSWER_FORMAT_1: ANSWER_DICTIONARY_1, _ANSWER_FORMAT_2: ANSWER_DICTIONARY_2}


#: A compressor primed with format 2's dictionary, copied for each answer: loading 32 KiB of
#: dictionary cost more than deflating the answer (docs/benchmarks.md, ``answers``); the copy gives
#: the same bytes. Never used itself (``copy`` holds the object's lock, so threads may share it).
_PRIMED_COMPRESSOR_2 = zlib.compressobj(level=6, zdict=ANSWER_DICTIONARY_2)


def compress_answer(answer: str) -> bytes:
    """A scene's answer as stored: the format byte (2), then the zlib stream with its preset dictionary."""
    compressor = _PRIMED_COMPRESSOR_2.copy()
    return bytes([_ANSWER_FORMAT_2]) + compressor.compress(answer.encode()) + compressor.flush()


class DamagedAnswerError(ValueError):
    """A stored answer that cannot be read back: its bytes were damaged after they were written."""


def decompress_answer(stored: bytes) -> str:
    """The answer exactly as it was acknowledged (byte for byte), in whichever format it was stored;
    :class:`DamagedAnswerError` when the bytes are not a whole answer of a known format."""
    dictionary = _ANSWER_DICTIONARIES.get(stored[0]) if stored else None
    if dictionary is None:
        raise DamagedAnswerError(f"unknown stored answer format {stored[:1]!r}")
    decompressor = zlib.decompressobj(zdict=dictionary)
    try:
        data = decompressor.decompress(stored[1:]) + decompressor.flush()
        if not decompressor.eof:
            raise DamagedAnswerError("the stored answer ends before its compressed stream does")
        return data.decode()
    except (zlib.error, UnicodeDecodeError) as error:
        raise DamagedAnswerError(f"the stored answer cannot be decompressed ({error})") from error


def pack_arrays(arrays: dict[str, np.ndarray]) -> bytes:
    """Integer arrays as one deflated ``.npz`` blob, each in the smallest type that holds its values.

    The ``.npz`` is deflated as numpy writes it, 16 MiB at a time (:class:`_Deflating`), never
    whole in memory: a million-scene checkpoint's 127 MB archive was copied twice with the GIL
    held (into a buffer, then out of it), which a process's scene threads waited for while it was
    packed beside them (app/services/scenes.py ``store_checkpoint``)."""
    deflating = _Deflating()
    np.savez(deflating, allow_pickle=False, **{name: narrowest(array, copy=False) for name, array in arrays.items()})
    return deflating.blob()


class _Deflating(io.RawIOBase):
    """A write-only stream that deflates (zlib, level 1) what is written to it, as it comes: not
    seekable, so ``zipfile`` writes the archive's sizes after each entry's data."""

    def __init__(self) -> None:
        super().__init__()
        self._compressor = zlib.compressobj(1)
        self._parts: list[bytes] = []

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        view = memoryview(data)
        self._parts.append(self._compressor.compress(view))
        return view.nbytes

    def blob(self) -> bytes:
        return b"".join([*self._parts, self._compressor.flush()])


def unpack_arrays(blob: bytes) -> dict[str, np.ndarray]:
    """The arrays of :func:`pack_arrays`, in their stored (narrow) types: the caller converts each once
    (raises ValueError on a damaged blob)."""
    try:
        with np.load(io.BytesIO(zlib.decompress(blob)), allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (zlib.error, OSError, KeyError, EOFError) as error:
        raise ValueError(f"not a packed array blob ({type(error).__name__}: {error})") from error


def narrowest(array: np.ndarray, *, copy: bool = True) -> np.ndarray:
    """Integer ``array`` in the narrowest integer type that holds its values (unsigned when none is
    negative): always a copy, or with ``copy=False`` the array itself when it is already in that type."""
    values = np.asarray(array)
    return values.astype(_narrowest_type(values), copy=copy)


def _narrowest_type(values: np.ndarray) -> type[np.integer[Any]]:
    if values.size == 0:
        return np.uint8
    low, high = int(values.min()), int(values.max())
    for dtype in (np.uint8, np.uint16, np.uint32) if low >= 0 else (np.int8, np.int16, np.int32):
        info = np.iinfo(dtype)
        if info.min <= low and high <= info.max:
            return dtype
    return np.int64


#: Format bytes of :func:`pack_small_arrays`: the arrays as they are, or raw-deflated (the shorter).
_SMALL_ARRAYS_PLAIN = 1
_SMALL_ARRAYS_DEFLATED = 2
_SMALL_HEADER = struct.Struct("<IB")  # per array: its length and its item size (1, 2, 4 or 8 bytes)


def pack_small_arrays(arrays: Sequence[np.ndarray]) -> bytes:
    """Non-negative integer arrays of a few hundred values (one token batch) as a short blob.

    :func:`pack_arrays`' ``.npz`` spends about 250 bytes a member on zip and ``.npy`` headers
    (a 78-token scene with 20 reassigned tokens took 509 bytes); here a member costs 5 bytes of
    header, each array is in its narrowest unsigned type, and the whole is raw-deflated when that
    is shorter (the same scene: 190 bytes). The arrays come back in order, in their stored types.
    """
    narrow = [narrowest(array, copy=False) for array in arrays]
    if any(array.ndim != 1 or array.dtype.kind != "u" for array in narrow):
        raise ValueError("pack_small_arrays stores one-dimensional non-negative integer arrays only")
    header = bytes([len(narrow)]) + b"".join(_SMALL_HEADER.pack(a.shape[0], a.dtype.itemsize) for a in narrow)
    body = header + b"".join(a.astype(a.dtype.newbyteorder("<")).tobytes() for a in narrow)
    deflater = zlib.compressobj(9, zlib.DEFLATED, -15)
    deflated = deflater.compress(body) + deflater.flush()
    if len(deflated) < len(body):
        return bytes([_SMALL_ARRAYS_DEFLATED]) + deflated
    return bytes([_SMALL_ARRAYS_PLAIN]) + body


def unpack_small_arrays(blob: bytes) -> list[np.ndarray]:
    """The arrays of :func:`pack_small_arrays` (raises ValueError on a damaged blob)."""
    try:
        if not blob or blob[0] not in (_SMALL_ARRAYS_PLAIN, _SMALL_ARRAYS_DEFLATED):
            raise ValueError(f"unknown format byte {blob[:1]!r}")
        if blob[0] == _SMALL_ARRAYS_PLAIN:
            body = blob[1:]
        else:
            inflater = zlib.decompressobj(-15)
            body = inflater.decompress(blob[1:]) + inflater.flush()
            if not inflater.eof or inflater.unused_data:
                raise ValueError("the deflated stream is cut short or followed by other bytes")
        count, offset = body[0], 1
        shapes = []
        for _ in range(count):
            length, itemsize = _SMALL_HEADER.unpack_from(body, offset)
            shapes.append((length, np.dtype(f"<u{itemsize}")))
            offset += _SMALL_HEADER.size
        arrays = []
        for length, dtype in shapes:
            arrays.append(np.frombuffer(body, dtype=dtype, count=length, offset=offset).astype(dtype.newbyteorder("=")))
            offset += length * dtype.itemsize
        if offset != len(body):
            raise ValueError(f"{len(body) - offset} bytes after the arrays")
        return arrays
    except (zlib.error, struct.error, IndexError, TypeError, ValueError) as error:
        raise ValueError(f"not a packed small-array blob ({type(error).__name__}: {error})") from error
