# SPDX-License-Identifier: Apache-2.0
"""State-space realisations that keep their digits: sections, connections, exact ZOH, modes.

Polynomial coefficients of a high-order system lose digits fast: the ZOH of a sixth-order
plant at 1 kHz, taken back to polynomial form, is off by 1e-5 to 0.6 relative. Everything
the simulation and the diagnosis build therefore stays in state space:

- :func:`sections` realises a SISO ``num/den`` from its zeros and poles as a cascade of
  first- and second-order sections, each complex pole pair in the real modal block
  ``[[σ, ω], [-ω, σ]]`` (well conditioned whatever the frequencies);
- :func:`series` and :func:`parallel` connect realisations;
- :func:`zoh` discretises exactly (one matrix exponential of the augmented matrix), an
  input delay of fractional samples included;
- :func:`split_mode` separates one complex mode from the rest of a system (a similarity,
  no polynomial), so that the mode can be moved or scaled and added back
  (:func:`mode_block`).

Shapes: ``A`` (n, n), ``B`` (n, n_in), ``C`` (n_out, n), ``D`` (n_out, n_in).
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike

from ...errors import ModelError
from ..arrays import FloatArray
from .lti import StateSpace, TransferMatrix, balance, expm, proper, tf2ss


def _pairs(roots: ArrayLike) -> tuple[list[complex], list[float]]:
    """Complex roots with positive imaginary part (one of each pair), and the real roots."""
    tol = 1e-9
    cplx: list[complex] = []
    real: list[float] = []
    for p in np.atleast_1d(np.asarray(roots, dtype=complex)):
        scale = max(abs(p), 1.0)
        if abs(p.imag) <= tol * scale:
            real.append(float(p.real))
        elif p.imag > 0:
            cplx.append(complex(p))
    return cplx, real


def _section(zeros: list[complex], poles: list[complex]) -> StateSpace:
    """One monic section prod(s - z) / prod(s - p) of order 1 or 2 (real coefficients)."""
    num = np.real(np.poly(zeros)) if zeros else np.array([1.0])
    if len(poles) == 2 and abs(poles[0].imag) > 0:
        p = poles[0] if poles[0].imag > 0 else poles[1]
        sig, om = p.real, abs(p.imag)
        # num/den = d + (c1 s + c0)/den, den = s^2 - 2 sig s + sig^2 + om^2
        den = np.array([1.0, -2.0 * sig, sig * sig + om * om])
        b = np.concatenate([np.zeros(3 - num.size), num])
        d = b[0]
        c1 = b[1] - d * den[1]
        c0 = b[2] - d * den[2]
        A = np.array([[sig, om], [-om, sig]])
        B = np.array([[0.0], [om]])  # scaled so that B and C carry comparable sizes
        C = np.array([[(c0 + c1 * sig) / om, c1]]) / om
        return StateSpace(A, B, C, np.array([[d]]), None)
    if len(poles) == 2:  # two real poles: a cascade of two first-order sections
        z1, z2 = (zeros + [None, None])[:2]
        first = _section([z1] if z1 is not None else [], [poles[0]])
        second = _section([z2] if z2 is not None else [], [poles[1]])
        return series(first, second)
    if len(poles) == 1:
        p = float(poles[0].real)
        d = 1.0 if zeros else 0.0
        c = (p - float(zeros[0].real)) if zeros else 1.0  # (s - z)/(s - p) = 1 + (p - z)/(s - p)
        return StateSpace(
            np.array([[p]]), np.array([[1.0]]), np.array([[c]]), np.array([[d]]), None
        )
    return _unit(None)


def sections(num: ArrayLike, den: ArrayLike, dt: float | None = None) -> StateSpace:
    """A proper SISO ``num/den`` (descending powers) as a cascade of sections.

    Zeros and poles from the polynomial roots; every complex pole pair becomes a real
    modal block, paired with the nearest complex zero pair (or two real zeros) still free;
    the gain sits on the output. Works for s and z alike (``dt`` is carried).

    Raises
    ------
    ModelError
        The denominator is zero or the system is improper.
    """
    b, a = proper(num, den)
    if b.size == 0:
        return StateSpace(
            np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.zeros((1, 1)), dt
        )
    k = b[0] / a[0]
    zc, zr = _pairs(np.roots(b)) if b.size > 1 else ([], [])
    pc, pr = _pairs(np.roots(a)) if a.size > 1 else ([], [])
    zr_left = sorted(zr, key=abs)
    zc_left = list(zc)
    parts: list[StateSpace] = []
    for p in sorted(pc, key=abs):
        zs: list[complex] = []
        if zc_left:
            j = int(np.argmin([abs(z - p) for z in zc_left]))
            z = zc_left.pop(j)
            zs = [z, z.conjugate()]
        else:
            while zr_left and len(zs) < 2:
                zs.append(complex(zr_left.pop()))
        parts.append(_section(zs, [p, p.conjugate()]))
    pr_left = sorted(pr, key=abs)
    while zc_left:  # a complex zero pair over two real poles: one second-order block
        if len(pr_left) < 2:
            raise ModelError(f"improper transfer function: numerator {tuple(b)} over {tuple(a)}")
        z = zc_left.pop()
        p1, p2 = pr_left.pop(), pr_left.pop()
        parts.append(_poly_block(np.real(np.poly([z, z.conjugate()])), np.poly([p1, p2])))
    for p_ in pr_left:
        zs = [complex(zr_left.pop())] if zr_left else []
        parts.append(_section(zs, [complex(p_)]))
    ss = _unit(None)
    for part in parts:
        ss = series(ss, part)
    return balanced(StateSpace(ss.A, ss.B, k * ss.C, k * ss.D, dt))


def balanced(ss: StateSpace) -> StateSpace:
    """``ss`` under the diagonal similarity that balances ``[[A, |B|], [|C|, 0]]``.

    Powers of two (exact): a gain of 1e10 on the output otherwise leaves the state
    coordinates so unequal that the eigenvectors of a closed loop built from it look
    defective (condition 1e8-1e13; balanced: 5-400).
    """
    n = ss.A.shape[0]
    if n == 0:
        return ss
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = ss.A
    M[:n, n] = np.abs(ss.B).sum(axis=1)
    M[n, :n] = np.abs(ss.C).sum(axis=0)
    d = balance(M)
    d = d[:n] / d[n]
    return StateSpace(
        ss.A * d[None, :] / d[:, None], ss.B / d[:, None], ss.C * d[None, :], ss.D, ss.dt
    )


def _unit(dt: float | None, gain: float = 1.0) -> StateSpace:
    """The static SISO system ``gain`` (no states)."""
    return StateSpace(
        np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.full((1, 1), gain), dt
    )


def _poly_block(num: ArrayLike, den: ArrayLike) -> StateSpace:
    """Controllable canonical form of a low-order ``num/den`` (used only for leftovers)."""
    A, B, C, D = tf2ss(num, den)
    return StateSpace(A, B, C, D, None)


def series(first: StateSpace, second: StateSpace) -> StateSpace:
    """``second ∘ first``: the output of ``first`` drives ``second``."""
    n1, n2 = first.A.shape[0], second.A.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = first.A
    A[n1:, :n1] = second.B @ first.C
    A[n1:, n1:] = second.A
    B = np.vstack([first.B, second.B @ first.D])
    C = np.hstack([second.D @ first.C, second.C])
    D = second.D @ first.D
    return StateSpace(A, B, C, D, first.dt if first.dt is not None else second.dt)


def parallel(a: StateSpace, b: StateSpace) -> StateSpace:
    """``a + b`` (same inputs, outputs added)."""
    n1, n2 = a.A.shape[0], b.A.shape[0]
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = a.A
    A[n1:, n1:] = b.A
    return StateSpace(
        A,
        np.vstack([a.B, b.B]),
        np.hstack([a.C, b.C]),
        a.D + b.D,
        a.dt if a.dt is not None else b.dt,
    )


def block_diag(
    parts: list[StateSpace], n_out: int, n_in: int, where: list[tuple[int, int]]
) -> StateSpace:
    """An ``n_out x n_in`` system whose entry ``where[j]`` is the SISO ``parts[j]``."""
    n = sum(p.A.shape[0] for p in parts)
    A = np.zeros((n, n))
    B = np.zeros((n, n_in))
    C = np.zeros((n_out, n))
    D = np.zeros((n_out, n_in))
    k = 0
    dt = None
    for p, (o, i) in zip(parts, where, strict=True):
        m = p.A.shape[0]
        A[k : k + m, k : k + m] = p.A
        B[k : k + m, i] = p.B[:, 0]
        C[o, k : k + m] = p.C[0]
        D[o, i] += p.D[0, 0]
        k += m
        dt = p.dt if p.dt is not None else dt
    return StateSpace(A, B, C, D, dt)


def diagonal(part: StateSpace, n: int, *, channel: int | None = None) -> StateSpace:
    """``part`` (SISO) on channel ``channel`` of an n-channel path (identity elsewhere).

    On every channel when ``channel`` is None.
    """
    chans = range(n) if channel is None else [channel]
    parts, where = [], []
    for c in range(n):
        if c in chans:
            parts.append(part)
        else:
            parts.append(_unit(part.dt))
        where.append((c, c))
    return block_diag(parts, n, n, where)


def zoh(ss: StateSpace, dt: float, *, delay: float = 0.0) -> StateSpace:
    """Exact zero-order-hold discretisation, with an input delay of ``delay`` seconds.

    The held input reaches the plant ``delay`` s late: whole samples become a shift
    register on the input, a fractional part ``τ`` adds n_in states (the previous input):
    ``x[k+1] = Φ x[k] + Γ0 u[k] + Γ1 u[k-1]`` with ``Γ0 = ∫_0^{h-τ} e^{As} ds B`` and
    ``Γ1 = e^{A(h-τ)} ∫_0^τ e^{As} ds B``; ``y[k] = C x[k] + D u[k-1]`` when τ > 0.

    Raises
    ------
    ModelError
        ``ss`` is already discrete, or the delay is negative or not finite.
    """
    if ss.dt is not None:
        raise ModelError(f"system is already discrete (dt={ss.dt}); cannot discretise again")
    if not (np.isfinite(delay) and delay >= 0):
        raise ModelError(f"delay must be a finite number of seconds >= 0, got {delay!r}")
    whole = int(np.floor(delay / dt + 1e-9))
    frac = max(delay / dt - whole, 0.0) * dt
    if frac < 1e-9 * dt:
        frac = 0.0
    A, B, C, D = ss.A, ss.B, ss.C, ss.D
    n, m = B.shape

    def hold(t: float) -> tuple[FloatArray, FloatArray]:
        M = np.zeros((n + m, n + m))
        M[:n, :n] = A
        M[:n, n:] = B
        E = expm(M * t)
        return E[:n, :n], E[:n, n:]

    if frac == 0.0:
        Phi, G = hold(dt)
        out = StateSpace(Phi, G, C.copy(), D.copy(), dt)
    else:
        Phi_a, G0 = hold(dt - frac)
        Phi_f, Gf = hold(frac)
        Ad = np.zeros((n + m, n + m))
        Ad[:n, :n] = Phi_a @ Phi_f
        Ad[:n, n:] = Phi_a @ Gf
        Bd = np.vstack([G0, np.eye(m)])
        out = StateSpace(Ad, Bd, np.hstack([C, D]), np.zeros_like(D), dt)
    if whole:
        out = series(shift(m, whole, dt), out)
    return out


def shift(m: int, k: int, dt: float) -> StateSpace:
    """``u[j - k]`` on m channels: a shift register of k m states."""
    n = k * m
    A = np.zeros((n, n))
    A[m:, :-m] = np.eye(n - m)
    B = np.zeros((n, m))
    B[:m] = np.eye(m)
    C = np.zeros((m, n))
    C[:, -m:] = np.eye(m)
    return StateSpace(A, B, C, np.zeros((m, m)), dt)


def lowpass(frequency_hz: float, damping: float = 0.0) -> StateSpace:
    """Unit-gain low-pass: ``w/(s + w)`` (damping 0) or ``w^2/(s^2 + 2 ζ w s + w^2)``."""
    w = 2.0 * np.pi * frequency_hz
    if damping == 0.0:
        return StateSpace(
            np.array([[-w]]), np.array([[w]]), np.ones((1, 1)), np.zeros((1, 1)), None
        )
    return mode_block(frequency_hz, damping, [[0.0]], [[w * w]])


def notch(frequency_hz: float, damping: float, depth: float, dt: float) -> StateSpace:
    """A discrete notch at ``frequency_hz`` (gain ``depth`` at its centre).

    Tustin, prewarped, of ``(s^2 + 2 depth ζ w s + w^2)/(s^2 + 2 ζ w s + w^2)``.
    """
    k = 2.0 / dt
    w = k * np.tan(np.pi * frequency_hz * dt)  # prewarped: the centre stays at frequency_hz

    def tustin(z: float) -> FloatArray:
        return np.array(
            [k * k + 2 * z * w * k + w * w, 2 * (w * w - k * k), k * k - 2 * z * w * k + w * w]
        )

    return sections(tustin(depth * damping), tustin(damping), dt)


def mode_block(frequency_hz: float, damping: float, c1: ArrayLike, c0: ArrayLike) -> StateSpace:
    """``(c1 s + c0) / (s^2 + 2 ζ w s + w^2)`` with matrix numerators (n_out, n_in).

    Realised with 2 n_in states: ``[[0, I], [-w^2 I, -2ζw I]]``, scaled by w.
    """
    c1a = np.atleast_2d(np.asarray(c1, dtype=float))
    c0a = np.atleast_2d(np.asarray(c0, dtype=float))
    m = c1a.shape[1]
    w = 2.0 * np.pi * frequency_hz
    eye = np.eye(m)
    # states q = x / w and q' / w^2 ... keep it simple: x1 = w q, x2 = q'
    A = np.block([[np.zeros((m, m)), w * eye], [-w * eye, -2.0 * damping * w * eye]])
    B = np.vstack([np.zeros((m, m)), eye])
    C = np.hstack([c0a / w, c1a])
    return StateSpace(A, B, C, np.zeros((c1a.shape[0], m)), None)


def split_mode(ss: StateSpace, pole: complex) -> tuple[FloatArray, FloatArray, StateSpace]:
    """Separate the complex mode at ``pole`` (and its conjugate) from a continuous system.

    Returns ``(c1, c0, rest)``: the mode contributes ``(c1 s + c0)/((s - p)(s - p̄))``
    (c1, c0 of shape (n_out, n_in)), and ``rest`` realises everything else; the sum equals
    ``ss``. A similarity onto the mode's real invariant subspace and its complement (the
    complement may be defective: a rigid body stays as it is).

    Raises
    ------
    ModelError
        No simple eigenvalue of A is near ``pole``.
    """
    lam, V = np.linalg.eig(ss.A)
    j = int(np.argmin(np.abs(lam - pole)))
    if abs(lam[j] - pole) > 1e-6 * max(abs(pole), 1.0) or abs(lam[j].imag) == 0:
        raise ModelError(f"the system has no complex mode at {pole}")
    if lam[j].imag < 0:
        lam = lam.conj()
        V = V.conj()
    v = V[:, j]
    # left eigenvector: w^T A = lam w^T, normalised w^T v = 1
    lamL, W = np.linalg.eig(ss.A.T)
    k = int(np.argmin(np.abs(lamL - lam[j])))
    wv = W[:, k] / (W[:, k] @ v)
    V2 = np.column_stack([v.real, v.imag])  # A V2 = V2 [[s, w], [-w, s]]
    W2 = np.vstack([2.0 * wv.real, -2.0 * wv.imag])  # W2 V2 = I
    _, _, Vt = np.linalg.svd(W2)
    Q = Vt[2:].T  # null space of W2: the complement, A-invariant
    T = np.hstack([V2, Q])
    Ti = np.linalg.inv(T)
    At, Bt, Ct = Ti @ ss.A @ T, Ti @ ss.B, ss.C @ T
    rest = StateSpace(At[2:, 2:], Bt[2:], Ct[:, 2:], ss.D.copy(), ss.dt)
    # the mode part C2 (sI - A2)^-1 B2 as (c1 s + c0) / den
    A2, B2, C2 = At[:2, :2], Bt[:2], Ct[:, :2]
    c1 = C2 @ B2
    c0 = C2 @ (A2 - np.trace(A2) * np.eye(2)) @ B2  # adj(sI - A2) = sI + (A2 - tr A2 I)
    return c1, c0, rest


def realize(system: TransferMatrix) -> StateSpace:
    """A state-space realisation of every entry of a transfer matrix, through sections.

    Block-diagonal and non-minimal (entries sharing a denominator keep their own states);
    a zero entry has no states. Cached on the (immutable) transfer matrix: the diagnosis
    realises the same controller for every model it evaluates (about 700 times per
    diagnosis, 7 % of its time). The result's arrays are read-only (shared by every
    caller); a transfer matrix whose coefficients are not hashable (lists) is realised
    without the cache.
    """
    try:
        hash(system)
    except TypeError:  # unhashable coefficients
        return _realize(system)
    return _realize_cached(system)


@functools.lru_cache(maxsize=64)
def _realize_cached(system: TransferMatrix) -> StateSpace:
    ss = _realize(system)
    for a in (ss.A, ss.B, ss.C, ss.D):
        a.flags.writeable = False
    return ss


def _realize(system: TransferMatrix) -> StateSpace:
    no, ni = system.shape
    parts, where = [], []
    for o in range(no):
        for i in range(ni):
            if np.any(system.num[o][i]):
                parts.append(sections(system.num[o][i], system.den[o][i], system.dt))
                where.append((o, i))
    out = block_diag(parts, no, ni, where)
    return StateSpace(out.A, out.B, out.C, out.D, system.dt)
