# SPDX-License-Identifier: Apache-2.0
"""The streams the :class:`~mr_ident.live.align.Aligner` meets, by index: :class:`Stream`."""

from __future__ import annotations

from enum import IntEnum


class Stream(IntEnum):
    """One stream of the aligner; its value is its index (``io.blocks.STREAMS``' order).

    An ``IntEnum``: callers that pass the plain index (0 for r ...) keep working.
    """

    REFERENCE = 0  #: r_h, the excitation (recovered from the loop where missing)
    INPUT = 1  #: u_h, the plant input
    OUTPUT = 2  #: y_h, the plant output
    LABELS = 3  #: an excitation's labels (realization, period, sample), when streamed


#: r, u, y: the loop's signals (without the labels).
SIGNALS = (Stream.REFERENCE, Stream.INPUT, Stream.OUTPUT)
