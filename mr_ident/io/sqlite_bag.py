"""rosbag2 SQLite3 bags (``.db3``, the default storage up to Iron), read with Python's sqlite3.

rosbag2's SQLite storage keeps its topics in a ``topics`` table (id, name, type,
serialization format, QoS) and every message as a row of ``messages`` (id, topic_id,
timestamp = the receive time in ns, data = the CDR bytes); bags from Iron on add
``message_definitions`` (per type the concatenated ``ros2msg`` text, as MCAP schemas hold
it). A type without a definition there is looked up among the installed interface
packages and the ``--msg-path`` directories (``definitions``).

Reading is batched as for MCAP: rows come out :data:`ROWS` at a time, their payloads are
joined into one buffer, and each topic's messages of the batch are one
:class:`~mr_ident.io.cdr.Batch` (offsets into that buffer): no Python per message. SQLite
bags store no publish time: a type without header is placed by its receive time.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..numerics.arrays import IntArray
from .cdr import Batch

#: Rows fetched at a time.
ROWS = 1 << 16


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
            self._db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
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
        self.counts = {
            int(i): int(n)
            for i, n in self._db.execute(
                "SELECT topic_id, count(*) FROM messages GROUP BY topic_id"
            )
        }

    def close(self) -> None:
        """Close the database."""
        self._db.close()

    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """``(topic, batch, receive_ns)`` for the CDR messages of ``topics``, in row order."""
        ids = sorted(i for i, (n, _, f) in self.topics.items() if n in topics and f == "cdr")
        if not ids:
            return
        cur = self._db.execute(
            "SELECT topic_id, timestamp, length(data), data FROM messages WHERE topic_id IN "
            f"({', '.join('?' * len(ids))}) ORDER BY id",
            ids,
        )
        while rows := cur.fetchmany(ROWS):
            tid, stamp, length, data = zip(*rows, strict=True)
            tids = np.array(tid, dtype=np.int64)
            stamps = np.array(stamp, dtype=np.int64)
            lengths = np.array(length, dtype=np.int64)
            offsets = np.zeros(lengths.size, dtype=np.int64)
            np.cumsum(lengths[:-1], out=offsets[1:])
            buf = np.frombuffer(b"".join(data), dtype=np.uint8)
            for i in ids:
                sel = np.flatnonzero(tids == i)
                if sel.size:
                    yield self.topics[i][0], Batch(buf, offsets[sel], lengths[sel]), stamps[sel]
