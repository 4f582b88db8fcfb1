# SPDX-License-Identifier: Apache-2.0
"""Frozen result types of mr_ident.

Shapes follow one convention throughout the package:

* signals: ``(n_samples, n_channels)``
* FRFs: ``(n_freq, n_out, n_in)`` complex128, so batched ``@`` and ``solve``
  run over the leading frequency axis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DimensionError
from .arrays import BoolArray, ComplexArray, FloatArray, IntArray, frozen, readonly


@dataclass(frozen=True)
class FRF:
    """A frequency response function with its standard deviation.

    Attributes
    ----------
    frequency : ndarray, shape (n_freq,)
        Frequencies in Hz, strictly increasing.
    response : ndarray, shape (n_freq, n_out, n_in), complex128
        The estimate.
    std : ndarray, shape (n_freq, n_out, n_in), float64
        Standard deviation of the complex estimate, ``sqrt(E|G_hat - G|^2)``
        (so real and imaginary parts each have ``std / sqrt(2)`` for circular
        noise). NaN where the method gives no noise model (``etfe``).
    method : str
        The method that produced the estimate (``"freq-lifted"``, ``"model"``...).

    The arrays are held read-only: an array of the right dtype that is read-only down to
    the array owning its memory is kept as given (an estimator hands its arrays over that
    way, uncopied); anything else is copied (:func:`~mr_ident.numerics.arrays.frozen`).

    Raises
    ------
    DimensionError
        If ``frequency`` is not 1-D and strictly increasing, or ``response`` and ``std``
        are not both (n_freq, n_out, n_in).

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import FRF
    >>> frf = FRF(np.array([1.0, 2.0]), np.ones((2, 1, 1)), np.zeros((2, 1, 1)), "model")
    >>> frf.n_out, frf.n_in, frf.response.dtype, frf.response.flags.writeable
    (1, 1, dtype('complex128'), False)
    """

    frequency: FloatArray
    response: ComplexArray
    std: FloatArray
    method: str

    def __post_init__(self) -> None:
        f = frozen(self.frequency, np.float64)
        g = frozen(self.response, np.complex128)
        s = frozen(self.std, np.float64)
        if f.ndim != 1:
            raise DimensionError(f"frequency must be 1-D (n_freq,), got shape {f.shape}")
        if g.ndim != 3 or g.shape[0] != f.shape[0]:
            raise DimensionError(
                f"response must have shape (n_freq={f.shape[0]}, n_out, n_in), got {g.shape}"
            )
        if s.shape != g.shape:
            raise DimensionError(f"std must have the shape of response {g.shape}, got {s.shape}")
        if f.size > 1 and not np.all(np.diff(f) > 0):
            raise DimensionError("frequency must be strictly increasing")
        object.__setattr__(self, "frequency", f)
        object.__setattr__(self, "response", g)
        object.__setattr__(self, "std", s)

    @property
    def n_out(self) -> int:
        """Outputs (rows of each response matrix)."""
        return int(self.response.shape[1])

    @property
    def n_in(self) -> int:
        """Inputs (columns of each response matrix)."""
        return int(self.response.shape[2])


@dataclass(frozen=True)
class LiftedFRF:
    """An LPM estimate of a lifted (LTI MIMO) map with a Kronecker-factored covariance.

    The covariance of the estimate is
    ``E[dG[k,a,b] conj(dG[k,a2,b2])] = row_cov[k,a,a2] * col_cov[k,b,b2]``,
    which is the exact form of the least-squares covariance of the LPM
    (Pintelon & Schoukens 2012, ch. 7) and survives the indirect step. The arrays are
    held read-only (views: not copied).

    Attributes
    ----------
    bins : ndarray of int, shape (n_bins,)
        Low-rate DFT bin indices k (frequency ``k * fs_low / M``).
    response : ndarray, shape (n_bins, n_out, n_in), complex128
    row_cov : ndarray, shape (n_bins, n_out, n_out), complex128 (Hermitian)
    col_cov : ndarray, shape (n_bins, n_in, n_in), complex128 (Hermitian)
    domain : str
        ``"frequency"`` (aliases stacked) or ``"time"`` (samples stacked).
    ratio : int
        The lifting factor F.
    n_samples : int
        High-rate record length N (so the low-rate length is N / F).
    dof : int
        Degrees of freedom q of the noise covariance estimate
        (:func:`~mr_ident.numerics.local.lpm.dof`).

    Raises
    ------
    DimensionError
        If the shapes disagree (response (n_bins, n_out, n_in), row_cov (n_bins, n_out,
        n_out), col_cov (n_bins, n_in, n_in)), ``domain`` is neither "frequency" nor
        "time", or ``dof < 1``.

    References
    ----------
    .. [1] R. Pintelon, J. Schoukens, *System Identification: A Frequency Domain
       Approach*, 2nd ed., Wiley 2012, ch. 7.
    .. [2] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.
    """

    bins: IntArray
    response: ComplexArray
    row_cov: ComplexArray
    col_cov: ComplexArray
    domain: str
    ratio: int
    n_samples: int
    dof: int

    def __post_init__(self) -> None:
        for name, dtype in (
            ("bins", np.int64),
            ("response", np.complex128),
            ("row_cov", np.complex128),
            ("col_cov", np.complex128),
        ):
            object.__setattr__(self, name, readonly(getattr(self, name), dtype))
        g = self.response
        if g.ndim != 3 or g.shape[0] != np.shape(self.bins)[0]:
            raise DimensionError(f"response must be (n_bins, n_out, n_in), got {g.shape}")
        if self.row_cov.shape != (g.shape[0], g.shape[1], g.shape[1]):
            raise DimensionError(
                f"row_cov must be {(g.shape[0], g.shape[1], g.shape[1])}, got {self.row_cov.shape}"
            )
        if self.col_cov.shape != (g.shape[0], g.shape[2], g.shape[2]):
            raise DimensionError(
                f"col_cov must be {(g.shape[0], g.shape[2], g.shape[2])}, got {self.col_cov.shape}"
            )
        if self.domain not in ("frequency", "time"):
            raise DimensionError(f'domain must be "frequency" or "time", got {self.domain!r}')
        if self.dof < 1:
            raise DimensionError(f"dof must be >= 1, got {self.dof}")

    @property
    def std(self) -> FloatArray:
        """Standard deviation of each entry, shape (n_bins, n_out, n_in)."""
        r = np.real(np.diagonal(self.row_cov, axis1=1, axis2=2))
        c = np.real(np.diagonal(self.col_cov, axis1=1, axis2=2))
        out: FloatArray = np.sqrt(np.maximum(r[:, :, None] * c[:, None, :], 0.0))
        return out


@dataclass(frozen=True)
class PFG:
    """Performance Frequency Gain of a multirate loop r_h -> y_h.

    Attributes
    ----------
    frequency : ndarray, shape (n_freq,)
        Input frequency in Hz.
    gain : ndarray, shape (n_freq,)
        PFG: 2-norm (largest singular value) of the first block column of the
        frequency-lifted closed-loop map at that input frequency.
    std : ndarray, shape (n_freq,)
        First-order standard deviation; NaN where no noise model exists.
    source : str
        What it was computed from (``"model"``, ``"plant:freq-lifted"``, ...).

    The arrays are held read-only (views: not copied).

    Raises
    ------
    DimensionError
        If ``frequency``, ``gain`` and ``std`` do not share one 1-D shape.

    References
    ----------
    .. [1] T. Oomen, M. van de Wal, O. Bosgra, "Design framework for high-performance
       optimal sampled-data control with application to a wafer stage", IJC 80(6), 2007.
    .. [2] E. van Haren, L. Blanken, T. Oomen, "Performance analysis of multirate systems:
       a direct frequency-domain identification approach", MSSP 235, 2025.
    """

    frequency: FloatArray
    gain: FloatArray
    std: FloatArray
    source: str

    def __post_init__(self) -> None:
        for name in ("frequency", "gain", "std"):
            object.__setattr__(self, name, readonly(getattr(self, name), np.float64))
        f = self.frequency
        if f.ndim != 1 or self.gain.shape != f.shape or self.std.shape != f.shape:
            raise DimensionError(
                f"frequency, gain and std must share one 1-D shape, got {f.shape}, "
                f"{self.gain.shape}, {self.std.shape}"
            )

    def part(self, keep: slice | IntArray) -> PFG:
        """The PFG on a subset of its frequencies (``keep`` indexes them)."""
        return PFG(self.frequency[keep], self.gain[keep], self.std[keep], self.source)


@dataclass(frozen=True)
class Identification:
    """Everything one identification run produced.

    Attributes
    ----------
    plant : FRF
        High-rate plant estimate on (0, fs_high/2], shape (N//2, n_y, n_u).
    pfg : PFG or None
        PFG from the plant estimate and the known controller, when one was given.
    pfg_data : PFG or None
        PFG identified from data alone (the lifted closed-loop map r -> y; source
        ``"data:..."``), no controller needed; None where the data cannot give it.
    lifted_J, lifted_S : LiftedFRF or None
        The lifted closed-loop maps r->y and r->u (lifted methods only).
    fs_high : float
    ratio : int
    n_used : ndarray of int, shape (n_freq,), or None
        The LPM window half-width used at each plant frequency (chosen per bin with
        ``n="auto"``; constant otherwise; 0 for a method without a window).
    local : str
        The local model of the windows: ``"polynomial"`` (LPM) or ``"rational"`` (LRM).
    n_missing : ndarray of int, shape (n_y + n_u,)
        Missing samples (NaN in the input) of every channel of y, then of u; each was
        estimated as an unknown of the fit (zeros when the record was complete).
    injection : str
        Where r entered: ``"plant_input"`` or ``"setpoint"``.
    undetermined : ndarray of bool, shape (n_freq,), or None
        Plant frequencies where P_h is not determined by the data: with r at the setpoint,
        the bins whose window reaches a zero of the hold (multiples of fs_high/F; NaN at
        the zeros). None: every frequency is.
    r_recovered : int
        Missing samples of r recovered exactly from the loop (u - r or r held, a setpoint's
        controller equation): :func:`~mr_ident.numerics.missing_r.recover_r`.
    r_unknown : int
        Missing samples of r the fit reads that the data do not determine: guessed, their
        error part of the noise every std contains.

    Raises
    ------
    DimensionError
        If ``n_missing`` is not (n_y + n_u,), ``pfg``, ``pfg_data``, ``n_used`` or
        ``undetermined`` are not on the plant's frequencies, only one of ``lifted_J`` and
        ``lifted_S`` is given, or ``fs_high <= 0`` or ``ratio < 1``.

    References
    ----------
    .. [1] E. van Haren, L. Blanken, T. Oomen, "Frequency Domain Identification of
       Multirate Systems: A Lifted Local Polynomial Modeling Approach", CDC 2022.
    """

    plant: FRF
    pfg: PFG | None
    lifted_J: LiftedFRF | None
    lifted_S: LiftedFRF | None
    fs_high: float
    ratio: int
    n_used: IntArray | None = None
    local: str = "polynomial"
    pfg_data: PFG | None = None
    n_missing: IntArray | None = None
    injection: str = "plant_input"
    undetermined: BoolArray | None = None
    r_recovered: int = 0
    r_unknown: int = 0

    def __post_init__(self) -> None:
        n_ch = sum(self.plant.response.shape[1:])
        counts = readonly(
            np.zeros(n_ch, np.int64) if self.n_missing is None else self.n_missing, np.int64
        )
        if counts.shape != (n_ch,):
            raise DimensionError(f"n_missing must be (n_y + n_u = {n_ch},), got {counts.shape}")
        object.__setattr__(self, "n_missing", counts)
        for name, g in (("pfg", self.pfg), ("pfg_data", self.pfg_data)):
            if g is not None and g.frequency.shape != self.plant.frequency.shape:
                raise DimensionError(
                    f"{name} must be on the plant's {self.plant.frequency.size} frequencies, "
                    f"got {g.frequency.size}"
                )
        if self.n_used is not None:
            object.__setattr__(self, "n_used", readonly(self.n_used, np.int64))
            if self.n_used.shape != self.plant.frequency.shape:
                raise DimensionError(
                    f"n_used must be (n_freq={self.plant.frequency.size},), got "
                    f"{self.n_used.shape}"
                )
        if self.undetermined is not None:
            object.__setattr__(self, "undetermined", readonly(self.undetermined, np.bool_))
            if self.undetermined.shape != self.plant.frequency.shape:
                raise DimensionError(
                    f"undetermined must be (n_freq={self.plant.frequency.size},), got "
                    f"{self.undetermined.shape}"
                )
        if (self.lifted_J is None) != (self.lifted_S is None):
            raise DimensionError("lifted_J and lifted_S come together (both or neither)")
        if not (self.fs_high > 0 and self.ratio >= 1):
            raise DimensionError(
                f"fs_high must be > 0 and ratio >= 1, got {self.fs_high}, {self.ratio}"
            )

    @property
    def median_window(self) -> int | None:
        """The fit's typical window half-width: the median of the positive ``n_used``.

        None where no window was recorded.
        """
        if self.n_used is None or not np.any(self.n_used > 0):
            return None
        return int(np.median(self.n_used[self.n_used > 0]))
