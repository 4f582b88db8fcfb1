# SPDX-License-Identifier: Apache-2.0
"""The loop's y over a window of a record, in the frequency domain, up to free responses.

Over a window of L whole low-rate periods, the lifted loop (:func:`~.simulate.lifted_loop`,
LTI at the low rate) answers its lifted input ``W(q)`` (the unnormalised length-L DFT of
r and the output disturbance over the window) with ``G(z_q) W(q)`` on every bin
``z_q = e^{j2πq/L}``, ``G(z) = D + Σ_i Cm_i Bm_i / (z - λ_i)`` in the modal form: the
*circular* response. A simulation over the window differs from it only by a response of
the loop to some state at the window's start (the state the loop had there, less the
state that makes the response periodic), which lies in the span of the modes' free
responses from the window's start (:meth:`LoopSpectrum.free`). So wherever those are
projected out, as the diagnosis's criterion does, the circular response is the simulation:
O(bins x modes) per model, with no recursion over the samples. The high-rate DFT of y
follows from the lifted one per bin (``Y(k) = Σ_s e^{-j2πks/n} Y_s(k mod L) / √n``, n = LF).
"""

from __future__ import annotations

import functools

import numpy as np

from ..arrays import ComplexArray, FloatArray
from .model import Model
from .simulate import StateRecursion, free_spectrum, lifted_loop, window_phases


def lifted_dft(x: FloatArray, ratio: int) -> ComplexArray:
    """Unnormalised DFT over the low-rate periods of ``x`` (n, ch), n a multiple of F.

    Bins 0..L/2 of the L = n / F periods (the rest are their conjugates), shape
    (L // 2 + 1, F * ch), sample-major (the lifted channel of sample s, channel c is
    ``s * ch + c``), as :func:`~.simulate.lifted_loop` orders its inputs.
    """
    n, ch = x.shape
    return np.asarray(np.fft.rfft(x.reshape(n // ratio, ratio * ch), axis=0), dtype=complex)


@functools.lru_cache(maxsize=8)
def _disturbance_dft(model: Model, start: int, n_samples: int) -> ComplexArray:
    """:func:`lifted_dft` of ``model``'s output disturbance on samples start..start+n-1.

    Cached (read-only): a search moves one cause at a time, so the same disturbance comes
    back with many loops. ``model``: one with nothing but the disturbance's fields set.
    """
    d = lifted_dft(model.disturbance(start, n_samples), model.ratio)
    d.setflags(write=False)
    return d


@functools.lru_cache(maxsize=4)
def _unit_circle(n_periods: int) -> ComplexArray:
    """``e^{j2πq/L}`` on q = 0..L/2 (cached, read-only)."""
    z = np.asarray(np.exp(2j * np.pi * np.arange(n_periods // 2 + 1) / n_periods), complex)
    z.setflags(write=False)
    return z


class LoopSpectrum:
    """The loop of ``model`` (closed loop) as a frequency response over windows.

    ``modal`` is False where the lifted loop is (nearly) defective (StateRecursion then
    warns); ``stable`` whether every pole lies inside the unit circle.
    """

    def __init__(self, model: Model):
        self.model = model
        self._modal = StateRecursion(lifted_loop(model)).modal()
        self.modal = self._modal is not None
        lam = self._modal[0] if self._modal is not None else np.zeros(0)
        self.stable = bool(np.all(np.abs(lam) < 1.0))

    def y(
        self, r_lifted: ComplexArray, n_periods: int, start: int, disturbed: Model | None = None
    ) -> ComplexArray:
        """DFT of y over the window, circular response, shape (n // 2 + 1, n_y).

        ``r_lifted``: :func:`lifted_dft` of r over the window (samples ``start`` to
        ``start + n``, n = L F, L given as ``n_periods``); the output disturbance of
        ``disturbed`` (a model of this loop with other disturbances; default the loop's own
        model) over the same samples enters as well. Orthonormal like
        ``rfft(.., norm="ortho")`` over the n samples.
        """
        if self._modal is None:
            raise ValueError("the lifted loop is defective: no modal form")
        lam, Bm, Cm, D = self._modal
        m = self.model
        F, ny, nr = m.ratio, m.n_y, m.n_r
        L = n_periods
        n = L * F
        W = r_lifted
        Bw, Dw = Bm[:, : F * nr], D[: F * ny, : F * nr]
        v = m if disturbed is None else disturbed
        if v.disturbances:  # the disturbance enters where the noise does: v
            only = Model(v.fs_high, F, m.plant, disturbances=v.disturbances)
            W = np.concatenate([W, _disturbance_dft(only, start, n)], axis=1)
            Bw, Dw = Bm, D[: F * ny]
        z = _unit_circle(L)
        Z = (W @ Bw.T) / (z[:, None] - lam[None, :])  # modal states, (L/2 + 1, modes)
        Yl = Z @ Cm[: F * ny].T + W @ Dw.T  # lifted y on bins 0..L/2, (., F n_y)
        Yl = np.concatenate([Yl, Yl[1 : (L + 1) // 2][::-1].conj()])  # and L/2..L-1
        k = np.arange(n // 2 + 1)
        es = window_phases(n, F)  # e^{-j2πks/n}, (n_bins, F)
        Y = np.einsum("ks,ksc->kc", es, Yl[k % L].reshape(-1, F, ny))
        Y.view(float)[...] *= 1.0 / np.sqrt(n)  # real and imaginary parts alike
        return np.asarray(Y, dtype=complex)

    def free(self, n_samples: int) -> ComplexArray:
        """DFT of every mode's free response of y over a window of ``n_samples``.

        From the window's start, deadbeat and fast modes included (the circular response
        differs from a simulation in all of them); shape (n_bins, n_y, k) as
        :meth:`~.simulate.LoopStream.free_y_spectrum`.
        """
        if self._modal is None:
            raise ValueError("the lifted loop is defective: no modal form")
        lam, _, Cm, _ = self._modal
        return free_spectrum(
            lam, Cm, self.model.ratio, self.model.n_y, n_samples, 0, every_mode=True
        )
