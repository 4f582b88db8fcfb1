# SPDX-License-Identifier: Apache-2.0
"""The block contract: blocks of high-rate samples on a topic (the package's own dialect).

A ``std_msgs/msg/Float64MultiArray`` carries one block of consecutive high-rate
samples of one signal,

* ``layout.dim[0]``: label ``"samples"``, size n, stride n*c;
* ``layout.dim[1]``: label ``"channels"``, size c, stride c;
* ``layout.data_offset = 1`` and ``data[0]`` = index of the block's first sample
  (an integer >= 0, exact as a double below 2**53);
* ``data[1 + i*c + j]`` = sample ``first + i`` of channel j (row-major).

:func:`decode_block` checks one block and gives a :class:`Block`, or raises a
:class:`BlockError` (which, for NaN/inf samples, says which indices are lost).
Pure Python/numpy: the node, recordings and replay share it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ..errors import DataError
from ..numerics.arrays import FloatArray

#: The message type of the contract.
BLOCK_TYPE = "std_msgs/msg/Float64MultiArray"
SAMPLES, CHANNELS = "samples", "channels"
STREAMS = ("reference", "input", "output")  # r_h, u_h, y_h
#: The fourth stream beside r, u, y: an excitation's labels (3 channels: realization,
#: period, sample of the period; :mod:`mr_ident.numerics.excitation.schedule`) at the samples'
#: indices.
LABELS_STREAM = "excitation_index"
MAX_INDEX = 2**53


class BlockError(DataError):
    """A block that breaks the topic contract; ``kind`` is "malformed" or "nonfinite".

    ``span`` is ``(first, n)``, the indices the block covered, when they are known (a
    block of NaN/inf samples): they are lost, a hole in the stream.
    """

    def __init__(self, kind: str, reason: str, span: tuple[int, int] | None = None):
        super().__init__(reason)
        self.kind = kind
        self.span = span


@dataclass(frozen=True)
class Block:
    """One decoded block: ``samples`` (n, channels) starting at index ``first``."""

    first: int
    samples: FloatArray

    @property
    def end(self) -> int:
        """Index one past the block's last sample."""
        return self.first + int(self.samples.shape[0])


def encode_fields(
    first: int, samples: ArrayLike
) -> tuple[list[tuple[str, int, int]], int, FloatArray]:
    """The (dims, data_offset, data) of a block, for any Float64MultiArray writer."""
    x = np.asarray(samples, dtype=float)
    x = x[:, None] if x.ndim == 1 else x
    n, c = x.shape
    data = np.empty(1 + n * c)
    data[0] = first
    data[1:] = x.ravel()
    return [(SAMPLES, n, n * c), (CHANNELS, c, c)], 1, data


def decode_block(dims: Sequence[tuple[str, int, int]], data_offset: int, data: ArrayLike) -> Block:
    """Check and decode one block (see the module docstring).

    Raises
    ------
    BlockError
        kind "malformed" for any layout violation, "nonfinite" for NaN/inf samples.
    """
    if len(dims) != 2 or dims[0][0] != SAMPLES or dims[1][0] != CHANNELS:
        got = [d[0] for d in dims]
        raise BlockError(
            "malformed", f"layout dims must be labelled {[SAMPLES, CHANNELS]}, got {got}"
        )
    (_, n, s0), (_, c, s1) = dims
    if n < 1 or c < 1 or s1 != c or s0 != n * c:
        raise BlockError(
            "malformed",
            f"layout sizes/strides inconsistent: samples size {n} stride {s0}, "
            f"channels size {c} stride {s1} (need stride {n * c} and {c})",
        )
    if data_offset != 1:
        raise BlockError(
            "malformed",
            f"layout.data_offset must be 1 (data[0] is the first index), got {data_offset}",
        )
    values = np.asarray(data, dtype=float)
    if len(values) != 1 + n * c:
        raise BlockError(
            "malformed", f"data has {len(values)} values, layout needs 1 + {n}*{c} = {1 + n * c}"
        )
    first = float(values[0])
    if not (np.isfinite(first) and first == int(first) and 0 <= first < MAX_INDEX):
        raise BlockError(
            "malformed",
            f"data[0] (first sample index) must be an integer in [0, 2^53), got {first!r}",
        )
    x = values[1:].reshape(n, c)
    if not np.isfinite(x).all():
        bad = int(np.flatnonzero(~np.isfinite(x).all(axis=1))[0])
        raise BlockError(
            "nonfinite",
            f"sample {int(first) + bad} (block starting at {int(first)}) is NaN or inf",
            (int(first), n),
        )
    return Block(int(first), x)


def cdr_fields(payload: bytes) -> tuple[list[tuple[str, int, int]], int, FloatArray]:
    """The layout dims, data_offset and data of one CDR ``Float64MultiArray`` message.

    Raises
    ------
    BlockError
        ``malformed``: the bytes end before the message does.
    """
    import struct

    base = 4  # alignment origin: after the encapsulation header
    p = base

    def align(p: int, k: int) -> int:
        return base + (p - base + k - 1) // k * k

    try:
        p = align(p, 4)
        (ndim,) = struct.unpack_from("<I", payload, p)
        p += 4
        dims = []
        for _ in range(ndim):
            p = align(p, 4)
            (n,) = struct.unpack_from("<I", payload, p)
            label = payload[p + 4 : p + 4 + max(n - 1, 0)].decode(errors="replace")
            p = align(p + 4 + n, 4)
            size, stride = struct.unpack_from("<II", payload, p)
            dims.append((label, int(size), int(stride)))
            p += 8
        p = align(p, 4)
        offset, count = struct.unpack_from("<II", payload, p)
        p = align(p + 8, 8) if count else p + 8
        if p + 8 * count > len(payload):
            raise struct.error("data runs past the message")
        data = np.frombuffer(payload, dtype="<f8", count=count, offset=p).astype(float)
    except struct.error as err:
        raise BlockError("malformed", f"undecodable message: {err}") from None
    return dims, int(offset), data
