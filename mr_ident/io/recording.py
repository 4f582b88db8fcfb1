# SPDX-License-Identifier: Apache-2.0
"""MCAP recordings in rosbag2 (Jazzy) form, and their offline replay. No ROS import.

Writing (:class:`McapRecorder`) takes CDR bytes that rclpy produced (a raw
subscription) and stores them the way rosbag2's MCAP storage plugin does:
profile ``ros2``; one schema per type, encoding ``ros2msg``, holding the type's
``.msg`` text followed by every nested type's, each after a line of 80 ``=``
and ``MSG: pkg/Type``; message encoding ``cdr``; channel metadata
``offered_qos_profiles`` (YAML list of the publishers' QoS) and
``topic_type_hash`` (RIHS01). Log and publish times are in ns. Chunks are
zstd-compressed and closed every ``chunk_size`` bytes or, with ``chunk_s``, once their
first message is that old (wall clock), and the file is flushed to the operating system
at every chunk: a file cut short (a crash, SIGKILL) is readable up to its last finished
chunk. With ``exclusive`` an existing file is never opened (:func:`fresh_path` names a
new one).

Reading (:func:`read_blocks`) decodes MCAP files with the independent ``mcap_ros2``
decoder and tolerates a truncated file (it reports how much was recovered); SQLite3 and
zstd-compressed bags are read through :class:`~mr_ident.io.bags.Bag`, each block's CDR
decoded by :func:`~mr_ident.io.blocks.cdr_fields`. :mod:`mr_ident.live.replay` runs what
it reads through the node's own steps.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError, MrIdentError
from .blocks import BLOCK_TYPE, STREAMS, Block, BlockError, cdr_fields, decode_block
from .msgdef import message_definition, type_hash

if TYPE_CHECKING:
    from mcap.records import Channel, Message, Schema

    from .bags import Bag


def qos_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """``offered_qos_profiles`` metadata: one YAML list entry per publisher.

    Each profile maps history, depth, reliability, durability, deadline, lifespan,
    liveliness, liveliness_lease_duration, avoid_ros_namespace_conventions; policy
    values are lower-case names (``keep_last``, ``reliable``, ...) and durations
    ``{sec, nsec}``, as rosbag2 Jazzy writes them.
    """
    lines = []
    for p in profiles:
        first = True
        for key in (
            "history",
            "depth",
            "reliability",
            "durability",
            "deadline",
            "lifespan",
            "liveliness",
            "liveliness_lease_duration",
            "avoid_ros_namespace_conventions",
        ):
            v = p[key]
            lead = "- " if first else "  "
            first = False
            if isinstance(v, Mapping):
                lines.append(f"{lead}{key}:")
                lines.append(f"    sec: {int(v['sec'])}")
                lines.append(f"    nsec: {int(v['nsec'])}")
            elif isinstance(v, bool):
                lines.append(f"{lead}{key}: {'true' if v else 'false'}")
            else:
                lines.append(f"{lead}{key}: {v}")
    return "\n".join(lines) if lines else "[]"


def fresh_path(path: str | Path) -> Path:
    """``path`` if no file is there, else the first free ``<stem>_<k><suffix>`` (k = 1, 2...)."""
    p = Path(path)
    k = 0
    while (cand := p if k == 0 else p.with_name(f"{p.stem}_{k}{p.suffix}")).exists():
        k += 1
    return cand


class McapRecorder:
    """Thread-safe rosbag2-compatible MCAP writer (see the module docstring).

    Use as a context manager, or call :meth:`close`; ``close`` is idempotent and
    finalises the file (summary, footer), so call it from signal handlers' paths.
    ``exclusive``: raise FileExistsError rather than truncate an existing file.
    ``chunk_s``: a chunk is closed once its first message is this many seconds old, at
    the next :meth:`write` or :meth:`tick` (None: by size only).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = 1 << 20,
        chunk_s: float | None = None,
        exclusive: bool = False,
        library: str | None = None,
    ):
        from mcap.writer import CompressionType, Writer

        from ..version import __version__

        self.path = Path(path)
        self._fh: IO[bytes] | None = open(self.path, "xb" if exclusive else "wb")
        self._chunk_s = chunk_s
        self._chunk_started: float | None = None  # monotonic time of the open chunk's first
        self._chunks = 0
        self._writer = Writer(self._fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile="ros2", library=library or f"mr_ident {__version__}")
        self._lock = threading.Lock()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self.messages = 0
        self.error: OSError | None = None

    def add_topic(self, topic: str, type_name: str, qos: Sequence[Mapping[str, Any]]) -> int:
        """Register ``topic`` of ``type_name`` (pkg/msg/Type); returns the channel id."""
        with self._lock:
            if topic in self._channels:
                return self._channels[topic]
            if self._fh is None:
                raise MrIdentError(f"recording {self.path} is closed")
            if type_name not in self._schemas:
                self._schemas[type_name] = self._writer.register_schema(
                    name=type_name, encoding="ros2msg", data=message_definition(type_name).encode()
                )
            cid = self._writer.register_channel(
                topic=topic,
                message_encoding="cdr",
                schema_id=self._schemas[type_name],
                metadata={
                    "offered_qos_profiles": qos_yaml(qos),
                    "topic_type_hash": type_hash(type_name),
                },
            )
            self._channels[topic] = cid
            self._seq[cid] = 0
            return cid

    def write(
        self, channel: int, data: bytes, log_time_ns: int, publish_time_ns: int | None = None
    ) -> bool:
        """Append one serialized message; False once the file is closed or failed."""
        with self._lock:
            if self._fh is None or self.error is not None:
                return False
            try:
                self._writer.add_message(
                    channel,
                    log_time=log_time_ns,
                    data=data,
                    publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
                    sequence=self._seq[channel],
                )
                self._after_message()
            except OSError as err:  # e.g. disk full: keep what the finished chunks hold
                self.error = err
                return False
            self._seq[channel] += 1
            self.messages += 1
            return True

    def _after_message(self) -> None:
        if self._chunk_started is None:
            self._chunk_started = time.monotonic()
        self._chunk_due()

    def _chunk_due(self) -> None:
        """An open chunk past ``chunk_s`` closed; a chunk written goes to the OS at once."""
        assert self._fh is not None
        old = self._chunk_started is not None and time.monotonic() - self._chunk_started
        if self._chunk_s is not None and old is not False and old >= self._chunk_s:
            self._writer._Writer__finalize_chunk()  # type: ignore[attr-defined]
        count = self._writer._Writer__statistics.chunk_count  # type: ignore[attr-defined]
        if count != self._chunks:  # a chunk was written (by size or age): flush it now
            self._chunks, self._chunk_started = count, None
            self._fh.flush()

    def tick(self) -> None:
        """Close the open chunk when it is past ``chunk_s`` (a timer's call, between messages)."""
        with self._lock:
            if self._fh is None or self.error is not None:
                return
            try:
                self._chunk_due()
            except OSError as err:
                self.error = err

    @property
    def failure(self) -> str:
        """What stopped the recording ("" if nothing), for a log line or an error."""
        if self.error is None:
            return ""
        return (
            f"writing {self.path} failed after {self.messages} messages: "
            f"{self.error.strerror or self.error}; the file is readable up to its last finished "
            "chunk"
        )

    def close(self) -> None:
        """Finalise the file (summary, footer); idempotent."""
        with self._lock:
            if self._fh is None:
                return
            fh, self._fh = self._fh, None
            try:
                if self.error is None:
                    self._writer.finish()  # type: ignore[no-untyped-call]
            except OSError as err:
                self.error = err
            finally:
                try:
                    fh.close()
                except OSError as err:  # the buffered tail did not fit either
                    self.error = self.error or err

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# -- reading --------------------------------------------------------------------------
@dataclass
class RecordingInfo:
    """What :func:`read_blocks` found: messages per topic, and whether the file was cut short."""

    messages: dict[str, int] = field(default_factory=dict)
    truncated: bool = False
    bytes_read: int = 0
    file_bytes: int = 0
    reason: str = ""
    span: tuple[int, int] = (0, 0)  # recorded_signals: the aligned index span returned
    broken: str = ""  # recorded_signals: why earlier samples were left out ("" if none)


def _stream_names(topics: Sequence[str] | None, labels: str = "") -> list[str]:
    """The names of the streams' topics: r, u, y (``topics`` or the default), the labels."""
    return list(topics or STREAMS) + ([labels] if labels else [])


def matches_topic(topic: str, want: str, exact: bool) -> bool:
    """Whether recorded ``topic`` is the stream topic ``want`` (leading "/" ignored).

    ``exact``: the names are equal; else ``topic`` ends in ``want``'s name components
    (``/loop/reference`` is ``reference``; ``/loop/reference/excitation_index`` is
    ``reference/excitation_index``).
    """
    name, want = topic.strip("/"), want.strip("/")
    return name == want or (not exact and name.endswith("/" + want))


def _stream_of_topic(topic: str, topics: Sequence[str] | None, labels: str = "") -> int | None:
    """Stream number (0 r, 1 u, 2 y, 3 the labels) of a recorded topic, or None.

    With ``topics`` given, names must match exactly; otherwise by their last name
    components (:func:`matches_topic`).
    """
    for s, want in enumerate(_stream_names(topics, labels)):
        if matches_topic(topic, want, exact=bool(topics)):
            return s
    return None


def _plain_mcap(path: Path) -> bool:
    return not path.name.endswith((".db3", ".zstd"))


#: One decoded message: (stream, log time in ns, the block or why it is not one).
Item = tuple[int, int, Block | BlockError]


def _bag_blocks(
    bag: Bag, topics: Sequence[str] | None, labels: str = ""
) -> tuple[list[Item], RecordingInfo, list[str]]:
    """:func:`read_blocks` for an SQLite3 or zstd-compressed bag: through :class:`Bag`."""
    types = bag.scanned_topics()
    stream_of: dict[str, int] = {}
    for name, t in types.items():
        s = _stream_of_topic(name, topics, labels)
        if s is None:
            continue
        if t.type != BLOCK_TYPE:
            raise DataError(
                f"{bag.path}: topic {name!r} has schema {t.type!r}, expected {BLOCK_TYPE}"
            )
        stream_of[name] = s
    found = sorted(types)
    missing = [
        n for s, n in enumerate(_stream_names(topics, labels)) if s not in set(stream_of.values())
    ]
    if missing:
        raise DataError(f"{bag.path}: topic(s) {missing} not in the recording; it holds {found}")
    items: list[Item] = []
    for topic, batch, sent in bag.batches(set(stream_of)):
        for i in range(batch.size):  # a block holds many samples: few messages
            o, n = int(batch.offset[i]), int(batch.length[i])
            try:
                item: Block | BlockError = decode_block(
                    *cdr_fields(batch.buf[o : o + n].tobytes())
                )
            except BlockError as err:
                item = err
            items.append((stream_of[topic], int(sent[i]), item))
    items.sort(key=lambda it: it[1])  # a batch holds one topic after the other: by time
    cut = bag.cut
    info = RecordingInfo(
        messages=dict(bag.read),
        truncated=bool(cut),
        reason="; ".join(cut),
        file_bytes=sum(f.stat().st_size for f in bag.files),
    )
    info.bytes_read = info.file_bytes
    return items, info, found


def read_blocks(
    path: str | Path, topics: Sequence[str] | None = None, labels: str = ""
) -> tuple[list[Item], RecordingInfo, list[str]]:
    """Decode the block messages of an MCAP recording, in file order.

    Returns ``(items, info, topics_found)``; each item is ``(stream, log_time_ns,
    Block or BlockError)``. ``topics`` names the r, u, y topics (default: the
    topics whose last name component is reference, input, output); ``labels`` the topic
    of an excitation's labels, stream 3 (matched as ``topics``; "": none). A plain MCAP
    file is scanned here; a rosbag2 directory of MCAP files file by file; other bags
    through :class:`~mr_ident.io.bags.Bag`.

    Raises
    ------
    DataError
        Not an MCAP file, no readable message, a stream topic missing, or a topic
        whose schema is not std_msgs/msg/Float64MultiArray.
    """
    p = Path(path)
    if not p.is_dir() and _plain_mcap(p):
        return _mcap_blocks(p, topics, labels)
    from .bags import Bag

    bag = Bag.open(p)
    if not all(_plain_mcap(f) for f in bag.files):
        return _bag_blocks(bag, topics, labels)
    # a rosbag2 directory of MCAP files: each in order
    return _joined([_mcap_blocks(f, topics, labels) for f in bag.files])


def _joined(
    parts: list[tuple[list[Item], RecordingInfo, list[str]]],
) -> tuple[list[Item], RecordingInfo, list[str]]:
    """The files of one recording as one: items in file order, counts summed."""
    infos = [info for _, info, _ in parts]
    info = RecordingInfo(
        file_bytes=sum(i.file_bytes for i in infos), bytes_read=sum(i.bytes_read for i in infos)
    )
    for i in infos:
        for k, v in i.messages.items():
            info.messages[k] = info.messages.get(k, 0) + v
        if i.truncated:
            info.truncated, info.reason = True, i.reason
    found = sorted({t for _, _, topics in parts for t in topics})
    return [it for items, _, _ in parts for it in items], info, found


def _mcap_blocks(
    p: Path, topics: Sequence[str] | None, labels: str
) -> tuple[list[Item], RecordingInfo, list[str]]:
    """:func:`read_blocks` of one plain MCAP file: its records scanned in order."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    scan = _McapScan(p, topics, labels)
    info = RecordingInfo()
    try:
        info.file_bytes = p.stat().st_size
        fh = open(p, "rb")
    except OSError as err:
        raise DataError(f"cannot read recording {str(p)!r}: {err.strerror}") from err
    with fh:
        head = fh.read(8)
        fh.seek(0)
        if head != b"\x89MCAP0\r\n":
            raise DataError(f"{p}: not an MCAP file (bad magic)")
        info.bytes_read = len(head)
        reader = StreamReader(fh, skip_magic=False)
        try:
            for rec in reader.records:
                if isinstance(rec, Schema):
                    scan.schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    scan.channel(rec)
                elif isinstance(rec, Message):
                    scan.message(rec, info)
                info.bytes_read = fh.tell()
        except DataError:
            raise
        except (
            Exception
        ) as err:  # cut short or corrupt: keep what was read (McapError, EOF, struct)
            info.truncated, info.reason = True, _cut_reason(err, info.bytes_read)
    found = sorted({c.topic for c in scan.channels.values()})
    if not scan.channels:
        raise DataError(
            f"{p}: no channel could be read ({info.reason or 'the file holds none'}; "
            f"file of {info.file_bytes} bytes): nothing to recover"
        )
    streams = set(scan.stream_of.values())
    missing = [name for s, name in enumerate(_stream_names(topics, labels)) if s not in streams]
    if missing:
        raise DataError(f"{p}: topic(s) {missing} not in the recording; it holds {found}")
    return scan.items, info, found


def _cut_reason(err: Exception, bytes_read: int) -> str:
    """Why the scan of a file stopped at ``bytes_read`` (``RecordingInfo.reason``)."""
    detail = str(err).strip()
    if type(err).__name__ == "EndOfFile":
        return f"the file ends inside a record after byte {bytes_read}"
    return (
        f"unreadable record after byte {bytes_read} "
        f"({type(err).__name__}{': ' + detail if detail else ''})"
    )


class _McapScan:
    """The records of one MCAP file, in order: schemas, channels, and the streams' blocks."""

    def __init__(self, path: Path, topics: Sequence[str] | None, labels: str) -> None:
        from mcap_ros2.decoder import DecoderFactory

        self.path, self.topics, self.labels = path, topics, labels
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.decoders: dict[int, Any] = {}
        self.stream_of: dict[int, int] = {}  # channel id -> stream (its topic's)
        self.items: list[Item] = []
        self.factory = DecoderFactory()

    def message(self, rec: Message, info: RecordingInfo) -> None:
        """Count a message of a known channel; decode it when its topic is a stream's."""
        ch = self.channels.get(rec.channel_id)
        if ch is None:
            return
        info.messages[ch.topic] = info.messages.get(ch.topic, 0) + 1
        if rec.channel_id in self.stream_of:
            item = self._decoded(self.decoders[rec.channel_id], rec.data)
            self.items.append((self.stream_of[rec.channel_id], rec.log_time, item))

    def channel(self, rec: Channel) -> None:
        """Keep a channel; a stream's topic must carry blocks (its decoder made)."""
        self.channels[rec.id] = rec
        s = _stream_of_topic(rec.topic, self.topics, self.labels)
        if s is None:
            return
        schema = self.schemas.get(rec.schema_id)
        if schema is None or schema.name != BLOCK_TYPE:
            raise DataError(
                f"{self.path}: topic {rec.topic!r} has schema "
                f"{schema.name if schema else '(none)'!r}, expected "
                "std_msgs/msg/Float64MultiArray"
            )
        self.stream_of[rec.id] = s
        self.decoders[rec.id] = self.factory.decoder_for(rec.message_encoding, schema)

    @staticmethod
    def _decoded(decoder: Any, data: bytes) -> Block | BlockError:
        """One message's block, or why it is none (undecodable CDR counts as malformed)."""
        try:
            msg = decoder(data)
            dims = [(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim]
            return decode_block(
                dims, int(msg.layout.data_offset), np.asarray(msg.data, dtype=float)
            )
        except BlockError as err:
            return err
        except Exception as err:  # undecodable CDR: count it as malformed
            return BlockError("malformed", f"undecodable message: {err}")
