# SPDX-License-Identifier: Apache-2.0
"""Missing samples of r, the excitation: recovered where the loop determines them.

A recording loses messages of r as of u and y. r is the regressor of every fit (the
indirect method's noise-free input), so a missing r is not an unknown of the fit as a
missing u or y is (:mod:`mr_ident.numerics.lifted.missing`): it is recovered from the
data where the loop determines it, and only the rest is guessed.

Where the loop determines r (exactly, to round-off):

* **r held** over blocks (a setpoint logged at the controller's rate, held to the high
  rate): a hole takes the value of its block's other samples.
* **an open loop**, u equal to r: r is u where u came.
* **a periodic r** (a multisine of ``mr-ident excite``, wherever it enters): r repeats
  exactly, so a lost sample is the same sample a period before or after, where the
  samples around both agree (:func:`_periodic_values`: the same realization).
* **r at the plant input**, ``u_h = r_h + c_h`` with the controller's output ``c_h`` held
  over blocks of F: ``u - r`` is held, so ``r[n] = u[n] - (u - r)`` of its block, from any
  sample of the block where both came. Only a sample whose u is missing too (about the
  product of the two loss rates) is left.
* **r at the setpoint**, sampled by the controller once per block: the samples between
  are never read (``unused``); a taken sample is determined by the controller's equation
  ``c[m] = Σ a_i c[m-i] + Σ g_l (r - y)[m-l]`` (:func:`_fit_equation`), fitted from the
  record's complete blocks when it holds exactly (a digital controller: round-off).

The rest (``unknown``) is filled with the better of r's mean and the mean of its
neighbours, judged on r's own samples. Derivation of what that costs: write the filled
value ``r̂[m] = r[m] - δ_m``. Every fit's output is then ``Y = G R̂ + G Σ_m δ_m e^{-jωm}/√N
+ V``: the error term is, across a window's bins, a sum of phasors turning ``2π m/N`` per
bin, which the local model does not follow (except for m within about N/(2n+1) samples of
the record's ends, where the transient takes it). It is uncorrelated with the regressor
(δ_m is independent of r elsewhere for a white r; of order 1/N otherwise), so it adds to
the noise at each bin ``|G(ω)|² Σ_m δ_m²/N``: no bias, and the local fit's residual
variance, from which every std is computed, contains it. The std stays honest; the noise
floor rises by the unknown share times r's power through G (at :data:`MAX_UNKNOWN_SHARE`,
30 dB below the response to r). Checked numerically in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DataError
from .arrays import BoolArray, FloatArray
from .structure import (
    EQUATION_LAG,
    EQUATION_ORDERS,
    HELD_RTOL,
    SETPOINT,
    equation_fit,
    hold_of,
    u_equals_r,
)

#: The largest share of r's read samples that may be unknown (neither received nor
#: determined by the loop): their guesses' errors act as noise about
#: ``-10 log10(share)`` dB below the response to r (30 dB at 0.1 %; a 1 % loss of r and
#: of u, independent, leaves 0.01 %).
MAX_UNKNOWN_SHARE = 0.001
#: Passes over the equation's rows: each solves the lost samples whose row has every other
#: term (a run of lost blocks is solved from its start, one block a pass).
MAX_PASSES = 8


@dataclass(frozen=True)
class RecoveredR:
    """r with every missing sample filled, and how each was.

    Attributes
    ----------
    r : ndarray, shape (N_r, n_r)
        The excitation, no NaN.
    recovered : int
        Missing samples the loop determines, recovered exactly (to round-off).
    unknown : int
        Missing samples the fit reads and the data do not determine: guessed, their error
        part of the noise the std contains.
    unused : int
        Missing samples the fit never reads (a setpoint between the controller's samples).
    how : str
        What recovered them, in words ("" when nothing was missing).
    """

    r: FloatArray
    recovered: int = 0
    unknown: int = 0
    unused: int = 0
    how: str = ""

    @property
    def missing(self) -> int:
        """Every missing sample of r."""
        return self.recovered + self.unknown + self.unused

    def describe(self) -> str:
        """One line for the user ("" when r was complete)."""
        if not self.missing:
            return ""
        parts = [f"{self.recovered} recovered exactly ({self.how})" if self.recovered else ""]
        if self.unused:
            parts.append(f"{self.unused} between the controller's samples (never read)")
        if self.unknown:
            parts.append(f"{self.unknown} not determined by the data (guessed: counted as noise)")
        return f"{self.missing} samples of r missing: " + "; ".join(p for p in parts if p)


def recover_r(
    r: FloatArray,
    u: FloatArray,
    y: FloatArray,
    *,
    ratio: int,
    injection: str,
    phase: int = 0,
) -> RecoveredR:
    """Recover r's missing (NaN) samples from the loop where it determines them.

    Parameters
    ----------
    r : ndarray, shape (N, n_r), or (N/F, n_r) for a setpoint at the controller's rate
        The excitation; NaN where a sample is missing.
    u, y : ndarray, shape (N, n_u), (N or N/F, n_y)
        The plant input and output (NaN: missing).
    ratio : int
        F.
    injection : {"plant_input", "setpoint"}
        Where r enters.
    phase : int
        The sample of each block the controller takes y (and a setpoint) at.

    Returns
    -------
    RecoveredR

    Raises
    ------
    DataError
        More than :data:`MAX_UNKNOWN_SHARE` of the samples the fit reads are unknown.
    """
    missing = np.isnan(r)
    if not missing.any():
        return RecoveredR(r)
    x = r.copy()
    how: list[str] = []
    _fill(x, _held_values(x)[0], "r held over blocks", how)
    high_rate_y = y.shape[0] == u.shape[0]
    if injection == SETPOINT:
        if high_rate_y and x.shape[1] == u.shape[1] == y.shape[1]:
            _setpoint_by_equation(x, u, y, ratio, phase, how)
    elif x.shape == u.shape:
        if u_equals_r(x, u):  # an open loop: u is r
            _fill(x, u, "u equal to r (open loop)", how)
        _fill(x, u - _held_values(u - x)[0], "u - r held over blocks", how)
        if np.isnan(x).any() and high_rate_y:
            _plant_input_by_equation(x, u, y, ratio, phase, how)
    if np.isnan(x).any():
        _fill(x, _periodic_values(x), "r's own period (a periodic design repeats)", how)
    read = _read_mask(x.shape, u.shape[0], ratio, phase, injection)
    still = np.isnan(x)
    unknown = int((still & read).sum())
    n_read = int(read.sum())
    if unknown > MAX_UNKNOWN_SHARE * n_read:
        raise DataError(
            f"r has {unknown} of its {n_read} read samples missing where the loop does not "
            f"determine them ({100 * unknown / n_read:.2f} %, more than "
            f"{100 * MAX_UNKNOWN_SHARE:g} %): their guesses would raise the noise beyond "
            f"{10 * np.log10(MAX_UNKNOWN_SHARE):.0f} dB of the response (r is recovered where "
            "its u came, or the controller's equation holds; here u was lost with it)"
        )
    unused = int((still & ~read).sum())
    for i in range(x.shape[1]):
        x[:, i] = _guess(x[:, i], read[:, i])
    recovered = int(missing.sum()) - unknown - unused
    return RecoveredR(x, recovered, unknown, unused, ", ".join(dict.fromkeys(how)))


def _held_values(x: FloatArray) -> tuple[FloatArray, tuple[int, int] | None]:
    """Each sample's block value where ``x`` is held over blocks (NaN elsewhere), and the hold.

    The hold ``(F, s)`` is read from ``x`` itself
    (:func:`~mr_ident.numerics.structure.hold_of`; None: not held); a block's value is that
    of its received samples where they agree to
    :data:`~mr_ident.numerics.structure.HELD_RTOL` of x's scale (a block that changes
    within, or with no sample received: NaN).
    """
    out = np.full(x.shape, np.nan)
    hold = hold_of(x)
    if hold is None:
        return out, None
    F, s = hold
    N = x.shape[0]
    starts = np.unique(np.r_[0, np.arange(s, N, F)])
    lo = np.fmin.reduceat(x, starts, axis=0)
    hi = np.fmax.reduceat(x, starts, axis=0)
    scale = float(np.nanmax(np.abs(x)))
    agree = (hi - lo) <= HELD_RTOL * scale  # NaN (no sample received) compares False
    value = np.where(agree, lo, np.nan)
    return np.repeat(value, np.diff(np.r_[starts, N]), axis=0), hold


#: Samples on each side of a hole that must repeat exactly one period away before the
#: sample there is taken for it (so a realization's edge is never crossed).
PERIOD_CONTEXT = 8
#: Share of the samples one period apart that must agree for r to be taken as periodic
#: (M realizations of P periods agree on (P-1)/P of them: half at least, for P >= 2).
PERIOD_SHARE = 0.3


def _periodic_values(x: FloatArray) -> FloatArray:
    """Each sample's value one period away where r repeats there exactly (NaN elsewhere).

    The period is the lag of r's largest autocorrelation (by FFT, over lags of at least
    :data:`PERIOD_CONTEXT`), taken where at least :data:`PERIOD_SHARE` of the sample pairs
    it spans agree to :data:`~mr_ident.numerics.structure.HELD_RTOL` of r's scale. A hole
    takes the sample a period before (or after) when the :data:`PERIOD_CONTEXT` received
    samples on each side of both agree too.
    """
    out = np.full(x.shape, np.nan)
    N = x.shape[0]
    if N < 4 * PERIOD_CONTEXT:
        return out
    scale = float(np.nanmax(np.abs(x), initial=0.0))
    if not scale > 0:
        return out
    tol = HELD_RTOL * scale
    for i in range(x.shape[1]):
        xi = x[:, i]
        z = np.nan_to_num(xi - np.nanmean(xi))
        spec = np.fft.rfft(z, 2 * N)
        acf = np.fft.irfft(np.abs(spec) ** 2)[: N // 2]
        if acf.size <= PERIOD_CONTEXT:
            continue
        P = PERIOD_CONTEXT + int(np.argmax(acf[PERIOD_CONTEXT:]))
        both = np.isfinite(xi[P:]) & np.isfinite(xi[:-P])
        agree = np.abs(xi[P:] - xi[:-P]) <= tol
        if not both.any() or (agree & both).sum() < PERIOD_SHARE * both.sum():
            continue
        holes = np.flatnonzero(np.isnan(xi))
        j = np.r_[-PERIOD_CONTEXT:0, 1 : PERIOD_CONTEXT + 1]
        for shift in (-P, P):
            src = holes + shift
            ok = (src >= 0) & (src < N)
            h, s = holes[ok], src[ok]
            a, b = h[:, None] + j, s[:, None] + j
            inside = (a >= 0) & (a < N) & (b >= 0) & (b < N)
            va = np.where(inside, xi[np.clip(a, 0, N - 1)], np.nan)
            vb = np.where(inside, xi[np.clip(b, 0, N - 1)], np.nan)
            seen = np.isfinite(va) & np.isfinite(vb)
            same = (np.abs(va - vb) <= tol) | ~seen
            take = same.all(axis=1) & (seen.sum(axis=1) >= PERIOD_CONTEXT) & np.isfinite(xi[s])
            fill = np.isnan(out[h, i]) & take
            out[h[fill], i] = xi[s[fill]]
    return out


def _fill(x: FloatArray, values: FloatArray, how: str, said: list[str]) -> None:
    """Fill x's NaN where ``values`` is known (in place); note ``how`` when any was."""
    take = np.isnan(x) & np.isfinite(values)
    if take.any():
        x[take] = values[take]
        said.append(how)


def _read_mask(
    shape: tuple[int, ...], n_samples: int, ratio: int, phase: int, injection: str
) -> BoolArray:
    """The samples of r a fit reads: a high-rate setpoint's at the controller's phase only."""
    read = np.ones(shape, dtype=bool)
    if injection == SETPOINT and shape[0] == n_samples:
        read[:] = False
        read[phase::ratio] = True
    return read


def _per_block(x: FloatArray, F: int, at: int) -> FloatArray:
    """Sample ``m F + at`` of every whole block m, shape (N // F, channels)."""
    M = x.shape[0] // F
    return x[at::F][:M] if at < x.shape[0] - (M - 1) * F else x[at::F][: M - 1]


def _setpoint_by_equation(
    r: FloatArray, u: FloatArray, y: FloatArray, F: int, phase: int, how: list[str]
) -> None:
    """A setpoint's taken samples solved from the controller's equation (in place).

    The held output c (u's block values) and the error ``e = r_l - y_l`` the controller
    took: where :func:`_fit_equation` holds, a missing ``r_l[m] = e[m] + y_l[m]`` with
    ``e[m]`` the root of the first row it enters with a nonzero gain.
    """
    held, hold = _held_values(u)
    if hold is None or hold[0] != F:
        return
    c = _per_block(held, F, hold[1])
    y_l = _per_block(y, F, phase)
    low = r.shape[0] != u.shape[0]
    r_l = r if low else r[phase::F]
    M = min(c.shape[0], y_l.shape[0], r_l.shape[0])
    for i in range(r.shape[1]):
        gap = np.isnan(r_l[:M, i])
        if not gap.any():
            continue
        eq = _fit_equation(c[:M, i], r_l[:M, i] - y_l[:M, i])
        if eq is None:
            continue
        for _ in range(MAX_PASSES):  # a root found lets a row with two lost samples solve
            e = eq.solve_input(c[:M, i], r_l[:M, i] - y_l[:M, i])
            take = np.isnan(r_l[:M, i]) & np.isfinite(e)
            if not take.any():
                break
            r_l[:M, i][take] = e[take] + y_l[:M, i][take]  # r_l is a view of r
            how.append("the controller's equation")


def _plant_input_by_equation(
    r: FloatArray, u: FloatArray, y: FloatArray, F: int, phase: int, how: list[str]
) -> None:
    """Recover r where its whole block is lost, from the controller's output predicted.

    With r at the plant input, the controller's output ``c = u - r`` is held; where no
    sample of a block came with both r and u, c is predicted from the controller's
    equation (``e = -y_l``, fitted by :func:`_fit_equation`) and ``r = u - c`` (in place).
    """
    held, hold = _held_values(u - r)
    if hold is None or hold[0] != F:
        return
    s = hold[1]
    c = _per_block(held, F, s)
    y_l = _per_block(y, F, phase)
    M = min(c.shape[0], y_l.shape[0])
    for i in range(r.shape[1]):
        if not np.isnan(c[:M, i]).any():
            continue
        eq = _fit_equation(c[:M, i], -y_l[:M, i])
        if eq is None:
            continue
        ci = c[:M, i].copy()
        for _ in range(MAX_PASSES):  # a block predicted lets the next one lost be
            pred = eq.predict(ci, -y_l[:M, i])
            take = np.isnan(ci) & np.isfinite(pred)
            if not take.any():
                break
            ci[take] = pred[take]
        pred = ci
        block_c = np.full(r.shape[0], np.nan)  # each sample's predicted block value
        for_blocks = np.repeat(pred, F)
        block_c[s : s + for_blocks.size] = for_blocks[: r.shape[0] - s]
        take = np.isnan(r[:, i]) & np.isfinite(u[:, i]) & np.isfinite(block_c)
        if take.any():
            r[take, i] = u[take, i] - block_c[take]
            how.append("the controller's equation")


@dataclass(frozen=True)
class _Equation:
    """``c[m] = Σ_i a_i c[m-i] + Σ_l g_l e[m-l] + b``: a controller's exact equation."""

    a: FloatArray  # (order,), i = 1..order
    g: FloatArray  # (order + EQUATION_LAG,), l = 0..
    b: float

    def _rows(self, c: FloatArray, e: FloatArray) -> tuple[FloatArray, FloatArray]:
        L = self.g.size
        M = c.shape[0]
        past = np.column_stack([c[L - i : M - i] for i in range(1, self.a.size + 1)])
        errs = np.column_stack([e[L - j : M - j] for j in range(L)])
        return past, errs

    def predict(self, c: FloatArray, e: FloatArray) -> FloatArray:
        """c[m] from its past and e where every term is received (NaN elsewhere), (M,)."""
        past, errs = self._rows(c, e)
        out = np.full(c.shape[0], np.nan)
        out[self.g.size :] = past @ self.a + errs @ self.g + self.b
        return out

    def solve_input(self, c: FloatArray, e: FloatArray) -> FloatArray:
        """e[m] from the first row it enters with a gain above round-off (NaN elsewhere)."""
        L, M = self.g.size, c.shape[0]
        big = np.flatnonzero(np.abs(self.g) > 1e-9 * np.max(np.abs(self.g)))
        lag = int(big[0])
        past, errs = self._rows(c, e)
        others = np.delete(errs, lag, axis=1) @ np.delete(self.g, lag)
        root = (c[L:] - past @ self.a - others - self.b) / self.g[lag]
        out = np.full(M, np.nan)
        m = np.arange(L, M) - lag  # row m + lag solves e[m]
        out[m] = root
        return out


def _fit_equation(c: FloatArray, e: FloatArray) -> _Equation | None:
    """The controller's equation of the lowest order that holds exactly, or None.

    Orders :data:`~mr_ident.numerics.structure.EQUATION_ORDERS`, each fitted by
    :func:`~mr_ident.numerics.structure.equation_fit` (a digital controller and the y it
    took: round-off).
    """
    for order in EQUATION_ORDERS:
        coef = equation_fit(c, [e], order)
        if coef is not None:
            g = coef[order : 2 * order + EQUATION_LAG]
            if np.max(np.abs(g)) > 0:
                return _Equation(coef[:order], g, float(coef[-1]))
    return None


def _guess(x: FloatArray, read: BoolArray) -> FloatArray:
    """Fill x's NaN with the better guess of r's mean and its neighbours' mean.

    The read samples are filled along their own sequence (a setpoint's: one per block),
    with the guess of least mean squared error on their received samples where both
    neighbours came (for a white r the mean; for a smooth one the neighbours'); samples
    not read take the mean (they do not matter).
    """
    out = x.copy()
    seq = out[read]
    ok = np.isfinite(seq)
    mean = float(seq[ok].mean()) if ok.any() else 0.0
    gap = ~ok
    if gap.any():
        mid = ok[1:-1] & ok[:-2] & ok[2:]
        err_mean = float(np.mean((seq[ok] - mean) ** 2))
        err_near = (
            float(np.mean((0.5 * (seq[:-2] + seq[2:]) - seq[1:-1])[mid] ** 2))
            if mid.any()
            else np.inf
        )
        known = np.flatnonzero(ok)
        if err_near < err_mean and known.size >= 2:
            seq[gap] = np.interp(np.flatnonzero(gap), known, seq[known])
        else:
            seq[gap] = mean
        out[read] = seq
    out[np.isnan(out)] = mean
    return out
