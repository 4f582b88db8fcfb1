# SPDX-License-Identifier: Apache-2.0
"""The one ingest path from decoded messages to the aligned window, for the node and replay.

"Replay equals live" holds because both hand every decoded item - a good block or a
:class:`~mr_ident.io.blocks.BlockError` - to :meth:`Ingest.offer`, which alone decides
what it does to the window: a good block is pushed; a block of NaN/inf samples, whose
indices are known, is a hole (missing samples of u or y within the aligner's bridging
limits, else the stream restarts after it); any other bad block is counted and dropped.
The node adds only wall-clock timing (``now`` and
:meth:`Ingest.expire`); replay expires what never came at the end of the file.
"""

from __future__ import annotations

from ..io.blocks import Block, BlockError
from .align import Aligner


class Ingest:
    """Decoded items of the three streams into an :class:`~mr_ident.live.align.Aligner`."""

    def __init__(self, aligner: Aligner):
        self.aligner = aligner

    def offer(self, stream: int, item: Block | BlockError, now: float = 0.0) -> str | None:
        """Take one decoded item of stream 0 (r), 1 (u), 2 (y) or 3 (the labels, if any).

        ``now`` is the caller's clock.

        Returns None, or what happened for a log line.
        """
        al = self.aligner
        if isinstance(item, Block):
            return al.push(stream, item, now)
        al.count(stream, item.kind)
        if item.kind == "nonfinite" and item.span is not None:
            note = al.hole(stream, *item.span, now=now)
            return f"{note} ({item})" if note else None
        return f"{al.names[stream]}: malformed block dropped: {item}"

    def expire(self, now: float, max_wait: float) -> list[str]:
        """Declare the blocks that waited longer than ``max_wait`` for a missing one a gap."""
        return self.aligner.expire(now, max_wait)
