# SPDX-License-Identifier: Apache-2.0
"""Working-memory budget: how many frequency bins a pass over the data takes at once.

Every batched kernel works on blocks of bins, so that its temporaries do not grow with the
record. A block's memory grows with the unknowns per bin, which grow with F and with the
channels: the sizes here shrink with that per-bin cost so that a block's memory stays about
the same whatever the loop. Sizes are powers of two (the blocks tile the bins evenly).
"""

from __future__ import annotations

#: LPM bins per chunk for up to twice a SISO loop's unknowns at F = 3 (the factor
#: alone is 12 x 12 x 4096 complex = 9.4 MB for 3 inputs, R = 2): of 1024..8192, the one
#: timed fastest at the paper's size.
CHUNK_BINS = 4096

#: Low-rate bins per block of the frequency-lifted path for a SISO loop at F = 3; the
#: blocks run on the worker threads.
BLOCK_BINS = 8192


def _power_of_two_below(k: int, most: int, least: int) -> int:
    """The largest power of two <= k, clipped to [least, most]."""
    return most if k >= most else max(least, 1 << (max(k, 1).bit_length() - 1))


def lpm_cost(n_in: int, n_out: int, degree: int) -> int:
    """Complex numbers an LPM chunk holds per bin.

    The factor (Q x Q), the forward solve (Q x n_out), the window sums of the products and
    the outputs' covariance, with Q = (degree + 1)(n_in + 1).
    """
    q = (degree + 1) * (n_in + 1)
    return (
        q * q
        + q * n_out
        + (2 * degree + 1) * n_in * (n_in + 1) // 2
        + (degree + 1) * n_in * n_out
        + n_out**2
    )


def lifted_cost(ratio: int, n_in: int, n_out: int) -> int:
    """Complex numbers a lifted block holds per bin.

    [J; S], its noise covariance and the inverse Gram matrix of the F * n_in lifted inputs.
    """
    a, b = ratio * n_in, ratio * (n_out + n_in)
    return a * b + b * b + a * a


def chunk_bins(n_in: int, n_out: int, degree: int) -> int:
    """LPM bins per chunk.

    :data:`CHUNK_BINS` up to twice the unknowns of a SISO loop's lifted fit at F = 3,
    fewer past that (at least 64).
    """
    k = 2 * CHUNK_BINS * lpm_cost(3, 6, 2) // lpm_cost(n_in, n_out, degree)
    return _power_of_two_below(k, CHUNK_BINS, 64)


def block_bins(ratio: int, n_in: int, n_out: int) -> int:
    """Low-rate bins per block of the lifted methods.

    :data:`BLOCK_BINS` up to twice a SISO loop's lifted size at F = 3, fewer past that
    (at least 256).
    """
    k = 2 * BLOCK_BINS * lifted_cost(3, 1, 1) // lifted_cost(ratio, n_in, n_out)
    return _power_of_two_below(k, BLOCK_BINS, 256)


#: Complex numbers an LRM chunk may hold (32 MB): its windows are formed explicitly.
LRM_CHUNK_NUMBERS = 1 << 21


def lrm_cost(n_in: int, n_out: int, degree: int, n: int) -> int:
    """Complex numbers an LRM chunk holds per bin.

    Four copies of the windows' regressor and right-hand sides (2n+1 rows of
    (R+1)(n_in+1) + n_out (R+1) columns), three P x P matrices and the denominator's
    cross products.
    """
    p = (degree + 1) * (n_in + 1)
    return 4 * (2 * n + 1) * (p + n_out * (degree + 1)) + 3 * p * p + (n_out * degree) ** 2


def lrm_chunk_bins(n_in: int, n_out: int, degree: int, n: int) -> int:
    """LRM bins per chunk: :data:`LRM_CHUNK_NUMBERS` over :func:`lrm_cost` (64 to 4096)."""
    return _power_of_two_below(
        LRM_CHUNK_NUMBERS // lrm_cost(n_in, n_out, degree, n), CHUNK_BINS, 64
    )
