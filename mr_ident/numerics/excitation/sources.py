# SPDX-License-Identifier: Apache-2.0
"""Excitation signals and an endless simulated loop, block by block (pure numpy).

:class:`Excitation` is the reference r_h: white noise or a random-phase multisine
repeated period after period; :class:`SimSource` runs the loop of a model on it with
the state carried from block to block (:class:`~mr_ident.numerics.systems.simulate.LoopStream`),
so consecutive blocks equal one long simulation. ``mr-ident-sim`` publishes its blocks.
:class:`Follower` runs the loop on a reference that arrives from outside, block by block
(``mr-ident-sim --reference-topic``).
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import ConfigError
from ..arrays import FloatArray
from ..systems.model import Model
from ..systems.simulate import LoopStream


def multisine(model: Model, period_s: float, rng: np.random.Generator) -> FloatArray:
    """One period (P, n_r) of a random-phase multisine, flat on bins 1..P/2-1.

    Its RMS is the model's ``reference_std``.
    """
    F = model.ratio
    P = F * max(2, int(round(period_s * model.fs_high / F)))
    spec = np.zeros((P // 2 + 1, model.n_r), dtype=complex)
    spec[1 : P // 2] = np.exp(2j * np.pi * rng.random((P // 2 - 1, model.n_r)))
    x = np.fft.irfft(spec, n=P, axis=0)
    out: FloatArray = model.reference_std * x / np.sqrt(np.mean(x**2, axis=0))
    return out


class Excitation:
    """Endless reference: white noise, a multisine period after period, or a signal looped.

    ``kind`` "signal": the given ``signal`` (n, n_r) played in a loop (a designed
    excitation, e.g. every realization of ``mr-ident excite`` one after another).
    """

    def __init__(
        self,
        model: Model,
        kind: str,
        rng: np.random.Generator,
        period_s: float = 10.0,
        signal: FloatArray | None = None,
    ):
        self.model, self.kind, self.rng = model, kind, rng
        self._period = multisine(model, period_s, rng) if kind == "multisine" else None
        if kind == "signal":
            if signal is None or signal.ndim != 2 or signal.shape[1] != model.n_r:
                got = None if signal is None else signal.shape
                raise ConfigError(
                    f"an excitation signal must have shape (n, n_r={model.n_r}), got {got}"
                )
            self._period = np.asarray(signal, float)

    def take(self, first: int, n: int) -> FloatArray:
        """Samples ``first .. first + n - 1`` of the reference, shape (n, n_r)."""
        if self._period is None:
            white: FloatArray = self.model.reference_std * self.rng.standard_normal(
                (n, self.model.n_r)
            )
            return white
        P = self._period.shape[0]
        periodic: FloatArray = self._period[(first + np.arange(n)) % P]
        return periodic


class SimSource:
    """Blocks of (first, r, u, y), exactly continuous, of ``block`` samples each."""

    def __init__(
        self,
        model: Model,
        *,
        block: int,
        excitation: str = "white",
        seed: int = 0,
        period_s: float = 10.0,
        start_index: int = 0,
        signal: FloatArray | None = None,
    ):
        self.model, self.block = model, int(block)
        self.rng = np.random.default_rng(seed)
        self.exc = Excitation(model, excitation, self.rng, period_s, signal)
        self.loop = LoopStream(model)
        self.next_index = start_index
        self._buf = np.zeros((0, model.n_r + model.n_u + model.n_y))

    def next(self) -> tuple[int, FloatArray, FloatArray, FloatArray]:
        """The next block: ``(first, r, u, y)``, each (block, channels)."""
        m, F, b = self.model, self.model.ratio, self.block
        if self._buf.shape[0] < b:
            n = F * math.ceil((b - self._buf.shape[0]) / F)
            start = self.next_index + self._buf.shape[0]
            r = self.exc.take(start, n)
            v = m.noise_std * self.rng.standard_normal((n, m.n_y)) if m.noise_std > 0 else None
            u, y = self.loop.next(r, v)
            self._buf = np.concatenate([self._buf, np.concatenate([r, u, y], axis=1)])
        out, self._buf = self._buf[:b], self._buf[b:]
        first = self.next_index
        self.next_index += b
        nr, nu = m.n_r, m.n_u
        return first, out[:, :nr], out[:, nr : nr + nu], out[:, nr + nu :]


class Follower:
    """The loop driven by reference blocks: each index simulated once, u and y published.

    ``offer(first, r)`` takes a block of r (n, n_r) at index ``first`` and returns the
    (first, u, y) that became ready (whole multiples of F; the rest waits for the next
    block). Pure numpy; ``mr-ident-sim --reference-topic`` feeds it from a
    subscription.
    """

    def __init__(self, model: Model, seed: int = 0) -> None:
        self.model = model
        self.loop = LoopStream(model)
        self.rng = np.random.default_rng(seed)
        self.next: int | None = None  # the first index not yet simulated
        self.start: int | None = None  # the first index simulated
        self._pending = np.zeros((0, model.n_r))
        self.gap_samples = 0
        self.repeated_samples = 0

    @property
    def simulated(self) -> int:
        """Samples simulated so far."""
        return 0 if self.next is None or self.start is None else self.next - self.start

    def offer(self, first: int, r: FloatArray) -> tuple[int, FloatArray, FloatArray] | None:
        """Simulate what ``r`` at ``first`` completes; None when nothing is ready yet."""
        m, F = self.model, self.model.ratio
        r = np.asarray(r, float).reshape(-1, m.n_r)
        if self.next is None:
            start = -(-first // F) * F  # the loop starts on a multiple of F
            r, first = r[start - first :], start
            if r.shape[0] == 0:
                return None
            self.next = self.start = first
        end = self.next + self._pending.shape[0]
        if first + r.shape[0] <= end:
            self.repeated_samples += r.shape[0]
            return None
        if first < end:
            self.repeated_samples += end - first
            r, first = r[end - first :], end
        if first > end:  # never came: the loop ran on with r = 0
            self.gap_samples += first - end
            r = np.concatenate([np.zeros((first - end, m.n_r)), r])
        r = np.concatenate([self._pending, r])
        n = r.shape[0] // F * F
        r, self._pending = r[:n], r[n:]
        if n == 0:
            return None
        v = m.noise_std * self.rng.standard_normal((n, m.n_y)) if m.noise_std > 0 else None
        u, y = self.loop.next(r, v)
        out, self.next = self.next, self.next + n
        return out, u, y
