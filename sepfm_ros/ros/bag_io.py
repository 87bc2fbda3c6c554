"""rosbag2 bags (mcap, the Jazzy default) on the pure-Python ``rosbags`` library, with typed errors.

Reading: :class:`BagReader` opens a bag directory (or a bare ``.mcap`` / ``.db3`` file) and turns
every failure into a :class:`BagError` subclass with a message meant for people: missing bag,
truncated or corrupt storage, missing topic, unknown message type, stamps out of order. Messages
come out as raw CDR bytes (:class:`RawMessage`) so they can be republished or copied unchanged.

Writing: :class:`BagWriter` never leaves an unreadable bag behind, even when the process is
killed (SIGKILL) mid-run. rosbags writes an mcap file's index and the bag's ``metadata.yaml`` only
when the writer is closed, so an interrupted plain writer leaves a bag nobody can open. Here the
bag is written as a *split bag* (several storage files, the way ``ros2 bag record
--max-bag-duration`` splits): messages go into a segment file that is closed (complete, indexed
mcap) whenever :meth:`BagWriter.flush` is called or ``flush_interval_s`` has passed, and after
every closed segment ``metadata.yaml`` is rewritten atomically (temporary file + rename) to list
all closed segments. A kill therefore loses only the messages written since the last flush, and
callers that must lose nothing (``process``) flush after every result. On a normal close the
segments are merged into one file (``metadata.yaml`` always lists only files that exist, see
:meth:`BagWriter._merge`), so a finished bag is one ``.mcap`` plus ``metadata.yaml``.

rosbags 0.11 writes mcap (``StoragePlugin.MCAP``), which is what this module uses by default.
"""

from __future__ import annotations

import os
import secrets
import shutil
import struct
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import Reader, StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)

GROUND_TRUTH_TOPIC = "/ground_truth/fundamental"


class BagError(Exception):
    """A bag problem with a message meant for the user (no traceback needed)."""


class BagNotFoundError(BagError):
    """The bag path does not exist or is not a bag."""


class BagCorruptError(BagError):
    """The bag's metadata or storage cannot be read (truncated, corrupt, unsupported)."""


class TopicNotFoundError(BagError):
    """A requested topic is not in the bag."""


class UnknownTypeError(BagError):
    """A message type is not known (not a ROS 2 Jazzy type) or not the type that was expected."""


class StampOrderError(BagError):
    """Header stamps of a topic go backwards or repeat."""


class OutputExistsError(BagError):
    """The output path exists already; nothing is overwritten."""


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


def header_stamp_ns(data: bytes) -> int:
    """Stamp (ns) of the std_msgs/Header that starts a CDR message (Image, PointCloud2, ...).

    The CDR encapsulation header (4 bytes) is followed by ``int32 sec, uint32 nanosec``; the
    second byte of the encapsulation says the byte order (1 = little endian).
    """
    if len(data) < 12:
        raise BagCorruptError(f"message of {len(data)} bytes is too short to hold a header")
    order = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


def has_header(msgtype: str) -> bool:
    """True when messages of ``msgtype`` start with a std_msgs/Header field."""
    try:
        fields = TYPESTORE.fielddefs[msgtype][1]
    except KeyError:
        return False
    if not fields:
        return False
    name, desc = fields[0]
    return name == "header" and "std_msgs/msg/Header" in str(desc)


class BagReader:
    """A read-only bag with typed errors. Use as a context manager.

    Args:
        path: a rosbag2 directory (``metadata.yaml`` + storage files) or one ``.mcap``/``.db3``.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagNotFoundError(f"bag not found: {self.path}")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise BagNotFoundError(f"{self.path} is not a rosbag2 bag (no metadata.yaml in it)")
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as err:  # noqa: BLE001 - rosbags raises many kinds on bad storage
            raise BagCorruptError(f"cannot read bag {self.path}: {err}") from None
        self.topics: dict[str, TopicInfo] = {}
        for conn in self._reader.connections:
            qos = (
                tuple(conn.ext.offered_qos_profiles)
                if hasattr(conn.ext, "offered_qos_profiles")
                else ()
            )
            old = self.topics.get(conn.topic)
            count = conn.msgcount + (old.count if old else 0)
            if old is not None and old.msgtype != conn.msgtype:
                raise BagCorruptError(
                    f"topic {conn.topic} has two types in {self.path}: "
                    f"{old.msgtype}, {conn.msgtype}"
                )
            self.topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, count, qos)

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

    def check_known_types(self, topics: Iterable[str]) -> None:
        """UnknownTypeError unless every topic's type is a ROS 2 Jazzy message type."""
        for topic in topics:
            msgtype = self.require(topic).msgtype
            if msgtype not in TYPESTORE.fielddefs:
                raise UnknownTypeError(
                    f"topic {topic} in bag {self.path} has message type {msgtype}, "
                    "which is not a ROS 2 Jazzy message type known here"
                )

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
                yield RawMessage(conn.topic, conn.msgtype, int(log_time), bytes(data))
        except Exception as err:  # noqa: BLE001 - corrupt storage raises many kinds (zstd, lz4, ...)
            raise BagCorruptError(
                f"bag {self.path} is corrupt: {type(err).__name__}: {err}"
            ) from None

    def deserialize(self, msg: RawMessage) -> Any:
        """A rosbags message object (field access like rclpy messages)."""
        try:
            return TYPESTORE.deserialize_cdr(msg.data, msg.msgtype)
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


def format_stamp(ns: int) -> str:
    """Nanoseconds -> ``sec.nanosec``."""
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"


def check_output_path(path: str | os.PathLike) -> Path:
    """OutputExistsError when ``path`` exists; the parent folder must exist or be creatable."""
    out = Path(path)
    if out.exists():
        raise OutputExistsError(f"output {out} exists already; not overwriting (remove it first)")
    return out


def _yaml() -> YAML:
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    return yaml


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf8") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


def remove_stale_scratch(final: Path) -> list[Path]:
    """Remove the hidden ``.NAME.creating-<pid>-*`` siblings of ``final`` whose process is gone.

    Such a folder is what a writer killed in its first milliseconds leaves (before the bag got
    its name, so before anything was written to it). Folders of live processes are kept.
    Returns the removed paths.
    """
    removed = []
    prefix = f".{final.name}.creating-"
    if not final.parent.is_dir():
        return removed
    for entry in final.parent.iterdir():
        if not entry.name.startswith(prefix) or not entry.is_dir():
            continue
        pid_text = entry.name[len(prefix) :].split("-", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed


@dataclass
class _Topic:
    name: str
    msgtype: str
    qos: tuple[Qos, ...]
    msgdef: str | None
    rihs01: str | None


class BagWriter:
    """Write a bag that stays readable if the process dies (see the module docstring).

    Args:
        path: output bag directory; must not exist (OutputExistsError).
        flush_interval_s: close the current segment automatically when this much wall time has
            passed since the last one (None: only on :meth:`flush` and :meth:`close`).
        compress: zstd-compress mcap chunks (readable by rosbags and ``ros2 bag``).
        merge: on :meth:`close`, merge the segments into one storage file.

    Use as a context manager, or call :meth:`close` (or :meth:`abort` to keep what was flushed).
    """

    def __init__(
        self,
        path: str | os.PathLike,
        flush_interval_s: float | None = 1.0,
        compress: bool = False,
        merge: bool = True,
    ) -> None:
        final = check_output_path(path)
        # the bag appears only complete: built as a hidden sibling with an empty metadata.yaml,
        # then renamed (a SIGKILL between mkdir and the first metadata left a folder that is no
        # bag; a kill now leaves either nothing under the name or a readable empty bag). What
        # such a kill left behind is removed when the name is written again.
        remove_stale_scratch(final)
        scratch = final.with_name(f".{final.name}.creating-{os.getpid()}-{secrets.token_hex(4)}")
        try:
            scratch.mkdir(parents=True)
        except OSError as err:
            raise BagError(f"cannot create output bag {final}: {err.strerror}") from None
        self.path = scratch
        self.flush_interval_s = flush_interval_s
        self.compress = compress
        self.merge = merge
        self._topics: dict[str, _Topic] = {}
        self._segments: list[dict[str, Any]] = []  # metadata of closed segments
        self._writer: Writer | None = None
        self._conns: dict[str, Connection] = {}
        self._pending = 0
        self._last_flush = time.monotonic()
        self._closed = False
        self._write_metadata()  # an empty, readable bag from the start
        try:
            os.rename(scratch, final)
        except OSError as err:
            shutil.rmtree(scratch, ignore_errors=True)
            raise BagError(f"cannot create output bag {final}: {err.strerror}") from None
        self.path = final

    # ------------------------------------------------------------------ topics
    def add_topic(
        self,
        topic: str,
        msgtype: str,
        qos: Sequence[Qos] = (),
        msgdef: str | None = None,
        rihs01: str | None = None,
    ) -> None:
        """Register a topic (a no-op when it exists with the same type).

        ``msgdef``/``rihs01`` default to the Jazzy typestore's; UnknownTypeError for other types.
        """
        old = self._topics.get(topic)
        if old is not None:
            if old.msgtype != msgtype:
                raise BagError(f"topic {topic} already has type {old.msgtype}, not {msgtype}")
            return
        if (msgdef is None or rihs01 is None) and msgtype not in TYPESTORE.fielddefs:
            raise UnknownTypeError(f"cannot write {topic}: unknown message type {msgtype}")
        self._topics[topic] = _Topic(topic, msgtype, tuple(qos), msgdef, rihs01)
        if self._writer is not None:
            self._connect(self._topics[topic])

    def _connect(self, t: _Topic) -> None:
        assert self._writer is not None
        kwargs: dict[str, Any] = {"offered_qos_profiles": list(t.qos)}
        if t.msgdef is not None and t.rihs01 is not None:
            kwargs.update(msgdef=t.msgdef, rihs01=t.rihs01)
        else:
            kwargs["typestore"] = TYPESTORE
        self._conns[t.name] = self._writer.add_connection(t.name, t.msgtype, **kwargs)

    # ------------------------------------------------------------------ writing
    def _segment_dir(self, index: int) -> Path:
        return self.path / f".segment_{index}"

    def _open_segment(self) -> None:
        seg_dir = self._segment_dir(len(self._segments))
        if seg_dir.exists():
            shutil.rmtree(seg_dir)
        writer = Writer(seg_dir, version=9, storage_plugin=StoragePlugin.MCAP)
        if self.compress:
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
        self._writer = writer
        self._conns = {}
        for t in self._topics.values():
            self._connect(t)

    def write(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Append one message (raw CDR bytes) of a registered topic."""
        if self._closed:
            raise BagError(f"bag {self.path} is closed")
        if topic not in self._topics:
            raise BagError(f"topic {topic} was not added to {self.path}")
        if self._writer is None:
            self._open_segment()
        assert self._writer is not None
        try:
            self._writer.write(self._conns[topic], int(log_time_ns), data)
        except WriterError as err:
            raise BagError(f"cannot write to {self.path}: {err}") from None
        self._pending += 1
        if (
            self.flush_interval_s is not None
            and time.monotonic() - self._last_flush >= self.flush_interval_s
        ):
            self.flush()

    def flush(self) -> None:
        """Close the current segment (if it holds messages) so it survives a kill."""
        self._last_flush = time.monotonic()
        if self._writer is None or self._pending == 0:
            return
        writer, self._writer = self._writer, None
        writer.close()
        index = len(self._segments)
        seg_dir = self._segment_dir(index)
        meta = _yaml().load((seg_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        name = f"{self.path.name}_{index}.mcap"
        src = seg_dir / meta["relative_file_paths"][0]
        with open(src, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(src, self.path / name)
        shutil.rmtree(seg_dir, ignore_errors=True)
        meta["relative_file_paths"] = [name]
        meta["files"][0]["path"] = name
        self._segments.append(meta)
        self._pending = 0
        _fsync_dir(self.path)
        self._write_metadata()

    def _write_metadata(self) -> None:
        """Write metadata.yaml listing every closed segment (atomically)."""
        segs = self._segments
        counts: dict[str, int] = {}
        topic_meta: dict[str, dict[str, Any]] = {}
        for seg in segs:
            for entry in seg["topics_with_message_count"]:
                name = entry["topic_metadata"]["name"]
                topic_meta.setdefault(name, entry["topic_metadata"])
                counts[name] = counts.get(name, 0) + int(entry["message_count"])
        starts = [s["starting_time"]["nanoseconds_since_epoch"] for s in segs if s["message_count"]]
        ends = [
            s["starting_time"]["nanoseconds_since_epoch"] + s["duration"]["nanoseconds"]
            for s in segs
            if s["message_count"]
        ]
        start = min(starts) if starts else 0
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "relative_file_paths": [s["relative_file_paths"][0] for s in segs],
            "duration": {"nanoseconds": (max(ends) - start) if ends else 0},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(int(s["message_count"]) for s in segs),
            "topics_with_message_count": [
                {"topic_metadata": topic_meta[n], "message_count": c} for n, c in counts.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "files": [s["files"][0] for s in segs],
            "custom_data": None,
            "ros_distro": "rosbags",
        }
        from io import StringIO

        buf = StringIO()
        _yaml().dump({"rosbag2_bagfile_information": info}, buf)
        _write_atomic(self.path / "metadata.yaml", buf.getvalue())

    def close(self) -> None:
        """Flush, then merge the segments into one file (when ``merge``)."""
        if self._closed:
            return
        self.flush()
        self._closed = True
        if self._writer is not None:  # opened but empty
            self._writer.close()
            self._writer = None
        for seg_dir in self.path.glob(".segment_*"):
            shutil.rmtree(seg_dir, ignore_errors=True)
        if self.merge and len(self._segments) > 1:
            self._merge()

    def abort(self) -> None:
        """Stop writing; keep what was flushed (the bag stays readable), drop the open segment."""
        if self._closed:
            return
        self._closed = True
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - dropping the unflushed segment anyway
                pass
            self._writer = None
        for seg_dir in self.path.glob(".segment_*"):
            shutil.rmtree(seg_dir, ignore_errors=True)

    def _merge(self) -> None:
        """Merge the segments into ``<name>_0.mcap``; the bag stays readable at every instant.

        The merged file is built in a scratch folder inside the bag, then ``metadata.yaml`` is
        switched to it atomically, the segments are deleted, the merged file gets its final name
        by a hard link, ``metadata.yaml`` is switched again, and the scratch name is removed.
        A kill at any point leaves a bag listing only files that exist.
        """
        scratch = self.path / ".merging"
        if scratch.exists():
            shutil.rmtree(scratch)
        with BagReader(self.path) as reader:
            writer = Writer(scratch, version=9, storage_plugin=StoragePlugin.MCAP)
            if self.compress:
                writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            writer.open()
            conns = {}
            for conn in reader._reader.connections:
                if conn.topic in conns:
                    continue
                ext = conn.ext
                conns[conn.topic] = writer.add_connection(
                    conn.topic,
                    conn.msgtype,
                    msgdef=conn.msgdef.data,
                    rihs01=conn.digest,
                    offered_qos_profiles=ext.offered_qos_profiles
                    if isinstance(ext, ConnectionExtRosbag2)
                    else (),
                )
            for msg in reader.messages():
                writer.write(conns[msg.topic], msg.log_time_ns, msg.data)
            writer.close()
        meta = _yaml().load((scratch / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        final = f"{self.path.name}_0.mcap"
        temp = f"{self.path.name}_merged.mcap"
        src = scratch / info["relative_file_paths"][0]
        with open(src, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(src, self.path / temp)
        shutil.rmtree(scratch, ignore_errors=True)

        def point_to(name: str) -> None:
            info["relative_file_paths"] = [name]
            info["files"][0]["path"] = name
            from io import StringIO

            buf = StringIO()
            _yaml().dump(meta, buf)
            _write_atomic(self.path / "metadata.yaml", buf.getvalue())
            _fsync_dir(self.path)

        point_to(temp)  # readable: the merged file only
        for seg in self._segments:
            (self.path / seg["relative_file_paths"][0]).unlink(missing_ok=True)
        os.link(self.path / temp, self.path / final)
        point_to(final)
        (self.path / temp).unlink()
        _fsync_dir(self.path)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None or exc_type in (KeyboardInterrupt, SystemExit):
            self.close()
        else:
            self.abort()


def write_bag(path: str | os.PathLike, messages: Iterable[RawMessage], **kwargs: Any) -> None:
    """Write ``messages`` (registering their topics on first sight) into a new bag at ``path``."""
    with BagWriter(path, **kwargs) as writer:
        for msg in messages:
            writer.add_topic(msg.topic, msg.msgtype)
            writer.write(msg.topic, msg.log_time_ns, msg.data)
