"""Bags: rosbag2 directories and bare MCAP files, read chunk by chunk for speed.

A bag is either a rosbag2 directory (``metadata.yaml`` lists its files in
``relative_file_paths``; split bags are read in that order) or one ``.mcap`` file (written
by ``ros2 bag record``, ``rosbags``, ``mcap_ros2`` or ``mr-ident record``). SQLite
(``.db3``) bags are refused with the command that converts them. A directory without
``metadata.yaml`` (a recording that was killed) is read file by file in name order.

Reading is organised for speed: the MCAP summary lists the chunks; each chunk is read and
decompressed once, and its message index gives, per channel, the offset of every
message, so that a channel's messages of one chunk are one :class:`~mr_ident.io.cdr.Batch`
and their fields come out with a few NumPy operations (:mod:`mr_ident.io.cdr`). A chunk
without message index, or a file without summary (cut short), is scanned record by record
instead, as far as it can be read; :attr:`Bag.notes` says what was skipped.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import DataError, yaml_problem
from ..numerics.arrays import IntArray
from .cdr import Batch

MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x03, 0x04, 0x05, 0x06
#: Message record: opcode, length, channel, sequence, log time, publish time, then data.
_MESSAGE_HEAD = 1 + 8 + 2 + 4 + 8 + 8


@dataclass(frozen=True)
class Topic:
    """A topic of a bag: its message type and the schema text it embeds."""

    name: str
    type: str
    schema: str
    encoding: str
    messages: int = 0


@dataclass
class _File:
    path: Path
    schemas: dict[int, tuple[str, str, bytes]] = field(
        default_factory=dict
    )  # id -> name, encoding, data
    channels: dict[int, tuple[str, int, str]] = field(
        default_factory=dict
    )  # id -> topic, schema, encoding
    chunks: list[Any] = field(default_factory=list)  # mcap ChunkIndex
    counts: dict[int, int] = field(default_factory=dict)
    summary: bool = True


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        out: bytes = lz4.frame.decompress(data)
        return out
    raise DataError(f"unknown MCAP chunk compression {compression!r}")


def _string(buf: bytes, p: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, p)
    return buf[p + 4 : p + 4 + n].decode(), p + 4 + n


class Bag:
    """The files of one bag (module docstring); use :meth:`open`."""

    def __init__(self, path: Path, files: list[Path], notes: list[str]):
        self.path = path
        self.notes = notes
        self._files = [self._index(f) for f in files]

    @classmethod
    def open(cls, path: str | Path) -> Bag:
        """A rosbag2 directory or a ``.mcap`` file.

        Raises
        ------
        DataError
            Not a bag, an SQLite bag, a compressed rosbag2 bag, or a listed file missing.
        """
        p = Path(path)
        notes: list[str] = []
        if p.is_dir():
            meta = p / "metadata.yaml"
            if meta.is_file():
                files = _files_of(p, meta)
            else:
                files = sorted(p.glob("*.mcap"))
                if sorted(p.glob("*.db3")):
                    raise DataError(_SQLITE.format(p))
                if not files:
                    raise DataError(
                        f"{p}: not a bag: no metadata.yaml and no .mcap file in the directory"
                    )
                notes.append(
                    f"{p} has no metadata.yaml; reading {len(files)} .mcap file(s) in name order"
                )
            return cls(p, files, notes)
        if p.suffix == ".db3":
            raise DataError(_SQLITE.format(p))
        if not p.exists():
            raise DataError(f"cannot read bag {str(p)!r}: no such file or directory")
        return cls(p, [p], notes)

    # -- index --------------------------------------------------------------------------
    def _index(self, path: Path) -> _File:
        from mcap.reader import make_reader

        f = _File(path)
        try:
            with open(path, "rb") as fh:
                if fh.read(8) != MAGIC:
                    raise DataError(f"{path}: not an MCAP file (bad magic)")
                fh.seek(0)
                summary = make_reader(fh).get_summary()
        except DataError:
            raise
        except Exception:  # noqa: BLE001 - no readable summary: scan instead
            summary = None
        if summary is None:
            f.summary = False
            self.notes.append(
                f"{path.name} has no summary (not finalised or cut short); scanned record by "
                "record"
            )
            return f
        for sid, s in summary.schemas.items():
            f.schemas[sid] = (s.name, s.encoding, bytes(s.data))
        for cid, c in summary.channels.items():
            f.channels[cid] = (c.topic, c.schema_id, c.message_encoding)
        f.chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        if summary.statistics is not None:
            f.counts = dict(summary.statistics.channel_message_counts)
        return f

    @property
    def files(self) -> list[Path]:
        """The bag's files, in reading order."""
        return [f.path for f in self._files]

    @property
    def topics(self) -> dict[str, Topic]:
        """Every topic of the bag with its type and embedded schema.

        From the files with a summary; a scanned file adds its topics while it is read.
        """
        out: dict[str, Topic] = {}
        for f in self._files:
            for cid, (topic, sid, enc) in f.channels.items():
                name, sch_enc, data = f.schemas.get(sid, ("", "", b""))
                prev = out.get(topic)
                count = f.counts.get(cid, 0) + (prev.messages if prev else 0)
                out[topic] = Topic(
                    topic,
                    name,
                    data.decode(errors="replace") if sch_enc == "ros2msg" else "",
                    enc,
                    count,
                )
        return out

    def scanned_topics(self) -> dict[str, Topic]:
        """:attr:`topics`, after scanning files that have no summary (reads them once)."""
        for f in self._files:
            if not f.summary and not f.channels:
                for _ in self._scan(f, set()):
                    pass
        return self.topics

    # -- messages -------------------------------------------------------------------------
    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """``(topic, batch, log_time_ns)`` for the messages of ``topics``, chunk by chunk.

        In file order (within a chunk a topic's messages are in record order).
        """
        for f in self._files:
            if f.summary:
                yield from self._chunks(f, topics)
            else:
                yield from self._scan(f, topics)

    def _chunks(self, f: _File, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        wanted = {cid for cid, (t, _, enc) in f.channels.items() if t in topics and enc == "cdr"}
        with open(f.path, "rb") as fh:
            for ci in f.chunks:
                ids = (
                    wanted & set(ci.message_index_offsets) if ci.message_index_offsets else wanted
                )
                if not ids:
                    continue
                fh.seek(ci.chunk_start_offset)
                raw = fh.read(ci.chunk_length)
                records = self._chunk_records(raw, f.path)
                if ci.message_index_offsets:
                    fh.seek(ci.chunk_start_offset + ci.chunk_length)
                    index = fh.read(ci.message_index_length)
                    base = ci.chunk_start_offset + ci.chunk_length
                    for cid in sorted(ids):
                        offsets = _message_index(index, ci.message_index_offsets[cid] - base)
                        yield self._batch(f, cid, records, offsets)
                else:
                    yield from self._split(f, records, ids)

    @staticmethod
    def _chunk_records(raw: bytes, path: Path) -> bytes:
        if len(raw) < 9 or raw[0] != _OP_CHUNK:
            raise DataError(f"{path}: the summary points at a chunk that is not there")
        p = 9
        _start, _end, size, _crc = struct.unpack_from("<QQQI", raw, p)
        compression, p = _string(raw, p + 28)
        (n,) = struct.unpack_from("<Q", raw, p)
        return _decompress(compression, raw[p + 8 : p + 8 + n], size)

    @staticmethod
    def _batch(
        f: _File, cid: int, records: bytes, offsets: IntArray
    ) -> tuple[str, Batch, IntArray]:
        buf = np.frombuffer(records, dtype=np.uint8)
        windows = np.lib.stride_tricks.as_strided(
            buf, (max(buf.size - _MESSAGE_HEAD + 1, 1), _MESSAGE_HEAD), (1, 1), writeable=False
        )
        head = windows[offsets]
        length = np.ascontiguousarray(head[:, 1:9]).view("<u8")[:, 0].astype(np.int64)
        log = np.ascontiguousarray(head[:, 15:23]).view("<u8")[:, 0].astype(np.int64)
        sent = np.ascontiguousarray(head[:, 23:31]).view("<u8")[:, 0].astype(np.int64)
        # The time a message was sent: the publish time where the writer stored one (rosbag2
        # since Jazzy: the DDS source timestamp), else the log (receive) time.
        sent = np.where(sent > 0, sent, log)
        return f.channels[cid][0], Batch(buf, offsets + _MESSAGE_HEAD, length - 22), sent

    def _split(
        self, f: _File, records: bytes, ids: set[int]
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        """Records of a chunk without message index, scanned."""
        per: dict[int, list[int]] = {}
        p, n = 0, len(records)
        while p + 9 <= n:
            op, length = records[p], struct.unpack_from("<Q", records, p + 1)[0]
            if op == _OP_MESSAGE:
                (cid,) = struct.unpack_from("<H", records, p + 9)
                if cid in ids:
                    per.setdefault(cid, []).append(p)
            elif op == _OP_SCHEMA:
                self._schema_record(f, records, p + 9)
            elif op == _OP_CHANNEL:
                self._channel_record(f, records, p + 9)
            p += 9 + length
        for cid, offs in sorted(per.items()):
            yield self._batch(f, cid, records, np.asarray(offs, dtype=np.int64))

    @staticmethod
    def _schema_record(f: _File, b: bytes, p: int) -> None:
        (sid,) = struct.unpack_from("<H", b, p)
        name, p = _string(b, p + 2)
        enc, p = _string(b, p)
        (n,) = struct.unpack_from("<I", b, p)
        f.schemas[sid] = (name, enc, b[p + 4 : p + 4 + n])

    @staticmethod
    def _channel_record(f: _File, b: bytes, p: int) -> None:
        cid, sid = struct.unpack_from("<HH", b, p)
        topic, p = _string(b, p + 4)
        enc, _ = _string(b, p)
        f.channels[cid] = (topic, sid, enc)

    def _scan(self, f: _File, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """A file without summary, read record by record as far as it goes."""
        with open(f.path, "rb") as fh:
            data = fh.read()
        p, n = len(MAGIC), len(data)
        loose: dict[int, list[int]] = {}
        while p + 9 <= n:
            op, length = data[p], struct.unpack_from("<Q", data, p + 1)[0]
            if p + 9 + length > n:
                self.notes.append(
                    f"{f.path.name} ends inside a record after byte {p} of {n}; "
                    "what came before is used"
                )
                break
            body = p + 9
            if op == _OP_SCHEMA:
                self._schema_record(f, data, body)
            elif op == _OP_CHANNEL:
                self._channel_record(f, data, body)
            elif op == _OP_CHUNK:
                try:
                    records = self._chunk_records(data[p : p + 9 + length], f.path)
                except Exception as err:  # noqa: BLE001 - a damaged chunk ends the scan
                    self.notes.append(
                        f"{f.path.name}: unreadable chunk at byte {p} ({err}); what came before "
                        "is used"
                    )
                    break
                self._split_channels(f, records)
                ids = {c for c, (t, _, enc) in f.channels.items() if t in topics and enc == "cdr"}
                yield from self._split(f, records, ids)
            elif op == _OP_MESSAGE:
                (cid,) = struct.unpack_from("<H", data, body)
                loose.setdefault(cid, []).append(p)
            p = body + length
        for cid, offs in sorted(loose.items()):
            if f.channels.get(cid, ("", 0, ""))[0] in topics:
                yield self._batch(f, cid, data, np.asarray(offs, dtype=np.int64))

    def _split_channels(self, f: _File, records: bytes) -> None:
        p, n = 0, len(records)
        while p + 9 <= n:
            op, length = records[p], struct.unpack_from("<Q", records, p + 1)[0]
            if op == _OP_SCHEMA:
                self._schema_record(f, records, p + 9)
            elif op == _OP_CHANNEL:
                self._channel_record(f, records, p + 9)
            p += 9 + length


def _message_index(index: bytes, start: int) -> IntArray:
    """Offsets (into the chunk's records) of the messages of one MessageIndex record."""
    (n,) = struct.unpack_from("<I", index, start + 9 + 2)
    pairs = np.frombuffer(index, dtype="<u8", count=n // 8, offset=start + 9 + 2 + 4).reshape(
        -1, 2
    )
    return pairs[:, 1].astype(np.int64)


_SQLITE = (
    "{}: an SQLite (.db3) bag; mr-ident reads MCAP bags. Convert it with "
    "`ros2 bag convert -i BAG -o out.yaml`, out.yaml holding "
    "'output_bags: [{{uri: BAG_mcap, storage_id: mcap}}]'"
)


def _files_of(directory: Path, meta: Path) -> list[Path]:
    try:
        doc = yaml.safe_load(meta.read_text())
    except yaml.YAMLError as err:
        raise DataError(f"{meta}: not valid YAML: {yaml_problem(err)}") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise DataError(f"{meta}: no 'rosbag2_bagfile_information' mapping")
    storage = info.get("storage_identifier", "")
    if storage == "sqlite3":
        raise DataError(_SQLITE.format(directory))
    if storage not in ("mcap", ""):
        raise DataError(f"{meta}: storage {storage!r} is not read (only mcap)")
    if info.get("compression_format") or info.get("compression_mode"):
        raise DataError(
            f"{meta}: a bag compressed by rosbag2 ({info.get('compression_format')}, "
            f"{info.get('compression_mode')}) is not read; convert it with `ros2 bag convert` "
            "(MCAP's own chunk compression is read)"
        )
    rel = info.get("relative_file_paths") or []
    files = [directory / r for r in rel]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise DataError(f"{meta} lists {', '.join(missing)}, which do not exist")
    if not files:
        raise DataError(f"{meta}: relative_file_paths is empty")
    return files


def open_bag(path: str | Path) -> Bag:
    """:meth:`Bag.open`."""
    return Bag.open(path)
