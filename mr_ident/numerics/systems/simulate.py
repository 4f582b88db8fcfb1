# SPDX-License-Identifier: Apache-2.0
"""Fast simulation of the multirate loop by lifting.

One low-rate period of the loop (plant at the high rate, controller at the low
rate, sampling phase, hold and computation delay) is an LTI map from the lifted
inputs ``[r_bar; v_bar]`` to the lifted outputs ``[y_bar; u_bar]``. It is built
once, symbolically, as a state-space system at the low rate
(:func:`lifted_loop`), then simulated over all M = N/F periods at once with
compiled first-order recursions on its modes (``scipy.signal.lfilter``): no
Python loop per sample.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
from numpy.typing import ArrayLike

from ...errors import ConfigError, DimensionError
from ..arrays import ComplexArray, FloatArray, IntArray
from ..signals import LoopData
from .lti import StateSpace, diagonalisable
from .model import Model
from .realize import balanced


def lifted_loop(model: Model) -> StateSpace:
    """The loop over one low-rate period as an LTI system at the low rate.

    Inputs ``[r(mF..mF+F-1); v(mF..mF+F-1)]`` (F*n_r + F*n_y, sample-major),
    outputs ``[y_meas(...); u(...)]`` (F*n_y + F*n_u), where ``y_meas = P_h u + v``
    is what the controller and the logger see. r enters where ``model.injection`` says:
    added to the plant input (n_r = n_u) or as the controller's setpoint, sampled with y
    at the sampling phase (n_r = n_y; the other F - 1 samples of r do not act).

    Parameters
    ----------
    model : Model
        The loop; open loop (no controller) maps r straight to the plant input.

    Returns
    -------
    StateSpace
        Discrete at ``ratio / fs_high``; F*n_r + F*n_y inputs, F*n_y + F*n_u outputs.

    Raises
    ------
    ModelError
        If the plant or the controller cannot be realised (an improper transfer
        function, a negative input delay).

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.

    Examples
    --------
    >>> from mr_ident import lifted_loop
    >>> from mr_ident.io.modelfile import model_from_dict
    >>> model = model_from_dict({"fs_high": 100.0, "ratio": 2,
    ...                          "plant": {"num": [1.0], "den": [1.0, 1.0]},
    ...                          "controller": {"num": [0.5], "den": [1.0]}})
    >>> lifted_loop(model).shape  # [y; u] of F = 2 samples from [r; v] of 2 samples
    (4, 4)
    """
    Pd = model.plant_discrete()
    F, ny, nu = model.ratio, model.n_y, model.n_u
    A, B, C, D = Pd.A, Pd.B, Pd.C, Pd.D
    nx = A.shape[0]
    if model.controller is not None:
        Kd = model.controller_ss()
        Ak, Bk, Ck, Dk = Kd.A, Kd.B, Kd.C, Kd.D
    else:
        Ak = np.zeros((0, 0))
        Bk = np.zeros((0, ny))
        Ck = np.zeros((nu, 0))
        Dk = np.zeros((nu, ny))
    nk = Ak.shape[0]
    setpoint = model.setpoint
    nr = model.n_r
    phase, hold = model.sample_phase, model.sample_phase + model.control_delay
    nh = -((0 - hold) // F) if model.controller is not None else 0  # ceil(hold / F)
    ns = nx + nk + nh * nu
    nz = ns + F * nr + F * ny
    eye = np.eye(nz)
    X = eye[:nx]
    XK = eye[nx : nx + nk]
    H = [eye[nx + nk + j * nu : nx + nk + (j + 1) * nu] for j in range(nh)]  # H[j] = u_c[m-1-j]
    r = [eye[ns + i * nr : ns + (i + 1) * nr] for i in range(F)]
    v = [eye[ns + F * nr + i * ny : ns + F * nr + (i + 1) * ny] for i in range(F)]
    zero_u = np.zeros((nu, nz))
    # r at the plant input (ru) or subtracted from y where the controller samples it (rs)
    ru = [zero_u] * F if setpoint else r
    rs = r[phase] if setpoint else np.zeros((ny, nz))
    UC = None
    XK_next = XK
    Ys, Us = [], []
    closed = model.controller is not None
    for i in range(F):
        j = -((i - hold) // F)  # u_c[m - j] is held at sample i
        if closed and i == phase:
            if j == 0:  # output applied at the sampling instant: algebraic loop
                Q = np.linalg.inv(np.eye(nu) + Dk @ D)
                UC = Q @ (Ck @ XK + Dk @ (C @ X + D @ ru[i] + v[i] - rs))
            else:
                yi = C @ X + D @ (ru[i] - H[j - 1]) + v[i]
                UC = Ck @ XK + Dk @ (yi - rs)
        if not closed:
            ui = r[i] if not setpoint else zero_u
        elif j == 0:
            assert UC is not None
            ui = ru[i] - UC
        else:
            ui = ru[i] - H[j - 1]
        yi = C @ X + D @ ui + v[i]
        if closed and i == phase:
            XK_next = Ak @ XK + Bk @ (yi - rs)
        Ys.append(yi)
        Us.append(ui)
        X = A @ X + B @ ui
    Hn: list[FloatArray] = []
    if nh:
        assert UC is not None
        Hn = [UC, *H[:-1]]
    nxt = np.vstack([X, XK_next] + Hn) if ns else np.zeros((0, nz))
    out = np.vstack(Ys + Us)
    return StateSpace(
        nxt[:, :ns], nxt[:, ns:], out[:, :ns], out[:, ns:], model.ratio / model.fs_high
    )


def loop_poles(model: Model) -> ComplexArray:
    """Poles of the lifted loop (low-rate z-plane); stable iff all |p| < 1."""
    A = lifted_loop(model).A
    if not A.size:
        return np.zeros(0, dtype=np.complex128)
    return np.asarray(np.linalg.eigvals(A), dtype=np.complex128)


class StateRecursion:
    """``x[m+1] = A x[m] + B w[m]``, ``out[m] = C x[m] + D w[m]``.

    Run piece by piece from x = 0, the state carried from one :meth:`run` to the next.

    Uses the modal form and one compiled first-order recursion per mode; falls
    back to a direct recursion (with a RuntimeWarning) when A is not safely
    diagonalisable.
    """

    def __init__(self, ss: StateSpace):
        ss = balanced(ss)  # the eigenvectors of a badly scaled loop look defective
        self.ss = ss
        self._modal = True
        if ss.A.shape[0] == 0:
            self._lam = np.zeros(0, dtype=complex)
            self._Bm = np.zeros((0, ss.B.shape[1]), dtype=complex)
            self._Cm = np.zeros((ss.C.shape[0], 0), dtype=complex)
        else:
            lam, V = np.linalg.eig(ss.A)
            if not diagonalisable(V):
                warnings.warn(
                    "simulate: state matrix is (nearly) defective; using the slow direct "
                    "recursion",
                    RuntimeWarning,
                    stacklevel=3,
                )
                self._modal = False
                self._x = np.zeros(ss.A.shape[0])
            else:
                self._lam = lam
                self._Bm = np.linalg.solve(V, ss.B.astype(complex))  # (n, n_in)
                self._Cm = ss.C @ V  # (n_out, n)
        self._z = np.zeros(self._lam.shape[0] if self._modal else 0, dtype=complex)

    def modal(self) -> tuple[ComplexArray, ComplexArray, ComplexArray, FloatArray] | None:
        """The modal form: λ (n,), Bm = V⁻¹B (n, n_in), Cm = C V (n_out, n) and D.

        λ the eigenvalues, Cm the output directions; None where A is (nearly) defective and
        the direct recursion is used instead.
        """
        return (self._lam, self._Bm, self._Cm, self.ss.D) if self._modal else None

    def run(self, w: ArrayLike) -> FloatArray:
        """Outputs (M, n_out) for inputs ``w`` (M, n_in), continuing from the last call."""
        import scipy.signal  # here, not at the top: off the start-up of every command

        wa = np.asarray(w, dtype=float)
        ss = self.ss
        if not self._modal:
            _, yout, xout = scipy.signal.dlsim((ss.A, ss.B, ss.C, ss.D, 1.0), wa, x0=self._x)
            self._x = ss.A @ xout[-1] + ss.B @ wa[-1]
            return np.asarray(yout).reshape(wa.shape[0], -1)
        out = wa @ ss.D.T
        # two real products (what a real-by-complex matmul costs depends on numpy's
        # version: docs/benchmarks.md, "Choices in the code")
        Bm, Cm = self._Bm, self._Cm
        drive = wa @ Bm.real.T + 1j * (wa @ Bm.imag.T)  # (M, n)
        Z = np.empty_like(drive)
        for i, li in enumerate(self._lam):
            # zeta[m] = li zeta[m-1] + drive[m-1]: the state before sample m.
            Z[:, i], zf = scipy.signal.lfilter(
                [0.0, 1.0], [1.0, -li], drive[:, i], zi=[self._z[i]]
            )
            self._z[i] = zf[0]
        out += Z.real @ Cm.real.T - Z.imag @ Cm.imag.T
        return out


def simulate(
    model: Model,
    *,
    n_samples: int | None = None,
    duration: float | None = None,
    rng: np.random.Generator | None = None,
    reference: ArrayLike | None = None,
    noise: ArrayLike | None = None,
) -> LoopData:
    """Simulate the loop of ``model`` at the high rate.

    Parameters
    ----------
    model : Model
    n_samples : int, optional
        N, a multiple of F.
    duration : float, optional
        Seconds; rounded to a whole number of low-rate periods
        (``N = F * round(duration * fs_low)``). Give exactly one of n_samples, duration,
        or a ``reference``.
    rng : numpy.random.Generator, optional
        Source of the white-noise reference (std ``model.reference_std``) and of the
        output noise (std ``model.noise_std``); required unless both are given.
    reference : array_like, shape (N, n_r), optional
        The excitation r: n_r = n_u at the plant input, n_y at the setpoint
        (``model.injection``); drawn white when not given.
    noise : array_like, shape (N, n_y), optional
        Output noise added to y (also seen by the controller). The model's
        ``disturbances`` are added on top.

    Returns
    -------
    LoopData
        r, u, y (N, channels) with ``fs_high`` and ``ratio`` of the model.

    Raises
    ------
    ConfigError
        If none of ``n_samples``, ``duration``, ``reference`` is given, ``duration`` is
        not a positive number, or ``rng`` is missing where something is drawn.
    DimensionError
        If N is not a positive multiple of F, or ``reference`` (N, n_r) or ``noise``
        (N, n_y) has another shape.
    ModelError
        If the plant or the controller cannot be realised (an improper transfer
        function, a negative input delay).

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import simulate
    >>> from mr_ident.io.modelfile import model_from_dict
    >>> model = model_from_dict({"fs_high": 100.0, "ratio": 2,
    ...                          "plant": {"num": [1.0], "den": [1.0, 1.0]},
    ...                          "controller": {"num": [0.5], "den": [1.0]}})
    >>> sim = simulate(model, duration=1.0, rng=np.random.default_rng(0))
    >>> sim.r.shape, sim.u.shape, sim.y.shape, sim.fs_high, sim.ratio
    ((100, 1), (100, 1), (100, 1), 100.0, 2)
    """
    F, ny, nr = model.ratio, model.n_y, model.n_r
    if reference is not None:
        ra = np.asarray(reference, dtype=float)
        ra = ra[:, None] if ra.ndim == 1 else ra
        if ra.ndim != 2 or ra.shape[1] != nr:
            where = "setpoint: n_y" if model.setpoint else "plant input: n_u"
            raise DimensionError(
                f"reference must have shape (N, n_r={nr}) (r at the {where}), got "
                f"{np.shape(reference)}"
            )
        N = ra.shape[0]
    elif n_samples is not None:
        N = int(n_samples)
    elif duration is not None:
        if not (np.isfinite(duration) and duration > 0):
            raise ConfigError(f"duration must be a positive number of seconds, got {duration!r}")
        N = F * int(round(duration * model.fs_low))
    else:
        raise ConfigError("give n_samples, duration or reference")
    if N < F or N % F:
        raise DimensionError(f"N = {N} samples must be a positive multiple of ratio F={F}")
    needs_rng = reference is None or (noise is None and model.noise_std > 0)
    if needs_rng and rng is None:
        raise ConfigError(
            "rng (numpy.random.Generator) is required to draw the reference or noise"
        )
    if reference is None:
        assert rng is not None
        ra = model.reference_std * rng.standard_normal((N, nr))
    if noise is not None:
        va = np.asarray(noise, dtype=float)
        va = va[:, None] if va.ndim == 1 else va
        if va.shape != (N, ny):
            raise DimensionError(f"noise must have shape (N={N}, n_y={ny}), got {va.shape}")
    elif model.noise_std > 0:
        assert rng is not None
        va = model.noise_std * rng.standard_normal((N, ny))
    else:
        va = np.zeros((N, ny))
    u, y = LoopStream(model).next(ra, va)
    return LoopData(ra, u, y, fs_high=model.fs_high, ratio=F)


@functools.lru_cache(maxsize=8)
def _phases(n_samples: int, start: int, F: int) -> tuple[ComplexArray, ...]:
    """Per-bin phase factors of :func:`_geometric_dft`, independent of the model (cached).

    With ``ω = 2π k / n_eff`` on the rfft bins k: ``e^{-jωF}``, ``e^{-jωF M}``
    (M = periods from ``start // F`` on), ``e^{-jωs}`` and ``e^{-jω(s - p)}`` for s < F
    (p = ``start % F``), each phase reduced exactly modulo 2π in integers first.
    """
    n_eff = n_samples - start
    q, p = divmod(start, F)
    M = n_samples // F - q
    k = np.arange(n_eff // 2 + 1, dtype=np.int64)

    def cis(n: IntArray) -> ComplexArray:  # e^{-j 2π n / n_eff}
        return np.asarray(np.exp((-2j * np.pi / n_eff) * (n % n_eff)), dtype=complex)

    s = np.arange(F)
    out = (cis(k * F), cis(k * F * M), cis(np.outer(k, s)), cis(np.outer(k, s - p)))
    for a in out:
        a.setflags(write=False)
    return out


def _geometric_dft(
    lam: ComplexArray, Cm: ComplexArray, n_samples: int, start: int, F: int
) -> ComplexArray:
    """``Σ_{n=start}^{N-1} g[n] e^{-jω(n - start)}`` of ``g[mF + s] = λ^m Cm[s]``, per bin.

    ``ω = 2π k / (N - start)`` on the rfft bins; ``Cm`` (F, n_y, k), ``lam`` (k,).
    With ``start = qF + p`` and ``z = λ e^{-jωF}``: the whole periods from q on give
    ``λ^q e^{jωp} c(ω) (1 - z^M) / (1 - z)`` with ``c(ω) = Σ_s Cm[s] e^{-jωs}``, less the
    first p samples of period q, ``λ^q Σ_{s<p} Cm[s] e^{-jω(s - p)}``. Shape (n_bins, n_y, k).
    For |λ| < 1 - 1e-4 (a stable loop) ``1 - z`` keeps 12 digits.
    """
    eF, eFM, es, esp = _phases(n_samples, start, F)
    q, p = divmod(start, F)
    M = n_samples // F - q
    _, ny, k = Cm.shape
    lam_q = lam**q
    # from a period's start over whole periods the phases repeat every M bins (ωFM = 2πk):
    # the geometric factor is computed on the first M and read on the rest
    rows = min(M, eF.size) if p == 0 and n_samples % F == 0 else eF.size
    with np.errstate(divide="ignore", invalid="ignore"):
        geo = np.asarray(
            (1.0 - np.multiply.outer(eFM[:rows], lam**M))
            / (1.0 - np.multiply.outer(eF[:rows], lam)),
            dtype=complex,
        )
    geo[~np.isfinite(geo)] = M  # z = 1 exactly: a mode on the unit circle at this bin
    if start:
        geo *= esp[:rows, :1] * lam_q  # e^{jωp} λ^q
    g: ComplexArray = (es @ Cm.reshape(F, -1)).reshape(-1, ny, k)
    for a in range(0, g.shape[0], rows):  # blocks of M bins (a few at most)
        g[a : a + rows] *= geo[: g.shape[0] - a, None, :]
    if p:
        g -= (esp[:, :p] @ Cm[:p].reshape(p, -1)).reshape(-1, ny, k) * lam_q
    return g


def window_phases(n_samples: int, ratio: int) -> ComplexArray:
    """``e^{-j2πks/n}`` on the rfft bins k of ``n_samples`` and s < F, shape (n_bins, F)."""
    return _phases(n_samples, 0, ratio)[2]


def free_spectrum(
    lam: ComplexArray,
    Cm: ComplexArray,
    F: int,
    ny: int,
    n_samples: int,
    start: int,
    *,
    every_mode: bool = False,
) -> ComplexArray:
    """DFT of the free responses ``λ_i^m Cm_i`` of y from ``start`` on, (n_bins, n_y, k).

    ``lam`` (n,) and ``Cm`` (F n_y or more rows, n) of the lifted loop's modal form; see
    :meth:`LoopStream.free_y_spectrum`. Modes dead by ``start`` (λ^q underflows) and
    deadbeat ones are left out unless ``every_mode``.
    """
    n_eff = n_samples - start
    n_bins = n_eff // 2 + 1
    q = start // F
    keep = lam.imag >= 0
    if not every_mode:
        keep &= (np.abs(lam) ** q > 0.0) & (lam != 0.0)
    lam, Cm = lam[keep], Cm[: F * ny, keep]
    if not lam.size:
        return np.zeros((n_bins, ny, 0), dtype=complex)
    # the DFT of λ^m Cv at -k is the conjugate of λ̄'s at k: each pair's conjugate
    # joins the modes, one pass over the positive bins gives G(λ) and G(λ̄)
    cplx = lam.imag > 0
    n_c = int(np.count_nonzero(cplx))
    lam_all = np.concatenate([lam, lam[cplx].conj()])
    C_all = np.concatenate([Cm, Cm[:, cplx].conj()], axis=1).reshape(F, ny, -1)
    G: ComplexArray = _geometric_dft(lam_all, C_all, n_samples, start, F)
    # real and imaginary parts scaled alike (real arithmetic on the real view throughout)
    G.view(float)[...] *= 1.0 / np.sqrt(n_eff)
    if not n_c:
        return G  # real modes: Re(λ^m Cv) is the sequence itself
    n = lam.size
    ci = np.flatnonzero(cplx)
    g, gc = G[..., ci], G[..., n:]
    out: ComplexArray = np.empty((*G.shape[:-1], n + n_c), dtype=complex)
    out[..., :n] = G[..., :n]
    re = g + gc  # DFT of Re(λ^m Cv): (G(λ) + G(λ̄)) / 2
    re.view(float)[...] *= 0.5
    out[..., ci] = re
    d = g - gc  # and of Im(λ^m Cv): (G(λ) - G(λ̄)) / 2j
    im = out[..., n:]
    np.multiply(d.imag, 0.5, out=im.real)
    np.multiply(d.real, -0.5, out=im.imag)
    return out


class LoopStream:
    """The loop of ``model`` simulated piece by piece, state carried across calls.

    ``next(reference, noise)`` continues exactly where the previous call stopped,
    so concatenated pieces equal one :func:`simulate` over the whole record. Used by
    ``mr-ident-sim`` to publish an endless stream.
    """

    def __init__(self, model: Model):
        self.model = model
        self._loop = StateRecursion(lifted_loop(model))
        self._n = 0  # samples simulated so far (for the disturbance's time)

    def free_y_spectrum(self, n_samples: int, start: int) -> ComplexArray:
        """DFT of the free responses of y from sample ``start`` on, shape (n_bins, n_y, k).

        Where the loop, started at rest, differs from one that was already running: the
        response of y to the loop's state at sample 0 (zero input), from sample ``start`` to
        ``n_samples``, one real basis sequence per real mode and two per complex pair (real
        and imaginary part of ``λ^m C v``), for every mode that is not deadbeat. Returned as
        ``rfft(basis, axis=0, norm="ortho")`` over those ``n_samples - start`` samples
        (n_bins = (n_samples - start) // 2 + 1), in closed form: a mode is geometric
        over the low-rate periods, so its DFT is a finite geometric sum per bin
        (:func:`_geometric_dft`), O(modes * bins) with no sequence built and no FFT.
        Empty (k = 0) where there is no mode or A is defective.
        """
        modal = self._loop.modal()
        F, ny = self.model.ratio, self.model.n_y
        if modal is None:
            return np.zeros(((n_samples - start) // 2 + 1, ny, 0), dtype=complex)
        return free_spectrum(modal[0], modal[2], F, ny, n_samples, start)

    def next(
        self, reference: ArrayLike, noise: ArrayLike | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """Plant input and output (u, y) for ``reference`` (N, n_r), N a multiple of F."""
        F, ny, nu, nr = self.model.ratio, self.model.n_y, self.model.n_u, self.model.n_r
        ra = np.asarray(reference, dtype=float).reshape(-1, nr)
        N = ra.shape[0]
        if N % F:
            raise DimensionError(f"reference length {N} must be a multiple of ratio F={F}")
        va = np.zeros((N, ny)) if noise is None else np.asarray(noise, dtype=float).reshape(N, ny)
        if self.model.disturbances:
            va = va + self.model.disturbance(self._n, N)
        self._n += N
        M = N // F
        w = np.concatenate([ra.reshape(M, F * nr), va.reshape(M, F * ny)], axis=1)
        out = self._loop.run(w)
        return out[:, F * ny :].reshape(N, nu), out[:, : F * ny].reshape(N, ny)
