# SPDX-License-Identifier: Apache-2.0
"""What a periodic excitation adds to the node's status: the BLA's parts.

With ``excitation_index_topic`` set, the labels (``mr-ident excite --publish TOPIC`` puts
them on ``TOPIC/excitation_index``) are a fourth aligned stream: with the block contract a
block subscription beside reference, input, output (:mod:`mr_ident.ros.node`), with
per-sample sources read as the signals are (:class:`~mr_ident.ros.sources.SourceSubscriber`).
A window of whole periods is identified as the best linear approximation in the shared
path (:func:`~mr_ident.live.estimate.estimate`) and published on the usual result topics;
:func:`bla_values` adds its parts to the node's ``/diagnostics`` status. Adapter only.
"""

from __future__ import annotations

import math

from ..live.estimate import Estimate
from ..live.periodic import nl_to_noise


def _db(x: float) -> str:
    return "nan" if math.isnan(x) else f"{x:.1f}"


def bla_values(est: Estimate) -> dict[str, str]:
    """Status values of an estimate's periodic part ({} without labels).

    ``periodic``: what the labels gave; with a BLA its realizations and periods, the
    median nonlinear over noise std, and the odd and even distortion in dB above the noise
    (:attr:`~mr_ident.numerics.excitation.bla.BLA.odd_db`).
    """
    if not est.periodic:
        return {}
    out = {"periodic": est.periodic}
    bla = est.bla
    if bla is not None:
        ratio = nl_to_noise(bla)
        out.update(
            {
                "bla_realizations": str(bla.realizations),
                "bla_periods": str(bla.periods),
                "bla_period_samples": str(est.period),
                "bla_nl_to_noise_std": "nan" if math.isnan(ratio) else f"{ratio:.3g}",
                "bla_odd_db": _db(float(bla.odd_db[0])),
                "bla_even_db": _db(float(bla.even_db[0])),
            }
        )
    return out
