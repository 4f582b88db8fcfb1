# SPDX-License-Identifier: Apache-2.0
"""Poles, their stable parametrisation, and the partial-fraction columns of each domain.

A pole set is one array: real poles and one pole of each complex pair (``Im p > 0``).
Each real pole gives one column, each pair two (``b_p + b_p̄`` and ``j(b_p - b_p̄)``, whose
coefficients are ``Re R`` and ``Im R`` of the pair's residue), so the model is linear in
real coefficients.

Domains (sample time ``h``, delay ``τ = m h + ε``, ``0 <= ε < h``, bins ``z = e^{jωh}``):

- ``"continuous"``: ``G(s) e^{-sτ}`` behind a zero-order hold, exactly: the held input's
  response of ``1/(s - p)`` is ``z^{-m} (Γ0 + Γ1 z^{-1}) / (z - e^{ph})`` with
  ``Γ0 = (e^{p(h-ε)} - 1)/p`` and ``Γ1 = e^{p(h-ε)} (e^{pε} - 1)/p`` (the modified
  z-transform). The identified P_h is this hold-equivalent, and the simulator discretises
  the file's continuous plant the same way, so the fitted model reproduces P_h.
- ``"discrete"``: ``z^{-m} / (z - λ)`` (whole samples of delay only).

Stable by construction, with a margin (:func:`from_params`): a pair's damping lies in
``(ζ_min, 1)``, a real pole is faster than ``ω_min``; a discrete pair's angle stays in
``(0, π)``.
"""

from __future__ import annotations

import numpy as np

from ..arrays import ComplexArray, FloatArray

DOMAINS = ("continuous", "discrete")


def n_states(poles: ComplexArray) -> int:
    """Order: a real pole counts one, a pair two."""
    return int(np.sum(np.where(poles.imag > 0, 2, 1)))


#: Least damping of a fitted pair, and slowest real pole relative to ω_ref: a pole on the
#: stability boundary is never fitted (a rigid body or integrator becomes a slow pole).
ZETA_MIN = 1e-4
RATE_MIN = 1e-5


def _logit(t: float) -> float:
    t = float(np.clip(t, 1e-12, 1 - 1e-12))
    return float(np.log(t / (1 - t)))


def _sigmoid(a: float) -> float:
    return float(1.0 / (1.0 + np.exp(-a)))


def to_params(poles: ComplexArray, domain: str, h: float, w_ref: float) -> FloatArray:
    """The unconstrained parameters of a stable pole set (inverse of :func:`from_params`)."""
    out: list[float] = []
    w_min = RATE_MIN * w_ref
    for p in poles:
        if p.imag > 0:
            s = complex(p) if domain == "continuous" else complex(np.log(p)) / h
            zeta = -s.real / abs(s)
            out.append(_logit((zeta - ZETA_MIN) / (1 - ZETA_MIN)))
            if domain == "continuous":
                out.append(float(np.log(abs(s) / w_ref)))
            else:
                out.append(_logit(float(np.angle(p)) / np.pi))
        elif domain == "continuous":
            out.append(float(np.log(max(-p.real - w_min, 1e-9 * w_ref) / w_ref)))
        else:
            r = float(p.real) / np.exp(-h * w_min)
            out.append(float(np.arctanh(np.clip(r, -1 + 1e-12, 1 - 1e-12))))
    return np.array(out)


#: The least log-radius of a discrete pair (a radius of 5e-131: at the origin for any fit, and
#: still a pair: its imaginary part stays above zero).
LOG_RADIUS_MIN = -300.0


def from_params(
    u: FloatArray, pair: list[bool], domain: str, h: float, w_ref: float
) -> ComplexArray:
    """The pole set of parameters ``u``; ``pair[k]``: pole k is a complex pair.

    Pair: damping ``ζ = ζ_min + (1 - ζ_min) σ(a)``; continuous ``|p| = ω_ref e^{b}``,
    discrete angle ``π σ(b)`` (so it stays a pair) and radius ``e^{-ζ θ / sqrt(1 - ζ²)}``.
    Real: ``-(ω_min + ω_ref e^{a})``, discrete ``tanh(a) e^{-h ω_min}``.
    """
    out = np.empty(len(pair), dtype=complex)
    w_min = RATE_MIN * w_ref
    j = 0
    for k, is_pair in enumerate(pair):
        if is_pair:
            zeta = ZETA_MIN + (1 - ZETA_MIN) * _sigmoid(u[j])
            c = np.sqrt(max(1 - zeta * zeta, 1e-300))
            if domain == "continuous":
                w = w_ref * np.exp(u[j + 1])
                out[k] = complex(-zeta * w, c * w)
            else:
                theta = np.pi * _sigmoid(u[j + 1])
                # log-radius floored: at ζ -> 1 the radius underflowed to 0, the pole became
                # real (imag 0) and its columns one instead of two
                out[k] = np.exp(max(-zeta * theta / c, LOG_RADIUS_MIN) + 1j * theta)
            j += 2
        elif domain == "continuous":
            out[k] = -(w_min + w_ref * np.exp(u[j]))
            j += 1
        else:
            out[k] = np.tanh(u[j]) * np.exp(-h * w_min)
            j += 1
    return out


def stabilise(poles: ComplexArray, domain: str) -> ComplexArray:
    """Unstable poles mirrored into the stable region (``-conj p`` or ``1/conj λ``)."""
    p = np.asarray(poles, dtype=complex).copy()
    if domain == "continuous":
        bad = p.real >= 0
        p[bad] = -np.abs(p[bad].real) - 1e-6 * np.abs(p[bad]) + 1j * p[bad].imag
    else:
        r = np.abs(p)
        bad = r >= 1
        p[bad] = 0.999 * p[bad] / r[bad] ** 2
    return p


def split_pairs(values: ComplexArray, tol: float = 1e-9) -> ComplexArray:
    """Eigenvalues as a pole set: real ones real, one of each pair (Im > 0)."""
    v = np.asarray(values, dtype=complex)
    scale = np.maximum(np.abs(v), 1e-12)
    real = np.abs(v.imag) <= tol * scale
    out = np.concatenate([v[real].real.astype(complex), v[~real & (v.imag > 0)]])
    return np.asarray(out[np.argsort(np.abs(out))], dtype=complex)


def _split_delay(delay: float, h: float) -> tuple[int, float]:
    """``τ = m h + ε`` with ``0 <= ε < h`` (ε below 1e-12 h is zero)."""
    m = int(np.floor(delay / h + 1e-9))
    eps = max(delay - m * h, 0.0)
    return m, (0.0 if eps < 1e-12 * h else eps)


def _fractions(
    p: ComplexArray, z: ComplexArray, domain: str, h: float, m: int, *, eps: float, kind: str
) -> ComplexArray:
    """Each pole's basis function at the bins (K, n), or its derivative.

    ``kind``: "value" ``b(p)``; "pole" ``∂b/∂p`` (b is holomorphic in p); "delay"
    ``∂b/∂ε`` (continuous only).
    """
    shift = (z ** (-m))[:, None]
    zz = z[:, None]
    if domain == "discrete":
        b = shift / (zz - p)
        return b / (zz - p) if kind == "pole" else (b if kind == "value" else 0.0 * b)
    a = h - eps
    Ea, Eh = np.exp(p * a), np.exp(p * h)
    g0 = np.expm1(p * a) / p
    g1 = Ea * np.expm1(p * eps) / p
    d = zz - Eh
    if kind == "value":
        return np.asarray(shift * (g0 + g1 / zz) / d, dtype=complex)
    if kind == "delay":
        return np.asarray(shift * Ea * (1.0 / zz - 1.0) / d, dtype=complex)
    dg0 = (a * Ea - g0) / p
    dg1 = (h * Eh - a * Ea - g1) / p
    return np.asarray(
        shift * ((dg0 + dg1 / zz) + (g0 + g1 / zz) * (h * Eh) / d) / d, dtype=complex
    )


def _assemble(
    poles: ComplexArray,
    z: ComplexArray,
    domain: str,
    h: float,
    delay: float,
    *,
    kind: str,
    direct: bool,
) -> ComplexArray:
    m, eps = _split_delay(delay, h)
    poles = np.asarray(poles, dtype=complex)
    pair = poles.imag > 0
    width = np.where(pair, 2, 1)
    first = np.concatenate([[0], np.cumsum(width)[:-1]]).astype(int)
    n = int(width.sum())
    out = np.zeros((z.size, n + (1 if direct else 0)), dtype=complex)
    if poles.size:
        B = _fractions(poles, z, domain, h, m, eps=eps, kind=kind)
        Bc = _fractions(poles[pair].conj(), z, domain, h, m, eps=eps, kind=kind)
        out[:, first[~pair]] = B[:, ~pair]
        out[:, first[pair]] = B[:, pair] + Bc
        out[:, first[pair] + 1] = 1j * (B[:, pair] - Bc)
    if direct and kind == "value":
        out[:, n] = z ** (-m) / z if (domain == "continuous" and eps > 0) else z ** (-m)
    return out


def columns(
    poles: ComplexArray,
    z: ComplexArray,
    domain: str,
    h: float,
    delay: float = 0.0,
    *,
    direct: bool = False,
) -> ComplexArray:
    """The partial-fraction columns at bins ``z = e^{jωh}``, shape (K, order [+1]).

    Column order: per pole its one (real) or two (pair) columns, then the direct term.
    """
    return _assemble(poles, z, domain, h, delay, kind="value", direct=direct)


def pole_derivatives(
    poles: ComplexArray, z: ComplexArray, domain: str, h: float, delay: float = 0.0
) -> ComplexArray:
    """``∂/∂Re p`` of each pole's columns (K, order), exactly.

    A pair's columns ``φ1 = b(p) + b(p̄)``, ``φ2 = j(b(p) - b(p̄))`` have ``∂/∂Re p`` =
    ``ψ1 = b'(p) + b'(p̄)``, ``ψ2 = j(b'(p) - b'(p̄))`` (returned), and ``∂/∂Im p``:
    ``∂φ1 = ψ2``, ``∂φ2 = -ψ1``.
    """
    return _assemble(poles, z, domain, h, delay, kind="pole", direct=False)


def delay_derivatives(
    poles: ComplexArray, z: ComplexArray, h: float, delay: float, *, direct: bool
) -> ComplexArray:
    """``∂/∂τ`` of the continuous columns (K, order [+1]) within a sample.

    The direct term's column is piecewise constant in τ: its derivative is 0.
    """
    return _assemble(poles, z, "continuous", h, delay, kind="delay", direct=direct)


def residues_of(
    coef: FloatArray, poles: ComplexArray, n_out: int, n_in: int, *, direct: bool
) -> tuple[ComplexArray, FloatArray]:
    """Residues (n_p, n_out, n_in) and direct term from coefficients (n_cols, n_out, n_in)."""
    R = np.empty((poles.size, n_out, n_in), dtype=complex)
    j = 0
    for k, p in enumerate(poles):
        if p.imag > 0:
            R[k] = coef[j] + 1j * coef[j + 1]
            j += 2
        else:
            R[k] = coef[j]
            j += 1
    D = coef[j] if direct else np.zeros((n_out, n_in))
    return R, np.asarray(D, dtype=float)


def initial_poles(
    order: int, f_lo: float, f_hi: float, domain: str, h: float, spacing: float = 0.0
) -> ComplexArray:
    """Starting poles: lightly damped pairs over the band (+ one real pole).

    The pairs' frequencies are equally spaced in ``log(f + c)``: log-spaced (c = 0) where
    that keeps neighbours ``spacing`` Hz apart (two bins, say), else with the least c
    that does (towards linear spacing), or linear spacing (the widest) when none does.
    Pairs closer than the bins are nearly the same columns: the first relocation's least
    squares lost up to 5 digits to them (a condition number of 5e4 at order 40 over three
    decades).
    """
    n_pairs = order // 2
    lo = max(f_lo, 1e-6)
    k = (np.arange(n_pairs) + 0.5) / max(n_pairs, 1)  # mid-points

    def freqs(c: float) -> FloatArray:
        out: FloatArray = (lo + c) * ((f_hi + c) / (lo + c)) ** k - c
        return out

    def tight(c: float) -> bool:
        f = freqs(c)
        return bool(f.size > 1 and np.min(np.diff(f)) < spacing)

    c = 0.0
    if tight(0.0):
        a, b = 0.0, 1e6 * (f_hi + spacing)  # b: as good as linear spacing
        if not tight(b):
            for _ in range(60):
                c = 0.5 * (a + b)
                a, b = (c, b) if tight(c) else (a, c)
        c = b
    f = freqs(c)
    w = 2.0 * np.pi * f
    s = np.concatenate([(-0.01 * w + 1j * w), [-2.0 * np.pi * np.sqrt(f_lo * f_hi)]])
    if order % 2 == 0:
        s = s[:-1]
    return s if domain == "continuous" else np.exp(s * h)
