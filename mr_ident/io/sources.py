# SPDX-License-Identifier: Apache-2.0
"""Sources resolved against the topics they read, and their samples out of a bag.

A :class:`~mr_ident.io.paths.SourceSpec` names a topic and a path; :func:`resolve` finds
the topic's type (from the schema a bag embeds, or an installed type on a live graph),
checks the path against it (an error names the fields that exist) and decides how to
read it:

``path``
    Any message type: the path is evaluated on every message (:func:`mr_ident.io.layout.evaluate`).
``blocks``
    A bare topic of ``std_msgs/msg/Float64MultiArray``: the block contract.
``introspection``
    ``/controller_manager/introspection_data{name=="..."}``: ros2_control's introspection
    (pal_statistics). Read from ``<topic>/full`` (``Statistics``: the path becomes
    ``.statistics[:]{name=="..."}.value``) or from ``<topic>/values`` (``StatisticsValues``)
    with the names of ``<topic>/names`` (``StatisticsNames``) of the same ``names_version``.

:func:`samples` gives, per source, the stamps (``header.stamp``, else the bag's log time)
and the values of every message; turning stamps into sample indices is the live layer's
(:mod:`mr_ident.live.sampling`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import DataError, DataFieldError
from ..numerics.arrays import BoolArray, FloatArray, IntArray
from .bags import Bag
from .blocks import BLOCK_TYPE
from .cdr import Batch, check, element_at, header_stamp, string_arrays
from .layout import Layout, evaluate
from .msgdef import Registry, parse_schema
from .paths import SourceSpec, Step

STATISTICS = "pal_statistics_msgs/msg/Statistics"
STATISTICS_VALUES = "pal_statistics_msgs/msg/StatisticsValues"
STATISTICS_NAMES = "pal_statistics_msgs/msg/StatisticsNames"


@dataclass(frozen=True)
class Resolved:
    """A source and how to read it (module docstring).

    Attributes
    ----------
    spec : SourceSpec
        As written (for messages); ``path`` the one evaluated (rewritten for ``/full``).
    topic, type : str
        The topic actually read and its message type.
    kind : {"path", "blocks", "introspection"}
    registry : dict
        The message definitions of ``type``.
    names_topic : str
        For ``introspection`` from ``/values``: the topic with the names.
    stamped : bool
        The type has ``header.stamp``; else the log (receive) time is the stamp.
    """

    spec: SourceSpec
    path: SourceSpec
    topic: str
    type: str
    kind: str
    registry: Registry
    names_topic: str = ""
    stamped: bool = True


def resolve(spec: SourceSpec, types: Mapping[str, tuple[str, str]]) -> Resolved:
    """Resolve ``spec`` against ``types``: topic -> (type name, ros2msg schema text).

    Raises
    ------
    DataError
        The topic is not there (naming those that are), the type's schema is missing, the
        path does not exist in the type, or a bare topic does not follow the block contract.
    """
    where = f"source {spec.text!r}"
    if spec.topic not in types:
        intro = _introspection(spec, types)
        if intro is not None:
            return intro
        raise DataError(
            f"{where}: topic {spec.topic} not found; there are: "
            f"{', '.join(sorted(types)) or 'none'}"
        )
    type_name, schema = types[spec.topic]
    if spec.block_contract:
        if type_name != BLOCK_TYPE:
            raise DataError(
                f"{where}: topic {spec.topic} has type {type_name!r}; a bare topic must follow "
                f"the block contract ({BLOCK_TYPE}); give a field path, e.g. {spec.topic}.data"
            )
        return Resolved(spec, spec, spec.topic, type_name, "blocks", {}, stamped=False)
    if spec.steps and spec.steps[0].kind == "sibling":
        raise DataError(
            f"{where}: a filter right after the topic is only for the introspection "
            f"topics ({spec.topic}/full, /values); {spec.topic} is a {type_name}"
        )
    reg = _registry(spec, type_name, schema)
    check(reg, type_name, spec)
    return Resolved(
        spec, spec, spec.topic, type_name, "path", reg, stamped=_stamped(reg, type_name)
    )


def _registry(spec: SourceSpec, type_name: str, schema: str) -> Registry:
    if not schema:
        raise DataFieldError(
            f"source {spec.text!r}: no message definition of {type_name}: the bag embeds none "
            "and it is not installed; give {msg_path} DIR with its .msg files (and those it "
            f"uses) as DIR/{type_name.split('/')[0]}/msg/<Type>.msg",
            "msg_path",
        )
    return parse_schema(type_name, schema)


def _stamped(reg: Registry, type_name: str) -> bool:
    return any(f.name == "header" and f.type == "std_msgs/msg/Header" for f in reg[type_name])


def _introspection(spec: SourceSpec, types: Mapping[str, tuple[str, str]]) -> Resolved | None:
    steps = spec.steps
    if len(steps) != 1 or steps[0].kind != "sibling" or steps[0].key != "name":
        return None
    name = steps[0].value
    full, values, names = (f"{spec.topic}/{s}" for s in ("full", "values", "names"))
    if full in types and types[full][0] == STATISTICS:
        path = replace(
            spec,
            topic=full,
            steps=(
                Step("field", name="statistics"),
                Step("match", key="name", value=name),
                Step("field", name="value"),
            ),
        )
        reg = _registry(spec, STATISTICS, types[full][1])
        check(reg, STATISTICS, path)
        return Resolved(spec, path, full, STATISTICS, "path", reg)
    if values in types and names in types and types[values][0] == STATISTICS_VALUES:
        reg = _registry(spec, STATISTICS_VALUES, types[values][1])
        return Resolved(
            spec, spec, values, STATISTICS_VALUES, "introspection", reg, names_topic=names
        )
    return None


@dataclass
class Samples:
    """What one source gave: per message its stamp (ns), value and whether it is valid."""

    stamps: IntArray
    values: FloatArray
    valid: BoolArray
    log_time: bool  # stamps are the log (receive) times: the type has no header


def evaluate_batch(
    src: Resolved,
    batch: Batch,
    names: Mapping[int, list[str]] | None = None,
    cache: dict[str, Layout] | None = None,
) -> tuple[FloatArray, BoolArray]:
    """The source's value of every message of ``batch`` (a batch of ``src.topic``).

    ``cache``: a dict kept per source across batches (the fast path's layouts).
    """
    if src.kind == "path":
        v = evaluate(batch, src.registry, src.type, src.path, cache)
        return v.value, v.valid
    if src.kind == "introspection":
        target = src.spec.steps[0].value
        version = evaluate(
            batch,
            src.registry,
            src.type,
            replace(src.spec, steps=(Step("field", name="names_version"),)),
            cache,
        ).value
        index = np.full(batch.size, -1, dtype=np.int64)
        for ver, lst in (names or {}).items():
            if target in lst:
                index[version == ver] = lst.index(target)
        v = element_at(batch, src.registry, src.type, "values", index, src.spec)
        return v.value, v.valid
    raise DataError(f"source {src.spec.text!r}: the block contract is read as blocks, not values")


def stamps_of(src: Resolved, batch: Batch, sent: IntArray) -> IntArray:
    """``header.stamp`` of each message (ns).

    For a type without header, ``sent``: the time the message was sent (live: the DDS source
    timestamp; in a bag: its publish time, else its log time).
    """
    s = header_stamp(batch, src.registry, src.type) if src.stamped else None
    return sent if s is None else s


def names_by_version(reg: Registry, batch: Batch) -> dict[int, list[str]]:
    """``names_version`` -> names, from a batch of ``StatisticsNames`` messages."""
    spec = SourceSpec("names_version", "", (Step("field", name="names_version"),))
    versions = evaluate(batch, reg, STATISTICS_NAMES, spec).value.astype(np.int64)
    lists = string_arrays(batch, reg, STATISTICS_NAMES, "names")
    return {int(v): lst for v, lst in zip(versions, lists, strict=True)}


def describe(sources: Sequence[Resolved]) -> str:
    """One line per source: what is read from where (for logs and errors)."""
    return "; ".join(f"{s.spec.text} <- {s.topic} ({s.type}, {s.kind})" for s in sources)


def extract(bag: Bag, sources: Sequence[Resolved]) -> list[Samples]:
    """Every message's stamp and value for each source.

    Read from ``bag`` in one pass (the names of the introspection topics first).
    """
    names: dict[str, dict[int, list[str]]] = {}
    name_topics = {s.names_topic for s in sources if s.names_topic}
    if name_topics:
        types = bag.topics
        for topic, batch, _ in bag.batches(name_topics):
            reg = parse_schema(STATISTICS_NAMES, types[topic].schema)
            names.setdefault(topic, {}).update(names_by_version(reg, batch))
    parts: list[list[tuple[IntArray, FloatArray, BoolArray]]] = [[] for _ in sources]
    by_topic: dict[str, list[int]] = {}
    for i, s in enumerate(sources):
        by_topic.setdefault(s.topic, []).append(i)
    caches: list[dict[str, Layout]] = [{} for _ in sources]
    for topic, batch, log in bag.batches(set(by_topic)):
        for i in by_topic.get(topic, []):
            src = sources[i]
            value, valid = evaluate_batch(src, batch, names.get(src.names_topic), caches[i])
            parts[i].append((stamps_of(src, batch, log), value, valid))
    out = []
    for src, pieces in zip(sources, parts, strict=True):
        if pieces:
            st, va, ok = (np.concatenate([p[k] for p in pieces]) for k in range(3))
        else:
            st, va, ok = np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool)
        out.append(Samples(st, va, ok, not src.stamped))
    return out


def bag_types(bag: Bag) -> dict[str, tuple[str, str]]:
    """Topic -> (type, schema text) of a bag, for :func:`resolve`."""
    return {t.name: (t.type, t.schema) for t in bag.scanned_topics().values()}
