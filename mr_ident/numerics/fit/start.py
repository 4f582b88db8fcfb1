# SPDX-License-Identifier: Apache-2.0
"""Starting poles by vector fitting's pole relocation (Gustavsen & Semlyen 1999).

In z (bins on the unit circle, so the partial fractions ``1/(z - λ)`` are well scaled
whatever the frequencies), common poles for every entry, each bin weighted by ``1/σ``:
per iteration solve ``Σ c_e ψ - H_e Σ c̃ ψ ≈ H_e`` in least squares (per entry the Schur
complement of its own coefficients' block, summed over entries, gives the shared ``c̃``:
the fast form of Deschrijver et al. 2008, on Gram matrices over blocks of bins), then the
new poles are the zeros of ``σ(z) = 1 + Σ c̃ ψ(z)``: ``eig(A - b c̃ᵀ)`` in real form;
unstable ones are mirrored inside the unit circle.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..arrays import ComplexArray, FloatArray
from .basis import columns, split_pairs, stabilise
from .normal import gram, solve

#: Relocations without a decrease of the judged cost beyond the tolerance that stop them.
PATIENCE = 15


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


def _sigma(
    z: ComplexArray,
    H: ComplexArray,
    W: FloatArray,
    poles: ComplexArray,
    direct: bool,
    workers: int | None,
) -> tuple[FloatArray, float]:
    """The coefficients ``c̃`` of σ (one relocation's least squares), its condition number.

    The condition number: the largest of the entries' residue blocks and of the shared
    ``c̃``'s Schur complement (each of its columns scaled to unit norm).
    """
    K, E = H.shape
    Psi = columns(poles, z, "discrete", 1.0)
    n = Psi.shape[1]
    lhs = np.column_stack([Psi, np.ones(z.size)]) if direct else Psi
    nl = lhs.shape[1]

    def build(r: slice, e: int) -> ComplexArray:
        w, y = W[r, e, None], H[r, e, None]
        return np.hstack([w * lhs[r], -(w * y) * Psi[r], w * y])

    G = gram(build, K, E, nl + n + 1, workers)
    # per entry the Schur complement of its residues' block: the shared c̃'s equations
    Y, k1 = solve(G[:, :nl, :nl], G[:, :nl, nl:])
    S = G[:, nl:, nl:] - np.swapaxes(G[:, :nl, nl:], 1, 2) @ Y
    ct, k2 = solve(np.sum(S[:, :n, :n], axis=0), np.sum(S[:, :n, n], axis=0))
    return ct, max(k1, k2)


def relocate(
    z: ComplexArray,
    H: ComplexArray,
    W: FloatArray,
    poles: ComplexArray,
    *,
    iterations: int = 20,
    direct: bool = False,
    workers: int | None = None,
    judge: Callable[[ComplexArray], float] | None = None,
    tol: float = 0.0,
) -> tuple[ComplexArray, float, float]:
    """Discrete poles (one of each pair) fitted to ``H`` (K, E) with weights ``W`` (K, E).

    ``poles``: the starting set (inside the unit circle); its order is kept. ``judge``:
    the cost of a pole set (None: the poles' own convergence stops the relocations); the
    best poles judged are kept, and the relocations stop once :data:`PATIENCE` of them
    lowered it by no more than ``tol``. Returns the poles, their cost (``inf`` without a
    judge) and the largest condition number of the relocations' least-squares steps.
    """
    best, best_v, stall, cond = poles, np.inf, 0, 1.0
    for _ in range(iterations):
        ct, kappa = _sigma(z, H, W, poles, direct, workers)
        cond = max(cond, kappa)
        A, b = _real_form(poles)
        new = split_pairs(np.asarray(np.linalg.eigvals(A - np.outer(b, ct)), dtype=complex))
        new = stabilise(new, "discrete")
        done = new.size == poles.size and np.allclose(
            np.sort_complex(new), np.sort_complex(poles), rtol=1e-7, atol=1e-9
        )
        poles = new
        if judge is not None:
            v = judge(poles)
            stall = stall + 1 if v > best_v - tol else 0
            if v < best_v:
                best, best_v = poles, v
            done = done or stall >= PATIENCE
        else:
            best = poles
        if done:
            break
    return best, best_v, cond
