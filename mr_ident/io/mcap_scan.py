# SPDX-License-Identifier: Apache-2.0
"""MCAP files read completely, whatever their layout: the data section walked in file order.

The MCAP specification leaves a writer free in what it indexes: chunks or none, message
indexes or none, chunk indexes, a summary, summary offsets and statistics are all optional,
and a file that was not finalised has no footer. A reader that only follows the chunk
index sees nothing in an unchunked file or in one written without it. This module
therefore walks the top-level records of the data section in file order, reading the file
sequentially in windows of :data:`WINDOW` bytes, so that every message is seen; the
indexes only make the walk faster where they are there:

* the chunk index of a complete summary: the chunks that hold no wanted channel (and
  their message indexes) are not read at all (the walk jumps over them);
* a chunk followed by its message index records: each message's offset comes from the
  index (no walk over the chunk's records), and a chunk that holds no wanted channel is
  not decompressed;
* a chunk without message index: its records are walked;
* a chunk whose data do not match its CRC (where the writer stored one), or that does
  not decompress, is skipped and said (its messages are a gap);
* messages outside chunks (an unchunked file): walked, one batch per channel and window.

Either way a channel's messages come out as one :class:`~mr_ident.io.cdr.Batch` per chunk
or window, in file order, so the CDR fields are read with a few NumPy operations. The
summary (through the footer) gives the schemas, channels and message counts before
reading; where there is none, they are collected by a scan. A file cut short is read up
to its last whole record. The bytes come from a file or from any readable stream (a
zstd-compressed file, decompressed as it is read).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

from ..errors import DataError
from ..numerics.arrays import IntArray
from .cdr import Batch

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_DATA_END = 0x07, 0x08, 0x0B, 0x0F
#: Message record: opcode, length, channel, sequence, log time, publish time, then data.
MESSAGE_HEAD = 1 + 8 + 2 + 4 + 8 + 8
#: Bytes read at a time; a record larger than this is read whole.
WINDOW = 1 << 24
#: A record longer than this in a stream (whose size is not known) is taken as damage.
LARGEST = 1 << 33
_HEAD = struct.Struct("<BQ")
_FOOTER = 1 + 8 + 8 + 8 + 4  # opcode, length, summary start, summary offset start, crc


@dataclass
class McapInfo:
    """What is known of one MCAP file: schemas, channels, messages per channel.

    ``complete``: the summary listed the channels before reading (else a scan finds them).
    ``data_end``: where the data section ends (None: not known, read to the end).
    """

    schemas: dict[int, tuple[str, str, bytes]] = field(default_factory=dict)
    channels: dict[int, tuple[str, int, str]] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    complete: bool = False
    data_end: int | None = None
    scanned: bool = False
    #: From the chunk index: per chunk its byte range (with its message indexes) and channels.
    chunks: list[tuple[int, int, frozenset[int]]] = field(default_factory=list)


def _string(buf: bytes | memoryview, p: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, p)
    return bytes(buf[p + 4 : p + 4 + n]).decode(), p + 4 + n


def _decompress(compression: str, data: memoryview, size: int) -> bytes | memoryview:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        out: bytes = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        return out
    if compression == "lz4":
        import lz4.frame

        out = lz4.frame.decompress(bytes(data))
        return out
    raise DataError(f"unknown MCAP chunk compression {compression!r} (zstd, lz4 or none are read)")


def walk(buf: bytes | memoryview, p: int, end: int) -> tuple[list[int], int]:
    """Offsets of the whole records in ``buf[p:end]``, and where the walk stopped."""
    offs: list[int] = []
    head = _HEAD.unpack_from
    while p + 9 <= end:
        _, n = head(buf, p)
        q = p + 9 + n
        if q > end:
            break
        offs.append(p)
        p = q
    return offs, p


def read_summary(fh: BinaryIO, size: int) -> McapInfo:
    """The summary of a seekable file through its footer (empty info when there is none)."""
    info = McapInfo()
    if size < 2 * len(MAGIC) + _FOOTER:
        return info
    fh.seek(size - len(MAGIC) - _FOOTER)
    tail = fh.read(len(MAGIC) + _FOOTER)
    if tail[_FOOTER:] != MAGIC or tail[0] != OP_FOOTER:
        return info  # not finalised, or cut short
    start, _offsets, _crc = struct.unpack_from("<QQI", tail, 9)
    footer = size - len(MAGIC) - _FOOTER
    info.data_end = start if 0 < start <= footer else footer
    if start == 0 or start > footer:
        return info
    fh.seek(start)
    buf = fh.read(footer - start)
    offs, _ = walk(buf, 0, len(buf))
    for p in offs:
        _record(info, buf, p)
    stats_channels = info.counts.pop(-1, None)
    info.complete = bool(info.channels) and (
        stats_channels is None or stats_channels == len(info.channels)
    )
    return info


def _record(info: McapInfo, b: bytes | memoryview, p: int) -> None:
    """Register a schema, channel or statistics record at ``p``."""
    op = b[p]
    body = p + 9
    if op == OP_SCHEMA:
        (sid,) = struct.unpack_from("<H", b, body)
        name, q = _string(b, body + 2)
        enc, q = _string(b, q)
        (n,) = struct.unpack_from("<I", b, q)
        info.schemas.setdefault(sid, (name, enc, bytes(b[q + 4 : q + 4 + n])))
    elif op == OP_CHANNEL:
        cid, sid = struct.unpack_from("<HH", b, body)
        topic, q = _string(b, body + 4)
        enc, _ = _string(b, q)
        info.channels.setdefault(cid, (topic, sid, enc))
    elif op == OP_CHUNK_INDEX:
        start, length = struct.unpack_from("<QQ", b, body + 16)
        (n,) = struct.unpack_from("<I", b, body + 32)
        pairs = [struct.unpack_from("<HQ", b, body + 36 + 10 * k) for k in range(n // 10)]
        (index_length,) = struct.unpack_from("<Q", b, body + 36 + n)
        end = start + length
        if pairs and min(o for _, o in pairs) == end:  # its message indexes follow it
            end += index_length
        if pairs:  # a chunk without message index: its channels are not known
            info.chunks.append((start, end, frozenset(c for c, _ in pairs)))
    elif op == OP_STATISTICS:
        (channel_count,) = struct.unpack_from("<I", b, body + 8 + 2)
        (n,) = struct.unpack_from("<I", b, body + 42)
        for k in range(n // 10):
            cid, count = struct.unpack_from("<HQ", b, body + 46 + 10 * k)
            info.counts[cid] = count
        info.counts[-1] = channel_count  # read by read_summary, then removed


def message_batch(records: bytes | memoryview, offsets: IntArray) -> tuple[Batch, IntArray]:
    """The messages at ``offsets`` (of their Message records) as a batch, and their send times.

    The time a message was sent: the publish time where the writer stored one (rosbag2
    since Jazzy: the DDS source timestamp), else the log (receive) time.
    """
    buf = np.frombuffer(records, dtype=np.uint8)
    windows = np.lib.stride_tricks.as_strided(
        buf, (max(buf.size - MESSAGE_HEAD + 1, 1), MESSAGE_HEAD), (1, 1), writeable=False
    )
    head = windows[offsets]
    length = np.ascontiguousarray(head[:, 1:9]).view("<u8")[:, 0].astype(np.int64)
    log = np.ascontiguousarray(head[:, 15:23]).view("<u8")[:, 0].astype(np.int64)
    sent = np.ascontiguousarray(head[:, 23:31]).view("<u8")[:, 0].astype(np.int64)
    sent = np.where(sent > 0, sent, log)
    return Batch(buf, offsets + MESSAGE_HEAD, length - 22), sent


def _channel_ids(arr: np.ndarray, offsets: IntArray) -> IntArray:
    lo = arr[offsets + 9].astype(np.int64)
    hi = arr[offsets + 10].astype(np.int64)
    return lo | (hi << 8)


class McapScan:
    """One MCAP file (or stream) walked record by record (module docstring).

    Parameters
    ----------
    name : str
        For notes and errors.
    opener : callable
        Opens the bytes of the file from its first byte (a file, or a decompressing stream).
    info : McapInfo
        What the summary gave (filled in further while scanning).
    notes : list of str
        Where what was skipped is said (a file cut short, an unreadable chunk).
    size : int, optional
        The file's size in bytes (None for a stream).
    """

    def __init__(
        self,
        name: str,
        opener: Callable[[], BinaryIO],
        info: McapInfo,
        notes: list[str],
        size: int | None = None,
    ):
        self.name = name
        self.size = size
        self.opener = opener
        self.info = info
        self.notes = notes
        self.cut = ""  # why the file was not read to its end ("" if it was)
        self._expected: set[str] | None = None

    def _known(self) -> set[str]:
        """Topics whose channel and schema are known."""
        schemas = self.info.schemas
        return {t for t, sid, _ in self.info.channels.values() if sid == 0 or sid in schemas}

    def _wanted(self, topics: set[str]) -> set[int]:
        return {
            cid for cid, (t, _, enc) in self.info.channels.items() if t in topics and enc == "cdr"
        }

    def scan(self, expected: set[str] | None = None) -> None:
        """Read the file once to learn its schemas, channels and message counts.

        ``expected``: the topics the file is known to hold (a rosbag2 metadata.yaml); the
        scan stops once each has its channel (its counts are then not known).
        """
        if self.info.scanned:
            return
        self.info.counts = {}
        self._expected = expected
        try:
            for _ in self.messages(set(), count=True):
                pass
        finally:
            self._expected = None
        self.info.scanned = True

    def messages(
        self, topics: set[str], count: bool = False
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        """``(topic, batch, sent_ns)`` of the wanted topics' CDR messages, in file order."""
        with self.opener() as fh:
            try:
                head = fh.read(len(MAGIC))
            except Exception as err:  # noqa: BLE001 - e.g. a .zstd that is not zstd
                raise DataError(
                    f"{self.name}: cannot be read ({type(err).__name__}: {err})"
                ) from None
            if head != MAGIC:
                raise DataError(f"{self.name}: not an MCAP file (bad magic)")
            yield from self._walk_file(fh, topics, count)

    def _skipped(self, topics: set[str], count: bool) -> list[tuple[int, int]]:
        """Byte ranges of the chunks (with their message indexes) that hold no wanted channel.

        From the chunk index of a complete summary; they are not read at all.
        """
        if count or not self.info.complete or self.size is None:
            return []
        wanted = self._wanted(topics)
        known = set(self.info.channels)
        out: list[tuple[int, int]] = []
        for start, end, cids in sorted(self.info.chunks):
            if cids <= known and not cids & wanted and (not out or start >= out[-1][1]):
                out.append((start, end))
        return out

    def _walk_file(
        self, fh: BinaryIO, topics: set[str], count: bool
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        """The data section, less the chunks :meth:`_skipped` (read in segments between)."""
        end = self.info.data_end
        state = {"summary": False, "done": False, "stopped": False}
        pos = len(MAGIC)
        for a, b in self._skipped(topics, count):
            if a > pos:
                fh.seek(pos)
                yield from self._walk(fh, pos, a, topics, count, state)
            if state["done"] or state["stopped"]:
                return
            pos = b
        fh.seek(pos)
        yield from self._walk(fh, pos, end, topics, count, state)

    def _walk(
        self,
        fh: BinaryIO,
        pos: int,
        end: int | None,
        topics: set[str],
        count: bool,
        state: dict[str, bool],
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        """Records from ``pos`` to ``end`` (None: the end of the file or stream), in windows."""
        carry, want = b"", WINDOW
        segment = end is not None and end != self.info.data_end
        while not state["done"]:
            n = want  # new bytes, after what is carried over
            if end is not None:
                n = min(n, end - pos - len(carry))
            try:
                more = fh.read(n) if n > 0 else b""
            except Exception as err:  # noqa: BLE001 - a damaged stream (zstd) ends the reading
                more, n = b"", 1
                self.cut = (
                    f"{self.name}: unreadable after byte {pos + len(carry)} "
                    f"({type(err).__name__}: {err}); what came before is used"
                )
                self.notes.append(self.cut)
                state["stopped"] = True
            buf = carry + more if carry else more
            at_end = len(more) < n or n <= 0
            view = memoryview(buf)
            offs, stop = walk(view, 0, len(buf))
            if not at_end:
                offs = _defer_last_chunk(view, offs)
                stop = offs[-1] + 9 + _HEAD.unpack_from(view, offs[-1])[1] if offs else 0
            if not offs:
                if at_end:
                    break
                need = 9 + _HEAD.unpack_from(view, 0)[1] if len(buf) >= 9 else WINDOW
                carry = buf
                if need > (self.size - pos if self.size is not None else LARGEST):
                    break  # a length past the end of the file (cut short, or damaged)
                want = max(2 * want, need - len(buf) + WINDOW)
                continue
            yield from self._records(view, offs, pos, topics, count, state)
            carry, pos, want = buf[stop:], pos + stop, WINDOW
            if at_end:
                break
            if self._expected and self._expected <= self._known():
                return  # a scan for topics: every expected topic is known
        if (segment and not carry) or state["stopped"]:
            return  # a segment between skipped chunks read whole, or a damaged stream (said)
        if (
            not state["done"] and not state["summary"] and end is None
        ):  # no footer: not finalised, or cut short
            where = "inside a record" if carry else "without a footer"
            self.cut = f"{self.name} ends {where} after byte {pos}; what came before is used"
            if self.cut not in self.notes:
                self.notes.append(self.cut)
            state["stopped"] = True
        elif carry and end is not None and not state["done"]:
            self.cut = (
                f"{self.name}: the record at byte {pos} runs past the end of the data "
                f"(damaged); what came before is used"
            )
            if self.cut not in self.notes:
                self.notes.append(self.cut)
            state["stopped"] = True

    def _records(
        self,
        view: memoryview,
        offs: list[int],
        base: int,
        topics: set[str],
        count: bool,
        state: dict[str, bool],
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        arr = np.frombuffer(view, dtype=np.uint8)
        at = np.asarray(offs, dtype=np.int64)
        ops = arr[at]
        special = np.flatnonzero(ops != OP_MESSAGE).tolist() + [len(offs)]
        prev = 0
        for i in special:
            if prev < i and not state["summary"]:
                yield from self._loose(view, at[prev:i], topics, count)
            prev = i + 1
            if i == len(offs) or state["done"]:
                continue
            op, p = int(ops[i]), offs[i]
            if state["summary"] or op in (OP_SCHEMA, OP_CHANNEL):
                if op in (OP_SCHEMA, OP_CHANNEL, OP_STATISTICS):
                    _record(self.info, view, p)
                    self.info.counts.pop(-1, None)
                state["done"] = op == OP_FOOTER
            elif op == OP_CHUNK:
                j = i + 1
                while j < len(offs) and ops[j] == OP_MESSAGE_INDEX:
                    j += 1
                try:
                    yield from self._chunk(view, p, offs[i + 1 : j], topics, count)
                except Exception as err:  # noqa: BLE001 - a damaged chunk is skipped, and said
                    self.notes.append(
                        f"{self.name}: unreadable chunk at byte {base + p} "
                        f"({type(err).__name__}: {err}); its messages are left out"
                    )
            elif op == OP_DATA_END:
                state["summary"] = True  # a stream: the summary follows (schemas, counts)
            elif op == OP_FOOTER:
                state["done"] = True

    def _loose(
        self, view: memoryview, at: IntArray, topics: set[str], count: bool
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        """Messages outside chunks (records at ``at`` of ``view``)."""
        yield from self._by_channel(view, at, topics, count)

    def _by_channel(
        self, records: bytes | memoryview, at: IntArray, topics: set[str], count: bool
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        if at.size == 0:
            return
        cids = _channel_ids(np.frombuffer(records, dtype=np.uint8), at)
        if count:
            ids, n = np.unique(cids, return_counts=True)
            for c, k in zip(ids.tolist(), n.tolist(), strict=True):
                self.info.counts[c] = self.info.counts.get(c, 0) + k
        for cid in sorted(self._wanted(topics)):
            sel = at[cids == cid]
            if sel.size:
                batch, sent = message_batch(records, sel)
                yield self.info.channels[cid][0], batch, sent

    def _chunk(
        self, view: memoryview, p: int, index_at: list[int], topics: set[str], count: bool
    ) -> Iterator[tuple[str, Batch, IntArray]]:
        """One chunk; ``index_at``: the message index records that follow it."""
        body = p + 9
        size, crc = struct.unpack_from("<QI", view, body + 16)
        compression, q = _string(view, body + 28)
        (n,) = struct.unpack_from("<Q", view, q)
        raw = view[q + 8 : q + 8 + n]
        index: dict[int, int] = {}
        for ip in index_at:
            index[struct.unpack_from("<H", view, ip + 9)[0]] = ip
        known = bool(index) and all(c in self.info.channels for c in index)
        wanted = self._wanted(topics)
        if known and not count and not wanted & set(index):
            return  # nothing wanted in it: not decompressed
        if known and count and not wanted & set(index):
            for c, ip in index.items():
                (nb,) = struct.unpack_from("<I", view, ip + 11)
                self.info.counts[c] = self.info.counts.get(c, 0) + nb // 16
            return
        records = _decompress(compression, raw, size)
        if crc and zlib.crc32(records) != crc:  # a damaged chunk may decompress to garbage
            raise DataError(f"its data do not match its CRC ({len(records)} bytes)")
        if known:
            offsets = {c: _index_offsets(view, ip) for c, ip in index.items()}
            if all(_valid(records, o) for o in offsets.values()):
                for c, o in offsets.items():
                    if count:
                        self.info.counts[c] = self.info.counts.get(c, 0) + o.size
                for cid in sorted(wanted & set(offsets)):
                    batch, sent = message_batch(records, offsets[cid])
                    yield self.info.channels[cid][0], batch, sent
                return
        # no (usable) message index: walk the chunk's records
        offs, _ = walk(records, 0, len(records))
        at = np.asarray(offs, dtype=np.int64)
        if at.size == 0:
            return
        ops = np.frombuffer(records, dtype=np.uint8)[at]
        for k in np.flatnonzero(ops != OP_MESSAGE).tolist():
            _record(self.info, records, offs[k])
            self.info.counts.pop(-1, None)
        yield from self._by_channel(records, at[ops == OP_MESSAGE], topics, count)


def _index_offsets(view: memoryview, ip: int) -> IntArray:
    """Offsets (into the chunk's records) of one MessageIndex record's messages, file order."""
    (n,) = struct.unpack_from("<I", view, ip + 11)
    pairs = np.frombuffer(view, dtype="<u8", count=n // 16 * 2, offset=ip + 15).reshape(-1, 2)
    return np.sort(pairs[:, 1].astype(np.int64))


def _valid(records: bytes | memoryview, offsets: IntArray) -> bool:
    """Whether every offset points at a whole Message record of ``records``."""
    if offsets.size == 0:
        return True
    size = len(records)
    if offsets[0] < 0 or offsets[-1] + MESSAGE_HEAD > size:
        return False
    return bool(np.all(np.frombuffer(records, dtype=np.uint8)[offsets] == OP_MESSAGE))


def _defer_last_chunk(view: memoryview, offs: list[int]) -> list[int]:
    """Leave a window's last chunk to the next window: its message index may be cut off."""
    k = len(offs) - 1
    while k >= 0 and view[offs[k]] == OP_MESSAGE_INDEX:
        k -= 1
    if k >= 0 and view[offs[k]] == OP_CHUNK:
        return offs[:k]
    return offs
