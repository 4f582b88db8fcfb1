# SPDX-License-Identifier: Apache-2.0
"""Sums over sliding windows of frequency bins: the LPM's moment sums, batched.

Every entry of the LPM's normal equations (``K^H K``, ``K^H Y``, ``Y^H Y``) is a sum over
the window ``r = -n..n`` of a product signal times a kernel ``(r/n)^q`` (or the window's
orthonormal polynomials): :func:`window_sums` computes them for all bins at once by one of
three routes, chosen by their cost (:func:`route`):

* ``"toeplitz"``: one real BLAS product per block of bins against a banded Toeplitz matrix
  (:class:`Kernel`), ``(B + 2n) n_q`` multiply-adds per bin: the cheapest for narrow windows;
* ``"doubling"``: the moments of blocks of ``2^j`` bins about their own centres, merged in
  pairs, and every window assembled from the blocks of its binary decomposition
  (:func:`doubling_sums`): about ``log2(2n+1)`` small products per bin, whatever n;
* ``"direct"``: windows that do not overlap (a stride of at least 2n+1), one product each.

:func:`kernels` builds the kernels of :func:`~mr_ident.numerics.local.lpm.lpm_bins_last`;
:func:`moving_sum` is the unweighted sum by doubling.

**Why doubling is exact to round-off.** A block of ``w = 2^j`` bins starting at bin a holds
``B_j[p, a] = sum_t Z[a + (w-1)/2 + t] (t/h)^p`` (t its offsets from its centre, h = w/2,
so ``|t/h| < 1``). Two neighbouring blocks merge with the binomial theorem about the new
centre, ``t' = t -+ w/2``::

    B_{j+1}[p, a] = 2^-p sum_{s<=p} C(p, s) ((-1)^(p-s) B_j[s, a] + B_j[s, a + w])

and a window's moments about its centre (offset d of a block's centre, ``|d| + h <= n +
1/2``) are ``sum_p C(q, p) (h/n)^p (d/n)^(q-p) B_j[p]`` summed over its blocks. The
absolute values of each row of coefficients sum to 1 in a merge (``2^-p 2^p`` per side)
and to ``((h + |d|)/n)^q <= (1 + 1/(2n))^q`` in the assembly, so no step amplifies an
error: after the ``log2(2n+1)`` merges each moment is off by a few ulps of ``sum |Z|`` over
its window (growing with the number of merges, not with n, nor with the bins' index; the
kernel's monomial coefficients then scale it, :func:`kernels`). Prefix sums of ``Z k^q``
would instead subtract numbers of size ``k^q sum |Z|`` (k up to 1e5).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from math import comb

import numpy as np
from numpy.typing import NDArray

#: Bins per block of the Toeplitz route: a fixed block about as fast as any near it and
#: faster than one of 2n bins at wide windows (measured: docs/benchmarks.md).
BLOCK = 16
#: Cost weights of :func:`route`, in the Toeplitz route's multiply-adds: a doubling merge's
#: multiply-add per bin and moment pair, and a copied number of the direct route.
MERGE_WEIGHT = 3.0
COPY_WEIGHT = 2.0


@dataclass(frozen=True, eq=False)
class Kernel:
    """Weights ``w[q, r]`` (r = -n..n) of :func:`window_sums`, and their monomial form.

    ``coef`` (n_q, P + 1), when given: ``w[q, r] = sum_p coef[q, p] (r/n)^p`` (the doubling
    route needs it). The Toeplitz route's matrix (:attr:`taps`) is built when first used.
    """

    w: NDArray[np.float64]
    coef: NDArray[np.float64] | None
    stride: int = 1
    B: int = BLOCK

    @classmethod
    def of(
        cls, w: NDArray[np.float64], stride: int = 1, coef: NDArray[np.float64] | None = None
    ) -> Kernel:
        """The kernel of weights ``w`` (n_q, 2n+1), outputs every ``stride`` bins."""
        w = np.array(w, dtype=np.float64)
        w.flags.writeable = False
        if coef is not None:
            coef = np.array(coef, dtype=np.float64)
            coef.flags.writeable = False
        return cls(w, coef, stride)

    @property
    def n(self) -> int:
        """Half-width of the window."""
        return int(self.w.shape[1] - 1) // 2

    @property
    def n_out(self) -> int:
        """Kernels, n_q."""
        return int(self.w.shape[0])

    @functools.cached_property
    def taps(self) -> NDArray[np.float64]:
        """The banded Toeplitz matrix of a block of B outputs, (s (B - 1) + 2n + 1, n_q B).

        Output i of a block is the window centred ``s i`` bins after the block's first
        centre: ``taps[t, (q, i)] = w[q, t - s i]``. The work per output is ``(s (B - 1) +
        2n + 1) n_q`` multiply-adds, so B is small and fixed (:data:`BLOCK`): a B that grew
        with n (it was 2n) made a window of n = 27 cost 1.8x one of n = 8 in the sums.
        """
        nq, L = self.w.shape
        B, s = self.B, self.stride
        T = np.zeros((s * (B - 1) + L, nq, B))
        for i in range(B):
            T[s * i : s * i + L, :, i] = self.w.T
        T = T.reshape(T.shape[0], nq * B)
        T.flags.writeable = False
        return T

    @functools.cached_property
    def plan(self) -> tuple[NDArray[np.float64], NDArray[np.float64], tuple[tuple[int, int], ...]]:
        """The doubling route's matrices: merge ``[M_E M_D]``, assembly, and the blocks.

        Merge (P+1, 2(P+1)): ``B_{j+1} = M_E (B_j[a] + B_j[a+w]) + M_D (B_j[a+w] - B_j[a])``.
        Blocks: (j, offset) of the window's binary decomposition, widest first. Assembly
        (n_q, blocks (P+1)): ``coef`` times each block's re-centring to the window's centre.
        """
        if self.coef is None:
            raise ValueError("the doubling route needs the kernel's monomial coefficients")
        n, P1 = self.n, self.coef.shape[1]
        C = np.array([[comb(p, s) for s in range(P1)] for p in range(P1)], dtype=float)
        half = 0.5 ** np.arange(P1)[:, None]
        odd = (np.arange(P1)[:, None] - np.arange(P1)[None, :]) % 2 == 1
        merge = np.concatenate([np.where(odd, 0.0, C * half), np.where(odd, C * half, 0.0)], 1)
        L = 2 * n + 1
        blocks, offset = [], 0
        for j in range(L.bit_length() - 1, -1, -1):
            if L >> j & 1:
                blocks.append((j, offset))
                offset += 1 << j
        parts = []
        for j, o in blocks:
            h, d = (1 << j) / 2.0, o + ((1 << j) - 1) / 2.0 - n
            q, p = np.arange(P1)[:, None], np.arange(P1)[None, :]
            R = np.where(p <= q, C * (h / n) ** p * (d / n) ** np.maximum(q - p, 0), 0.0)
            parts.append(self.coef @ R)
        return merge, np.concatenate(parts, axis=1), tuple(blocks)


@functools.lru_cache(maxsize=32)
def kernels(
    n: int, degree: int, stride: int = 1
) -> tuple[NDArray[np.float64], Kernel, Kernel, Kernel, Kernel]:
    """The constant transient factor ``L_TT`` and the window kernels of :func:`lpm_bins_last`.

    For half-width n and degree R; the sums every ``stride`` centres.

    With ``x = r/n`` and ``phi_u`` the polynomials orthonormal on the window
    (``phi = V L_TT^-T``, ``V[r, t] = x^t``, ``L_TT L_TT^T = V^T V``):

    * ``x^q``, q = 0..2R, for the products ``conj(U_i) U_j`` (the G-G block);
    * ``phi_u(r) x^s``, u = 0..R, s = R..0, for ``conj(U_i)``: the G-transient block of
      the Cholesky factor, ``L_GT = A_GT L_TT^-T``, directly;
    * ``x^s``, s = 0..R, for ``conj(U_i) Y_o`` (the right-hand side of G);
    * ``phi_u``, u = 0..R, for ``Y_o``: the transient rows of the forward solve directly.

    Each also in monomial form (``phi_u = sum_t (L_TT^-1)[u, t] x^t``) for the doubling route.
    """
    x = np.arange(-n, n + 1) / n
    T = degree + 1
    V = x[:, None] ** np.arange(T)[None, :]
    L_TT = np.linalg.cholesky(V.T @ V)
    L_TT.flags.writeable = False
    Li = np.linalg.inv(L_TT)
    phi = V @ Li.T  # (2n+1, T)
    powers = x[None, :] ** np.arange(2 * degree + 1)[:, None]  # (2R+1, 2n+1)
    s_desc = np.arange(degree, -1, -1)
    phi_x = (phi.T[:, None, :] * powers[s_desc][None, :, :]).reshape(T * T, -1)
    c_phi_x = np.zeros((T, T, 2 * degree + 1))
    for i, s in enumerate(s_desc):
        c_phi_x[:, i, s : s + T] = Li
    return (
        L_TT,
        Kernel.of(powers, stride, np.eye(2 * degree + 1)),
        Kernel.of(phi_x, stride, c_phi_x.reshape(T * T, -1)),
        Kernel.of(powers[:T], stride, np.eye(T)),
        Kernel.of(phi.T, stride, Li),
    )


@functools.lru_cache(maxsize=16)
def plain(n: int, stride: int = 1) -> Kernel:
    """The kernel of the plain sum over the window (all weights 1)."""
    return Kernel.of(np.ones((1, 2 * n + 1)), stride, np.ones((1, 1)))


def route(kernel: Kernel, K: int) -> str:
    """The cheapest route of :func:`window_sums` for K outputs: the one place that decides.

    Costs per output, in multiply-adds of the Toeplitz product (n_q kernels, P their
    degree, s the stride, L = 2n+1):

    * Toeplitz: ``(s (B - 1) + L) n_q``;
    * doubling: ``s log2(L)`` merges of ``2 (P+1)^2``, each weighted by
      :data:`MERGE_WEIGHT` (small products, not one large one), and the assembly
      ``(P+1) n_q`` per block of L's binary digits;
    * direct (windows that do not overlap, ``s >= L``): ``L (n_q +`` :data:`COPY_WEIGHT` ``)``.

    The weights were measured with one BLAS thread on blocks of 4096 bins (n = 8..710,
    strides 1, 2h+1 and 2n+1, the kernels of R = 2, one and two signals): the route chosen
    was the fastest or within 7 % of it in all 140 cases; Toeplitz up to n = 41-93,
    doubling from there at stride 1 (flat in n, where Toeplitz's cost grows with it:
    docs/benchmarks.md, "Setpoint excitation"), direct for the gathered windows.
    """
    s, nq, L = kernel.stride, kernel.n_out, kernel.w.shape[1]
    cost = {"toeplitz": float((s * (kernel.B - 1) + L) * nq)}
    if s >= L:
        cost["direct"] = float(L * (nq + COPY_WEIGHT))
    if kernel.coef is not None:
        P1, levels = kernel.coef.shape[1], L.bit_length() - 1
        blocks = bin(L).count("1")
        cost["doubling"] = s * levels * 2 * P1 * P1 * MERGE_WEIGHT + blocks * P1 * nq
    return min(cost, key=cost.__getitem__)


def window_sums(Z: NDArray[np.complex128], kernel: Kernel, K: int) -> NDArray[np.complex128]:
    """Windowed sums ``S[q, c, k] = sum_{r=-n}^{n} w[q, r] Z[c, s k + n + r]``, k = 0..K-1.

    Z has shape (C, s (K-1) + 2n + 1) (s the kernel's stride, usually 1; missing bins at
    the end count as zeros); the result (n_q, C, K), by the route :func:`route` chooses.
    """
    how = route(kernel, K)
    if how == "doubling":
        return doubling_sums(Z, kernel, K)
    if how == "direct":
        return _direct_sums(Z, kernel, K)
    return _toeplitz_sums(Z, kernel, K)


def _padded(Z: NDArray[np.complex128], need: int) -> NDArray[np.complex128]:
    """Z with zero columns appended up to ``need`` (itself when long enough)."""
    if Z.shape[1] >= need:
        return Z
    Zp = np.zeros((Z.shape[0], need), dtype=np.complex128)
    Zp[:, : Z.shape[1]] = Z
    return Zp


def _toeplitz_sums(Z: NDArray[np.complex128], kernel: Kernel, K: int) -> NDArray[np.complex128]:
    """The Toeplitz route: one real matrix product (BLAS) per block of B outputs.

    The real and imaginary parts of every signal over the block's windows are rows.
    """
    C = Z.shape[0]
    B, nq, st = kernel.B, kernel.n_out, kernel.stride
    taps = kernel.taps
    span = taps.shape[0]  # s (B - 1) + 2n + 1
    nb = -(-K // B)
    Z = _padded(Z, (nb - 1) * B * st + span)
    c_st, k_st = Z.strides
    blocks = np.lib.stride_tricks.as_strided(
        Z, (C, nb, span), (c_st, B * st * k_st, k_st), writeable=False
    )  # overlapping: block b = Z[:, b B s : b B s + span]
    X = np.empty((2, C, nb, span))
    X[0] = blocks.real
    X[1] = blocks.imag
    o = (X.reshape(2 * C, nb, span) @ taps).reshape(2, C, nb, nq, B)
    out = np.empty((nq, C, nb, B), dtype=np.complex128)
    out.real = o[0].transpose(2, 0, 1, 3)
    out.imag = o[1].transpose(2, 0, 1, 3)
    return out.reshape(nq, C, nb * B)[:, :, :K]


def _direct_sums(Z: NDArray[np.complex128], kernel: Kernel, K: int) -> NDArray[np.complex128]:
    """The direct route (stride >= 2n+1): each window's bins times the weights, one product."""
    C, (nq, L), s = Z.shape[0], kernel.w.shape, kernel.stride
    Z = _padded(Z, s * (K - 1) + L)
    c_st, k_st = Z.strides
    win = np.lib.stride_tricks.as_strided(Z, (C, K, L), (c_st, s * k_st, k_st), writeable=False)
    X = np.empty((2, C, K, L))
    X[0] = win.real
    X[1] = win.imag
    o = X @ kernel.w.T  # (2, C, K, nq)
    out = np.empty((nq, C, K), dtype=np.complex128)
    out.real = o[0].transpose(2, 0, 1)
    out.imag = o[1].transpose(2, 0, 1)
    return out


def doubling_sums(Z: NDArray[np.complex128], kernel: Kernel, K: int) -> NDArray[np.complex128]:
    """The doubling route of :func:`window_sums` (module docstring: the merge, the error).

    The blocks' moments ``(P+1, C, bins)`` are held for every start bin, level by level:
    one merge per level (the sums and differences of neighbours, then one small real
    product); the window's blocks are gathered as their level comes up and assembled in
    one product. Work per bin about ``log2(2n+1) 4 (P+1)^2`` multiply-adds, whatever n;
    memory ``3 (P+1) C`` numbers per bin and ``(P+1)`` per block of the window per output.
    """
    merge, assemble, blocks = kernel.plan
    P1, s, L = merge.shape[0], kernel.stride, kernel.w.shape[1]
    C = Z.shape[0]
    width = s * (K - 1) + L
    Z = _padded(Z, width)[:, :width]
    top = blocks[0][0]
    parts = np.empty((len(blocks), P1, C, K), dtype=np.complex128)
    pairs = np.empty(2 * P1 * C * width, dtype=np.complex128)  # sums, then differences
    moments = np.empty(P1 * C * width, dtype=np.complex128)  # the level's blocks
    cur = moments[: P1 * C * width].reshape(P1, C, width)
    for j in range(top + 1):
        for m, (jm, o) in enumerate(blocks):
            if jm == j and j == 0:  # a single bin: its moments about itself are Z, 0, ...
                parts[m, 0] = Z[:, o : o + s * (K - 1) + 1 : s]
                parts[m, 1:] = 0.0
            elif jm == j:
                parts[m] = cur[:, :, o : o + s * (K - 1) + 1 : s]
        if j == top:
            break
        w = 1 << j
        npos = width - 2 * w + 1  # blocks of 2w bins that fit
        if j == 0:  # pairs of bins: B_1[p] = 2^-p (Z[a + 1] + (-1)^p Z[a])
            X = pairs[: 2 * C * npos].reshape(2, C, npos)
            np.add(Z[:, :npos], Z[:, 1:], out=X[0])
            np.subtract(Z[:, 1:], Z[:, :npos], out=X[1])
            cur = moments[: P1 * C * npos].reshape(P1, C, npos)
            for p in range(P1):
                np.multiply(X[p % 2], 0.5**p, out=cur[p])
            continue
        X = pairs[: 2 * P1 * C * npos].reshape(2 * P1, C, npos)
        np.add(cur[:, :, :npos], cur[:, :, w:], out=X[:P1])
        np.subtract(cur[:, :, w:], cur[:, :, :npos], out=X[P1:])
        cur = moments[: P1 * C * npos].reshape(P1, C, npos)
        np.matmul(merge, _real(X, 2 * P1), out=_real(cur, P1))
    nq = assemble.shape[0]
    out = np.empty((nq, C, K), dtype=np.complex128)
    np.matmul(assemble, _real(parts, len(blocks) * P1), out=_real(out, nq))
    return out


def _real(a: NDArray[np.complex128], rows: int) -> NDArray[np.float64]:
    """A contiguous complex array as ``rows`` rows of interleaved reals (a view)."""
    out: NDArray[np.float64] = a.view(np.float64).reshape(rows, -1)
    return out


def moment_index(n_in: int) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """The upper-triangle pairs (i, j) of n_in inputs and each pair's index, symmetric."""
    iu, ju = np.triu_indices(n_in)
    pair = np.empty((n_in, n_in), dtype=np.intp)
    pair[iu, ju] = np.arange(iu.size)
    pair[ju, iu] = np.arange(iu.size)
    return iu, ju, pair


def moving_sum(Z: NDArray[np.complex128], n: int, K: int) -> NDArray[np.complex128]:
    """``S[c, k] = sum_{r=-n}^{n} Z[c, k+n+r]`` by doubling: O(log n) adds, no cumsum drift."""
    L = 2 * n + 1
    out: NDArray[np.complex128] | None = None
    offset = 0
    block = Z  # block[c, j] = sum of `width` samples starting at j
    width = 1
    while True:
        if L & width:
            part = block[:, offset : offset + K]
            out = part.copy() if out is None else out + part
            offset += width
        if 2 * width > L:
            break
        block = block[:, :-width] + block[:, width:]
        width *= 2
    assert out is not None
    return out
