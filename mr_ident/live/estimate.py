# SPDX-License-Identifier: Apache-2.0
"""One estimate from one aligned window: the step the node repeats and replay runs once.

:func:`estimate` takes a window (:class:`~mr_ident.numerics.signals.LoopData` with its
``first`` index) and an :class:`~mr_ident.io.config.IdentConfig`, resolves the lifting
phase (parameter or detected), runs :func:`~mr_ident.numerics.identify.identify` and returns an
:class:`Estimate`. The node and ``mr-ident replay`` call exactly this, so the
same window gives the same numbers in both.

A window that carries an excitation's labels (``excitation_index_topic``) and holds whole
periods of it is identified as the best linear approximation instead
(:mod:`mr_ident.live.periodic`: the period means give P_h at the excited lines, their
spread over the periods the noise std); with too few whole periods, as any window.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ..errors import DataError
from ..io.config import IdentConfig
from ..numerics.excitation.bla import BLA
from ..numerics.identify import identify
from ..numerics.results import Identification
from ..numerics.signals import LoopData
from ..numerics.structure import Settled, held_phase, read_structure, settle_structure
from ..numerics.systems.lti import TransferMatrix
from .periodic import bla_identification, cut_by_labels, periodic_bla


@dataclass(frozen=True)
class PhaseDetection:
    """Result of :func:`detect_phase`.

    Attributes
    ----------
    phase : int
        Sampling phase (0..F-1, absolute index mod F) = hold phase - control delay.
    hold : int
        Index (mod F) at which the held controller output changes.
    contrast : float
        Within-period variation of u - r at the best hold phase relative to the
        next best (0: clear; near 1: undetermined, e.g. open loop or F = 1).
    """

    phase: int
    hold: int
    contrast: float

    @property
    def determined(self) -> bool:
        """Whether the phase is clear (contrast below 0.1)."""
        return self.contrast < 0.1


def detect_phase(
    first: int, r: NDArray, u: NDArray, ratio: int, control_delay: int = 0
) -> PhaseDetection:
    """Detect the controller's phase from u - r = -H_u K_l S_d y (held over F samples).

    ``first`` is the absolute index of the first sample. For each candidate hold
    phase h the variation of u - r between consecutive samples *inside* the hold
    intervals starting at indices = h (mod F) is summed; the true h gives (nearly) 0.
    """
    F = int(ratio)
    hold, contrast = held_phase(first, np.asarray(u, dtype=float) - np.asarray(r, dtype=float), F)
    return PhaseDetection((hold - control_delay) % F, hold, contrast)


def low_rate_output(first: int, y: NDArray, ratio: int) -> tuple[NDArray, int]:
    """The output measured at the low rate, from its samples on the high-rate grid: (y_l, q).

    A low-rate y source reaches the grid held (``.@hold``: each sample covers F indices
    from its own), so the samples are taken where the held y changes (:func:`held_phase`;
    q = 0 when that is not clear, e.g. a y at the high rate: then every F-th sample).
    Returns y_l (N/F, n_y), its first sample at the record's sample q (0..F-1): the
    ``y_phase`` of :func:`~mr_ident.numerics.identify.identify`.
    """
    F = int(ratio)
    hold, contrast = held_phase(first, y, F)
    q = (hold - first) % F if contrast < 0.1 else 0
    return y[q::F], q


@dataclass(frozen=True)
class Estimate:
    """One identification of one window.

    Attributes
    ----------
    first, n_samples : int
        The window: absolute indices [first, first + n_samples).
    identification : Identification
        P_h (and the PFG when the controller is configured), full resolution.
    phase : int
        Lifting phase used (absolute index mod F at which the controller samples).
    phase_source : str
        "parameter", "auto", or "auto (undetermined: 0 assumed)".
    compute_s : float
        Wall time of the identification.
    bla : BLA or None
        The best linear approximation, when the window's labels gave whole periods (then
        ``identification`` is it on the excited lines).
    periodic : str
        What the window's labels gave ("" without labels): the periods used, or why the
        window was identified as any other.
    period : int
        Samples per period of the BLA (0 without one).
    structure : str
        What the window showed of the loop (the hold, F, where r enters), in words.
    """

    first: int
    n_samples: int
    identification: Identification
    phase: int
    phase_source: str
    compute_s: float
    bla: BLA | None = None
    periodic: str = ""
    period: int = 0
    structure: str = ""


def _phase(window: LoopData, config: IdentConfig, loop: Settled) -> tuple[int, str]:
    """The lifting phase of ``window``: the parameter, else read from the hold.

    The hold the structure read exactly (:func:`~mr_ident.numerics.structure.hold_of`),
    else the hold's contrast (:func:`~mr_ident.numerics.structure.held_phase`, for a u - r
    logged with noise).
    """
    F = config.ratio
    if config.phase is not None:
        return config.phase, "parameter"
    found = loop.found
    if found.ratio == F and found.hold_start is not None and found.held != "u":
        return (found.hold_start + window.first - config.control_delay) % F, "auto"
    det = detect_phase(window.first, window.r, window.u, F, config.control_delay)
    if det.determined:
        return det.phase, "auto"
    return 0, "auto (undetermined: 0 assumed)"


def loop_structure(window: LoopData, config: IdentConfig) -> Settled:
    """Where r enters the window's loop and, for a setpoint, the controller's phase.

    Read from the window (:func:`~mr_ident.numerics.structure.read_structure`) and checked
    against the parameters ``ratio``, ``injection`` and ``lifting_phase``
    (:func:`~mr_ident.numerics.structure.settle_structure`: ConfigError where the data
    contradict one). The phase is the window's (relative to its first sample).
    """
    F = config.ratio
    phases = [] if config.phase is None else [("lifting_phase", (config.phase - window.first) % F)]
    return settle_structure(
        read_structure(window.r, window.u, window.y),
        ratios=[("the ratio parameter", F)],
        injections=[] if config.injection == "auto" else [("injection", config.injection)],
        phases=phases,
    )


def estimate(window: LoopData, config: IdentConfig) -> Estimate:
    """Identify P_h (and the PFG) from one aligned window; see the module docstring."""
    t0 = time.perf_counter()
    F = config.ratio
    loop = loop_structure(window, config)
    if loop.injection == "setpoint":
        hold = loop.found.hold_start
        q = loop.phase if loop.phase is not None else ((hold or 0) - config.control_delay) % F
        phase = (q + window.first) % F
        source = "parameter" if config.phase is not None else "auto"
    else:
        phase, source = _phase(window, config, loop)
    periodic = ""
    if window.labels is not None:
        try:
            cut = cut_by_labels(window, None, config.transient_periods)
        except DataError as err:
            periodic = f"no BLA ({err}): identified with {config.method}"
        else:
            bla = periodic_bla(cut, F)
            if loop.injection == "setpoint":  # the PFG from data is r-at-the-plant-input's
                bla = replace(bla, pfg=None, pfg_std=None)
            ident = bla_identification(bla, cut.period, config.fs_high, F)
            return Estimate(
                window.first, window.n_samples, ident, phase, source,
                time.perf_counter() - t0, bla, f"BLA from {cut.describe()}", cut.period,
            )  # fmt: skip
    window, cut_note = _r_determined(window, loop.injection, (phase - window.first) % F, config)
    controller = config.controller
    K_low = None if controller is None else _controller_low(controller, window.n_samples // F)
    y, y_phase = window.y, 0
    if config.y_rate == "low":
        y, y_phase = low_rate_output(window.first, window.y, F)
    ident = identify(
        window.r,
        window.u,
        y,
        fs_high=config.fs_high,
        ratio=F,
        method=config.method,
        n=config.identify_n,
        degree=config.degree,
        local=config.local,
        controller_low=K_low,
        phase=(phase - window.first) % F,
        delay=config.control_delay,
        keep_lifted=False,
        workers=config.workers,
        y_phase=y_phase,
        injection=loop.injection,
    )
    # The result does not depend on the number of threads (bit-identical).
    dt = time.perf_counter() - t0
    return Estimate(
        window.first, window.n_samples, ident, phase, source, dt, None, periodic,
        structure=loop.found.describe() + cut_note,
    )  # fmt: skip


def _r_determined(
    window: LoopData, injection: str, phase: int, config: IdentConfig
) -> tuple[LoopData, str]:
    """The window, or its part after r's last hole, and a note ("": the window).

    Where the loop leaves too many of r's holes undetermined
    (:func:`~mr_ident.numerics.missing_r.recover_r`), the window restarts after the last
    one, as it does after any hole it cannot bridge. DataError when that part is shorter
    than ``min_window_s``.
    """
    if not np.isnan(window.r).any():
        return window, ""
    from ..numerics.missing_r import recover_r

    F = config.ratio
    try:
        recover_r(window.r, window.u, window.y, ratio=F, injection=injection, phase=phase)
    except DataError as err:
        last = int(np.flatnonzero(np.isnan(window.r).any(axis=1))[-1])
        lo = -(-(last + 1) // F) * F  # whole blocks after it
        part = window.part(lo, window.n_samples // F * F)
        if part.n_samples < config.min_samples:
            raise DataError(
                f"{err}; after the last of them {part.n_samples} samples remain, fewer than "
                f"min_window_s = {config.min_window_s:g} s"
            ) from None
        reason = str(err).split(":")[0]
        return part, f"; {reason}: identified after the last of them, [{part.first}, {part.end})"
    return window, ""


@functools.lru_cache(maxsize=2)
def _controller_low(controller: TransferMatrix, n_low: int) -> NDArray[np.complex128]:
    """K_l on the n_low low-rate bins of a window (read-only; the node's windows share it).

    Every estimate of a node has the same window length: evaluated once, not per estimate.
    """
    K = controller.dft_response(n_low)
    K.flags.writeable = False
    return K


def warm_up(config: IdentConfig, n_samples: int | None = None) -> float:
    """Run one identification of a synthetic window and discard it; return its wall time.

    The first identification in a process pays one-time costs: FFT plans for the
    window length, the LPM's kernel tables, the first touch of its working memory (the
    first identification of a process is the slower: docs/benchmarks.md, "Choices in the
    code"). The node calls this once at start-up, off the executor
    thread, so that its first real estimate does not. The window is
    ``n_samples`` (default ``config.window_samples``) of white noise with the configured
    channels (the sources' or K_l's n_u and n_y; SISO for block topics without a
    controller), method, n, R, F, controller and threads.
    """
    N = (
        config.window_samples
        if n_samples is None
        else config.ratio * (int(n_samples) // config.ratio)
    )
    n_u = len(config.u_source) or config.controller_rows
    n_y = len(config.y_source) or config.controller_cols
    rng = np.random.default_rng(0)
    r, u, y = (rng.standard_normal((N, c)) for c in (n_u, n_u, n_y))
    return estimate(LoopData(r, u, y, ratio=config.ratio), config).compute_s


def publish_grid(n_bins: int, points: int) -> NDArray[np.intp]:
    """At most ``points`` bin indices out of ``n_bins``.

    Log-spaced (duplicates at the dense low end merged), first and last kept.
    """
    if n_bins <= points:
        return np.arange(n_bins)
    return np.unique(np.round(np.geomspace(1, n_bins, points)).astype(np.intp) - 1)
