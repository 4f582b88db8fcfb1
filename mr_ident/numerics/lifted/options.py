# SPDX-License-Identifier: Apache-2.0
"""The option and record-length rules of the methods, and the fits missing samples must suit.

:func:`check_options`, :func:`default_n` and :func:`min_samples` (re-exported by
:mod:`mr_ident.numerics.identify`, shared with the node's configuration);
:func:`missing_rules` and :func:`missing_limits`: which lifted fits a record with missing
samples must leave enough degrees of freedom to, and the largest hole and share of holes
they carry (the method page, "Missing samples", derives them).
"""

from __future__ import annotations

from dataclasses import dataclass

from ...errors import ConfigError
from ..local.fit import check_local, smallest_n
from ..local.fit import check_options as check_local_options
from .methods import METHODS, Method
from .missing import max_share

#: The paper's window half-width: the least the default takes.
N_FLOOR = 8
#: The default n leaves at least this many degrees of freedom beyond the minimum.
DOF_MARGIN = 2


def method_of(name: str) -> Method:
    """The row of :data:`METHODS` named ``name``; ConfigError naming the choices otherwise."""
    if name not in METHODS:
        raise ConfigError(f"method must be one of {', '.join(METHODS)}; got {name!r}")
    return METHODS[name]


def check_options(
    method: str,
    n: int,
    degree: int,
    ratio: int,
    n_in: int,
    n_out: int,
    *,
    local: str = "polynomial",
) -> int:
    """Validate the LPM options of ``method``; return the residual degrees of freedom q.

    For ``n_in`` excitation and ``n_out`` = max(n_y, n_u) channels; q is 0 for the ETFE
    (which has no local model: ``local`` must be "polynomial" there).

    The rule: ``q = 2n+1 - (R+1)(lift n_in + 1) > lift n_out`` with lift = F for the
    lifted methods, else 1 (:func:`~mr_ident.numerics.local.lpm.check_lpm_options`); with
    ``local="rational"`` the denominator's unknowns count too
    (:func:`~mr_ident.numerics.local.lrm.check_lrm_options`).
    """
    m = method_of(method)
    if not m.uses_lpm:
        if check_local(local) != "polynomial":
            raise ConfigError(
                f"local = {local!r} applies to the LPM methods; {method} fits no local model"
            )
        return 0
    lift = m.lift(ratio)
    return check_local_options(local, n, degree, n_in * lift, n_out * lift)


def default_n(
    method: str, degree: int, ratio: int, n_in: int, n_out: int, local: str = "polynomial"
) -> int:
    """The default window half-width: 8 (the paper's), or more where F or the channels need it.

    The smallest n >= 8 whose residual degrees of freedom exceed the outputs of the fit by
    :data:`DOF_MARGIN`: ``2n+1 - (R+1)(lift n_in + 1) >= lift n_out + 2``, lift = F for a
    lifted method, else 1 (``local="rational"``: less the denominator's share,
    :func:`~mr_ident.numerics.local.lrm.dof`).

    >>> default_n("freq-lifted", 2, 3, 1, 1), default_n("freq-lifted", 2, 10, 1, 1)
    (8, 22)
    >>> default_n("freq-lifted", 2, 3, 1, 1, "rational")
    9
    """
    m = method_of(method)
    if not m.uses_lpm:
        return N_FLOOR
    lift = m.lift(ratio)
    return max(
        N_FLOOR, smallest_n(local, degree, n_in * lift, n_out * lift, margin=DOF_MARGIN - 1)
    )


def min_samples(method: str, n: int, ratio: int) -> int:
    """The shortest record ``method`` accepts.

    See :meth:`~mr_ident.numerics.lifted.methods.Method.min_samples`.
    """
    return method_of(method).min_samples(n, ratio)


#: Missing samples of a signal leave each fit at least half of the residual degrees of
#: freedom it can spare beyond its noise model (the node's and the recordings' bridging
#: keep a window within this share of :func:`max_share`).
SHARE_MARGIN = 0.5


def missing_rules(
    method: str,
    n: int,
    degree: int,
    ratio: int,
    n_in: int,
    n_out: int,
    *,
    local: str = "polynomial",
    n_samples: int | None = None,
    auto: bool = False,
) -> list[tuple[str, int, int, int]]:
    """The fits a record with missing samples goes through: (name, n, q, n_map) each.

    The lifted polynomial fit r -> [y; u] that estimates them (θ: the window ``n`` of a
    lifted method, else freq-lifted's default, at least ``n``; with the automatic window,
    ``auto``, twice that as ``n_samples`` allows), then the method's own fit (an LPM
    method's). q: a window's residual degrees of freedom; n_map: the outputs of one map.
    """
    m = method_of(method)
    n_theta = n if m.lifted else max(n, default_n("freq-lifted", degree, ratio, n_in, n_out))
    if auto and n_samples is not None:
        n_theta = max(n_theta, min(2 * n_theta, (n_samples // (2 * ratio) - 1) // 2))
    q_theta = check_options("freq-lifted", n_theta, degree, ratio, n_in, n_out)
    rules = [("lifted r -> [y; u]", n_theta, q_theta, ratio * n_out)]
    if m.uses_lpm:
        q = check_options(method, n, degree, ratio, n_in, n_out, local=local)
        rules.append((method, n, q, m.lift(ratio) * n_out))
    return rules


@dataclass(frozen=True)
class MissingLimits:
    """How much of a record of ``n_samples`` may be missing, and how long one hole may be.

    ``share``: the missing share of a signal the fits carry with a margin,
    :data:`SHARE_MARGIN` times the least :func:`~mr_ident.numerics.lifted.missing.max_share`
    of :func:`missing_rules`. ``gap``: the longest run of missing samples, ``share`` of the
    record: a hole's samples are estimated from the local models of the rest of the record
    whatever its length (the method page measures bursts up to 800 samples), so one hole is
    bounded only by the share it takes on its own.
    """

    share: float
    gap: int


def missing_limits(
    method: str,
    n: int,
    degree: int,
    ratio: int,
    n_in: int,
    n_out: int,
    *,
    local: str = "polynomial",
    n_samples: int = 0,
    auto: bool = False,
) -> MissingLimits:
    """The :class:`MissingLimits` of a record of ``n_samples`` (as :func:`missing_rules`)."""
    rules = missing_rules(
        method, n, degree, ratio, n_in, n_out, local=local, n_samples=n_samples, auto=auto
    )
    share = max(SHARE_MARGIN * min(max_share(nj, q, n_map) for _, nj, q, n_map in rules), 0.0)
    return MissingLimits(share, int(share * n_samples))
