"""Read a ROS bag that was cut short (a recorder killed mid-write) up to its cut, when rosbags cannot open it.

rosbags opens a bag through its index: the summary at the end of an MCAP file, the index records
at the end of a ROS 1 bag, SQLite's page count in a rosbag2 ``.db3`` header. A file cut short has
none of them, so rosbags refuses it whole. Here the file is read from its start, record by record,
and every message before the cut is kept:

* **MCAP**: the maintained ``mcap`` package (Foxglove, MIT) reads records in order without the
  summary. A chunk cut in the middle is read up to the cut (uncompressed chunks, as rosbags writes
  them, and zstd or lz4 chunks through their incremental decompressors); its last message is
  dropped, since it may be cut.
* **rosbag2 sqlite3**: the standard library's ``sqlite3``, read-only, with ``PRAGMA
  writable_schema=ON``: SQLite then trusts the file's size over the page count in its header
  (without it, it refuses the whole file as "malformed"). Rows are read in insertion order until
  a missing page or a row that is not a message.
* **ROS 1**: records are parsed in order with rosbags' record-header reader: connection and
  message-data records, inside chunks (uncompressed, bz2 or lz4, decompressed up to the cut).

Messages must be recorded in time order (recorders write them as they arrive), so every message
older than the last one read was read. Only the topics the caller keeps hold their bytes in
memory (the file has no index to come back to them); the others are counted.
"""

from __future__ import annotations

import bz2
import sqlite3
import struct
from collections import Counter
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

from bridge.errors import InvalidRecordingError

ROS1_MAGIC = b"#ROSBAG V2.0\n"
MCAP_MAGIC_SIZE = 8
#: ROS 1 record ops (the rosbag format 2.0).
ROS1_MESSAGE, ROS1_BAG_HEADER, ROS1_CHUNK, ROS1_CONNECTION = 0x02, 0x03, 0x05, 0x07


@dataclass(frozen=True)
class Channel:
    """A topic of a salvaged bag; stands in for rosbags' ``Connection`` (``topic``, ``msgtype``)."""

    id: int
    topic: str
    msgtype: str
    definition: str = ""


@dataclass(frozen=True)
class TopicCount:
    msgtype: str
    msgcount: int


@dataclass
class Salvage:
    """What was read of a cut bag: its channels, the kept messages in file order, and where it ends.

    ``problem`` says where the file ends ("the file ends inside a chunk ..."); it is None when every
    message was read (only the index or summary after them is cut).
    """

    ros1: bool
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[tuple[Channel, int, bytes]] = field(default_factory=list)
    counts: Counter[int] = field(default_factory=Counter)
    last: tuple[Channel, int] | None = None
    earliest: int | None = None
    problem: str | None = None

    def add(self, channel_id: int, time: int, data: bytes, keep: Collection[str]) -> None:
        """Count a message; keep its bytes when its topic is kept or it is among the earliest (the bag's identity)."""
        channel = self.channels[channel_id]
        self.counts[channel_id] += 1
        self.last = (channel, time)
        earliest = self.earliest is None or time <= self.earliest
        if earliest:
            self.earliest = time
        if channel.topic in keep or earliest:
            self.messages.append((channel, time, bytes(data)))


class TruncatedBag:
    """A salvaged bag with the part of rosbags' ``AnyReader`` that :class:`bridge.tools.bags.BagReplay` uses."""

    def __init__(self, salvage: Salvage, typestore: Any) -> None:
        self.salvage = salvage
        self.typestore = typestore
        self.connections = list(salvage.channels.values())
        times = [time for _, time, _ in salvage.messages]
        last_time = salvage.last[1] if salvage.last else 0
        self.start_time = min(times, default=last_time)
        self.end_time = max([*times, last_time])
        self.message_count = sum(salvage.counts.values())

    @property
    def topics(self) -> dict[str, TopicCount]:
        counts: Counter[tuple[str, str]] = Counter()
        for channel in self.connections:
            counts[(channel.topic, channel.msgtype)] += self.salvage.counts[channel.id]
        return {topic: TopicCount(msgtype, count) for (topic, msgtype), count in counts.items()}

    def messages(self, connections: Collection[Any], start: int, stop: int) -> Iterator[tuple[Any, int, bytes]]:
        """The kept messages of ``connections`` with ``start <= time < stop``, in time order."""
        ids = {connection.id for connection in connections}
        chosen = [m for m in self.salvage.messages if m[0].id in ids and start <= m[1] < stop]
        return iter(sorted(chosen, key=lambda message: message[1]))

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        if self.salvage.ros1:
            return self.typestore.deserialize_ros1(raw, msgtype)
        return self.typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        """Nothing is held open: the file was read whole."""


def salvage_bag(path: Path, keep: Collection[str], typestore: Callable[[bool], Any]) -> TruncatedBag:
    """Read ``path`` (a ``.bag``, ``.mcap`` or ``.db3`` file, or a rosbag2 folder) up to its cut.

    ``keep``: the topics whose messages are kept; ``typestore(ros1)``: the store of the standard and
    audio types, to which the salvaged definitions are added.
    """
    files = _storage_files(path)
    salvage = Salvage(ros1=files[0].suffix.lower() == ".bag")
    for file in files:
        readers = {".mcap": _read_mcap, ".db3": _read_sqlite3, ".bag": _read_ros1}
        readers[file.suffix.lower()](file, salvage, keep)
        if salvage.problem is not None:
            salvage.problem = f"{file.name}: {salvage.problem}" if len(files) > 1 else salvage.problem
            break
    return TruncatedBag(salvage, _typestore(salvage, typestore(salvage.ros1)))


def _storage_files(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    files = sorted(path.glob("*.mcap")) or sorted(path.glob("*.db3"))
    if not files:
        raise InvalidRecordingError(str(path), "holds no .mcap or .db3 storage file")
    return files


def _typestore(salvage: Salvage, store: Any) -> Any:
    """The default store plus the bag's own definitions (ROS 1 connections, MCAP schemas), as rosbags does."""
    from rosbags.typesys import get_types_from_msg

    for channel in salvage.channels.values():
        if channel.definition:
            try:
                store.register(get_types_from_msg(channel.definition, channel.msgtype))
            except Exception:  # noqa: BLE001, S112 - a definition the store holds differently: its own serves
                continue
    return store


def _read_mcap(file: Path, salvage: Salvage, keep: Collection[str]) -> None:
    from mcap.exceptions import McapError
    from mcap.records import Channel as McapChannel
    from mcap.records import Chunk, DataEnd, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Schema] = {}

    def take(record: Any) -> None:
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, McapChannel):
            schema = schemas.get(record.schema_id)
            name = schema.name if schema else ""
            definition = schema.data.decode(errors="replace") if schema and schema.encoding == "ros2msg" else ""
            salvage.channels[record.id] = Channel(record.id, record.topic, name, definition)
        elif isinstance(record, Message) and record.channel_id in salvage.channels:
            salvage.add(record.channel_id, record.log_time, record.data, keep)

    data_end = False
    with file.open("rb") as stream:
        records = StreamReader(stream, emit_chunks=True).records
        while True:
            start = max(stream.tell(), MCAP_MAGIC_SIZE)  # each step reads one whole record (the magic first)
            try:
                record = next(records)
            except StopIteration:
                return
            except (McapError, ValueError, struct.error):
                if not data_end:
                    salvage.problem = _mcap_cut_record(stream, start, take)
                return
            if isinstance(record, DataEnd):
                data_end = True
            if isinstance(record, Chunk):
                for inner in _mcap_chunk_records(record)[0]:
                    take(inner)
            else:
                take(record)


def _mcap_cut_record(stream: BinaryIO, start: int, take: Callable[[Any], None]) -> str:
    """Read the record the file ends in: a chunk gives its records up to the cut (all but the last)."""
    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import McapError
    from mcap.records import Chunk
    from mcap.stream_reader import Opcode

    stream.seek(start)
    data = ReadDataStream(stream)
    try:
        if data.read1() != Opcode.CHUNK:
            return f"the file ends inside a record (at byte {start:,})"
        data.read8()
        chunk = Chunk.read(data)
    except (McapError, struct.error):
        return f"the file ends inside a chunk's header (at byte {start:,})"
    records, whole = _mcap_chunk_records(chunk)
    for inner in records if whole else records[:-1]:  # the last record of a cut chunk may itself be cut
        take(inner)
    return f"the file ends inside a chunk ({chunk.compression or 'uncompressed'}, from byte {start:,})"


def _mcap_chunk_records(chunk: Any) -> tuple[list[Any], bool]:
    """The records of a chunk, and whether it is whole; a cut chunk gives the records up to its cut."""
    from mcap.exceptions import McapError
    from mcap.stream_reader import StreamReader

    data = _partial_decompress(chunk.data, chunk.compression)
    records = []
    try:
        for record in StreamReader(BytesIO(data), skip_magic=True).records:
            records.append(record)  # noqa: PERF402 - a cut chunk raises mid-way: keep the records before it
    except (McapError, ValueError, struct.error):
        pass  # the end of the chunk's records (whole or cut)
    return records, len(data) >= chunk.uncompressed_size


def _partial_decompress(data: bytes, compression: str) -> bytes:
    """As much of ``data`` as decompresses: a cut stream gives its whole blocks."""
    try:
        if compression in ("", "none"):
            return bytes(data)
        if compression == "zstd":
            import zstandard

            return zstandard.ZstdDecompressor().decompressobj().decompress(data)
        if compression == "lz4":
            import lz4.frame

            return lz4.frame.LZ4FrameDecompressor().decompress(data)
        if compression == "bz2":
            return bz2.BZ2Decompressor().decompress(data)
    except Exception:  # noqa: BLE001 - each decompressor raises its own error on a cut stream
        return b""
    return b""


def _read_sqlite3(file: Path, salvage: Salvage, keep: Collection[str]) -> None:
    connection = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
    try:
        connection.execute("PRAGMA writable_schema=ON")  # trust the file's size, not the header's page count
        try:
            for topic_id, name, msgtype in connection.execute("SELECT id, name, type FROM topics"):
                salvage.channels[topic_id] = Channel(topic_id, name, msgtype)
        except sqlite3.DatabaseError as error:
            salvage.problem = f"the file ends before its topics table is whole (sqlite3: {error})"
            return
        rows = connection.execute("SELECT topic_id, timestamp, data FROM messages ORDER BY id")
        try:
            for topic_id, time, data in rows:
                if topic_id not in salvage.channels or not isinstance(time, int) or not isinstance(data, bytes):
                    break  # a zeroed page past the cut
                salvage.add(topic_id, time, data, keep)
        except sqlite3.DatabaseError as error:
            salvage.problem = f"the file ends inside its messages table (sqlite3: {error})"
            return
        salvage.problem = "the file ends inside its messages table (SQLite finds pages missing)"
    finally:
        connection.close()


def _read_ros1(file: Path, salvage: Salvage, keep: Collection[str]) -> None:
    from rosbags.rosbag1.reader import ReaderError

    size = file.stat().st_size
    with file.open("rb") as stream:
        if stream.readline() != ROS1_MAGIC:
            raise InvalidRecordingError(str(file), "is not a ROS 1 bag (version 2.0)")
        index_position = 0
        while stream.tell() < size:
            start = stream.tell()
            try:
                header, data, whole = _ros1_record(stream)
            except ReaderError:
                header, data, whole = None, b"", False
            op = header.get_uint8("op") if header is not None else None
            if whole and op == ROS1_BAG_HEADER:
                index_position = header.get_uint64("index_pos")
            elif op == ROS1_CHUNK:
                chunk = BytesIO(_partial_decompress(data, header.get_string("compression")))
                whole = _ros1_records(chunk, salvage, keep) and whole
            elif whole and op is not None:
                _ros1_take(op, header, data, salvage, keep)
            if not whole:
                if not index_position or start < index_position:  # past the index position: every message was read
                    where = "a chunk" if op == ROS1_CHUNK else "a record"
                    salvage.problem = f"the file ends inside {where} (at byte {size:,})"
                return
        if not index_position:
            salvage.problem = f"the file ends before its index (at byte {size:,})"


def _ros1_record(stream: BinaryIO) -> tuple[Any, bytes, bool]:
    """One record: its header, its data (cut short when the file is) and whether the data is whole."""
    from rosbags.rosbag1.reader import Header, read_uint32

    header = Header.read(stream)
    length = read_uint32(stream)
    data = stream.read(length)
    return header, data, len(data) == length


def _ros1_records(stream: BinaryIO, salvage: Salvage, keep: Collection[str]) -> bool:
    """The connection and message records of a chunk's data; False when the data ends inside a record."""
    from rosbags.rosbag1.reader import ReaderError

    end = len(stream.getbuffer()) if isinstance(stream, BytesIO) else None
    while end is None or stream.tell() < end:
        try:
            header, data, whole = _ros1_record(stream)
        except ReaderError:
            return False
        if not whole:
            return False
        _ros1_take(header.get_uint8("op"), header, data, salvage, keep)
    return True


def _ros1_take(op: int, header: Any, data: bytes, salvage: Salvage, keep: Collection[str]) -> None:
    from rosbags.rosbag1.reader import Header, normalize
    from rosbags.typesys.msg import normalize_msgtype

    if op == ROS1_CONNECTION:
        connection = header.get_uint32("conn")
        if connection not in salvage.channels:
            details = Header.read(BytesIO(len(data).to_bytes(4, "little") + data))
            definition = details.get_string("message_definition")
            msgtype = normalize_msgtype(details.get_string("type"))
            salvage.channels[connection] = Channel(
                connection, normalize(header.get_string("topic")), msgtype, definition
            )
    elif op == ROS1_MESSAGE and header.get_uint32("conn") in salvage.channels:
        salvage.add(header.get_uint32("conn"), header.get_time("time"), data, keep)
