# SPDX-License-Identifier: Apache-2.0
"""CDR (ROS 2's serialization) read for a batch of messages at once.

A :class:`Batch` holds the serialized payloads of n messages of one type in one byte
buffer. :func:`walk_all` follows a source path (:mod:`mr_ident.io.paths`) through all
of them together: every field on the way is one NumPy operation over the n messages
(align, read a length, skip), so the cost per batch grows with the number of fields
visited, not with the number of messages. Messages whose layout differs (another
``frame_id``, another joint order, a longer array) need no fallback: positions are
arrays, one per message. Sequences of strings or of messages are walked element by
element, each step again over all messages at once.

CDR as ROS 2 writes it (XCDR1, little endian): a 4-byte encapsulation header
``00 01 00 00``, then the fields in order, each aligned to its size relative to the
first byte after the header; strings are a uint32 length (with the terminating NUL)
and the bytes; sequences a uint32 count and the elements, aligned only when there is
one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from ..numerics.arrays import BoolArray, FloatArray, IntArray
from .msgdef import DTYPES, PRIMITIVES, Field, Registry
from .paths import SourceSpec, Step

_U32 = np.dtype("<u4")


@dataclass(frozen=True)
class Batch:
    """Serialized messages.

    ``buf`` (uint8) and, per message, the offset of its first byte (the encapsulation
    header) and its length.
    """

    buf: np.ndarray
    offset: IntArray
    length: IntArray

    @classmethod
    def of(cls, payloads: list[bytes]) -> Batch:
        """A batch from separate payloads (live messages)."""
        lengths = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=len(payloads))
        offsets = np.zeros(len(payloads), dtype=np.int64)
        np.cumsum(lengths[:-1], out=offsets[1:])
        return cls(np.frombuffer(b"".join(payloads), dtype=np.uint8), offsets, lengths)

    @property
    def size(self) -> int:
        """The number of messages."""
        return int(self.offset.size)


class Walk:
    """Positions of n messages moved together through their CDR fields."""

    def __init__(self, batch: Batch, record: bool = False):
        self.b = batch
        #: With ``record``: every read of message 0 as (offset from its base, dtype, is_value).
        self.log: list[tuple[int, str, bool]] | None = [] if record else None
        self.base = batch.offset + 4  # alignment origin
        self.end = batch.offset + batch.length
        self.bad = np.zeros(batch.size, dtype=bool)  # ran past the end: malformed
        self._windows: dict[int, np.ndarray] = {}
        head = self.gather(batch.offset, 2)
        if batch.size and not (np.all(head[:, 0] == 0) and np.all(head[:, 1] == 1)):
            kinds = sorted({bytes(h).hex() for h in head})
            raise DataError(f"only little-endian CDR (encapsulation 0001) is read; found {kinds}")

    def gather(self, pos: IntArray, width: int) -> np.ndarray:
        """The ``width`` bytes at each position, (n, width).

        One row gather from a strided view of overlapping windows (no index matrix);
        positions clipped into the buffer.
        """
        win = self._windows.get(width)
        if win is None:
            buf = self.b.buf
            if buf.size < width:
                buf = np.concatenate([buf, np.zeros(width - buf.size, np.uint8)])
            win = self._windows[width] = np.lib.stride_tricks.as_strided(
                buf, (buf.size - width + 1, width), (1, 1), writeable=False
            )
        out: np.ndarray = win[np.clip(pos, 0, win.shape[0] - 1)]
        return out

    def align(self, pos: IntArray, size: int) -> IntArray:
        """``pos`` moved up to a multiple of ``size`` from each message's alignment origin."""
        if size <= 1:
            return pos
        rel = pos - self.base
        return self.base + (rel + size - 1) // size * size

    def read(self, pos: IntArray, dtype: str, value: bool = False) -> np.ndarray:
        """A ``dtype`` value at each position (``value``: the source's value, for the log)."""
        dt = np.dtype(dtype)
        if self.log is not None and pos.size:
            self.log.append((int(pos[0] - self.base[0]), dtype, value))
        self.bad |= pos + dt.itemsize > self.end
        return self.gather(pos, dt.itemsize).view(dt)[:, 0]

    def count(self, pos: IntArray) -> tuple[IntArray, IntArray]:
        """A uint32 length at ``pos`` (aligned); returns it and the position after it."""
        p = self.align(pos, 4)
        n = self.read(p, "<u4").astype(np.int64)
        n = np.where(self.bad, 0, n)
        return n, p + 4

    def string_match(self, pos: IntArray, text: str) -> tuple[BoolArray, IntArray]:
        """Whether the string at ``pos`` equals ``text``; and the position after it."""
        n, p = self.count(pos)
        target = np.frombuffer(text.encode() + b"\0", dtype=np.uint8)
        if self.log is not None and p.size:
            self.log.append((int(p[0] - self.base[0]), f"S{target.size}", False))
        same = (n == target.size) & np.all(self.gather(p, target.size) == target[None, :], axis=1)
        return same, p + n

    def skip(self, f: Field, pos: IntArray, reg: Registry, active: BoolArray) -> IntArray:
        """The position after field ``f`` at ``pos`` (only where ``active``)."""
        if f.array is None:
            return self.skip_one(f.type, pos, reg, active)
        if f.array >= 0:
            n = np.full(pos.shape, f.array, dtype=np.int64)
            p = pos
        else:
            n, p = self.count(pos)
            n = np.where(active, n, 0)
        size = PRIMITIVES.get(f.type, 0)
        if size:
            p = np.where(n > 0, self.align(p, size), p)
            return np.where(active, p + n * size, pos)
        for k in range(int(n.max(initial=0))):
            p = self.skip_one(f.type, p, reg, active & (k < n))
        return np.where(active, p, pos)

    def skip_one(self, type_: str, pos: IntArray, reg: Registry, active: BoolArray) -> IntArray:
        """The position after one value of ``type_`` at ``pos`` (only where ``active``)."""
        if type_ in ("string", "wstring"):
            n, p = self.count(pos)
            width = 4 if type_ == "wstring" else 1
            return np.where(active, p + n * width, pos)
        size = PRIMITIVES.get(type_)
        if size:
            return np.where(active, self.align(pos, size) + size, pos)
        for f in reg[type_]:
            pos = self.skip(f, pos, reg, active)
        return pos

    def fields(
        self, type_: str, pos: IntArray, reg: Registry, active: BoolArray, wanted: set[str]
    ) -> dict[str, IntArray]:
        """Start positions of the ``wanted`` fields of ``type_`` at ``pos`` (walks no further)."""
        out: dict[str, IntArray] = {}
        for f in reg[type_]:
            if f.name in wanted:
                out[f.name] = pos
                if len(out) == len(wanted):
                    return out
            pos = self.skip(f, pos, reg, active)
        missing = sorted(wanted - set(out))
        raise DataError(
            f"{type_} has no field {missing[0]!r}; it has {', '.join(x.name for x in reg[type_])}"
        )


def _field(reg: Registry, type_: str, name: str, spec: SourceSpec) -> Field:
    for f in reg[type_]:
        if f.name == name:
            return f
    have = ", ".join(f.name for f in reg[type_])
    raise DataError(f"source {spec.text!r}: {type_} has no field {name!r}; its fields: {have}")


@dataclass(frozen=True)
class Values:
    """What a path gave for each message.

    ``value`` (float64) and whether it is ``valid`` (False where a filter matched nothing,
    an index was out of range, or the message was malformed).
    """

    value: FloatArray
    valid: BoolArray


def walk_all(batch: Batch, reg: Registry, root: str, spec: SourceSpec) -> Values:
    """Follow ``spec``'s path through every message of ``batch`` at once (any layouts).

    Raises
    ------
    DataError
        The path does not exist in the type (naming the fields that do), or does not end
        at a number.
    """
    w = Walk(batch)
    active = np.ones(batch.size, dtype=bool)
    value, valid = walk_path(w, reg, root, w.base.copy(), active, list(spec.steps), spec=spec)
    return Values(value, valid & ~w.bad)


def walk_path(
    w: Walk,
    reg: Registry,
    type_: str,
    pos: IntArray,
    active: BoolArray,
    steps: list[Step],
    *,
    spec: SourceSpec,
) -> tuple[FloatArray, BoolArray]:
    """The rest ``steps`` of a path from ``pos`` (messages of type ``type_``) on ``w``."""
    if not steps:
        raise DataError(
            f"source {spec.text!r} ends at a message of type {type_}, not at a number; "
            f"its fields: {', '.join(f.name for f in reg[type_])}"
        )
    step, rest = steps[0], steps[1:]
    if step.kind != "field":
        raise DataError(
            f"source {spec.text!r}: {type_} is a message, not an array; "
            f"expected .field, its fields: {', '.join(f.name for f in reg[type_])}"
        )
    f = _field(reg, type_, step.name, spec)
    if rest and rest[0].kind == "sibling":
        sib = rest[0]
        key = _field(reg, type_, sib.key, spec)
        if f.array is None or key.array is None:
            raise DataError(
                f"source {spec.text!r}: {{{sib.key}==...}} after .{f.name} needs two "
                f"arrays ({f.name} and {sib.key}) in {type_}"
            )
        both = w.fields(type_, pos, reg, active, {f.name, key.name})
        index, found = _find(w, key, both[key.name], sib.value, active, spec)
        return _element(w, reg, f, both[f.name], index, active & found, rest=rest[1:], spec=spec)
    at = w.fields(type_, pos, reg, active, {f.name})[f.name]
    if f.array is not None:
        if not rest or rest[0].kind not in ("index", "match"):
            raise DataError(
                f"source {spec.text!r}: {f.name} is an array ({f.type}); "
                "expected [i], [:]{field==value} or {sibling==value} after it"
            )
        sel = rest[0]
        if sel.kind == "index":
            count = _count(w, f, at)
            idx = np.where(sel.index < 0, count + sel.index, sel.index)
            return _element(
                w, reg, f, at, idx, active & (idx >= 0) & (idx < count), rest=rest[1:], spec=spec
            )
        if f.primitive:
            raise DataError(
                f"source {spec.text!r}: [:]{{...}} filters an array of messages; "
                f"{f.name} holds {f.type}"
            )
        return _match(w, reg, f, at, sel, active, rest=rest[1:], spec=spec)
    if f.primitive:
        if rest:
            raise DataError(f"source {spec.text!r}: {f.name} is a {f.type}; nothing follows it")
        return _scalar(w, f.type, at, spec), active.copy()
    return walk_path(w, reg, f.type, at, active, rest, spec=spec)


def _scalar(
    w: Walk, type_: str, pos: IntArray, spec: SourceSpec, value: bool = True
) -> FloatArray:
    if type_ not in DTYPES:
        raise DataError(f"source {spec.text!r} ends at a {type_}, not at a number")
    size = PRIMITIVES[type_]
    return w.read(w.align(pos, size), DTYPES[type_], value).astype(np.float64)


def _count(w: Walk, f: Field, pos: IntArray) -> IntArray:
    if f.array is not None and f.array >= 0:
        return np.full(pos.shape, f.array, dtype=np.int64)
    return w.count(pos)[0]


def _element(
    w: Walk,
    reg: Registry,
    f: Field,
    pos: IntArray,
    index: IntArray,
    active: BoolArray,
    *,
    rest: list[Step],
    spec: SourceSpec,
) -> tuple[FloatArray, BoolArray]:
    """Element ``index`` (per message) of array field ``f`` at ``pos``, then the path's rest."""
    if f.array is not None and f.array >= 0:
        count, p = np.full(pos.shape, f.array, dtype=np.int64), pos
    else:
        count, p = w.count(pos)
    index = np.where(active, index, 0)
    size = PRIMITIVES.get(f.type, 0)
    if size:
        if rest:
            raise DataError(
                f"source {spec.text!r}: the elements of {f.name} are {f.type}; nothing follows"
            )
        p = np.where(count > 0, w.align(p, size), p)
        return _scalar(w, f.type, p + index * size, spec), active.copy()
    for k in range(int(np.max(np.where(active, index, 0), initial=0))):
        p = w.skip_one(f.type, p, reg, active & (k < index))
    if f.primitive:
        raise DataError(f"source {spec.text!r}: {f.name} holds {f.type}, not numbers")
    return walk_path(w, reg, f.type, p, active, rest, spec=spec)


def _find(
    w: Walk, key: Field, pos: IntArray, value: str | float, active: BoolArray, spec: SourceSpec
) -> tuple[IntArray, BoolArray]:
    """Per message, the index in array ``key`` where it holds ``value`` (first match)."""
    count, p = (
        w.count(pos) if key.array == -1 else (np.full(pos.shape, key.array or 0, np.int64), pos)
    )
    index = np.zeros(pos.shape, dtype=np.int64)
    found = np.zeros(pos.shape, dtype=bool)
    size = PRIMITIVES.get(key.type, 0)
    if key.type == "string":
        if not isinstance(value, str):
            raise DataError(f'source {spec.text!r}: {key.name} holds strings; compare with "..."')
        for k in range(int(np.max(np.where(active, count, 0), initial=0))):
            live = active & (k < count)
            same, p = w.string_match(p, value)
            hit = live & same & ~found
            index[hit], found[hit] = k, True
        return index, found
    if not size or isinstance(value, str):
        raise DataError(
            f"source {spec.text!r}: cannot compare {key.name} ({key.type}) with {value!r}"
        )
    p = np.where(count > 0, w.align(p, size), p)
    for k in range(int(np.max(np.where(active, count, 0), initial=0))):
        live = active & (k < count)
        hit = live & ~found & (w.read(p + k * size, DTYPES[key.type]) == value)
        index[hit], found[hit] = k, True
    return index, found


def _match(
    w: Walk,
    reg: Registry,
    f: Field,
    pos: IntArray,
    sel: Step,
    active: BoolArray,
    *,
    rest: list[Step],
    spec: SourceSpec,
) -> tuple[FloatArray, BoolArray]:
    """``f[:]{key==value}`` then ``rest``: the first element of the array that matches."""
    key = _field(reg, f.type, sel.key, spec)
    if key.array is not None:
        raise DataError(
            f"source {spec.text!r}: {f.type}.{sel.key} is an array; filter on a single value"
        )
    count, p = w.count(pos) if f.array == -1 else (np.full(pos.shape, f.array or 0, np.int64), pos)
    out = np.zeros(pos.shape)
    found = np.zeros(pos.shape, dtype=bool)
    for k in range(int(np.max(np.where(active, count, 0), initial=0))):
        live = active & (k < count) & ~found
        kp = w.fields(f.type, p, reg, live, {key.name})[key.name]
        if key.type == "string":
            if not isinstance(sel.value, str):
                raise DataError(f'source {spec.text!r}: {sel.key} is a string; compare with "..."')
            hit = live & w.string_match(kp, sel.value)[0]
        else:
            if isinstance(sel.value, str):
                raise DataError(
                    f"source {spec.text!r}: {sel.key} is a {key.type}; compare with a number"
                )
            hit = live & (_scalar(w, key.type, kp, spec, value=False) == sel.value)
        if hit.any():
            v, ok = walk_path(w, reg, f.type, p, hit, rest, spec=spec)
            out = np.where(hit, v, out)
            found |= hit & ok
        p = w.skip_one(f.type, p, reg, active & (k < count))
    if not found.any():  # the rest of the path is checked even with no match
        walk_path(w, reg, f.type, p, np.zeros_like(active), rest, spec=spec)
    return out, found


def element_at(
    batch: Batch, reg: Registry, root: str, name: str, index: IntArray, spec: SourceSpec
) -> Values:
    """Element ``index[i]`` of the top-level array field ``name`` of message i.

    For an index known per message, e.g. from a names list.
    """
    w = Walk(batch)
    f = _field(reg, root, name, spec)
    if f.array is None:
        raise DataError(f"source {spec.text!r}: {root}.{name} is not an array")
    pos = w.fields(root, w.base.copy(), reg, np.ones(batch.size, bool), {name})[name]
    count = _count(w, f, pos)
    ok = (index >= 0) & (index < count)
    value, valid = _element(w, reg, f, pos, index, ok, rest=[], spec=spec)
    return Values(value, valid & ~w.bad)


def check(reg: Registry, root: str, spec: SourceSpec) -> None:
    """Raise the DataError :func:`evaluate` would: the path against the type, without data."""
    empty = Batch(np.zeros(0, dtype=np.uint8), np.zeros(0, np.int64), np.zeros(0, np.int64))
    walk_all(empty, reg, root, spec)


def header_stamp(batch: Batch, reg: Registry, root: str) -> IntArray | None:
    """``header.stamp`` of every message in ns, or None when the type has no ``header``."""
    if not any(f.name == "header" and f.type == "std_msgs/msg/Header" for f in reg[root]):
        return None
    w = Walk(batch)
    if reg[root][0].name == "header":  # the usual case: the stamp is the first 8 bytes
        hp = w.base
    else:
        hp = w.fields(root, w.base.copy(), reg, np.ones(batch.size, bool), {"header"})["header"]
    hp = w.align(hp, 4)
    w.bad |= hp + 8 > w.end
    raw = w.gather(hp, 8)
    sec = raw[:, :4].copy().view("<i4")[:, 0].astype(np.int64)
    nsec = raw[:, 4:].copy().view("<u4")[:, 0].astype(np.int64)
    return np.where(w.bad, -1, sec * 1_000_000_000 + nsec)


def string_arrays(batch: Batch, reg: Registry, root: str, name: str) -> list[list[str]]:
    """The string array field ``name`` of each message.

    Decoded (for the few name lists of the introspection topics).
    """
    w = Walk(batch)
    pos = w.fields(root, w.base.copy(), reg, np.ones(batch.size, bool), {name})[name]
    out = []
    for i in range(batch.size):
        p = int(pos[i])
        base = int(w.base[i])
        p = base + (p - base + 3) // 4 * 4
        n = int(np.frombuffer(batch.buf[p : p + 4].tobytes(), "<u4")[0])
        p += 4
        items = []
        for _ in range(n):
            p = base + (p - base + 3) // 4 * 4
            size = int(np.frombuffer(batch.buf[p : p + 4].tobytes(), "<u4")[0])
            items.append(
                batch.buf[p + 4 : p + 4 + max(size - 1, 0)].tobytes().decode(errors="replace")
            )
            p += 4 + size
        out.append(items)
    return out
