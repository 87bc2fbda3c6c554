"""Writing bags that stay readable if the process dies: :class:`BagWriter`.

rosbags writes an mcap file's index and the bag's ``metadata.yaml`` only when the writer is
closed, so an interrupted plain writer leaves a bag nobody can open. Here the bag is written as a
*split bag* (several storage files, the way ``ros2 bag record --max-bag-duration`` splits):
messages go into a segment file that is closed (complete, indexed mcap) whenever
:meth:`BagWriter.flush` is called or ``flush_interval_s`` has passed, and after every closed
segment ``metadata.yaml`` is rewritten atomically (temporary file + rename) to list all closed
segments. A kill therefore loses only the messages written since the last flush, and callers
that must lose nothing (``process``) flush after every result. On a normal close the segments are
merged into one file (``metadata.yaml`` always lists only files that exist, see
:meth:`BagWriter._merge`), so a finished bag is one ``.mcap`` plus ``metadata.yaml``.

rosbags 0.11 writes mcap (``StoragePlugin.MCAP``), which is what this module uses.
"""

from __future__ import annotations

import os
import secrets
import shutil
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from io import StringIO
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from sepfm_ros.ros.bags.crash_safety import (
    fsync_dir,
    remove_stale_scratch,
    safe_yaml,
    write_atomic,
)
from sepfm_ros.ros.bags.errors import BagError, OutputExistsError, UnknownTypeError
from sepfm_ros.ros.bags.reader import BagReader, RawMessage
from sepfm_ros.ros.bags.types import SEPFM_MSGS, TYPESTORE

# file names of storage formats this writer does not write (it writes a rosbag2 folder, mcap)
_OTHER_FORMATS = {".bag": "a ROS 1 bag file", ".db3": "a rosbag2 sqlite3 file"}


def check_output_path(path: str | os.PathLike) -> Path:
    """The output bag's path, checked before any work: OutputExistsError when it exists,
    BagError when its name says another format than the one written (a rosbag2 folder of
    mcap storage): ``out.bag`` would be a folder that every reader takes for a ROS 1 file."""
    out = Path(path)
    what = _OTHER_FORMATS.get(out.suffix.lower())
    if what is not None:
        raise BagError(
            f"output {out} names {what}, but the output is a rosbag2 bag (a folder holding mcap "
            f"storage): give a folder name without {out.suffix}, e.g. {out.with_suffix('')}"
            + (
                f" (rosbags-convert --src {out.with_suffix('')} --dst {out} makes a ROS 1 bag "
                "of it)"
                if out.suffix.lower() == ".bag"
                else ""
            )
        )
    if out.exists():
        raise OutputExistsError(f"output {out} exists already; not overwriting (remove it first)")
    return out


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
            hint = ""
            if msgtype.startswith(f"{SEPFM_MSGS}/"):
                hint = f" ({SEPFM_MSGS} is not installed: pip install ./{SEPFM_MSGS})"
            raise UnknownTypeError(f"cannot write {topic}: unknown message type {msgtype}{hint}")
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
        meta = safe_yaml().load((seg_dir / "metadata.yaml").read_text())[
            "rosbag2_bagfile_information"
        ]
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
        fsync_dir(self.path)
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
        buf = StringIO()
        safe_yaml().dump({"rosbag2_bagfile_information": info}, buf)
        write_atomic(self.path / "metadata.yaml", buf.getvalue())

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
                qos = ext.offered_qos_profiles if isinstance(ext, ConnectionExtRosbag2) else ()
                if conn.msgtype in reader.migrated:  # read as today's type: stored as such
                    conns[conn.topic] = writer.add_connection(
                        conn.topic, conn.msgtype, typestore=TYPESTORE, offered_qos_profiles=qos
                    )
                    continue
                conns[conn.topic] = writer.add_connection(
                    conn.topic,
                    conn.msgtype,
                    msgdef=conn.msgdef.data,
                    rihs01=conn.digest,
                    offered_qos_profiles=qos,
                )
            for msg in reader.messages():
                writer.write(conns[msg.topic], msg.log_time_ns, msg.data)
            writer.close()
        meta = safe_yaml().load((scratch / "metadata.yaml").read_text())
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
            buf = StringIO()
            safe_yaml().dump(meta, buf)
            write_atomic(self.path / "metadata.yaml", buf.getvalue())
            fsync_dir(self.path)

        point_to(temp)  # readable: the merged file only
        for seg in self._segments:
            (self.path / seg["relative_file_paths"][0]).unlink(missing_ok=True)
        os.link(self.path / temp, self.path / final)
        point_to(final)
        (self.path / temp).unlink()
        fsync_dir(self.path)

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
