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

Stable by construction: a continuous pole is ``ω_ref (-e^{a} + j e^{b})`` (``-ω_ref e^{a}``
when real); a discrete pair ``e^{-h ω_ref e^{a}} e^{jπ/(1 + e^{-b})}`` (radius below 1,
angle in (0, π): it stays a pair), a discrete real pole ``tanh(a)``.
"""

from __future__ import annotations

import numpy as np

from ..arrays import ComplexArray, FloatArray

DOMAINS = ("continuous", "discrete")


def n_states(poles: ComplexArray) -> int:
    """Order: a real pole counts one, a pair two."""
    return int(np.sum(np.where(poles.imag > 0, 2, 1)))


def to_params(poles: ComplexArray, domain: str, h: float, w_ref: float) -> FloatArray:
    """The unconstrained parameters of a stable pole set (inverse of :func:`from_params`)."""
    out: list[float] = []
    for p in poles:
        if domain == "discrete" and p.imag == 0:
            out.append(float(np.arctanh(np.clip(p.real, -0.999999, 0.999999))))
            continue
        s = complex(p) if domain == "continuous" else complex(np.log(p)) / h
        out.append(float(np.log(max(-s.real, 1e-9 * w_ref) / w_ref)))
        if p.imag > 0 and domain == "continuous":
            out.append(float(np.log(max(s.imag, 1e-9 * w_ref) / w_ref)))
        elif p.imag > 0:  # the angle in (0, π) through a logistic
            t = float(np.clip(np.angle(p) / np.pi, 1e-9, 1 - 1e-9))
            out.append(float(np.log(t / (1 - t))))
    return np.array(out)


def from_params(
    u: FloatArray, pair: list[bool], domain: str, h: float, w_ref: float
) -> ComplexArray:
    """The pole set of parameters ``u``; ``pair[k]``: pole k is a complex pair."""
    out = np.empty(len(pair), dtype=complex)
    j = 0
    for k, is_pair in enumerate(pair):
        if domain == "discrete" and not is_pair:
            out[k] = np.tanh(u[j]) * (1.0 - 1e-12)  # strictly inside when tanh saturates
            j += 1
            continue
        if domain == "discrete":  # radius e^{-h w_ref e^a}, angle π / (1 + e^{-b})
            angle = np.pi / (1.0 + np.exp(-u[j + 1]))
            out[k] = np.exp(-h * w_ref * np.exp(u[j]) - 1e-12 + 1j * angle)
            j += 2
            continue
        out[k] = complex(-w_ref * np.exp(u[j]), w_ref * np.exp(u[j + 1]) if is_pair else 0.0)
        j += 2 if is_pair else 1
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
    m = int(np.floor(delay / h + 1e-9))
    eps = max(delay - m * h, 0.0)
    if eps < 1e-12 * h:
        eps = 0.0
    shift = z ** (-m)
    cols: list[ComplexArray] = []

    def one(p: complex) -> ComplexArray:
        if domain == "discrete":
            return shift / (z - p)
        e = np.exp(p * (h - eps))
        g0 = (e - 1.0) / p
        g1 = e * (np.exp(p * eps) - 1.0) / p
        return np.asarray(shift * (g0 + g1 / z) / (z - np.exp(p * h)), dtype=complex)

    for p in poles:
        b = one(complex(p))
        if p.imag > 0:
            bc = one(complex(p).conjugate())
            cols += [b + bc, 1j * (b - bc)]
        else:
            cols.append(b)
    if direct:
        cols.append(shift / z if (domain == "continuous" and eps > 0) else shift)
    if not cols:
        return np.zeros((z.size, 0), dtype=complex)
    return np.column_stack(cols)


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


def initial_poles(order: int, f_lo: float, f_hi: float, domain: str, h: float) -> ComplexArray:
    """Starting poles: lightly damped pairs log-spaced over the band (+ one real pole)."""
    n_pairs = order // 2
    f = np.geomspace(max(f_lo, 1e-6), f_hi, n_pairs) if n_pairs else np.zeros(0)
    w = 2.0 * np.pi * f
    s = np.concatenate([(-0.01 * w + 1j * w), [-2.0 * np.pi * np.sqrt(f_lo * f_hi)]])
    if order % 2 == 0:
        s = s[:-1]
    return s if domain == "continuous" else np.exp(s * h)
