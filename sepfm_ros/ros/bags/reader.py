"""Reading bags with typed errors: :class:`BagReader` and the per-topic :class:`StampChecker`.

Every failure becomes a :class:`~sepfm_ros.ros.bags.errors.BagError` subclass with a message
meant for people: missing bag, truncated or corrupt storage, missing topic, unknown message type,
stamps out of order. Messages come out as raw CDR bytes (:class:`RawMessage`) so they can be
republished or copied unchanged.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from rosbags.convert.converter import (
    LATCH,
    STATIC_MSGTYPE_RENAMES,
    is_same_wireformat,
    migrate_bytes,
)
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import Reader as Reader2
from rosbags.typesys import Stores, get_typestore

from sepfm_ros.ros.bags.errors import (
    BagCorruptError,
    BagNotFoundError,
    StampOrderError,
    TopicNotFoundError,
    UnknownTypeError,
)
from sepfm_ros.ros.bags.types import TYPESTORE, format_stamp


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: name, type (``pkg/msg/Name``), message count, offered QoS."""

    name: str
    msgtype: str
    count: int
    qos: tuple[Qos, ...]


@dataclass(frozen=True)
class RawMessage:
    """One message as stored: topic, type, log time (ns since epoch) and CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


BAG_SUFFIXES = (".mcap", ".db3", ".bag")


class BagReader:
    """A read-only bag with typed errors, on rosbags' ``AnyReader``. Use as a context manager.

    Reads rosbag2 bags (sqlite3 or mcap: a directory with ``metadata.yaml``, or one bare
    ``.mcap``/``.db3`` file) and ROS 1 bags (one ``.bag`` file). ROS 1 messages are converted to
    ROS 2 CDR as they are read (types from the bag's own definitions, ``Header.seq`` dropped,
    ``tf/tfMessage`` renamed to ``tf2_msgs/msg/TFMessage``, the way ``rosbags-convert`` does), so
    every :class:`RawMessage` holds CDR bytes whatever the format. A rosbag2 message whose type
    the bag defines otherwise than today's types (an older ``sepfm_msgs``) is migrated to
    today's definition as it is read (``_prepare_ros2``).

    Args:
        path: the bag (see above).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagNotFoundError(f"bag not found: {self.path}")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise BagNotFoundError(f"{self.path} is not a rosbag2 bag (no metadata.yaml in it)")
        if self.path.is_file() and self.path.suffix not in BAG_SUFFIXES:
            raise BagNotFoundError(
                f"{self.path} is not a bag: expected a rosbag2 folder or a "
                f"{', '.join(BAG_SUFFIXES)} file"
            )
        self._reader: AnyReader | Reader2 = self._open()
        self.is_ros1 = isinstance(self._reader, AnyReader) and not self._reader.is2
        self.typestore = TYPESTORE
        self._to_cdr: dict[str, Callable[[bytes], bytes]] = {}
        self._msgtype: dict[int, str] = {}  # connection id -> ROS 2 type name
        #: rosbag2 types read as today's definition, not the bag's (``_prepare_ros2``)
        self.migrated: set[str] = set()
        if self.is_ros1:
            try:
                self._prepare_ros1()
            except Exception as err:  # noqa: BLE001 - bad definitions in the bag
                self._reader.close()
                raise BagCorruptError(
                    f"cannot read the message definitions of {self.path}: {err}"
                ) from None
        elif isinstance(self._reader, AnyReader):
            self._prepare_ros2()
        self.topics: dict[str, TopicInfo] = {}
        for conn in self._reader.connections:
            msgtype = self._ros2_type(conn)
            qos: tuple[Qos, ...] = ()
            if hasattr(conn.ext, "offered_qos_profiles"):
                qos = tuple(conn.ext.offered_qos_profiles)
            elif getattr(conn.ext, "latching", 0):
                qos = tuple(LATCH)
            old = self.topics.get(conn.topic)
            count = conn.msgcount + (old.count if old else 0)
            if old is not None and old.msgtype != msgtype:
                self._reader.close()
                raise BagCorruptError(
                    f"topic {conn.topic} has two types in {self.path}: {old.msgtype}, {msgtype}"
                )
            self.topics[conn.topic] = TopicInfo(conn.topic, msgtype, count, qos)

    def _open(self) -> AnyReader | Reader2:
        """AnyReader; for a rosbag2 bag whose stored definitions rosbags cannot parse or verify
        (messages are CDR and read with the Jazzy types anyway), the plain rosbag2 reader."""
        try:
            reader = AnyReader([self.path], default_typestore=TYPESTORE)
            reader.open()
            return reader
        except Exception as err:  # noqa: BLE001 - rosbags raises many kinds on bad storage
            first = err
        if self.path.suffix != ".bag":
            try:
                plain = Reader2(self.path)
                plain.open()
                return plain
            except Exception:  # noqa: BLE001 - report AnyReader's error, the first cause
                pass
        raise BagCorruptError(f"cannot read bag {self.path}: {first}") from None

    def _ros2_type(self, conn: Connection) -> str:
        return self._msgtype.get(conn.id, conn.msgtype)

    def _prepare_ros1(self) -> None:
        """Converters ROS 1 bytes -> ROS 2 CDR per message type, as ``rosbags-convert`` builds them.

        Types known to ROS 2 Jazzy keep Jazzy's definition (what rclpy deserialises); others
        take the bag's own definition. Where the two differ in wire format, fields are migrated
        by name.
        """
        src = self._reader.typestore
        dst = get_typestore(Stores.EMPTY)
        dst.register(TYPESTORE.fielddefs)
        extra = {k: v for k, v in src.fielddefs.items() if k not in TYPESTORE.fielddefs}
        extra.pop("std_msgs/msg/Header", None)
        dst.register(extra)
        cache: dict[str, object] = {}
        for conn in self._reader.connections:
            msgtype = STATIC_MSGTYPE_RENAMES.get(conn.msgtype, conn.msgtype)
            self._msgtype[conn.id] = msgtype
            if conn.msgtype in self._to_cdr:
                continue
            if is_same_wireformat(src, dst, conn.msgtype, msgtype):
                self._to_cdr[conn.msgtype] = partial(dst.ros1_to_cdr, typename=msgtype)
            else:
                self._to_cdr[conn.msgtype] = partial(
                    migrate_bytes,
                    src,
                    dst,
                    conn.msgtype,
                    msgtype,
                    cache,
                    src_is2=False,
                    dst_is2=True,
                )
        self.typestore = dst

    def _prepare_ros2(self) -> None:
        """Converters for the rosbag2 types whose stored definition differs in wire format from
        today's (a bag written with an older sepfm_msgs: the ``TwoViewEstimate`` of 0.1.0 has no
        ``line_search_skipped``): fields are migrated by name, new fields take their defaults,
        so rclpy deserialises every message with today's types. Bags without stored
        definitions are read with today's types as they are."""
        src = self._reader.typestore
        cache: dict[str, object] = {}
        for conn in self._reader.connections:
            msgtype = conn.msgtype
            if msgtype in self._to_cdr or msgtype not in TYPESTORE.fielddefs:
                continue
            try:
                same = is_same_wireformat(src, TYPESTORE, msgtype, msgtype)
            except KeyError:  # a nested type the bag does not define: read as stored
                continue
            if not same:
                self.migrated.add(msgtype)
                self._to_cdr[msgtype] = partial(
                    migrate_bytes, src, TYPESTORE, msgtype, msgtype, cache,
                    src_is2=True, dst_is2=True,
                )  # fmt: skip

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._reader.close()

    @property
    def start_time_ns(self) -> int:
        return int(self._reader.start_time) if self.message_count else 0

    @property
    def end_time_ns(self) -> int:
        return int(self._reader.end_time) if self.message_count else 0

    @property
    def message_count(self) -> int:
        return int(self._reader.message_count)

    def resolve(self, topic: str) -> str:
        """The bag's own spelling of ``topic``, matched with or without the leading slash.

        ROS 1 bags and some recorders store names without it (``camera/left/image_raw``) while
        users, image_transport and other topics of the same bag write ``/camera/...``; both
        name one topic. Returns ``topic`` unchanged when the bag has neither spelling.
        """
        if topic in self.topics:
            return topic
        other = topic[1:] if topic.startswith("/") else "/" + topic
        return other if other in self.topics else topic

    def require(self, topic: str, types: Sequence[str] = ()) -> TopicInfo:
        """The topic's info; TopicNotFoundError / UnknownTypeError if absent or of a wrong type."""
        info = self.topics.get(topic)
        if info is None:
            have = ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(self.topics.items()))
            raise TopicNotFoundError(
                f"topic {topic} is not in bag {self.path}; it has: {have or 'no topics'}"
            )
        if types and info.msgtype not in types:
            raise UnknownTypeError(
                f"topic {topic} in bag {self.path} has type {info.msgtype}; "
                f"expected {' or '.join(types)}"
            )
        return info

    def messages(
        self, topics: Iterable[str] | None = None, start_ns: int | None = None
    ) -> Iterator[RawMessage]:
        """Messages of ``topics`` (all when None) in log-time order, as raw CDR bytes."""
        wanted = None if topics is None else set(topics)
        conns = [c for c in self._reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        try:
            for conn, log_time, data in self._reader.messages(conns, start=start_ns):
                convert = self._to_cdr.get(conn.msgtype)
                if convert is not None:  # ROS 1, or an older definition of a type
                    data = convert(data)
                yield RawMessage(conn.topic, self._ros2_type(conn), int(log_time), bytes(data))
        except Exception as err:  # noqa: BLE001 - corrupt storage raises many kinds (zstd, lz4, ...)
            raise BagCorruptError(
                f"bag {self.path} is corrupt: {type(err).__name__}: {err}"
            ) from None

    def deserialize(self, msg: RawMessage) -> Any:
        """A rosbags message object (field access like rclpy messages)."""
        try:
            return self.typestore.deserialize_cdr(msg.data, msg.msgtype)
        except KeyError:
            raise UnknownTypeError(f"unknown message type {msg.msgtype}") from None
        except Exception as err:  # rosbags raises several kinds on bad CDR
            raise BagCorruptError(
                f"cannot decode a {msg.msgtype} message on {msg.topic} at {msg.log_time_ns} ns: "
                f"{err}"
            ) from None


class StampChecker:
    """Checks that header stamps increase strictly, per topic (StampOrderError otherwise)."""

    def __init__(self) -> None:
        self._last: dict[str, int] = {}

    def check(self, topic: str, stamp_ns: int, index: int | None = None) -> None:
        last = self._last.get(topic)
        if last is not None and stamp_ns <= last:
            what = "repeats" if stamp_ns == last else "goes backwards from"
            where = f" (message {index})" if index is not None else ""
            raise StampOrderError(
                f"header stamps on {topic} are not increasing: {format_stamp(stamp_ns)}{where} "
                f"{what} {format_stamp(last)}"
            )
        self._last[topic] = stamp_ns
