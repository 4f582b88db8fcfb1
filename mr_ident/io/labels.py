# SPDX-License-Identifier: Apache-2.0
"""An excitation's labels beside its signal: their topic, and the sources that read them.

``mr-ident excite --publish TOPIC`` puts each sample's labels (realization, period,
sample of the period; :data:`~mr_ident.numerics.excitation.schedule.LABELS`) on
``TOPIC/excitation_index`` in the form of the signal (:mod:`mr_ident.ros.excite_pub`):

- the block contract: a block of 3 channels at the samples' indices (read as a fourth
  block stream beside r, u, y);
- ``sensor_msgs/JointState``: one message per sample with the samples' stamp, the labels
  in ``position`` under the names ``realization``, ``period``, ``sample``;
- ``std_msgs/Float64MultiArray`` per sample: ``data = [realization, period, sample]``.

:func:`label_sources` gives the source specs (:mod:`mr_ident.io.paths`) that read the two
per-sample forms, so the labels go the way of r, u and y: stamps to indices, aligned by
index (:mod:`mr_ident.live.feed`, :mod:`mr_ident.live.align`).
"""

from __future__ import annotations

from ..errors import DataError
from ..numerics.excitation.schedule import LABELS
from .blocks import BLOCK_TYPE

#: The labels' topic, under the signal's topic.
INDEX_TOPIC = "excitation_index"
JOINT_STATE = "sensor_msgs/msg/JointState"


def index_topic(topic: str) -> str:
    """The topic of the labels of the samples published on ``topic``."""
    return f"{topic.rstrip('/')}/{INDEX_TOPIC}"


def label_sources(topic: str, type_name: str) -> tuple[str, ...]:
    """The three per-sample source specs reading the labels on ``topic`` of ``type_name``.

    Raises
    ------
    DataError
        ``type_name`` is not a form the labels are published in.
    """
    if type_name == JOINT_STATE:
        return tuple(f'{topic}.position{{name=="{name}"}}' for name in LABELS)
    if type_name == BLOCK_TYPE:
        return tuple(f"{topic}.data[{i}]" for i in range(len(LABELS)))
    raise DataError(
        f"excitation labels: topic {topic} has type {type_name!r}; the labels come as "
        f"{JOINT_STATE} or {BLOCK_TYPE} (mr-ident excite --publish --as ...)"
    )
