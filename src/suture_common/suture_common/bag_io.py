# SPDX-License-Identifier: Apache-2.0
"""Reading and writing rosbag2 bags with MCAP storage, without rclpy or rosbag2.

A bag written here is a rosbag2 directory (format version 9)::

    BAG/metadata.yaml     rosbag2 metadata, for ``ros2 bag info`` / ``ros2 bag play``
    BAG/BAG.mcap          MCAP, ros2 profile, zstd-compressed chunks, ros2msg schemas embedded

so ``ros2 bag`` on a full ROS 2 install and Foxglove both open it. Topics are
recorded without offered QoS profiles, so ``ros2 bag play`` publishes them with
its default QoS (reliable, volatile), which both sensor-data (best-effort) and
reliable subscribers accept.

Readers accept a bag directory (with ``metadata.yaml``), a directory holding
exactly one ``.mcap`` file and no metadata (e.g. a copied or Foxglove-exported
recording), or a single ``.mcap`` file (rosbags reads its summary section
directly). Messages come in timestamp order.

A damaged MCAP file (a recording cut short by a crash, so without its summary and
end magic) is refused unless the caller passes a :class:`BagDamage` to the reader: then
every message in the readable part of the file is returned and the object says what
was lost (the counts a bag's ``metadata.yaml`` promised, where it has one).

Every problem with a bag on disk (missing, not a bag, corrupt, existing or
unwritable target) raises :class:`BagError`, a subclass of ``OSError`` so that
command-line tools can report all file problems in one ``except OSError``.
Misuse by the caller (an object that is not a rosbags message, a negative
timestamp, two types on one topic) raises ``TypeError``/``ValueError``.
"""

from __future__ import annotations

import functools
import shutil
from collections import Counter
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from numbers import Integral
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import yaml
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from rosbags.rosbag2 import (
    CompressionFormat,
    CompressionMode,
    Reader,
    ReaderError,
    StoragePlugin,
    Writer,
    WriterError,
)

from suture_common.messages import TYPESTORE

try:  # the zstd module rosbags itself uses
    from compression import zstd
except ImportError:
    from backports import zstd


class BagError(OSError):
    """A bag cannot be read or written; the text names the path and what to do."""


@dataclass(frozen=True)
class BagMessage:
    """One deserialised message of a bag.

    ``message`` is a rosbags dataclass of :data:`suture_common.messages.TYPESTORE`;
    ``timestamp_ns`` is the bag's receive (log) time in integer nanoseconds.
    """

    topic: str
    msgtype: str
    timestamp_ns: int
    message: Any


@dataclass
class BagDamage:
    """What a reader could not read of a damaged bag; pass one to :func:`read_raw`/:func:`read_messages`.

    ``error``: why the bag is damaged, None while it read whole; ``read``: messages read per
    topic (of the topics asked for); ``expected``: messages per topic that the bag's
    ``metadata.yaml`` lists, None without one.
    """

    error: str | None = None
    read: Counter = field(default_factory=Counter)
    expected: dict[str, int] | None = None

    @property
    def damaged(self) -> bool:
        return self.error is not None

    def lost(self, topic: str) -> int | None:
        """Messages of ``topic`` the damage cost (None when the bag does not say how many it had)."""
        if self.expected is None or topic not in self.expected:
            return None
        return max(0, self.expected[topic] - self.read[topic])


class BagWriter:
    """Write a new MCAP rosbag2 bag; use as a context manager.

    ``BagWriter(path)`` creates the directory ``path`` (which must not exist) on
    entry; :meth:`write` and :meth:`write_raw` register each topic on first use.
    On a clean exit the bag is finalised (MCAP summary and ``metadata.yaml``); if the ``with`` body
    raises, the partial bag directory is removed, so a bag on disk is always
    complete. ``compress`` selects zstd compression of MCAP chunks (readable by
    ``ros2 bag``, Foxglove and the ``mcap`` tools without extra options);
    ``compression_level`` is zstd's level (1 fast ... 19 small; 3 is zstd's default).
    """

    def __init__(self, path: str | Path, compress: bool = True, compression_level: int = 3) -> None:
        self.path = Path(path)
        if not 1 <= compression_level <= 22:
            raise ValueError(f"zstd compression level must be 1..22, got {compression_level}")
        self._compression_level = compression_level if compress else None
        if self.path.suffix == ".mcap":
            raise BagError(
                f"{self.path}: BagWriter writes a rosbag2 directory (metadata.yaml + {self.path.stem}.mcap); "
                "give a directory path without the .mcap suffix"
            )
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f"{self.path} exists already; choose a new bag path or delete the old bag first")
        try:
            self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
            if compress:
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        except WriterError as exc:
            raise BagError(f"{self.path}: cannot create bag: {exc}") from exc
        self._connections: dict[str, Any] = {}
        self._open = False
        self._created = False

    def open(self) -> Self:
        """Create the bag directory and MCAP file (done by ``with``)."""
        if self._open:
            raise BagError(f"{self.path}: bag is already open")
        if self._created:
            raise BagError(f"{self.path}: a BagWriter writes one bag once; create a new BagWriter")
        try:
            self._writer.open()
            if self._compression_level is not None:
                # rosbags compresses MCAP chunks with zstd's default level and has no
                # option for it; its MCAP storage exposes the compressor to replace.
                self._writer.storage.compressor = functools.partial(
                    zstd.compress, level=self._compression_level
                )
        except (WriterError, OSError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            raise BagError(
                f"cannot create bag directory {self.path}: {reason}; "
                "check that the parent directory exists and is writable"
            ) from exc
        self._open = True
        self._created = True
        return self

    def write(self, topic: str, message: Any, timestamp_ns: int) -> None:
        """Append ``message`` (a rosbags message, e.g. from :mod:`suture_common.messages`) on ``topic``.

        ``timestamp_ns`` is the record (log) time in integer nanoseconds; this
        pipeline uses the message's header stamp. Messages may be written in any
        time order; readers return them sorted.
        """
        self._check_open()
        msgtype = getattr(message, "__msgtype__", None)
        if not isinstance(msgtype, str):
            raise TypeError(
                f"BagWriter.write needs a rosbags message (from suture_common.messages), got "
                f"{type(message).__module__}.{type(message).__name__}"
            )
        connection, timestamp_ns = self._prepare(topic, msgtype, timestamp_ns)
        self._writer.write(connection, timestamp_ns, TYPESTORE.serialize_cdr(message, msgtype))

    def write_raw(self, topic: str, msgtype: str, cdr: bytes, timestamp_ns: int) -> None:
        """Append an already serialised message: ``cdr`` of type ``msgtype`` on ``topic``.

        ``msgtype`` is a full name like ``'sensor_msgs/msg/Image'`` known to
        :data:`~suture_common.messages.TYPESTORE` (its schema goes into the bag);
        ``cdr`` is the CDR serialisation with its 4-byte encapsulation header, as
        :func:`read_raw` returns it and rclpy's ``serialize_message`` makes it. The
        bytes are stored as given (not parsed). Same checks as :meth:`write`.
        """
        self._check_open()
        if not isinstance(msgtype, str) or msgtype not in TYPESTORE.types:
            raise ValueError(
                f"message type {msgtype!r} is not a ROS 2 Jazzy standard message known to the bag "
                "type store; give a full name like 'sensor_msgs/msg/Image'"
            )
        if not isinstance(cdr, bytes | bytearray | memoryview):
            raise TypeError(f"cdr must be bytes (CDR with encapsulation header), got {type(cdr).__name__}")
        if len(cdr) < 4:
            raise ValueError(f"cdr of {len(cdr)} bytes is too short to hold the CDR encapsulation header")
        connection, timestamp_ns = self._prepare(topic, msgtype, timestamp_ns)
        self._writer.write(connection, timestamp_ns, bytes(cdr))

    def _check_open(self) -> None:
        if not self._open:
            raise BagError(f"{self.path}: bag is not open; use 'with BagWriter(path) as bag:'")

    def _prepare(self, topic: str, msgtype: str, timestamp_ns: int) -> tuple[Any, int]:
        """Check ``timestamp_ns`` and ``topic``; the topic's connection, registered on first use."""
        if isinstance(timestamp_ns, bool) or not isinstance(timestamp_ns, Integral) or timestamp_ns < 0:
            raise ValueError(f"timestamp_ns must be a non-negative int (nanoseconds), got {timestamp_ns!r}")
        if not isinstance(topic, str) or not topic.startswith("/"):
            raise ValueError(f"topic {topic!r} must be absolute (start with '/')")
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE)
            self._connections[topic] = connection
        elif connection.msgtype != msgtype:
            raise ValueError(
                f"topic {topic} already carries {connection.msgtype}; cannot also write {msgtype}"
            )
        return connection, int(timestamp_ns)

    def close(self) -> None:
        """Finalise the bag (MCAP summary and metadata.yaml)."""
        if not self._open:
            return
        self._open = False
        try:
            self._writer.close()
        except (WriterError, OSError) as exc:
            raise BagError(f"{self.path}: cannot finalise bag: {exc}") from exc

    def abort(self) -> None:
        """Stop writing and delete the partial bag directory."""
        if self._open:
            self._open = False
            self._writer.abort()
        if self._created:
            shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def read_messages(
    path: str | Path, topics: Collection[str] | None = None, damage: BagDamage | None = None
) -> Iterator[BagMessage]:
    """Deserialised messages of the bag at ``path`` in timestamp order.

    ``topics`` restricts the output; topics absent from the bag are ignored (use
    :func:`bag_summary` to check for them). The bag is checked when this is
    called, so a missing or invalid bag raises :class:`BagError` immediately; a
    message type outside ROS 2 Jazzy's standard set raises it when reached.
    ``damage``: read what can be read of a damaged MCAP file (see :func:`read_raw`).
    """
    raw = read_raw(path, topics, damage)

    def generate() -> Iterator[BagMessage]:
        for topic, msgtype, timestamp, data in raw:
            if msgtype not in TYPESTORE.types:
                raise BagError(
                    f"{path}: topic {topic} has type {msgtype}, which is not a ROS 2 Jazzy standard "
                    "message; use read_raw for it or pass topics= to skip it"
                )
            yield BagMessage(topic, msgtype, timestamp, TYPESTORE.deserialize_cdr(data, msgtype))

    return generate()


def read_raw(
    path: str | Path, topics: Collection[str] | None = None, damage: BagDamage | None = None
) -> Iterator[tuple[str, str, int, bytes]]:
    """``(topic, msgtype, timestamp_ns, cdr_bytes)`` of the bag at ``path`` in timestamp order.

    ``msgtype`` is like ``'sensor_msgs/msg/Image'``; ``cdr_bytes`` is the CDR
    serialisation with its 4-byte encapsulation header, as rclpy's
    ``deserialize_message`` takes it. ``topics`` as in :func:`read_messages`.

    ``damage``: without it a damaged bag raises :class:`BagError`; with it, an MCAP file
    that cannot be opened (cut short, no summary) is read record by record up to the
    damage, its messages are returned (sorted by time), and ``damage`` is filled in.
    """
    source = _bag_source(path)
    wanted = None if topics is None else set(_check_topics(topics))
    if damage is not None:
        damage.expected = _expected_counts(path)
    try:
        with _open_reader(source, path):  # check now, not at the first next()
            pass
    except BagError as error:
        mcap_file = _mcap_file(source)
        if damage is None or mcap_file is None or isinstance(error.__cause__, PermissionError):
            raise
        return _salvage(mcap_file, path, wanted, damage, str(error))

    def generate() -> Iterator[tuple[str, str, int, bytes]]:
        with _open_reader(source, path) as reader:
            connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
            if not connections:
                return
            try:
                for connection, timestamp, data in reader.messages(connections=connections):
                    if damage is not None:
                        damage.read[connection.topic] += 1
                    yield connection.topic, connection.msgtype, timestamp, bytes(data)
            except ReaderError as exc:
                if damage is None:
                    raise BagError(f"{path}: bag is corrupt: {exc}") from exc
                damage.error = f"{path}: bag is corrupt: {exc}"

    return generate()


def _mcap_file(source: Path) -> Path | None:
    """The MCAP file of a bag source (the directory's single storage file), if there is one."""
    if source.suffix == ".mcap":
        return source
    mcaps = sorted(source.glob("*.mcap"))
    return mcaps[0] if len(mcaps) == 1 else None


def _expected_counts(path: str | Path) -> dict[str, int] | None:
    """Messages per topic that a bag directory's metadata.yaml lists (None without a readable one)."""
    metadata = Path(path) / "metadata.yaml"
    if not metadata.is_file():
        return None
    try:
        info = yaml.safe_load(metadata.read_text())["rosbag2_bagfile_information"]
        return {
            entry["topic_metadata"]["name"]: int(entry["message_count"])
            for entry in info["topics_with_message_count"]
        }
    except (yaml.YAMLError, KeyError, TypeError, ValueError):
        return None


def _salvage(
    mcap_file: Path, shown: str | Path, wanted: set[str] | None, damage: BagDamage, error: str
) -> Iterator[tuple[str, str, int, bytes]]:
    """Messages of the readable part of a damaged MCAP file, sorted by time; fills ``damage``."""
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    found: list[tuple[int, int, str, str, bytes]] = []
    try:
        with open(mcap_file, "rb") as stream:
            for record in StreamReader(stream).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
                elif isinstance(record, Message) and record.channel_id in channels:
                    topic, msgtype = channels[record.channel_id]
                    if wanted is None or topic in wanted:
                        found.append((record.log_time, len(found), topic, msgtype, record.data))
        damage.error = error  # opened record by record to its end: only the summary was broken
    except (McapError, EOFError, ValueError, OSError) as exc:
        if not channels:
            raise BagError(f"{shown} is not a readable rosbag2/MCAP bag: {error}") from exc
        where = f"{type(exc).__name__} {exc}".strip()
        damage.error = f"{shown}: MCAP file damaged or cut short ({where}); read up to the damage"
    found.sort()
    damage.read.update(topic for _, _, topic, _, _ in found)

    def generate() -> Iterator[tuple[str, str, int, bytes]]:
        for timestamp, _, topic, msgtype, data in found:
            yield topic, msgtype, timestamp, bytes(data)

    return generate()


def bag_summary(path: str | Path) -> dict[str, tuple[str, int]]:
    """``{topic: (msgtype, message_count)}`` of the bag at ``path``, sorted by topic, from its index.

    A topic recorded with several types (not written by this module) lists them as ``"a|b"``.
    """
    with _open_reader(_bag_source(path), path) as reader:
        summary: dict[str, tuple[str, int]] = {}
        for connection in reader.connections:
            msgtype, count = summary.get(connection.topic, (connection.msgtype, 0))
            if connection.msgtype not in msgtype.split("|"):  # several types on one topic: "a|b"
                msgtype = f"{msgtype}|{connection.msgtype}"
            summary[connection.topic] = (msgtype, count + connection.msgcount)
        return dict(sorted(summary.items()))


def _check_topics(topics: Collection[str]) -> Collection[str]:
    if isinstance(topics, str):
        raise TypeError(
            f"topics must be a collection of topic names, got the string {topics!r}; use [{topics!r}]"
        )
    return topics


def _bag_source(path: str | Path) -> Path:
    """The path rosbags should open: the bag directory, or the .mcap file of a metadata-less directory."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag {path} does not exist")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return path
        mcaps = sorted(path.glob("*.mcap"))
        if len(mcaps) == 1:
            return mcaps[0]
        found = f"{len(mcaps)} .mcap files" if mcaps else "no .mcap file"
        raise BagError(
            f"{path} is not a bag: it has no metadata.yaml and {found}; pass a rosbag2 bag directory "
            "or a single .mcap file"
        )
    if path.suffix != ".mcap":
        raise BagError(f"{path} is not a bag: expected a rosbag2 directory or a .mcap file")
    return path


@contextmanager
def _open_reader(source: Path, shown: str | Path) -> Iterator[Reader]:
    """An open rosbags Reader of ``source``; its errors become BagError naming ``shown``."""
    try:
        reader = Reader(source)
        reader.open()
    except PermissionError as exc:
        raise BagError(f"{shown}: permission denied reading the bag ({exc.filename})") from exc
    except (ReaderError, OSError, ValueError, KeyError) as exc:
        raise BagError(f"{shown} is not a readable rosbag2/MCAP bag: {exc}") from exc
    try:
        yield reader
    finally:
        reader.close()
