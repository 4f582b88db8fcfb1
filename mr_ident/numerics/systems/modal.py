# SPDX-License-Identifier: Apache-2.0
"""A plant in modal form: :class:`ModalPlant` (poles, matrix residues, direct term).

``G(x) = D + Σ_k R_k / (x - p_k)`` over real poles and complex pairs (each pair once, with
``Im p > 0``, its conjugate implied), ``x`` = s (``dt`` None) or z (sample time ``dt``).
A complex pair contributes ``(C1 x + C0) / ((x - σ)² + ω²)`` with ``C1 = 2 Re R`` and
``C0 = -2 Re(R p̄)`` (real matrices): the form the model file holds (``modes``), realised
as one real modal block ``[[σ, ω], [-ω, σ]]`` per pair and input — no polynomial, so a
fitted model of any order is simulated exactly (:mod:`~mr_ident.numerics.systems.realize`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ...errors import DimensionError
from ..arrays import ComplexArray, FloatArray, readonly
from .lti import StateSpace


@dataclass(frozen=True, eq=False)
class ModalPlant:
    """``D + Σ R_k / (x - p_k)`` (+ conjugates of the complex poles).

    Attributes
    ----------
    poles : ndarray, shape (n_p,), complex128
        Real poles and one pole of each complex pair (``Im p > 0``).
    residues : ndarray, shape (n_p, n_out, n_in), complex128
        ``R_k``; real for a real pole.
    direct : ndarray, shape (n_out, n_in), float64
    dt : float or None
        None: continuous (s); else the sample time of z.
    """

    poles: ComplexArray
    residues: ComplexArray
    direct: FloatArray
    dt: float | None = None

    def __post_init__(self) -> None:
        p = readonly(self.poles, np.complex128, copy=True)
        r = readonly(self.residues, np.complex128, copy=True)
        d = readonly(self.direct, np.float64, copy=True)
        if p.ndim != 1 or np.any(p.imag < 0):
            raise DimensionError("poles must be 1-D with Im p >= 0 (one pole of each pair)")
        if d.ndim != 2 or r.shape != (p.size, *d.shape):
            raise DimensionError(
                f"residues must have shape (n_poles={p.size}, n_out, n_in) = "
                f"({p.size}, {d.shape[0] if d.ndim == 2 else '?'}, ...), got {r.shape}"
            )
        object.__setattr__(self, "poles", p)
        object.__setattr__(self, "residues", r)
        object.__setattr__(self, "direct", d)

    @property
    def shape(self) -> tuple[int, int]:
        """(n_out, n_in)."""
        return int(self.direct.shape[0]), int(self.direct.shape[1])

    @property
    def order(self) -> int:
        """Number of states per input: real poles count one, complex pairs two."""
        return int(np.sum(np.where(self.poles.imag > 0, 2, 1)))

    def all_poles(self) -> ComplexArray:
        """Every pole, conjugates included, shape (order,)."""
        cplx = self.poles[self.poles.imag > 0]
        return np.concatenate([self.poles, cplx.conj()])

    def modes(self) -> list[tuple[complex, FloatArray, FloatArray]]:
        """Complex pairs as ``(p, C1, C0)``: ``(C1 x + C0) / ((x - p)(x - p̄))``."""
        out = []
        for p, R in zip(self.poles, self.residues, strict=True):
            if p.imag > 0:
                out.append((complex(p), 2.0 * R.real, -2.0 * (R * np.conj(p)).real))
        return out

    def freqresp(self, frequency: ArrayLike) -> ComplexArray:
        """``G`` at ``frequency`` Hz, shape (K, n_out, n_in)."""
        f = np.atleast_1d(np.asarray(frequency, dtype=float))
        x = 2j * np.pi * f if self.dt is None else np.exp(2j * np.pi * f * self.dt)
        out = np.broadcast_to(self.direct.astype(complex), (f.size, *self.shape)).copy()
        for p, R in zip(self.poles, self.residues, strict=True):
            out += R[None] / (x - p)[:, None, None]
            if p.imag > 0:
                out += np.conj(R)[None] / (x - np.conj(p))[:, None, None]
        return out

    def state_space(self) -> StateSpace:
        """A real realisation: per pole and input a modal block (pairs) or one state.

        A pair's block per input column ``c1 x + c0`` over ``(x-σ)² + ω²``:
        ``A = [[σ, ω], [-ω, σ]]``, ``B = [0, ω]ᵀ``, ``C = [(c0 + c1 σ)/ω, c1] / ω``.
        """
        no, ni = self.shape
        blocks_a, blocks_b, blocks_c = [], [], []
        for p, R in zip(self.poles, self.residues, strict=True):
            if p.imag > 0:
                sig, om = float(p.real), float(p.imag)
                c1 = 2.0 * R.real
                c0 = -2.0 * (R * np.conj(p)).real
                for i in range(ni):
                    blocks_a.append(np.array([[sig, om], [-om, sig]]))
                    b = np.zeros((2, ni))
                    b[1, i] = om
                    blocks_b.append(b)
                    blocks_c.append(
                        np.column_stack([(c0[:, i] + c1[:, i] * sig) / om, c1[:, i]]) / om
                    )
            else:
                for i in range(ni):
                    blocks_a.append(np.array([[float(p.real)]]))
                    b = np.zeros((1, ni))
                    b[0, i] = 1.0
                    blocks_b.append(b)
                    blocks_c.append(R.real[:, i : i + 1])
        n = sum(a.shape[0] for a in blocks_a)
        A = np.zeros((n, n))
        k = 0
        for a in blocks_a:
            m = a.shape[0]
            A[k : k + m, k : k + m] = a
            k += m
        B = np.vstack(blocks_b) if blocks_b else np.zeros((0, ni))
        C = np.hstack(blocks_c) if blocks_c else np.zeros((no, 0))
        return StateSpace(A, B, C, self.direct.copy(), self.dt)

    def with_mode(self, index: int, pole: complex, scale: float) -> ModalPlant:
        """The plant with pole ``index`` moved to ``pole`` and its numerator scaled.

        The pair's ``C1 x + C0`` times ``scale`` is kept for the new pole: the new residue
        is ``(C1 p + C0) / (p - p̄)`` times ``scale``.
        """
        p0 = complex(self.poles[index])
        R0 = self.residues[index]
        c1, c0 = 2.0 * R0.real, -2.0 * (R0 * np.conj(p0)).real
        R = scale * (c1 * pole + c0) / (pole - np.conj(pole))
        poles = self.poles.copy()
        residues = self.residues.copy()
        poles[index] = pole
        residues[index] = R
        return ModalPlant(poles, residues, self.direct, self.dt)
