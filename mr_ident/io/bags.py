# SPDX-License-Identifier: Apache-2.0
"""Bags: rosbag2 directories, MCAP files of any layout, SQLite3 bags, zstd-compressed files.

A bag is a rosbag2 directory (``metadata.yaml`` lists its files in ``relative_file_paths``;
split bags are read in that order) or one file: ``.mcap`` (written by ``ros2 bag record``,
``rosbags``, ``mcap_ros2``, the ``mcap`` library or ``mr-ident record``), ``.db3``
(rosbag2's SQLite3 storage, :mod:`mr_ident.io.sqlite_bag`) or ``.mcap.zstd`` (a file that
``ros2 bag record --compression-mode file --compression-format zstd`` compressed whole;
decompressed as it is read, never to disk; a ``.db3.zstd`` is decompressed into memory,
SQLite reading at random). A directory without ``metadata.yaml`` (a recording that was
killed) is read file by file in name order.

Every storage is a :class:`Part` (the protocol below; :data:`PARTS` maps a file to its
kind): its topics with their type and ``ros2msg`` definition, and its messages of some
topics as batches. MCAP files are walked in file order (:mod:`mr_ident.io.mcap_scan`), so
every message is read whatever the file indexes; :attr:`Bag.notes` says what was skipped.
A type whose definition the bag does not carry comes from the installed interface
packages or the ``msg_path`` directories (``pkg/msg/Type.msg``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import BinaryIO, Protocol

import yaml

from ..errors import DataError, DataFieldError, yaml_problem
from ..numerics.arrays import IntArray
from .cdr import Batch
from .mcap_scan import MAGIC, McapInfo, McapScan, read_summary
from .msgdef import find_definition
from .sqlite_bag import SqliteBag

#: Suffixes of the files a bag is made of.
BAG_FILES = (".mcap", ".db3", ".mcap.zstd", ".db3.zstd")


@dataclass(frozen=True)
class Topic:
    """A topic of a bag: its message type and the schema text it embeds."""

    name: str
    type: str
    schema: str
    encoding: str
    messages: int = 0


class Part(Protocol):
    """One file of a bag, whatever its storage."""

    path: Path

    def topics(self) -> dict[str, Topic]:
        """Its topics as far as they are known (all of them after :meth:`scan`)."""

    def scan(self, expected: set[str] | None = None) -> None:
        """Read the file where its topics are not known without it (until ``expected``)."""

    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """``(topic, batch, sent_ns)`` of the CDR messages of ``topics``, in file order."""


class McapPart:
    """An MCAP file, plain or zstd-compressed whole (read as a stream)."""

    def __init__(self, path: Path, notes: list[str], definitions: Callable[[str], str]):
        self.path = path
        self._definitions = definitions
        compressed = path.name.endswith(".zstd")
        size = None if compressed else path.stat().st_size
        if compressed:
            info = McapInfo()
            opener: Callable[[], BinaryIO] = lambda: _zstd_stream(path)  # noqa: E731
        else:
            opener = lambda: open(path, "rb")  # noqa: E731
            with opener() as fh:
                if fh.read(len(MAGIC)) != MAGIC:
                    raise DataError(f"{path}: not an MCAP file (bad magic)")
                info = read_summary(fh, path.stat().st_size)
        self.scanner = McapScan(str(path), opener, info, notes, size)

    def topics(self) -> dict[str, Topic]:
        """Its topics (:class:`Part`); a type without schema from ``definitions``."""
        info = self.scanner.info
        out: dict[str, Topic] = {}
        for cid, (topic, sid, enc) in info.channels.items():
            name, sch_enc, data = info.schemas.get(sid, ("", "", b""))
            schema = data.decode(errors="replace") if sch_enc == "ros2msg" else ""
            if not schema and name:
                schema = self._definitions(name)
            prev = out.get(topic)
            count = info.counts.get(cid, 0) + (prev.messages if prev else 0)
            out[topic] = Topic(topic, name, schema, enc, count)
        return out

    def scan(self, expected: set[str] | None = None) -> None:
        """Walk the file unless its summary listed the channels (until ``expected`` are)."""
        if not self.scanner.info.complete:
            self.scanner.scan(expected)

    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """:meth:`McapScan.messages`."""
        return self.scanner.messages(topics)


class SqlitePart:
    """A ``.db3`` file of rosbag2's SQLite3 storage."""

    def __init__(self, path: Path, notes: list[str], definitions: Callable[[str], str]):
        self.path = path
        self.db = SqliteBag(path, definitions)

    def topics(self) -> dict[str, Topic]:
        """Its topics (:class:`Part`), all known from its tables.

        Not counted (a pass over the table: :attr:`Bag.read` counts what is read).
        """
        return {
            name: Topic(name, type_, self.db.schemas.get(type_, ""), fmt)
            for name, type_, fmt in self.db.topics.values()
        }

    def scan(self, expected: set[str] | None = None) -> None:
        """Nothing to read: the tables list the topics."""

    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """:meth:`SqliteBag.batches` (send times are receive times)."""
        return self.db.batches(topics)


def _zstd_stream(path: Path) -> BinaryIO:
    import zstandard

    fh = open(path, "rb")
    reader: BinaryIO = zstandard.ZstdDecompressor().stream_reader(fh, closefd=True)
    return reader


#: How each kind of bag file is read (by the end of its name).
PARTS: dict[str, Callable[[Path, list[str], Callable[[str], str]], Part]] = {
    ".mcap": McapPart,
    ".mcap.zstd": McapPart,
    ".db3": SqlitePart,
    ".db3.zstd": SqlitePart,
}


def _part(path: Path, notes: list[str], definitions: Callable[[str], str]) -> Part:
    try:
        for suffix, kind in PARTS.items():
            if path.name.endswith(suffix):
                return kind(path, notes, definitions)
    except OSError as err:
        raise DataError(f"cannot read bag file {str(path)!r}: {err.strerror or err}") from None
    if path.name.endswith(".zstd"):
        raise DataError(
            f"{path}: a zstd-compressed {Path(path.stem).suffix or 'file'}; compressed .mcap "
            "and .db3 files are read (decompress it with `zstd -d`)"
        )
    return McapPart(path, notes, definitions)  # any other name: MCAP by its magic


class Bag:
    """The files of one bag (module docstring); use :meth:`open`."""

    def __init__(
        self, path: Path, files: list[Path], notes: list[str], msg_path: Sequence[Path] = ()
    ):
        self.path = path
        self.notes = notes
        extra = tuple(Path(d) for d in msg_path)
        self._parts = [_part(f, notes, cache(lambda t: find_definition(t, extra))) for f in files]
        self.read: dict[str, int] = {}  # messages handed out per topic
        self.short: list[str] = []  # topics of which fewer messages came than counted
        #: The topics metadata.yaml lists (a scan for topics stops when a file has them all).
        self.expected: set[str] | None = None

    @classmethod
    def open(cls, path: str | Path, *, msg_path: Sequence[str | Path] = ()) -> Bag:
        """A rosbag2 directory or a bag file (``.mcap``, ``.db3``, ``.mcap.zstd``, ``.db3.zstd``).

        ``msg_path``: directories of ``.msg`` files (``pkg/msg/Type.msg``) for types the
        bag does not define and that are not installed.

        Raises
        ------
        DataError
            Not a bag, a storage or compression that is not read, or a listed file missing.
        """
        p = Path(path)
        for d in msg_path:
            if not Path(d).is_dir():
                raise DataFieldError(f"{{msg_path}} {str(d)!r}: not a directory", "msg_path")
        dirs = [Path(d) for d in msg_path]
        notes: list[str] = []
        if p.is_dir():
            meta = p / "metadata.yaml"
            if meta.is_file():
                files, expected = _files_of(p, meta)
                bag = cls(p, files, notes, dirs)
                bag.expected = expected or None
                return bag
            files = sorted(f for f in p.iterdir() if f.name.endswith(BAG_FILES))
            if not files:
                raise DataError(
                    f"{p}: not a bag: no metadata.yaml and no .mcap, .db3, .mcap.zstd or "
                    ".db3.zstd file in the directory"
                )
            notes.append(f"{p} has no metadata.yaml; reading {len(files)} file(s) in name order")
            return cls(p, files, notes, dirs)
        if not p.exists():
            raise DataError(f"cannot read bag {str(p)!r}: no such file or directory")
        return cls(p, [p], notes, dirs)

    @property
    def files(self) -> list[Path]:
        """The bag's files, in reading order."""
        return [f.path for f in self._parts]

    @property
    def cut(self) -> list[str]:
        """Why files were not read whole (empty when every file was)."""
        marks = ("what came before is used", "are left out")
        return [n for n in self.notes if any(m in n for m in marks)] + self.short

    @property
    def topics(self) -> dict[str, Topic]:
        """Every topic of the bag with its type and definition, as far as known unscanned."""
        out: dict[str, Topic] = {}
        for part in self._parts:
            for name, t in part.topics().items():
                prev = out.get(name)
                n = t.messages + (prev.messages if prev else 0)
                out[name] = Topic(
                    name, t.type, t.schema or (prev.schema if prev else ""), t.encoding, n
                )
        return out

    def scanned_topics(self) -> dict[str, Topic]:
        """:attr:`topics`, after scanning the files whose topics are not known without it."""
        for part in self._parts:
            part.scan(self.expected)
        return self.topics

    def batches(self, topics: set[str]) -> Iterator[tuple[str, Batch, IntArray]]:
        """``(topic, batch, sent_ns)`` for the messages of ``topics``, file by file.

        In file order (within a chunk a topic's messages are in record order).
        """
        for part in self._parts:
            got: dict[str, int] = {}
            for topic, batch, sent in part.batches(topics):
                got[topic] = got.get(topic, 0) + batch.size
                self.read[topic] = self.read.get(topic, 0) + batch.size
                yield topic, batch, sent
            for name, t in part.topics().items():  # counts from a summary's statistics
                if name in topics and t.encoding == "cdr" and got.get(name, 0) < t.messages:
                    self.short.append(
                        f"{part.path.name}: read {got.get(name, 0)} of the {t.messages} "
                        f"messages of {name} that its summary counts"
                    )


def _files_of(directory: Path, meta: Path) -> tuple[list[Path], set[str]]:
    """The files metadata.yaml lists, in order, and the topics it names."""
    try:
        doc = yaml.safe_load(meta.read_text())
    except yaml.YAMLError as err:
        raise DataError(f"{meta}: not valid YAML: {yaml_problem(err)}") from None
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise DataError(f"{meta}: no 'rosbag2_bagfile_information' mapping")
    storage = info.get("storage_identifier", "")
    if storage not in ("mcap", "sqlite3", ""):
        raise DataError(f"{meta}: storage {storage!r} is not read (mcap or sqlite3)")
    mode = str(info.get("compression_mode") or "").lower()
    fmt = str(info.get("compression_format") or "").lower()
    if mode in ("", "none") and not fmt:
        mode = ""
    elif mode != "file" or fmt != "zstd":
        raise DataError(
            f"{meta}: compression_mode {info.get('compression_mode')!r} with "
            f"compression_format {info.get('compression_format')!r} is not read (a bag "
            "compressed by file with zstd is); convert it with `ros2 bag convert`"
        )
    rel = info.get("relative_file_paths") or []
    files = [directory / r for r in rel]
    if mode == "file":  # listed compressed; a bag still being recorded lists the plain name
        files = [
            f
            if f.name.endswith(".zstd") or not f.with_name(f.name + ".zstd").is_file()
            else f.with_name(f.name + ".zstd")
            for f in files
        ]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise DataError(f"{meta} lists {', '.join(missing)}, which do not exist")
    if not files:
        raise DataError(f"{meta}: relative_file_paths is empty")
    topics = {
        str(t["topic_metadata"]["name"])
        for t in info.get("topics_with_message_count") or []
        if isinstance(t, dict)
        and isinstance(t.get("topic_metadata"), dict)
        and t["topic_metadata"].get("name")
    }
    return files, topics


def open_bag(path: str | Path, *, msg_path: Sequence[str | Path] = ()) -> Bag:
    """:meth:`Bag.open`."""
    return Bag.open(path, msg_path=msg_path)
