# SPDX-License-Identifier: Apache-2.0
"""Linear time-invariant systems: transfer-function matrices and state space.

A :class:`TransferMatrix` holds one numerator per (output, input) entry and one
denominator per entry, coefficients in descending powers of s (continuous,
``dt = None``) or z (discrete, sample time ``dt``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ...errors import ModelError
from ..arrays import FloatArray

Poly = tuple[float, ...]


@dataclass(frozen=True)
class StateSpace:
    """``x+ = A x + B u, y = C x + D u`` (discrete) with sample time ``dt``.

    Continuous (``dx/dt = A x + B u``) when ``dt`` is None.

    Attributes
    ----------
    A, B, C, D : ndarray, shapes (n, n), (n, n_in), (n_out, n), (n_out, n_in)
    dt : float or None
        Sample time in s; None for continuous time.

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import StateSpace
    >>> ss = StateSpace(np.array([[0.5]]), np.ones((1, 1)), np.ones((1, 1)),
    ...                 np.zeros((1, 1)), dt=0.1)  # 1 / (z - 0.5)
    >>> ss.freqresp([0.0]).real  # at DC: 1 / (1 - 0.5)
    array([[[2.]]])
    """

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    D: NDArray[np.float64]
    dt: float | None

    @property
    def n_states(self) -> int:
        """Order of the realisation."""
        return int(self.A.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """(n_out, n_in)."""
        return int(self.D.shape[0]), int(self.D.shape[1])

    def poles(self) -> NDArray[np.complex128]:
        """Eigenvalues of A."""
        if not self.A.size:
            return np.zeros(0, dtype=np.complex128)
        return np.asarray(np.linalg.eigvals(self.A), dtype=np.complex128)

    def freqresp(self, frequency: ArrayLike) -> NDArray[np.complex128]:
        """``C (xI - A)^-1 B + D`` at ``frequency`` Hz, shape (K, n_out, n_in).

        ``x = exp(2j pi f dt)`` (discrete) or ``2j pi f`` (continuous); through the
        eigendecomposition of A when its eigenvectors are well conditioned, else (a shift
        register, a repeated pole) by block forward substitution over A's strongly connected
        blocks (:func:`triangular_blocks`), each block through its own eigenvectors or, when
        it is defective itself, one solve per point. On a pole: inf there.
        """
        f = np.atleast_1d(np.asarray(frequency, dtype=float))
        x = 2j * np.pi * f if self.dt is None else np.exp(2j * np.pi * f * self.dt)
        n = self.A.shape[0]
        out = np.array(np.broadcast_to(self.D.astype(complex), (f.size, *self.D.shape)))
        if n == 0:
            return out
        lam, V = np.linalg.eig(self.A)
        pole = _on_pole(x, lam, self.dt is not None)
        if np.any(pole):  # on a pole (an integrator at DC): infinite there, the rest as usual
            rest = StateSpace(self.A, self.B, self.C, self.D, self.dt).freqresp(f[~pole])
            out[~pole] = rest
            out[pole] = np.inf
            return out
        if diagonalisable(V):
            # C V diag(1 / (x - lam)) V^-1 B: one product of the resolvent's diagonal with
            # the modes' residues W[m, (o, i)] = (C V)[o, m] (V^-1 B)[m, i] per block
            Bm = np.linalg.solve(V, self.B.astype(complex))  # (n, n_in)
            W = ((self.C @ V).T[:, :, None] * Bm[:, None, :]).reshape(n, -1)
            for lo in range(0, f.size, 4096):
                g = 1.0 / (x[lo : lo + 4096, None] - lam[None, :])  # (k, n)
                out[lo : lo + 4096] += (g @ W).reshape(g.shape[0], *self.D.shape)
            return out
        # defective (a shift register's Jordan block, repeated poles of a series): block
        # forward substitution over A's strongly connected blocks, each one resolved alone
        perm, bounds = triangular_blocks(self.A)
        Ap, Bp, Cp = self.A[np.ix_(perm, perm)], self.B[perm].astype(complex), self.C[:, perm]
        no, ni = self.D.shape
        for lo in range(0, f.size, 4096):
            xs = x[lo : lo + 4096]
            Z = np.empty((n, xs.size, ni), dtype=complex)  # (x I - A)^-1 B, states first
            for a, b in bounds:
                rhs = np.broadcast_to(Bp[a:b, None, :], (b - a, xs.size, ni))
                if a:
                    rhs = rhs + (Ap[a:b, :a] @ Z[:a].reshape(a, -1)).reshape(b - a, -1, ni)
                Z[a:b] = _resolve(Ap[a:b, a:b], rhs, xs)
            out[lo : lo + 4096] += (Cp @ Z.reshape(n, -1)).reshape(no, -1, ni).transpose(1, 0, 2)
        return out


@dataclass(frozen=True)
class TransferMatrix:
    """An ``n_out x n_in`` matrix of rational transfer functions.

    Attributes
    ----------
    num, den : tuple of tuple of tuple of float
        ``num[o][i]`` and ``den[o][i]``: coefficients, descending powers.
    dt : float or None
        Sample time in s; None for continuous time.

    Examples
    --------
    >>> from mr_ident import TransferMatrix
    >>> g = TransferMatrix.siso([1.0], [1.0, 1.0])  # 1 / (s + 1)
    >>> g.shape, g(0.0).real
    ((1, 1), array([[[1.]]]))
    """

    num: tuple[tuple[Poly, ...], ...]
    den: tuple[tuple[Poly, ...], ...]
    dt: float | None

    @property
    def shape(self) -> tuple[int, int]:
        """(n_out, n_in)."""
        return len(self.num), len(self.num[0])

    @classmethod
    def siso(cls, num: ArrayLike, den: ArrayLike, dt: float | None = None) -> TransferMatrix:
        """A 1 x 1 transfer matrix ``num/den`` (descending powers)."""
        return cls(
            ((tuple(np.atleast_1d(np.asarray(num, float))),),),
            ((tuple(np.atleast_1d(np.asarray(den, float))),),),
            dt,
        )

    def __call__(self, x: ArrayLike) -> NDArray[np.complex128]:
        """Evaluate at complex points ``x`` (s or z), shape (K,) -> (K, n_out, n_in).

        On a pole (an integrating controller at z = 1) the value is inf, without a warning:
        that is the answer there.
        """
        xa = np.atleast_1d(np.asarray(x, dtype=complex))
        no, ni = self.shape
        out = np.empty((xa.size, no, ni), dtype=complex)
        with np.errstate(divide="ignore", invalid="ignore"):
            for o in range(no):
                for i in range(ni):
                    num, den = np.polyval(self.num[o][i], xa), np.polyval(self.den[o][i], xa)
                    out[:, o, i] = num / den
        return out

    def freqresp(self, frequency: ArrayLike, *, dt: float | None = None) -> NDArray[np.complex128]:
        """Frequency response at ``frequency`` Hz, shape (K, n_out, n_in).

        Discrete systems are evaluated at ``z = exp(2j pi f dt)``; continuous ones at
        ``s = 2j pi f``.
        """
        f = np.asarray(frequency, dtype=float)
        if self.dt is None:
            return self(2j * np.pi * f)
        return self(np.exp(2j * np.pi * f * self.dt))

    def dft_response(self, n: int) -> NDArray[np.complex128]:
        """A discrete system on the n DFT bins of its rate.

        ``z = exp(2j pi k / n)``, k = 0..n-1, shape (n, n_out, n_in) (a controller on
        every low-rate bin of a record).

        Raises
        ------
        ModelError
            If the system is continuous (``dt`` None).
        """
        if self.dt is None:
            raise ModelError("dft_response needs a discrete-time system (dt set)")
        from ..lifting import half_to_full  # (its threads are not every model reader's)

        # Real coefficients: evaluated on bins 0..n//2, the rest is their conjugate mirror.
        out: NDArray[np.complex128] = half_to_full(
            self(np.exp(2j * np.pi * np.arange(n // 2 + 1) / n)), n
        )
        return out

    def times(self, num: ArrayLike, den: ArrayLike) -> TransferMatrix:
        """Every entry multiplied by the scalar transfer function ``num/den`` (same domain)."""
        b = np.atleast_1d(np.asarray(num, float))
        a = np.atleast_1d(np.asarray(den, float))
        return TransferMatrix(
            tuple(tuple(tuple(np.polymul(e, b)) for e in row) for row in self.num),
            tuple(tuple(tuple(np.polymul(e, a)) for e in row) for row in self.den),
            self.dt,
        )

    def poles(self) -> NDArray[np.complex128]:
        """Roots of every entry's denominator (duplicates kept)."""
        return np.concatenate([np.roots(d) for row in self.den for d in row])


# Small LTI kernels in numpy: what scipy.signal would do for these few low-order systems,
# without the half second that importing scipy.signal (and scipy.linalg) adds to every
# program that loads a model.

#: Padé (13, 13) coefficients and the 1-norm below which it is accurate to double precision
#: (Higham, "The scaling and squaring method for the matrix exponential revisited", 2005).
_PADE13 = (
    64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
    129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
    40840800.0, 960960.0, 16380.0, 182.0, 1.0,
)  # fmt: skip
_THETA13 = 5.371920351148152


#: The condition number of A's eigenvector matrix up to which a response or a simulation goes
#: through the modes; past it A counts as (nearly) defective.
EIG_COND = 1e8


def diagonalisable(V: NDArray[np.complex128]) -> bool:
    """Whether the eigenvectors ``V`` (columns) are well enough conditioned to work in modes."""
    return bool(np.linalg.cond(V) < EIG_COND)


def _on_pole(
    x: NDArray[np.complex128], lam: NDArray[np.complex128], discrete: bool
) -> NDArray[np.bool_]:
    """The points ``x`` within ``1e-7 (1 + |x|)`` of an eigenvalue ``lam``: shape (K,).

    ``x`` lies on the unit circle (``discrete``) or the imaginary axis, so an eigenvalue
    can be that near only when ``|1 - |lam||`` resp. ``|Re lam|`` is within the largest
    tolerance: only those are compared with every point (usually none).
    """
    out = np.zeros(x.size, dtype=bool)
    if not x.size or not lam.size:
        return out
    reach = 1.5e-7 * (1.0 + float(np.abs(x).max()))
    gap = np.abs(1.0 - np.abs(lam)) if discrete else np.abs(lam.real)
    near = lam[gap <= reach]
    for lo in range(0, x.size, 4096) if near.size else ():
        xs = x[lo : lo + 4096]
        d = xs[:, None] - near[None, :]
        tol = 1e-7 * (1.0 + np.abs(xs))
        out[lo : lo + 4096] = (d.real**2 + d.imag**2).min(axis=1) <= tol * tol
    return out


def triangular_blocks(A: FloatArray) -> tuple[NDArray[np.intp], list[tuple[int, int]]]:
    """A permutation of the states under which A is block lower triangular, and its blocks.

    The blocks are the strongly connected parts of A's graph (state j drives state i where
    ``A[i, j] != 0``); a block comes after every block that drives it (ordered by how many
    states reach it). Returns ``perm`` (n,) and the blocks as ``(start, stop)`` in ``perm``.

    >>> A = np.array([[0.5, 0.0], [1.0, 0.0]])    # state 0 drives state 1
    >>> triangular_blocks(A)
    (array([0, 1]), [(0, 1), (1, 2)])
    """
    n = A.shape[0]
    reach = (A != 0) | np.eye(n, dtype=bool)  # reach[i, j]: j reaches i
    while True:
        nxt = (reach.astype(np.int64) @ reach.astype(np.int64)) > 0
        if (nxt == reach).all():
            break
        reach = nxt
    block = np.argmax(reach & reach.T, axis=1)  # the first state of each one's block
    perm = np.lexsort((block, reach.sum(axis=1)))
    edges = np.flatnonzero(np.diff(block[perm])) + 1
    starts, stops = np.r_[0, edges], np.r_[edges, n]
    return perm, [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def _resolve(
    A: FloatArray, rhs: NDArray[np.complex128], x: NDArray[np.complex128]
) -> NDArray[np.complex128]:
    """``(x_k I - A)^-1 rhs[:, k]`` for every point: rhs (n, K, m), result the same.

    Through A's eigenvectors when they are well conditioned, else one solve per point.
    """
    n = A.shape[0]
    if n == 1:
        out: NDArray[np.complex128] = rhs / (x - A[0, 0])[None, :, None]
        return out
    lam, V = np.linalg.eig(A)
    if diagonalisable(V):
        m = np.linalg.solve(V, rhs.reshape(n, -1)).reshape(rhs.shape)
        m = m / (x[None, :, None] - lam[:, None, None])
        out = (V @ m.reshape(n, -1)).reshape(rhs.shape)
        return out
    M = x[:, None, None] * np.eye(n) - A
    solved = np.linalg.solve(M, rhs.transpose(1, 0, 2)).transpose(1, 0, 2)
    return np.asarray(solved, dtype=np.complex128)


def balance(M: FloatArray) -> FloatArray:
    """Diagonal d (powers of two) balancing ``M[i, j] d[j] / d[i]``.

    Parlett and Reinsch's balancing as LAPACK's gebal does it (scaling only, radix 2, the
    2-norms of each row and column off the diagonal, a step taken only when it shrinks
    their sum below 0.95 of it): companion forms of polynomials whose coefficients span
    many decades are otherwise too badly scaled for an accurate expm. In plain Python
    floats: the matrices are a model's sections and loops (n up to about 12), and this keeps
    ``scipy.linalg``'s import off the path of every command that loads a model. Powers of two
    scale exactly, so any balancing this close to gebal's serves expm alike.
    """
    n = M.shape[0]
    if n == 0:
        return np.ones(0)
    A = np.asarray(M, dtype=float).tolist()
    d = [1.0] * n
    for _ in range(_BALANCE_SWEEPS):
        changed = False
        for i in range(n):
            c = math.sqrt(sum(A[j][i] * A[j][i] for j in range(n) if j != i))
            r = math.sqrt(sum(A[i][j] * A[i][j] for j in range(n) if j != i))
            if c == 0.0 or r == 0.0 or not math.isfinite(c + r):
                continue
            total, f = c + r, 1.0
            while c < r / 2.0 and f < _BALANCE_LIMIT:
                c, r, f = 2.0 * c, r / 2.0, 2.0 * f
            while c / 2.0 >= r and f > 1.0 / _BALANCE_LIMIT:
                c, r, f = c / 2.0, 2.0 * r, f / 2.0
            if c + r >= 0.95 * total:
                continue
            d[i] *= f
            changed = True
            for j in range(n):
                A[i][j] /= f
                A[j][i] *= f
        if not changed:
            break
    return np.array(d)


#: Sweeps of :func:`balance` at most (it converges in a few).
_BALANCE_SWEEPS = 100
#: The largest scaling one step of :func:`balance` applies.
_BALANCE_LIMIT = 2.0**400


def expm(A: ArrayLike) -> FloatArray:
    """Matrix exponential of a small real square matrix.

    Balancing, then scaling and squaring with the Padé (13, 13) approximant.
    """
    M = np.asarray(A, dtype=float)
    n = M.shape[0]
    if n == 0:
        return np.zeros((0, 0))
    d = balance(M)
    M = M * d[None, :] / d[:, None]
    norm = float(np.abs(M).sum(axis=0).max())
    s = max(0, int(np.ceil(np.log2(norm / _THETA13)))) if norm > _THETA13 else 0
    M = M / 2.0**s
    b = _PADE13
    eye = np.eye(n)
    M2 = M @ M
    M4 = M2 @ M2
    M6 = M4 @ M2
    U = M @ (
        M6 @ (b[13] * M6 + b[11] * M4 + b[9] * M2) + b[7] * M6 + b[5] * M4 + b[3] * M2 + b[1] * eye
    )
    V = M6 @ (b[12] * M6 + b[10] * M4 + b[8] * M2) + b[6] * M6 + b[4] * M4 + b[2] * M2 + b[0] * eye
    E: FloatArray = np.asarray(np.linalg.solve(V - U, V + U), dtype=float)
    for _ in range(s):
        E = E @ E
    return E * d[:, None] / d[None, :]


def proper(num: ArrayLike, den: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """``num`` and ``den`` (descending powers) without exact leading zeros, checked proper.

    Raises
    ------
    ModelError
        The denominator is zero or the numerator's degree exceeds the denominator's.
    """
    b = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=float)), "f")
    a = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=float)), "f")
    if a.size == 0:
        raise ModelError("denominator is zero")
    if b.size > a.size:
        raise ModelError(f"improper transfer function: numerator {tuple(b)} over {tuple(a)}")
    return b, a


def tf2ss(num: ArrayLike, den: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Controllable canonical realisation (A, B, C, D) of a proper SISO ``num/den``.

    Coefficients in descending powers; exact leading zeros are dropped. Unlike
    ``scipy.signal.tf2ss`` it never warns about small leading numerator coefficients: they
    are kept as they are (a tiny but non-zero leading term is part of the model).
    """
    b, a = proper(num, den)
    b, a = b / a[0], a / a[0]
    n = a.size - 1
    b = np.concatenate([np.zeros(n + 1 - b.size), b])
    d = b[0]
    A = np.zeros((n, n))
    if n:
        A[0] = -a[1:]
        A[1:, :-1] = np.eye(n - 1)
    B = np.zeros((n, 1))
    if n:
        B[0, 0] = 1.0
    C = (b[1:] - d * a[1:])[None, :]
    return A, B, C, np.array([[d]])
