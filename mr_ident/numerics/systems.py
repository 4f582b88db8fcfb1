"""Linear time-invariant systems: transfer-function matrices and state space.

A :class:`TransferMatrix` holds one numerator per (output, input) entry and one
denominator per entry, coefficients in descending powers of s (continuous,
``dt = None``) or z (discrete, sample time ``dt``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ModelError
from .arrays import FloatArray

Poly = tuple[float, ...]


@dataclass(frozen=True)
class StateSpace:
    """``x+ = A x + B u, y = C x + D u`` (discrete) with sample time ``dt``."""

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    C: NDArray[np.float64]
    D: NDArray[np.float64]
    dt: float | None

    @property
    def n_states(self) -> int:
        """Order of the realisation."""
        return int(self.A.shape[0])


@dataclass(frozen=True)
class TransferMatrix:
    """An ``n_out x n_in`` matrix of rational transfer functions.

    Attributes
    ----------
    num, den : tuple of tuple of tuple of float
        ``num[o][i]`` and ``den[o][i]``: coefficients, descending powers.
    dt : float or None
        Sample time in s; None for continuous time.
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
        """Evaluate at complex points ``x`` (s or z), shape (K,) -> (K, n_out, n_in)."""
        xa = np.atleast_1d(np.asarray(x, dtype=complex))
        no, ni = self.shape
        out = np.empty((xa.size, no, ni), dtype=complex)
        for o in range(no):
            for i in range(ni):
                out[:, o, i] = np.polyval(self.num[o][i], xa) / np.polyval(self.den[o][i], xa)
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
        """
        if self.dt is None:
            raise ModelError("dft_response needs a discrete-time system (dt set)")
        return self(np.exp(2j * np.pi * np.arange(n) / n))

    def discretize(self, dt: float, *, delay: float = 0.0) -> TransferMatrix:
        """Zero-order-hold discretisation of every entry (exact for ZOH inputs).

        ``delay`` (s, >= 0) is an input delay, fractional sample times included: the
        held input reaches the plant ``delay`` seconds late. Exact for ZOH inputs too
        (the modified z-transform: a fractional part adds one state).
        """
        if self.dt is not None:
            raise ModelError(f"system is already discrete (dt={self.dt}); cannot discretise again")
        if not (np.isfinite(delay) and delay >= 0):
            raise ModelError(f"delay must be a finite number of seconds >= 0, got {delay!r}")
        whole = int(np.floor(delay / dt + 1e-9))
        frac = max(delay / dt - whole, 0.0) * dt
        if frac < 1e-9 * dt:
            frac = 0.0
        no, ni = self.shape
        num, den = [], []
        for o in range(no):
            rn, rd = [], []
            for i in range(ni):
                b, a = _zoh_delayed(self.num[o][i], self.den[o][i], dt, frac)
                b = np.trim_zeros(b, "f")
                rn.append(tuple(b) if b.size else (0.0,))
                rd.append(tuple(np.concatenate([a, np.zeros(whole)])))  # z^-whole
            num.append(tuple(rn))
            den.append(tuple(rd))
        return TransferMatrix(tuple(num), tuple(den), dt)

    def times(self, num: ArrayLike, den: ArrayLike) -> TransferMatrix:
        """Every entry multiplied by the scalar transfer function ``num/den`` (same domain)."""
        b = np.atleast_1d(np.asarray(num, float))
        a = np.atleast_1d(np.asarray(den, float))
        return TransferMatrix(
            tuple(tuple(tuple(np.polymul(e, b)) for e in row) for row in self.num),
            tuple(tuple(tuple(np.polymul(e, a)) for e in row) for row in self.den),
            self.dt,
        )

    def to_ss(self) -> StateSpace:
        """A (non-minimal, block-diagonal) state-space realisation of all entries."""
        no, ni = self.shape
        blocks = []
        for o in range(no):
            for i in range(ni):
                if not np.any(self.num[o][i]):
                    continue  # a zero entry needs no states
                A, B, C, D = tf2ss(self.num[o][i], self.den[o][i])
                blocks.append((o, i, A, B, C, D))
        n = sum(b[2].shape[0] for b in blocks)
        A = np.zeros((n, n))
        B = np.zeros((n, ni))
        C = np.zeros((no, n))
        D = np.zeros((no, ni))
        k = 0
        for o, i, a, b, c, d in blocks:
            m = a.shape[0]
            A[k : k + m, k : k + m] = a
            B[k : k + m, i] = b[:, 0]
            C[o, k : k + m] = c[0]
            D[o, i] += d[0, 0]
            k += m
        return StateSpace(A, B, C, D, self.dt)

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


def _balance(M: FloatArray) -> FloatArray:
    """Diagonal d (powers of two) balancing ``M[i, j] d[j] / d[i]``.

    Parlett and Reinsch's balancing: companion forms of polynomials whose coefficients span
    many decades are otherwise too badly scaled for an accurate expm.
    """
    n = M.shape[0]
    d = np.ones(n)
    B = M.copy()
    for _ in range(100):
        done = True
        for i in range(n):
            c = float(np.abs(B[:, i]).sum() - abs(B[i, i]))
            r = float(np.abs(B[i, :]).sum() - abs(B[i, i]))
            if c == 0.0 or r == 0.0:
                continue
            f = 2.0 ** np.round(np.log2(r / c) / 2.0)
            if (c * f + r / f) < 0.95 * (c + r):
                B[:, i] *= f
                B[i, :] /= f
                d[i] *= f
                done = False
        if done:
            break
    return d


def expm(A: ArrayLike) -> FloatArray:
    """Matrix exponential of a small real square matrix.

    Balancing, then scaling and squaring with the Padé (13, 13) approximant.
    """
    M = np.asarray(A, dtype=float)
    n = M.shape[0]
    if n == 0:
        return np.zeros((0, 0))
    d = _balance(M)
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


def tf2ss(num: ArrayLike, den: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Controllable canonical realisation (A, B, C, D) of a proper SISO ``num/den``.

    Coefficients in descending powers; exact leading zeros are dropped. Unlike
    ``scipy.signal.tf2ss`` it never warns about small leading numerator coefficients: they
    are kept as they are (a tiny but non-zero leading term is part of the model).
    """
    b = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=float)), "f")
    a = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=float)), "f")
    if a.size == 0:
        raise ModelError("denominator is zero")
    if b.size > a.size:
        raise ModelError(f"improper transfer function: numerator {tuple(b)} over {tuple(a)}")
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


def ss2tf(A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(num, den) of a SISO state space.

    ``den = det(sI - A)`` and ``num = det(sI - A + BC) + (D - 1) den``.
    """
    A, B, C = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (A, B, C))
    d = float(np.asarray(D, dtype=float).reshape(-1)[0])
    if A.size == 0:
        return np.array([d]), np.array([1.0])
    den = np.real(np.poly(A))
    num = np.real(np.poly(A - B @ C)) + (d - 1.0) * den
    return num, den


def _zoh_delayed(num: Poly, den: Poly, dt: float, frac: float) -> tuple[FloatArray, FloatArray]:
    """ZOH discretisation of ``num/den`` with an input delay ``frac`` in [0, dt) seconds.

    With ``x' = A x + B u(t - frac)`` and u held over each sample time:
    ``x[k+1] = Phi x[k] + G0 u[k] + G1 u[k-1]``, ``G0 = int_0^(dt-frac) e^(As) ds B``,
    ``G1 = e^(A(dt-frac)) int_0^frac e^(As) ds B``; ``y[k] = C x[k] + D u[k-1]`` when
    frac > 0. Returns discrete (num, den) in descending powers of z.
    """
    A, B, C, D = tf2ss(num, den)
    n = A.shape[0]

    def hold_integral(t: float) -> tuple[FloatArray, FloatArray]:
        E = expm(np.block([[A, B], [np.zeros((1, n + 1))]]) * t)
        return E[:n, :n], E[:n, n:]

    if frac == 0.0:
        return ss2tf(*hold_integral(dt), C, D)
    Phi_a, G0 = hold_integral(dt - frac)
    Phi_f, Gf = hold_integral(frac)
    Ad = np.block([[Phi_a @ Phi_f, Phi_a @ Gf], [np.zeros((1, n + 1))]])  # state [x; u[k-1]]
    Bd = np.vstack([G0, np.ones((1, 1))])
    return ss2tf(Ad, Bd, np.hstack([C, D]), np.zeros((1, 1)))
