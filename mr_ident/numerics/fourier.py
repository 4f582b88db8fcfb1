# SPDX-License-Identifier: Apache-2.0
"""The unitary DFT and the spectra of real signals kept on bins 0..N//2.

* DFT ``X(k) = N**-0.5 * sum_n x[n] exp(-2j pi n k / N)`` (:func:`dft`, DEVELOPERS.md).
* Real signals: their DFT is kept on bins 0..N//2 (:func:`half_spectrum`); any bin is
  read through ``X(N - k) = conj X(k)`` (:func:`spectrum_bins`, :func:`half_to_full`,
  :func:`fold_half`).

:mod:`~mr_ident.numerics.lifting` re-exports every name: the lifting rules are read with
the spectra they lift.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from .arrays import AnyArray, BoolArray, ComplexArray, FloatArray, IndexArray
from .threads import thread_map


def _fft_columns(
    transform: Callable[..., ComplexArray], x: AnyArray, workers: int | None
) -> ComplexArray:
    """``transform`` (numpy's unitary FFT) along axis 0, the columns on ``workers`` threads.

    NumPy's FFT rather than scipy's: the same pocketfft, bit for bit, without the import of
    ``scipy.fft`` at every program's start (docs/benchmarks.md, "Start-up").
    """
    if workers is None or workers <= 1 or x.ndim < 2 or x[0].size <= 1:
        return transform(x, axis=0, norm="ortho")
    flat = x.reshape(x.shape[0], -1)
    cols = thread_map(
        lambda c: transform(c, norm="ortho"), [flat[:, i] for i in range(flat.shape[1])], workers
    )
    return np.stack(cols, axis=1).reshape((cols[0].shape[0], *x.shape[1:]))


def dft(x: ArrayLike, *, workers: int | None = None) -> ComplexArray:
    """Unitary DFT along axis 0: ``X(k) = N**-0.5 sum_n x[n] exp(-2j pi n k/N)``.

    Parameters
    ----------
    x : array_like, shape (N, ...)
        Signals along axis 0 (usually (N, n_channels)).
    workers : int, optional
        Threads over the columns; the result does not depend on it.

    Returns
    -------
    ndarray, shape (N, ...), complex128
        Bins k = 0..N-1 (``k/N`` cycles per sample); :func:`idft` inverts it.

    Examples
    --------
    >>> import numpy as np
    >>> from mr_ident import dft, idft
    >>> dft(np.ones(4))  # a constant: all of it at bin 0
    array([2.+0.j, 0.+0.j, 0.+0.j, 0.+0.j])
    >>> idft(dft([1.0, -2.0, 0.5])).real.round(12)
    array([ 1. , -2. ,  0.5])
    """
    return _fft_columns(np.fft.fft, np.asarray(x), workers)


def idft(X: ArrayLike, *, workers: int | None = None) -> ComplexArray:
    """Inverse of :func:`dft` (complex result; take ``.real`` for real signals).

    Parameters
    ----------
    X : array_like, shape (N, ...)
        A spectrum on bins 0..N-1 along axis 0.
    workers : int, optional
        Threads over the columns; the result does not depend on it.

    Returns
    -------
    ndarray, shape (N, ...), complex128
    """
    return _fft_columns(np.fft.ifft, np.asarray(X), workers)


def half_spectrum(x: FloatArray, *, workers: int = 1) -> list[ComplexArray]:
    """The DFT of a real (N, c) signal on bins 0..N//2: one (N//2+1,) array per column.

    One real transform per column, the columns on ``workers`` threads. The upper half is
    never formed; :func:`spectrum_bins` reads any bin through conjugate symmetry.
    """
    return half_spectra([x], workers=workers)[0]


def half_spectra(xs: list[FloatArray], *, workers: int = 1) -> list[list[ComplexArray]]:
    """:func:`half_spectrum` of several signals, all their columns on the threads at once.

    (Signal by signal, a SISO loop's r, u and y would each be one transform: one thread.)
    """

    def rfft(c: FloatArray) -> ComplexArray:
        out: ComplexArray = np.fft.rfft(c, norm="ortho")
        return out

    flat = thread_map(rfft, [x[:, i] for x in xs for i in range(x.shape[1])], workers)
    ends = np.cumsum([x.shape[1] for x in xs])
    return [flat[e - x.shape[1] : e] for x, e in zip(xs, ends, strict=True)]


def fold_half(kappa: ArrayLike, n_samples: int) -> tuple[IndexArray, BoolArray]:
    """Where bin ``kappa`` (0..N-1) of a real signal's DFT lies in its half 0..N//2.

    Returns ``(index, conj)``: ``X(kappa) = X_half(index)``, conjugated where ``conj``.
    """
    k = np.asarray(kappa, dtype=np.intp)
    upper = k > n_samples // 2
    return np.where(upper, n_samples - k, k), upper


def spectrum_bins(half: list[ComplexArray], idx: IndexArray, n_samples: int) -> ComplexArray:
    """``X[idx]`` of the full N-bin DFT of each column, shape ``idx.shape + (c,)``.

    ``half`` is :func:`half_spectrum`'s list of columns on bins 0..N//2; ``idx`` in 0..N-1.
    """
    src, upper = fold_half(idx, n_samples)
    out = np.stack([c[src] for c in half], axis=-1)
    np.conjugate(out, out=out, where=upper[..., None])
    return out


def half_to_full(X_half: AnyArray, n_samples: int) -> AnyArray:
    """Extend values on bins 0..N//2 (axis 0) to all N bins by conjugate symmetry."""
    h = n_samples // 2
    out = np.empty((n_samples,) + X_half.shape[1:], dtype=X_half.dtype)
    out[: h + 1] = X_half[: h + 1]
    upper = X_half[n_samples - h - 1 : 0 : -1]
    out[h + 1 :] = np.conj(upper) if np.iscomplexobj(X_half) else upper
    return out
