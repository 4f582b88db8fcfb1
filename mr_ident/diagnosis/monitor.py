"""Monitoring a running loop: drift levels held against alarm storms, and when to diagnose.

Each estimate gives a :class:`~mr_ident.diagnosis.drift.Drift`. :class:`Monitor` turns the
sequence into a status an operator can trust:

- **hysteresis**: the reported level changes only after ``hold`` consecutive estimates
  agree on the new one (a single noisy estimate never flips it);
- **the cause, once per drift**: a diagnosis is asked for when the reported level leaves
  ``ok``, and again only when the drift itself changes (its size by more than
  :data:`RESIZE_DB`, or its significant bins overlapping those of the last diagnosis by
  less than :data:`MIN_OVERLAP`), never for every estimate.

Only estimates move it: a stream problem (a gap, a stall) yields no estimate, so it is never
taken for plant drift (the node says the status is stale meanwhile). Pure state, no threads
and no ROS: the node feeds it and runs what it asks for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import ConfigError
from .drift import LEVELS, Drift

#: A drift whose size moved by more than this (dB) since the last diagnosis is diagnosed again.
RESIZE_DB = 3.0
#: ... or whose significant bins overlap the last diagnosed ones by less than this (IoU).
MIN_OVERLAP = 0.5


@dataclass(frozen=True)
class MonitorState:
    """What :meth:`Monitor.update` reports.

    Attributes
    ----------
    level : str
        The held level (``ok``, ``warn``, ``error``).
    raw_level : str
        This estimate's own level.
    changed : bool
        The held level changed with this estimate.
    diagnose : bool
        A diagnosis of the current window is due.
    drift : Drift
        This estimate's drift.
    """

    level: str
    raw_level: str
    changed: bool
    diagnose: bool
    drift: Drift


class Monitor:
    """Hysteresis and diagnosis scheduling over a sequence of drifts (module docstring)."""

    def __init__(self, hold: int = 3):
        if hold < 1:
            raise ConfigError(f"hold must be >= 1 estimate, got {hold}")
        self.hold = hold
        self.level = "ok"
        self._pending = "ok"
        self._count = 0
        self._diagnosed: tuple[float, NDArray[np.bool_]] | None = None
        self.estimates = 0
        self.alarms = 0  # times the held level left ok

    def update(self, d: Drift) -> MonitorState:
        """Take one estimate's drift; the held state and whether to diagnose."""
        if d.level not in LEVELS:
            raise ConfigError(f"drift level must be one of {LEVELS}, got {d.level!r}")
        self.estimates += 1
        if d.level == self.level:
            self._pending, self._count = self.level, 0
        elif d.level == self._pending:
            self._count += 1
        else:
            self._pending, self._count = d.level, 1
        changed = False
        if self._pending != self.level and self._count >= self.hold:
            if self.level == "ok":
                self.alarms += 1
            self.level, self._count, changed = self._pending, 0, True
        due = False
        if self.level == "ok":
            self._diagnosed = None
        elif d.level != "ok" and self._drift_changed(d):
            self._diagnosed = (d.size_db, d.significant.copy())
            due = True
        return MonitorState(self.level, d.level, changed, due, d)

    def _drift_changed(self, d: Drift) -> bool:
        if self._diagnosed is None:
            return True
        size, mask = self._diagnosed
        if abs(d.size_db - size) > RESIZE_DB or mask.shape != d.significant.shape:
            return True
        union = np.logical_or(mask, d.significant).sum()
        overlap = np.logical_and(mask, d.significant).sum() / union if union else 1.0
        return bool(overlap < MIN_OVERLAP)
