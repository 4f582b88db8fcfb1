# SPDX-License-Identifier: Apache-2.0
"""The diagnosis as a JSON-ready summary.

Every field is listed in the README's "Model validation" section. The HTML page is an
adapter: :mod:`mr_ident.htmlreport`.
"""

from __future__ import annotations

import math
from typing import Any

from ..numerics.lifted.pfg_check import COVERAGE, MIN_FRACTION
from .controller.relation import EXACT
from .criterion.distortion import NL_THRESHOLD_DB
from .criterion.timevarying import DRIFT_ALPHA, POOLED_ALPHA, VARYING_DB
from .diagnose import Diagnosis
from .selection.forward import ACCEPT_MARGIN


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def _validation_findings(d: Diagnosis) -> list[str]:
    """No extension validated, or the causes the validation data rejected, in words."""
    v = d.decision
    if v is None or not v.candidates:
        return []
    if not v.validated:
        return [v.text(corrected=d.corrected)]
    return [
        f"accepted on the estimation data, rejected on validation (z = {k.gain.z:.2f} <= "
        f"{v.z_critical:.2f}): {k.description}"
        for k in v.rejected
    ]


def _decision(d: Diagnosis) -> dict[str, Any] | None:
    """The ``validation_decision`` field (the README's "Model validation" section)."""
    v = d.decision
    if v is None:
        return None
    return {
        "extension_validated": v.validated or d.corrected,
        "text": v.text(corrected=d.corrected) or "no cause found on the estimation data",
        "statistic": v.statistic,
        "alpha": v.alpha,
        "z_critical": v.z_critical,
        "z": _finite(v.gain.z),
        "likelihood_gain": _finite(v.gain.likelihood),
        "level": _finite(v.gain.level),
        "fit_candidates": _finite(v.fit_candidates.y),
        "fit_u_candidates": None if v.fit_candidates.u is None else _finite(v.fit_candidates.u),
        "candidates": [
            {
                "cause": k.cause,
                "parameters": k.parameters,
                "description": k.description,
                "status": "validated" if k.validated else "rejected on validation",
                "z": _finite(k.gain.z),
                "likelihood_gain": _finite(k.gain.likelihood),
                "level": _finite(k.gain.level),
                "fit_with": _finite(k.fit_with),
                "fit_without": _finite(k.fit_without),
            }
            for k in v.checks
        ],
    }


def _applied(d: Diagnosis) -> list[dict[str, Any]]:
    """The ``applied`` field: each validated cause with its std and equivalents."""
    return [
        {
            "cause": c.cause,
            "parameters": c.parameters,
            "std": {k: _finite(v) for k, v in c.std.items()},
            "description": c.description,
            "equivalents": [
                {
                    "cause": q.cause,
                    "parameters": q.parameters,
                    "std": {k: _finite(v) for k, v in q.std.items()},
                    "description": q.description,
                    "delta_bic": _finite(q.delta_bic),
                }
                for q in c.equivalents
            ],
        }
        for c in d.applied
    ]


def _findings(d: Diagnosis) -> list[str]:
    """The ``findings`` field: every finding in words."""
    return (
        ([d.distortion_text()] if d.nonlinear else [])
        + ([d.segments.text()] if d.segments is not None and d.time_varying else [])
        + (
            [
                "the record's segments differ beyond their noise, but the residual's "
                "higher-order correlations show nonlinear distortion, whose segments differ "
                "with their amplitude: not named a plant that changes in time"
            ]
            if d.segments is not None and d.segments.varying and not d.time_varying
            else []
        )
        + ([d.blind_text()] if d.blind_text() else [])
        + (
            [d.relation.text()]
            if d.relation is not None and d.relation.error_before > EXACT
            else []
        )
        + ([d.controller.text()] if d.controller is not None and d.controller.differs else [])
        + ([d.controller_frf.text()] if d.controller_frf is not None else [])
        + [c.description for c in d.applied]
        + _validation_findings(d)
        + ([d.correction.text()] if d.correction is not None else [])
    )


def _nonlinear(d: Diagnosis) -> dict[str, Any]:
    """The ``nonlinear_distortion`` field."""
    return {
        "detected": d.nonlinear,
        "threshold_db": NL_THRESHOLD_DB,
        "bands": [
            {
                "band_hz": list(b.band),
                "excited_db": _finite(b.excited_db),
                "odd_db": _finite(b.odd_db),
                "even_db": _finite(b.even_db),
                "odd_threshold_db": _finite(b.odd_threshold_db),
                "even_threshold_db": _finite(b.even_threshold_db),
            }
            for b in d.distortion
        ],
        "records": d.records,
        "across_records": [
            {
                "band_hz": list(b.band),
                "level_db": _finite(b.level_db),
                "threshold_db": _finite(b.threshold_db),
                "nl_std_relative": _finite(b.nl_std),
                "noise_std_relative": _finite(b.noise_std),
                "lines": b.lines,
            }
            for b in d.spread
        ],
        "blind": d.blind_text() or None,
        "correlation": None if d.correlation is None else d.correlation.summary(),
    }


def _time_varying(d: Diagnosis) -> dict[str, Any] | None:
    """The ``time_varying`` field (None where the record is too short for segments)."""
    return (
        None
        if d.segments is None
        else {
            "detected": d.time_varying,
            "segments_differ": d.segments.varying,
            "segments": d.segments.parts,
            "level_db": _finite(d.segments.level_db),
            "threshold_db": VARYING_DB,
            "pooled": None
            if d.segments.pooled is None
            else {
                "gain_change": _finite(d.segments.pooled.change),
                "p": _finite(d.segments.pooled.p),
                "alpha": POOLED_ALPHA,
                "blocks": d.segments.pooled.blocks,
            },
            "time_domain": None
            if d.segments.drift is None
            else {
                "gain_change": _finite(d.segments.drift.change),
                "gains": [_finite(c) for c in d.segments.drift.gains],
                "p": _finite(d.segments.drift.p),
                "alpha": DRIFT_ALPHA,
            },
            "bands": [
                {"band_hz": list(b.band), "level_db": _finite(b.line_ratio_db), "lines": b.lines}
                for b in d.segments.bands
            ],
        }
    )


def _controller(d: Diagnosis) -> dict[str, Any]:
    """The ``controller_relation``, ``controller_frf`` and ``controller_check`` fields."""
    return {
        "controller_relation": None
        if d.relation is None
        else {
            "exact": d.relation.exact,
            "contradicted": d.relation.contradicted,
            "error_before": d.relation.error_before,
            "error_after": d.relation.error_after,
            "tolerance": EXACT,
            "samples": d.relation.samples,
            "text": d.relation.text(),
            "statistic": "rms of u - u_hat(r, y) over the rms of the controller's output, "
            "u_hat the model controller's output for the logged y, free responses projected out",
        },
        "controller_frf": None if d.controller_frf is None else d.controller_frf.summary(),
        "controller_check": None
        if d.controller is None
        else {
            "differs": d.controller.differs,
            "fraction": d.controller.fraction,
            "min_fraction": MIN_FRACTION,
            "coverage_std": COVERAGE,
            "median_relative": d.controller.relative,
            "bands_hz": [list(b) for b in d.controller.bands],
            "statistic": "|PFG_data - PFG_model_K| / sqrt(std_data^2 + std_model_K^2) per bin; "
            "fraction: share of the band beyond coverage_std, bins weighed by 1/f",
        },
    }


def report_dict(d: Diagnosis, *, extended_model: str | None, alpha: float) -> dict[str, Any]:
    """The JSON report (see the README's "Model validation" section for every field)."""
    none = next(c.score for c in d.ranking if c.cause == "none")
    causes = [
        {
            "cause": c.cause,
            "parameters": c.parameters,
            "score": _finite(c.score),
            "delta_bic": _finite(c.score - none),
            "applicable": c.applicable,
            "description": c.description,
        }
        for c in d.ranking
    ]
    return {
        "cause": d.cause,
        "parameters": d.parameters,
        "headline": d.headline.text if d.headline is not None else None,
        "causes": causes,
        "applied": _applied(d),
        "findings": _findings(d),
        "validation_decision": _decision(d),
        "nonlinear_distortion": _nonlinear(d),
        "time_varying": _time_varying(d),
        **_controller(d),
        "criterion": "BIC = 2 sum_k |E(k)|^2/S_noise(k) + p ln(n_bins) of the residual y - y_sim; "
        "lower is better; forward selection with joint re-fits: a cause (set) is accepted when "
        f"it lowers the BIC by more than {ACCEPT_MARGIN:g}",
        "fit_before": _finite(d.fit_before.y),
        "fit_after": _finite(d.fit_after.y),
        "fit_u_before": _finite(d.fit_before.u),
        "fit_u_after": _finite(d.fit_after.u),
        "frf_sigma_error_before": _finite(d.evidence_validation_before.median_sigma_error),
        "frf_sigma_error_after": _finite(d.evidence_after.median_sigma_error),
        "significant_bands": [list(b) for b in d.evidence_before.bands()],
        "significant_bands_after": [list(b) for b in d.evidence_after.bands()],
        "significant_bins": {
            "before": int(
                d.evidence_before.significant.sum() + d.evidence_before.loop_significant.sum()
            ),
            "after": int(
                d.evidence_after.significant.sum() + d.evidence_after.loop_significant.sum()
            ),
        },
        "test": {
            "statistic": "|P_hat - P_model| / sigma_hat per bin (max over entries)",
            "null": "F(2, 2q) for the squared statistic, Bonferroni over bins and entries",
            "alpha": alpha,
            "q": d.evidence_before.dof,
            "threshold_sigma": _finite(d.evidence_before.threshold),
            "loop_threshold_sigma": _finite(d.evidence_before.loop_threshold),
        },
        "extended_model": extended_model,
        "estimation": d.estimation,
        "validation": d.validation,
        "correction": None if d.correction is None else d.correction.summary(),
        "unexplained": {
            "significant_bands": [list(b) for b in d.evidence_after.bands()],
            "fit_gap_percent": _finite(100.0 - d.fit_after.y),
        }
        | (
            {}
            if d.unexplained is None
            else {
                k: _finite(v) if not isinstance(v, bool) else v
                for k, v in d.unexplained.summary().items()
            }
        ),
    }
