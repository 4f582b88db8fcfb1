# SPDX-License-Identifier: Apache-2.0
"""Starting poles by vector fitting's pole relocation (Gustavsen & Semlyen 1999).

In z (bins on the unit circle, so the partial fractions ``1/(z - λ)`` are well scaled
whatever the frequencies), common poles for every entry, each bin weighted by ``1/σ``:
per iteration solve ``Σ c_e ψ - H_e Σ c̃ ψ ≈ H_e`` in least squares (per entry a QR, whose
lower block gives the shared ``c̃``: the fast form of Deschrijver et al. 2008), then the
new poles are the zeros of ``σ(z) = 1 + Σ c̃ ψ(z)``: ``eig(A - b c̃ᵀ)`` in real form;
unstable ones are mirrored inside the unit circle.
"""

from __future__ import annotations

import numpy as np

from ..arrays import ComplexArray, FloatArray
from .basis import columns, split_pairs, stabilise


def _real_form(poles: ComplexArray) -> tuple[FloatArray, FloatArray]:
    """``A`` (block-diagonal, pairs as ``[[a, b], [-b, a]]``) and ``b`` of σ's realisation."""
    n = int(np.sum(np.where(poles.imag > 0, 2, 1)))
    A = np.zeros((n, n))
    b = np.zeros(n)
    j = 0
    for p in poles:
        if p.imag > 0:
            A[j : j + 2, j : j + 2] = [[p.real, p.imag], [-p.imag, p.real]]
            b[j] = 2.0
            j += 2
        else:
            A[j, j] = p.real
            b[j] = 1.0
            j += 1
    return A, b


def relocate(
    z: ComplexArray,
    H: ComplexArray,
    W: FloatArray,
    poles: ComplexArray,
    *,
    iterations: int = 20,
    direct: bool = False,
) -> ComplexArray:
    """Discrete poles (one of each pair) fitted to ``H`` (K, E) with weights ``W`` (K, E).

    ``poles``: the starting set (inside the unit circle); its order is kept.
    """
    E = H.shape[1]
    for _ in range(iterations):
        Psi = columns(poles, z, "discrete", 1.0)
        n = Psi.shape[1]
        lhs = np.column_stack([Psi, np.ones(z.size)]) if direct else Psi
        nl = lhs.shape[1]
        rows_R, rows_y = [], []
        for e in range(E):
            w = W[:, e]
            M = np.column_stack([w[:, None] * lhs, -(w * H[:, e])[:, None] * Psi])
            Mr = np.vstack([M.real, M.imag])
            y = w * H[:, e]
            yr = np.concatenate([y.real, y.imag])
            scale = np.linalg.norm(Mr, axis=0)
            scale[scale == 0] = 1.0
            R = np.asarray(np.linalg.qr(np.column_stack([Mr / scale, yr]), mode="r"))  # Qᵀy last
            rows_R.append(R[nl:-1, nl:-1] * scale[nl:][None, :])  # on the unscaled c̃
            rows_y.append(R[nl:-1, -1])
        ct, *_ = np.linalg.lstsq(np.vstack(rows_R), np.concatenate(rows_y), rcond=None)
        A, b = _real_form(poles)
        new = split_pairs(np.asarray(np.linalg.eigvals(A - np.outer(b, ct[:n])), dtype=complex))
        new = stabilise(new, "discrete")
        done = new.size == poles.size and np.allclose(
            np.sort_complex(new), np.sort_complex(poles), rtol=1e-8, atol=1e-10
        )
        poles = new
        if done:
            break
    return poles
