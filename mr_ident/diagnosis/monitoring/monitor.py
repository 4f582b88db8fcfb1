# SPDX-License-Identifier: Apache-2.0
"""Monitoring a running loop: drift levels held against alarm storms, and when to diagnose.

Each estimate gives a :class:`~mr_ident.diagnosis.monitoring.drift.Drift`. :class:`Monitor`
turns the sequence into a status an operator can trust:

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

import time
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from ...errors import ConfigError
from ...io.config import IdentConfig
from ...io.datafile import read_result
from ...io.modelfile import load_model
from ...live.estimate import Estimate, estimate
from ...numerics.identify import method_of
from ...numerics.local.lpm import dof as lpm_dof
from ...numerics.local.lpm import reaches_dc
from ...numerics.signals import LoopData
from ...numerics.systems.model import Model
from ..criterion.holes import diagnosable
from .drift import LEVELS, Drift, Reference, drift

if TYPE_CHECKING:
    from ..diagnose import Diagnosis

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


@dataclass(frozen=True)
class WindowDiagnosis:
    """A diagnosis of a monitored window, as the node publishes it (JSON-able ``as_dict``)."""

    cause: str
    parameters: dict[str, float]
    std: dict[str, float]
    findings: list[str]
    fit_before: float
    fit_after: float
    window_first: int
    window_samples: int
    seconds: float

    def as_dict(self) -> dict[str, object]:
        """Plain types only (finite numbers; inf/nan as None)."""

        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "cause": self.cause,
            "parameters": {k: num(v) for k, v in self.parameters.items()},
            "std": {k: num(v) for k, v in self.std.items()},
            "findings": list(self.findings),
            "fit_before": num(self.fit_before),
            "fit_after": num(self.fit_after),
            "window_first": self.window_first,
            "window_samples": self.window_samples,
            "seconds": self.seconds,
        }

    def headline(self) -> str:
        """One line for a status message: the findings, or that nothing was found."""
        if self.cause == "none":
            return "cause: none found (the model explains this window)"
        return "cause: " + "; ".join(self.findings)


class PlantWatch:
    """Monitoring of one loop against a reference: what the node and replay both run.

    ``reference``: the drift baseline; ``model``: the model that names causes (None: the
    cause is not sought); ``config``: the identification settings (method, n, degree) the
    estimates come from, and the monitor_* thresholds. The monitor's request for a
    diagnosis is passed on once the estimate's window lies wholly after the change (after
    the end of the first drifted estimate's window): within two windows of the change.
    """

    def __init__(self, reference: Reference, model: Model | None, config: IdentConfig):
        self.reference = reference
        self.model = model
        self.config = config
        self.monitor = Monitor(config.monitor_hold)
        self.last: MonitorState | None = None
        #: First sample index whose windows hold only drifted data (the end of the first
        #: drifted estimate's window), None while the estimates agree with the reference.
        self.onset: int | None = None
        self._pending = False

    def observe(self, est: Estimate) -> MonitorState:
        """Hold one estimate against the reference; the monitor's new state."""
        cfg = self.config
        ident = est.identification
        plant = ident.plant
        _, n_y, n_u = plant.response.shape
        n = (
            np.asarray(ident.n_used, float)
            if ident.n_used is not None  # n = auto: the window chosen per bin
            else np.full(plant.frequency.size, cfg.lpm_n(n_u, n_y), float)
        )
        # a setpoint's fit is the high-rate lpm's, whatever the configured method
        method = method_of("lpm" if ident.injection == "setpoint" else cfg.method)
        q = np.ones_like(n)  # no noise model (etfe): its std is nan, nothing is tested
        if method.uses_lpm:  # the dof of each window width used (a handful of widths)
            widths, where = np.unique(n, return_inverse=True)
            n_in = n_u * method.lift(cfg.ratio)
            q = np.array([max(lpm_dof(int(w), cfg.degree, n_in), 1) for w in widths])[where]
        d = drift(
            plant,
            self.reference,
            dof=q,
            alpha=cfg.monitor_alpha,
            error_db=cfg.monitor_error_db,
            untested=reaches_dc(plant.frequency, cfg.fs_high / est.n_samples, n),
        )
        state = self.monitor.update(d)
        end = est.first + est.n_samples
        if d.level != "ok" and self.onset is None:
            self.onset = end
        elif state.level == "ok" and d.level == "ok":
            self.onset = None
        # a diagnosis is run on a window that lies wholly after the change: a window that
        # straddles it would fit a blend of the old and the new plant
        self._pending = (self._pending or state.diagnose) and state.level != "ok"
        fresh = self.onset is not None and est.first >= self.onset
        due = self._pending and fresh
        if due:
            self._pending = False
        self.last = replace(state, diagnose=due)
        return self.last

    @property
    def waiting(self) -> bool:
        """A diagnosis is due once a window after the change is in."""
        return self._pending

    def diagnose(self, window: LoopData, est: Estimate) -> WindowDiagnosis | None:
        """The cause of the drift in ``window`` (the estimate's), or None without a model."""
        if self.model is None:
            return None
        t0 = time.perf_counter()
        window, _ = diagnosable(window, self.model)  # its holes within the limits: all of it
        d = diagnose_window(self.model, window)
        return WindowDiagnosis(
            d.cause,
            dict(d.parameters),
            dict(d.applied[0].std) if d.applied else {},
            [a.description for a in d.applied],
            float(d.fit_before.y),
            float(d.fit_after.y),
            int(window.first),
            int(window.n_samples),
            time.perf_counter() - t0,
        )


def diagnose_window(model: Model, window: LoopData) -> Diagnosis:
    """The diagnosis of ``model`` on one live window (its ``first`` an absolute index).

    The model's sampling phase is taken relative to the window's first sample; r enters
    where the window shows it entered (:func:`~mr_ident.diagnosis.diagnose.diagnose` reads
    it).
    """
    from ..diagnose import diagnose  # the heavy part, only when a window is diagnosed

    local = replace(model, sample_phase=(model.sample_phase - window.first) % model.ratio)
    data = replace(window, fs_high=model.fs_high, ratio=model.ratio, first=0)
    return diagnose(local, data)


def load_watch(cfg: IdentConfig) -> PlantWatch | None:
    """The watch ``cfg``'s monitor_* parameters ask for, or None (monitoring off).

    ConfigError/DataError naming the file and what is wrong with it (unreadable, another
    rate or F than the node's).
    """
    if not (cfg.monitor_model or cfg.monitor_reference):
        return None
    model: Model | None = None
    if cfg.monitor_model:
        model = load_model(cfg.monitor_model)
        if (model.fs_high, model.ratio) != (cfg.fs_high, cfg.ratio):
            raise ConfigError(
                f"monitor_model {cfg.monitor_model!r} is at fs_high = {model.fs_high:g} Hz, "
                f"F = {model.ratio}; the loop runs at fs_high = {cfg.fs_high:g} Hz, "
                f"F = {cfg.ratio}"
            )
    if cfg.monitor_reference:
        reference = Reference.of_frf(read_result(cfg.monitor_reference))
    else:
        assert model is not None  # one of the two is given
        reference = Reference.of_model(model)
    return PlantWatch(reference, model, cfg)


@dataclass(frozen=True)
class StatusEvent:
    """A change of the plant status in a replay: when (loop s), the level, in words."""

    time_s: float
    level: str
    text: str


def watch_windows(
    windows: Iterable[tuple[float, LoopData, IdentConfig]], watch: PlantWatch
) -> list[StatusEvent]:
    """Monitoring over recorded windows, as the node runs it live: the status changes.

    ``windows``: (loop time, window, config) as :func:`~mr_ident.live.replay.bag_windows`
    yields them. An event where the held level changes and where a cause is found (the
    diagnosis runs inline here, on the same window the node would use).
    """
    out: list[StatusEvent] = []
    for t, w, cfg in windows:
        est = estimate(w, cfg)
        state = watch.observe(est)
        if state.changed or not out:
            text = state.drift.describe() if state.level != "ok" else "matches the reference"
            out.append(StatusEvent(t, state.level, text))
        if state.diagnose:
            found = watch.diagnose(w, est)
            if found is not None:
                out.append(StatusEvent(t, state.level, found.headline()))
    return out
