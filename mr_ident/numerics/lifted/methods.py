# SPDX-License-Identifier: Apache-2.0
"""The identification methods as a table: one function per method, :data:`METHODS`.

Every method takes checked signals (a :class:`FitRequest`) and returns the high-rate plant
P_h with its variance on the DFT bins 0..N//2 (a :class:`PlantFit`); the lifted methods
also return the lifted closed-loop maps. :func:`~mr_ident.numerics.identify.identify`
does the checks, looks the method up here, and adds the PFG. A new method is one more
function and one more row.

``freq-lifted`` (default)
    Frequency-lift R, U, Y (stack the F aliases), LPM on r -> [y; u] giving the
    lifted J and S, indirect step ``P = J S^-1``, P_h from the diagonal blocks. With y at
    the low rate (N/F samples) its spectrum sums the aliases: J and P are one block row,
    whose blocks are P_h at the F aliases (:func:`~mr_ident.numerics.lifted.low_rate.unlift_row`).
``time-lifted``
    Time-lift r, u, y (stack F samples), LPM on their M-point DFTs, indirect step,
    P_h from the first block column (polyphase components).
``lpm``
    LTI LPM on the high-rate spectra r -> [y; u], indirect step: the frequency-lifted
    method with F = 1, blind to the periodic time variation (the aliases act as noise).
``structured``
    Frequency-lifted instrument, diagonal lifted plant: the lifted LPM of r -> u gives the
    instrument ``Z = S̃ R̃``; per alias an LPM of [y; u] on Z along the high-rate axis and
    the indirect step (:mod:`mr_ident.numerics.lifted.structured`).
``etfe``
    ``Y / U`` per bin, no window, no noise model (std NaN). SISO only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ...errors import DimensionError
from ..arrays import ComplexArray, FloatArray, IntArray
from ..budget import block_bins
from ..lifting import (
    dft,
    fold_half,
    freq_lift_half,
    half_spectra,
    half_to_full,
    time_lift,
    unlift_bins,
    unlift_frf,
    unlift_variance,
)
from ..local.fit import local_fit, merge_fits
from ..local.lpm import warn_rank_deficient
from ..local.lrm import DenominatorTerm
from ..local.segments import (
    Run,
    Segments,
    covers,
    fitted_mask,
    full_run,
    in_bin_order,
    n_centres,
    segments,
)
from ..results import LiftedFRF
from ..threads import thread_map
from .indirect import indirect_diag, indirect_on, time_den_variance
from .low_rate import low_rate_lift_half, unlift_row, unlift_row_variance
from .pfg_data import empty_pfg, store_lifted_pfg
from .spectra import Spectra
from .structured import structured_block


@dataclass(frozen=True)
class FitRequest:
    """Checked input of a method: r, u, y (N, channels), F, LPM options and threads.

    ``local``: the local model of the fits, "polynomial" (LPM) or "rational" (LRM),
    :mod:`mr_ident.numerics.local.fit`. ``data_pfg``: a lifted method that fits r -> y also
    returns the PFG of that fit (:mod:`mr_ident.numerics.lifted.pfg_data`). ``y`` may have N/F
    rows: the output at the low rate, ``y_h[m F + y_phase]`` (``freq-lifted`` only).
    ``runs``: the centre bins to fit and their half-widths
    (:mod:`mr_ident.numerics.local.segments`; bins 0..M//2 of a lifted method, 0..N//2 of
    ``lpm``); None: every bin with ``n``. Bins
    outside the runs are NaN in the result; the lifted maps are kept only when the runs
    cover every bin. ``spectra``: shared between the fits of one record (else computed).
    ``missing``: the share of filled (estimated) samples of every channel of [y; u]
    (:mod:`mr_ident.numerics.lifted.missing`), None when the record was complete.
    """

    r: FloatArray
    u: FloatArray
    y: FloatArray
    ratio: int
    n: int
    degree: int
    dof: int
    keep_lifted: bool
    workers: int
    local: str = "polynomial"
    data_pfg: bool = False
    y_phase: int = 0
    runs: tuple[Run, ...] | None = None
    spectra: Spectra | None = field(default=None, compare=False)
    missing: FloatArray | None = None

    def share(self, lift: int, part: str = "yu") -> FloatArray | None:
        """:attr:`missing` of the outputs of a fit: y, u or [y; u], each ``lift`` times.

        Lifted outputs are alias-major (``l c + ch``) or sample-major: both tile.
        """
        if self.missing is None:
            return None
        ny = self.y.shape[1]
        parts = {"y": [self.missing[:ny]], "u": [self.missing[ny:]]}
        parts["yu"] = parts["y"] + parts["u"]
        return np.concatenate([np.tile(p, lift) for p in parts[part]])

    @property
    def n_samples(self) -> int:
        """N."""
        return int(self.r.shape[0])

    def plan(self, n_bins: int) -> tuple[Run, ...]:
        """The runs to fit on centre bins 0..n_bins-1: :attr:`runs`, or all with :attr:`n`."""
        return full_run(n_bins, self.n) if self.runs is None else self.runs

    def halves(self, *names: str) -> list[list[ComplexArray]]:
        """The half spectra of several of r, u, y, computed side by side on the threads."""
        if self.spectra is not None:
            return self.spectra.halves(*names)
        signals = {"r": self.r, "u": self.u, "y": self.y}
        return half_spectra([signals[k] for k in names], workers=self.workers)

    def time_lifted(self, name: str) -> ComplexArray:
        """The DFT of the time-lifted r, u or y (shared through :attr:`spectra`)."""
        if self.spectra is not None:
            return self.spectra.time_lifted(name, self.ratio)
        x = {"r": self.r, "u": self.u, "y": self.y}[name]
        return dft(time_lift(x, self.ratio), workers=self.workers)


@dataclass(frozen=True)
class PlantFit:
    """What a method returns.

    P_h (N//2+1, n_y, n_u) and its variance ``E|dP|^2`` on bins 0..N//2 (NaN where it has no
    noise model), the lifted maps when kept, and the PFG of the lifted r -> y fit with its
    variance (N//2+1,) when asked for and the method has that fit.
    """

    P_half: ComplexArray
    var_half: FloatArray
    lifted_J: LiftedFRF | None = None
    lifted_S: LiftedFRF | None = None
    pfg_half: FloatArray | None = None
    pfg_var_half: FloatArray | None = None


@dataclass(frozen=True)
class Method:
    """One row of the table.

    Attributes
    ----------
    name : str
    fit : callable
        ``fit(FitRequest) -> PlantFit``.
    lifted : bool
        The LPM runs on lifted spectra: F inputs and outputs per channel, M = N/F bins
        per period (else 1 and N).
    uses_lpm : bool
        The LPM's degrees-of-freedom and record-length rules apply.
    strides : bool
        Its polynomial windows may be solved every ``2h + 1`` bins (the segments'
        offsets, :mod:`mr_ident.numerics.local.strided`); ``structured`` solves every window
        at its centre (its second stage's regressor is an estimated instrument, whose noise
        the strided check does not model: it re-solved 29 % of the windows at the paper's
        size, slower than no stride).
    """

    name: str
    fit: Callable[[FitRequest], PlantFit]
    lifted: bool
    uses_lpm: bool = True
    strides: bool = True

    def lift(self, ratio: int) -> int:
        """Channels per signal channel in the LPM: F for a lifted method, else 1."""
        return ratio if self.lifted else 1

    def min_samples(self, n: int, ratio: int) -> int:
        """The record-length rule.

        An LPM method needs 2 (2n+1) independent bins per period of its spectrum (M bins
        lifted, N bins not), i.e. N >= 2 (2n+1) F resp. 2 (2n+1); the ETFE one low-rate
        period.
        """
        return 2 * (2 * n + 1) * self.lift(ratio) if self.uses_lpm else ratio


def _store_half(
    P_half: ComplexArray,
    var_half: FloatArray,
    bins: IntArray,
    P: ComplexArray,
    var: FloatArray,
    *,
    ratio: int,
    n_samples: int,
) -> None:
    """Write unlifted estimates (K, F, n_y, n_u) of low-rate ``bins`` (K,) to the half spectrum.

    Alias by alias, the bins at or below N/2 as they are, those above conjugated at N -
    kappa.
    """
    kappa = unlift_bins(bins, ratio, n_samples)
    for l in range(ratio):
        idx, upper = fold_half(kappa[:, l], n_samples)
        for sel, value in ((~upper, P[:, l]), (upper, np.conj(P[:, l]))):
            P_half[idx[sel]] = value[sel]
            var_half[idx[sel]] = var[sel, l]


def _centres(seg: Segments) -> IntArray | None:
    """The centres of the engine's fit over ``seg.window`` that are the segment's bins.

    None when all are (one run): the windows that straddle two runs are not fitted.
    """
    return None if seg.whole else seg.keep


class _LiftedParts(NamedTuple):
    """A segment's lifted fit, bins first: G, the noise covariance, the inverse Gram."""

    G: ComplexArray
    noise_cov: ComplexArray
    inv_gram: ComplexArray


class _BlockFit(NamedTuple):
    """What one segment of :func:`_freq_lifted` returns besides the bins it writes."""

    n_bad: int  # centre bins whose regressor was rank deficient
    dof: int  # the local fit's residual degrees of freedom
    lifted: _LiftedParts | None  # None unless the lifted maps are kept


def _freq_lifted(req: FitRequest, *, lti: bool = False) -> PlantFit:
    """``freq-lifted``, or with ``lti`` the LTI ``lpm``: the same steps at F = 1.

    The LTI fit keeps no PFG of its own (the request's loop is lifted by its F), and its
    lifted maps only when F is 1 anyway.
    """
    F = 1 if lti else req.ratio
    N = req.n_samples
    ny, nu = req.y.shape[1], req.u.shape[1]
    M, half = N // F, N // 2
    Rh, Uh, Yh = req.halves("r", "u", "y")
    Kc = M // 2
    P_half = np.full((half + 1, ny, nu), np.nan + 0j)
    var_half = np.full((half + 1, ny, nu), np.nan)
    slow = req.y.shape[0] != N  # y at the low rate: r -> y is one lifted block row
    n_row = ny if slow else F * ny  # rows of the r -> y part of the fit
    plan = req.plan(Kc + 1)
    # the maps of the request's loop: lifted by its F (lpm's of a setpoint loop: F = 1)
    keep = req.keep_lifted and F == req.ratio and not slow and covers(plan, Kc + 1)
    pfg = empty_pfg(N) if req.data_pfg and not lti and not slow else None

    step = block_bins(F, req.r.shape[1], max(ny, nu))

    def block(seg: Segments) -> _BlockFit:
        """Lift, fit, indirect step and unlift one segment of bins.

        Segments bound the memory and run on threads; each writes only its own bins.
        """
        window, kb = seg.window, seg.bins
        Yl = low_rate_lift_half(Yh, window, F, M) if slow else freq_lift_half(Yh, window, F, N)
        fit = local_fit(
            req.local,
            freq_lift_half(Rh, window, F, N),
            np.concatenate([Yl, freq_lift_half(Uh, window, F, N)], axis=1),
            seg.n,
            req.degree,
            missing=req.share(F),
            centres=_centres(seg),
            offsets=seg.offsets,
        )  # bins-last, the segment's bins
        P, rdiag, cdiag, extra = indirect_diag(fit, n_row)
        if slow:
            Pk = unlift_row(P.transpose(2, 0, 1), F, kb, N, req.y_phase)
            var = unlift_row_variance(rdiag.T, cdiag.T, F)
            if extra is not None:  # (n_y, F n_u, K): entry (a, l n_u + b) is alias l's
                var = var + extra.transpose(2, 0, 1).reshape(len(kb), ny, F, nu).transpose(
                    0, 2, 1, 3
                )
        else:
            Pk, var = unlift_frf(P.transpose(2, 0, 1), F), unlift_variance(rdiag.T, cdiag.T, F)
            if extra is not None:  # the diagonal blocks, as for P
                var = var + unlift_frf(extra.transpose(2, 0, 1), F).real
        _store_half(P_half, var_half, kb, Pk, var, ratio=F, n_samples=N)
        if pfg is not None:
            G, Cv, d = fit.G, fit.noise_cov, fit.den
            den = None if d is None else DenominatorTerm(d.gain[: F * ny], d.cov)
            store_lifted_pfg(
                *pfg,
                kb,
                G[: F * ny],
                Cv[: F * ny, : F * ny],
                fit.inv_gram,
                ratio=F,
                n_samples=N,
                den=den,
            )
        lifted = (fit.G, fit.noise_cov, fit.inv_gram)
        kept = _LiftedParts(*(a.transpose(2, 0, 1) for a in lifted)) if keep else None
        return _BlockFit(n_bad=fit.n_bad, dof=fit.dof, lifted=kept)

    segs = segments(plan, 1, step)
    done = thread_map(block, segs, req.workers)
    warn_rank_deficient(sum(d.n_bad for d in done), n_centres(plan), stacklevel=4)
    pfg_half, pfg_var = (None, None) if pfg is None else pfg
    if not keep:
        return PlantFit(P_half, var_half, pfg_half=pfg_half, pfg_var_half=pfg_var)
    parts = [d.lifted for d in done if d.lifted is not None]
    G = in_bin_order(segs, [p.G for p in parts], Kc + 1)
    Cv = in_bin_order(segs, [p.noise_cov for p in parts], Kc + 1)
    Ainv = in_bin_order(segs, [p.inv_gram for p in parts], Kc + 1)
    q = min(d.dof for d in done)
    J, S = _lifted_maps(G, Cv, Ainv, F * ny, domain="frequency", req=req, dof=q)
    return PlantFit(
        P_half, var_half, lifted_J=J, lifted_S=S, pfg_half=pfg_half, pfg_var_half=pfg_var
    )


def _time_lifted(req: FitRequest) -> PlantFit:
    F, N = req.ratio, req.n_samples
    ny, nu = req.y.shape[1], req.u.shape[1]
    M, half, Kc = N // F, N // 2, N // F // 2
    Rt, Ut, Yt = (req.time_lifted(x) for x in ("r", "u", "y"))
    plan = req.plan(Kc + 1)
    segs = segments(plan, 1, Kc + 1)
    fits = []
    for seg in segs:
        idx = seg.window % M
        fit = local_fit(
            req.local,
            Rt[idx],
            np.concatenate([Yt[idx], Ut[idx]], axis=1),
            seg.n,
            req.degree,
            workers=req.workers,
            missing=req.share(F),
            centres=_centres(seg),
            offsets=seg.offsets,
        )
        fits.append(fit)
    warn_rank_deficient(sum(f.n_bad for f in fits), n_centres(plan), stacklevel=4)
    if len(fits) == 1 and segs[0].bins.size == Kc + 1:  # one run over every bin
        fit = fits[0]
    else:
        fit = merge_fits([seg.bins for seg in segs], fits, Kc + 1)
    G, Cv, Ainv = (a.transpose(2, 0, 1) for a in (fit.G, fit.noise_cov, fit.inv_gram))
    P, row, col = indirect_on(G, Cv, Ainv, F * ny, fitted_mask(segs, Kc + 1))
    # The lifted system is real: its FRF on bins 0..M//2 gives all M bins, and unlifting
    # those gives every high-rate bin k + l M.
    full = [half_to_full(a, M) for a in (P, row, col)]
    P_half = (
        unlift_frf(full[0], F, domain="time").transpose(1, 0, 2, 3).reshape(N, ny, nu)[: half + 1]
    )
    var = unlift_variance(full[1], full[2], F, domain="time")
    if fit.den is not None:
        var = var + time_den_variance(fit.den, P, G[:, F * ny :], F * ny, F, M)
    var_half = var.transpose(1, 0, 2, 3).reshape(N, ny, nu)[: half + 1]
    if not req.keep_lifted or not covers(plan, Kc + 1):
        return PlantFit(P_half, var_half)
    q = min(f.dof for f in fits)
    J, S = _lifted_maps(G, Cv, Ainv, F * ny, domain="time", req=req, dof=q)
    return PlantFit(P_half, var_half, lifted_J=J, lifted_S=S)


def _lifted_maps(
    G: ComplexArray,
    Cv: ComplexArray,
    Ainv: ComplexArray,
    n_y: int,
    *,
    domain: str,
    req: FitRequest,
    dof: int,
) -> tuple[LiftedFRF, LiftedFRF]:
    """The lifted J (the first ``n_y`` rows of G) and S, bins-first, on bins 0..K-1.

    For a rational fit their covariance is the Kronecker part only (without the
    denominator's term).
    """
    bins = np.arange(G.shape[0])
    F, N = req.ratio, req.n_samples
    return (
        LiftedFRF(bins, G[:, :n_y], Cv[:, :n_y, :n_y], Ainv, domain, F, N, dof),
        LiftedFRF(bins, G[:, n_y:], Cv[:, n_y:, n_y:], Ainv, domain, F, N, dof),
    )


def _structured(req: FitRequest) -> PlantFit:
    F, N = req.ratio, req.n_samples
    ny, nu = req.y.shape[1], req.u.shape[1]
    Rh, Uh, Yh = req.halves("r", "u", "y")
    Kc = N // F // 2
    P_half = np.full((N // 2 + 1, ny, nu), np.nan + 0j)
    var_half = np.full((N // 2 + 1, ny, nu), np.nan)
    step = block_bins(F, req.r.shape[1], max(ny, nu))
    plan = req.plan(Kc + 1)

    def block(seg: Segments) -> int:
        """Both stages and the indirect step on one segment of low-rate bins (own bins only)."""
        Rl, Yl, Ul = (freq_lift_half(X, seg.window, F, N) for X in (Rh, Yh, Uh))
        fit = structured_block(
            Rl,
            Yl,
            Ul,
            F,
            seg.n,
            req.degree,
            local=req.local,
            missing=req.missing,
            centres=_centres(seg),
        )
        P, rdiag, cdiag, extra = indirect_diag(fit, ny)  # bins ordered l * B + j
        B = seg.bins.size
        P = P.reshape(ny, nu, F, B).transpose(3, 2, 0, 1)
        var = (
            rdiag.reshape(ny, F, B).transpose(2, 1, 0)[:, :, :, None]
            * cdiag.reshape(nu, F, B).transpose(2, 1, 0)[:, :, None, :]
        )
        if extra is not None:
            var = var + extra.reshape(ny, nu, F, B).transpose(3, 2, 0, 1)
        _store_half(P_half, var_half, seg.bins, P, var, ratio=F, n_samples=N)
        return fit.n_bad

    n_bad = sum(thread_map(block, segments(plan, 2, step), req.workers))
    warn_rank_deficient(n_bad, F * n_centres(plan), stacklevel=4)
    return PlantFit(P_half, var_half)


def _lpm(req: FitRequest) -> PlantFit:
    return _freq_lifted(req, lti=True)


def _etfe(req: FitRequest) -> PlantFit:
    ny, nu = req.y.shape[1], req.u.shape[1]
    if ny != 1 or nu != 1:
        raise DimensionError(
            f"etfe needs a SISO loop (one experiment cannot separate {nu} inputs); got "
            f"n_y={ny}, n_u={nu}"
        )
    Uf, Yf = (h[0] for h in req.halves("u", "y"))
    with np.errstate(divide="ignore", invalid="ignore"):
        P = (Yf / Uf)[:, None, None]
    return PlantFit(P, np.full(P.shape, np.nan))


#: The methods, by name (in the README's order).
METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method("freq-lifted", _freq_lifted, lifted=True),
        Method("time-lifted", _time_lifted, lifted=True),
        Method("lpm", _lpm, lifted=False),
        Method("structured", _structured, lifted=True, strides=False),
        Method("etfe", _etfe, lifted=False, uses_lpm=False),
    )
}
