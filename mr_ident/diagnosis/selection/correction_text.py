# SPDX-License-Identifier: Apache-2.0
"""A plant correction in words: its poles (and a multiplicative one's zeros) in Hz and damping.

A discrete pole ``z`` is read as ``s = ln(z) fs``: ``|s| / 2π`` Hz, damping ``-Re s / |s|``.
Past :data:`LISTED` poles and zeros (a high order) they are counted and summarised: their
range and the least damped pair.
"""

from __future__ import annotations

import math

import numpy as np

from ...numerics.arrays import ComplexArray
from ...numerics.systems.modal import ModalPlant

#: Past this many poles and zeros (pairs once) the text summarises them (:func:`describe`).
LISTED = 6


def _hz_damping(z: complex, fs: float) -> tuple[float, float]:
    s = complex(np.log(complex(z))) * fs
    w = abs(s)
    return w / (2.0 * math.pi), (-s.real / w if w > 0 else 1.0)


def poles_text(C: ModalPlant) -> list[str]:
    """Each pole (pair) of a discrete correction in words: frequency and damping of ln(z) fs."""
    assert C.dt is not None
    fs = 1.0 / C.dt
    out = []
    for p in C.poles:
        f, z = _hz_damping(complex(p), fs)
        out.append(
            f"a pole pair at {f:.3g} Hz, damping {z:.2g}"
            if p.imag > 0
            else f"a real pole at {f:.3g} Hz"
        )
    return out


def _zeros(C: ModalPlant) -> ComplexArray:
    """Zeros of the SISO ``1 + C`` (multiplicative), upper half plane and real ones."""
    S = C.state_space()
    d = float(S.D[0, 0]) + 1.0
    if not S.A.size or abs(d) < 1e-12:
        return np.zeros(0, complex)
    z = np.linalg.eigvals(S.A - S.B @ S.C / d)
    return np.asarray(z[z.imag >= 0], complex)


def describe(kind: str, C: ModalPlant) -> str:
    """The correction in words: "an additive correction ... with a pole pair at 83 Hz, ...".

    Past :data:`LISTED` poles and zeros (a high order), counted and summarised instead:
    "... of order 9: 3 pole pairs and 3 real poles between 0.005 and 258 Hz (the least
    damped pair at 21.9 Hz, damping 0.59); ... zeros ...".
    """
    assert C.dt is not None  # fitted discrete
    fs = 1.0 / C.dt
    siso = kind == "multiplicative" and C.shape == (1, 1)
    zeros = _zeros(C) if siso else np.zeros(0, complex)
    article = "an" if kind == "additive" else "a"
    if C.poles.size + zeros.size > LISTED:
        parts = [_summarised(C.poles, "pole", fs)]
        if zeros.size:
            parts.append(_summarised(zeros, "zero", fs))
        return f"{article} {kind} correction of the plant of order {C.order}: {'; '.join(parts)}"
    parts = poles_text(C)
    for z in zeros:
        f, zeta = _hz_damping(complex(z), fs)
        kind_z = "a zero pair" if z.imag > 0 else "a real zero"
        parts.append(f"{kind_z} at {f:.3g} Hz, damping {zeta:.2g}" if z.imag > 0 else
                     f"{kind_z} at {f:.3g} Hz")  # fmt: skip
    body = ", ".join(parts[:-1]) + (" and " if len(parts) > 1 else "") + parts[-1]
    return f"{article} {kind} correction of the plant with {body}"


def _summarised(roots: ComplexArray, name: str, fs: float) -> str:
    """Discrete poles or zeros (pairs once) counted, with their range and the least damped."""
    pairs = [complex(r) for r in roots if r.imag > 0]
    kinds = ((len(pairs), f"{name} pair"), (roots.size - len(pairs), f"real {name}"))
    counts = [f"{k} {what}{'s' if k > 1 else ''}" for k, what in kinds if k]
    hz = [_hz_damping(complex(r), fs)[0] for r in roots]
    text = f"{' and '.join(counts)} between {min(hz):.3g} and {max(hz):.3g} Hz"
    if pairs:
        f, zeta = min((_hz_damping(p, fs) for p in pairs), key=lambda t: t[1])
        text += f" (the least damped pair at {f:.3g} Hz, damping {zeta:.2g})"
    return text
