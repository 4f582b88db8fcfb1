# SPDX-License-Identifier: Apache-2.0
"""A bag's per-sample sources read through the node's own steps into an aligner.

:func:`resolve_sources` (the r, u, y source specs against a bag's topics) and
:func:`read_bag` (every sample through :class:`~mr_ident.live.feed.SourceFeed` and
:class:`~mr_ident.live.ingest.Ingest` into an :class:`~mr_ident.live.align.Aligner`);
:mod:`mr_ident.live.replay` builds replay and the offline readings on them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataError, DataFieldError
from ..io.bags import Bag
from ..io.config import IdentConfig
from ..io.labels import label_sources
from ..io.paths import parse_sources
from ..io.recording import RecordingInfo
from ..io.sources import Resolved, Samples, bag_types, describe, extract, resolve
from .align import Aligner
from .feed import SignalSources, SourceFeed, check_rate, enough_messages
from .gaps import BridgeRule, bridging, config_bridging
from .ingest import Ingest
from .sampling import Sampler


def resolve_sources(
    types: Mapping[str, tuple[str, str]], specs: Mapping[str, Sequence[str]], labels: str = ""
) -> SignalSources:
    """Parse and resolve the ``r``, ``u``, ``y`` source specs against ``types``.

    ``types``: topic -> (type, schema). ``labels``: the topic of an excitation's labels
    (read in its form, :func:`mr_ident.io.labels.label_sources`; "": none).

    Raises
    ------
    DataError
        As :func:`~mr_ident.io.sources.resolve`; the labels' topic missing or of a type
        they do not come in.
    """
    groups = []
    for signal in ("r", "u", "y"):
        parsed = parse_sources(list(specs.get(signal, ())), signal)
        groups.append(tuple(resolve(p, types) for p in parsed))
    found: tuple[Resolved, ...] = ()
    if labels:
        topic = "/" + labels.strip("/")
        if topic not in types:
            raise DataError(
                f"excitation labels: topic {topic} not found (excitation_index_topic); "
                f"there are: {', '.join(sorted(types)) or 'none'}"
            )
        specs_l = parse_sources(list(label_sources(topic, types[topic][0])), "labels")
        found = tuple(resolve(p, types) for p in specs_l)
    out = SignalSources(groups[0], groups[1], groups[2], found)
    out.check()
    return out


@dataclass(frozen=True)
class BagRead:
    """A bag's sources read and aligned: the aligner, notes and what was read."""

    aligner: Aligner
    notes: tuple[str, ...]
    info: RecordingInfo
    fs_high: float
    ratio: int
    sources: str = ""
    node: Aligner | None = None  # with ``node``: the node's own window aligner, fed alike


def read_bag(
    path: str | Path,
    specs: Mapping[str, Sequence[str]],
    *,
    fs_high: float | None,
    ratio: int | None,
    capacity: int | None = None,
    reorder_blocks: int = 8,
    stop: int | None = None,
    history: bool = False,
    msg_path: Sequence[str | Path] = (),
    labels: str = "",
    bridge: BridgeRule | None = None,
    options: IdentConfig | None = None,
    node: IdentConfig | None = None,
) -> BagRead:
    """Every sample of the sources through the node's own steps into an aligner.

    Through :class:`SourceFeed`, into an aligner of ``capacity`` samples (default: all of
    them; ``history``: keeping every span); rates read off the stamps where not
    given, and checked where given. ``msg_path``: directories of ``.msg`` files for types
    the bag does not define. ``labels``: the topic of an excitation's labels, a fourth
    aligned stream ("": none). ``bridge``: the holes of u and y kept as missing samples
    (default: the node's limits over its window with the configuration ``options``, else
    ``identify``'s default options' over ``capacity`` samples or the whole bag).
    ``node``: the same samples also into the node's window aligner of that configuration
    (:attr:`BagRead.node`; the bag read once).

    Raises
    ------
    DataFieldError
        Bare topics given as sources (naming ``{topics}``, ``{r}``, ``{u}``, ``{y}``); rates
        the stamps cannot tell (:func:`~.feed.check_rate`).
    DataError
        An unreadable bag, sources that resolve in none of its topics, too few messages,
        stamps that contradict the rates.
    ConfigError
        The block contract mixed with per-sample sources, r and u of unequal counts.
    """
    bag = Bag.open(path, msg_path=msg_path)
    sources = resolve_sources(bag_types(bag), specs, labels)
    if sources.r[0].kind == "blocks":
        raise DataFieldError(
            f"{path}: bare topics follow the block contract; give them as {{topics}}, not "
            "{r}/{u}/{y}",
            "topics",
            "r",
            "u",
            "y",
        )
    samples = extract(bag, [src for _, _, src in sources.all])
    enough_messages(bag, sources, samples, what=str(path))
    fs, F = check_rate(samples, sources, fs_high, ratio, what=str(path))
    total = max((s.stamps.size for s in samples), default=0) * F
    n = capacity or max((s.stamps.size for s in samples), default=0)
    al = Aligner(
        capacity or max(total, F),
        F,
        reorder_blocks,
        history=history,
        labels=bool(labels),
        bridge=bridge
        or (
            config_bridging(options.replace(ratio=F))
            if options is not None
            else bridging(n, n, ratio=F)
        ),
    )
    feed = SourceFeed(sources, Ingest(al), fs_high=fs, ratio=F)
    if stop is not None:
        feed.sampler.t0 = min(
            int(s.stamps[s.stamps >= 0].min()) for s in samples if (s.stamps >= 0).any()
        )
        samples = [_before(s, feed.sampler, stop) for s in samples]
    notes = feed.push(samples) + Ingest(al).expire(float("inf"), 0.0)
    notes = feed.anomalies() + notes + bag.notes
    window = None
    if node is not None:
        cfg = node.replace(fs_high=fs, ratio=F)
        window = Aligner(
            cfg.window_samples,
            F,
            cfg.reorder_blocks,
            labels=bool(labels),
            bridge=config_bridging(cfg),
        )
        again = SourceFeed(sources, Ingest(window), fs_high=fs, ratio=F)
        again.sampler.t0 = feed.sampler.t0
        again.push(samples)
        Ingest(window).expire(float("inf"), 0.0)
    counts = {t: n for t, n in bag.read.items() if t in sources.topics}
    info = RecordingInfo(messages=counts, truncated=bool(bag.cut), reason="; ".join(bag.cut))
    what = describe([s for _, _, s in sources.all])
    return BagRead(al, tuple(notes), info, fs, F, what, window)


def _before(s: Samples, sampler: Sampler, stop: int) -> Samples:
    idx, _ = sampler.indices(s.stamps)
    keep = idx < stop
    return Samples(s.stamps[keep], s.values[keep], s.valid[keep], s.log_time)
