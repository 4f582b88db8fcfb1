# SPDX-License-Identifier: Apache-2.0
"""The fixed-layout fast path of reading a source: one read per value for a whole batch.

Most topics keep their layout message after message (JointState with the same joints,
Float64, controller states): a source's value then lies at the same offset in every
message. :func:`evaluate` walks the path on one message only, noting every byte the
layout depends on (lengths, counts, the strings a filter compares); the messages of the
batch with the same length and the same bytes there are read at that offset, all at
once. Messages whose layout changed go through :func:`mr_ident.io.cdr.walk_all`, the walk
over all messages at once, which handles any layout. A :class:`Layout` is kept per source
from batch to batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cdr import Batch, Values, Walk, walk_all, walk_path
from .msgdef import Registry
from .paths import SourceSpec


@dataclass
class Layout:
    """Where a source's value lies in messages of one layout (the fast path's template).

    ``struct`` are the byte ranges the layout depends on (offsets from the first byte after
    the encapsulation header) and ``expect`` the bytes they hold; ``value`` the offset and
    dtype of the value; ``length`` the message length.
    """

    length: int
    struct: list[tuple[int, int]]
    expect: np.ndarray
    value: tuple[int, str]
    span: tuple[int, int]
    cols: np.ndarray


def evaluate(
    batch: Batch,
    reg: Registry,
    root: str,
    spec: SourceSpec,
    cache: dict[str, Layout] | None = None,
) -> Values:
    """Follow ``spec``'s path through every message of ``batch`` (of type ``root``).

    Fast path: the path is walked on one message only, noting every byte its layout
    depends on (lengths, counts, the strings a filter compares); the messages with the
    same length and the same bytes there hold the value at the same offset, one read for
    all. The others (a layout that changed) go through the walk over all of them. Give
    ``cache`` (a dict kept per source) to reuse the layout from batch to batch.

    Raises
    ------
    DataError
        The path does not exist in the type (naming the fields that do), or does not end
        at a number.
    """
    if batch.size >= FAST_MIN:
        layout = cache.get(spec.text) if cache is not None else None
        if layout is None:
            layout = _layout(batch, 0, reg, root, spec)
        if layout is not None:
            fast = _fixed_layout(batch, layout, reg, root, spec)
            if cache is not None:
                cache[spec.text] = layout
            if fast is not None:
                return fast
    return walk_all(batch, reg, root, spec)


#: Batches at least this large try the fixed-layout fast path first.
FAST_MIN = 16


def _layout(batch: Batch, i: int, reg: Registry, root: str, spec: SourceSpec) -> Layout | None:
    """The layout of message ``i`` (None when the path gives it no single value)."""
    one = Batch(batch.buf, batch.offset[i : i + 1], batch.length[i : i + 1])
    w = Walk(one, record=True)
    _, ok = walk_path(
        w, reg, root, w.base.copy(), np.ones(1, dtype=bool), list(spec.steps), spec=spec
    )
    assert w.log is not None
    reads = [e for e in w.log if e[2]]
    if not ok[0] or w.bad[0] or len(reads) != 1:
        return None
    struct = [(rel, np.dtype(dt).itemsize) for rel, dt, is_value in w.log if not is_value]
    lo = min((r for r, _ in struct), default=0)
    hi = max((r + k for r, k in struct), default=0)
    cols = np.zeros(hi - lo, dtype=bool)
    for r, k in struct:
        cols[r - lo : r - lo + k] = True
    expect = w.gather(w.base + lo, hi - lo)[0, cols] if struct else np.zeros(0, np.uint8)
    return Layout(int(one.length[0]), struct, expect, reads[0][:2], (lo, hi), cols)


def _fixed_layout(
    batch: Batch, layout: Layout, reg: Registry, root: str, spec: SourceSpec
) -> Values | None:
    """:func:`evaluate`'s fast path with ``layout``; None when no message has it."""
    base = batch.offset + 4
    same = batch.length == layout.length
    whole = Walk(batch)
    lo, hi = layout.span
    if layout.struct:
        rows = whole.gather(base + lo, hi - lo)[:, layout.cols]
        same &= np.all(rows == layout.expect[None, :], axis=1)
    if not same.any():
        return None
    rel, dtype = layout.value
    value = whole.read(base + rel, dtype).astype(np.float64)
    valid = same & ~whole.bad
    if not same.all():
        rest = ~same
        other = walk_all(Batch(batch.buf, batch.offset[rest], batch.length[rest]), reg, root, spec)
        value[rest], valid[rest] = other.value, other.valid
    return Values(value, valid)
