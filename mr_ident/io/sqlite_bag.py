# SPDX-License-Identifier: Apache-2.0
"""rosbag2 SQLite3 bags (``.db3``, the default storage up to Iron), read with Python's sqlite3.

rosbag2's SQLite storage keeps its topics in a ``topics`` table (id, name, type,
serialization format, QoS) and every message as a row of ``messages`` (id, topic_id,
timestamp = the receive time in ns, data = the CDR bytes); bags from Iron on add
``message_definitions`` (per type the concatenated ``ros2msg`` text, as MCAP schemas hold
it). A type without a definition there is looked up among the installed interface
packages and the ``--msg-path`` directories (``definitions``).

Reading is batched as for MCAP: a topic's messages among :data:`ROWS` row ids come out
of SQLite as one row (``group_concat`` joins their payloads into one buffer and their ids,
timestamps and lengths into text NumPy parses at once) and are one
:class:`~mr_ident.io.cdr.Batch` (offsets into that buffer): no Python per message, not
even a row object. SQLite
bags store no publish time: a type without header is placed by its receive time. A
file-compressed SQLite3 bag (``.db3.zstd``) is decompressed into memory (SQLite reads its
pages at random, so it cannot be streamed).
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..numerics.arrays import IntArray
from .cdr import Batch

#: Rows of one read: topic ids, row ids, timestamps, lengths, the joined payloads.
_Part = tuple[IntArray, IntArray, IntArray, IntArray, bytes]


def _connect(path: Path) -> sqlite3.Connection:
    """The database read-only; a zstd-compressed one (``.db3.zstd``) decompressed in memory.

    SQLite reads pages at random, so a compressed database cannot be streamed: it is held
    in memory (never written to disk).
    """
    if not path.name.endswith(".zstd"):
        return sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    import zstandard

    with open(path, "rb") as fh, zstandard.ZstdDecompressor().stream_reader(fh) as z:
        data = z.read()
        while more := z.read(1 << 26):
            data += more
    db = sqlite3.connect(":memory:")
    db.deserialize(data)
    return db


def _checked(parts: Iterator[_Part], path: Path) -> Iterator[_Part]:
    """``parts``, a damaged database turned into a DataError naming the file."""
    try:
        yield from parts
    except sqlite3.DatabaseError as err:
        raise DataError(f"{path}: the SQLite3 database cannot be read ({err})") from None


#: Rows read at a time (a power of two).
ROWS = 1 << 16
#: Join each group of rows in SQLite (``group_concat``) rather than fetching rows.
AGGREGATE = True


class SqliteBag:
    """One ``.db3`` file of a rosbag2 bag.

    Parameters
    ----------
    path : Path
    definitions : callable
        Type name -> its concatenated ``ros2msg`` text ("" when found nowhere), for the types
        the bag carries no definition of.

    Raises
    ------
    DataError
        Not an SQLite database, or no ``topics``/``messages`` table.
    """

    def __init__(self, path: Path, definitions: Callable[[str], str]):
        self.path = path
        try:
            self._db = _connect(path)
            tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master")}
        except sqlite3.DatabaseError as err:
            raise DataError(f"{path}: not an SQLite3 bag ({err})") from None
        if not {"topics", "messages"} <= tables:
            raise DataError(
                f"{path}: not a rosbag2 SQLite3 bag: expected tables 'topics' and 'messages', "
                f"found {sorted(tables) or 'none'}"
            )
        rows = self._db.execute("SELECT id, name, type, serialization_format FROM topics")
        self.topics: dict[int, tuple[str, str, str]] = {
            int(i): (str(n), str(t), str(f)) for i, n, t, f in rows
        }
        embedded: dict[str, str] = {}
        if "message_definitions" in tables:
            for type_name, enc, text in self._db.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ):
                if enc == "ros2msg" and text:
                    embedded[str(type_name)] = str(text)
        self.schemas = {
            t: embedded.get(t) or definitions(t) for t in {t for _, t, _ in self.topics.values()}
        }

    def close(self) -> None:
        """Close the database."""
        self._db.close()

    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """``(topic, batch, receive_ns)`` for the CDR messages of ``topics``, in row order."""
        ids = sorted(i for i, (n, _, f) in self.topics.items() if n in topics and f == "cdr")
        if not ids:
            return
        where = f"topic_id IN ({', '.join(str(i) for i in ids)})"
        utf8 = next(iter(self._db.execute("PRAGMA encoding")))[0] == "UTF-8"
        parts = self._aggregated(ids) if utf8 and AGGREGATE else self._rows(where)
        for tids, rowid, stamps, lengths, blob in _checked(parts, self.path):
            order = np.argsort(rowid, kind="stable")  # row order (as SQLite scans: no cost)
            offsets = np.zeros(lengths.size, dtype=np.int64)
            np.cumsum(lengths[:-1], out=offsets[1:])
            buf = np.frombuffer(blob, dtype=np.uint8)
            tids, stamps, offsets, lengths = (
                tids[order],
                stamps[order],
                offsets[order],
                lengths[order],
            )
            for i in ids:
                sel = np.flatnonzero(tids == i)
                if sel.size:
                    yield self.topics[i][0], Batch(buf, offsets[sel], lengths[sel]), stamps[sel]

    def _aggregated(self, ids: list[int]) -> Iterator[_Part]:
        """:data:`ROWS` row ids at a time and topic by topic, each as one row joined by SQLite.

        ``group_concat`` joins the payloads byte for byte (a blob's bytes as text of its
        length, in a UTF-8 database) and the numbers as comma-separated text, NumPy parses
        them at once; a range of row ids is a range scan of the table (no sort).
        """
        lo, hi = self._db.execute("SELECT min(id), max(id) FROM messages").fetchone()
        if lo is None:
            return
        query = (
            "SELECT group_concat(id), group_concat(timestamp), group_concat(length(data)), "
            "group_concat(data, '') FROM messages WHERE id >= ? AND id < ? AND topic_id = ?"
        )
        self._db.text_factory = bytes
        try:
            for start in range(int(lo), int(hi) + 1, ROWS):
                for i in ids:
                    row = self._db.execute(query, (start, start + ROWS, i)).fetchone()
                    if row[0] is None:
                        continue
                    rowid, stamps, lengths = (
                        np.fromstring(x, dtype=np.int64, sep=",") for x in row[:3]
                    )
                    yield np.full(rowid.size, i, np.int64), rowid, stamps, lengths, row[3]
        finally:
            self._db.text_factory = str

    def _rows(self, where: str) -> Iterator[_Part]:
        """:data:`ROWS` rows at a time, fetched as rows (any database encoding)."""
        cur = self._db.execute(
            f"SELECT id, topic_id, timestamp, data FROM messages WHERE {where} ORDER BY id"
        )
        while rows := cur.fetchmany(ROWS):
            rowid, tid, stamp, data = zip(*rows, strict=True)
            lengths = np.fromiter(map(len, data), dtype=np.int64, count=len(data))
            yield (
                np.array(tid, dtype=np.int64),
                np.array(rowid, dtype=np.int64),
                np.array(stamp, dtype=np.int64),
                lengths,
                b"".join(data),
            )
