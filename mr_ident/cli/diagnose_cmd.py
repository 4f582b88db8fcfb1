# SPDX-License-Identifier: Apache-2.0
"""``mr-ident diagnose``: where and why a model disagrees with data."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError
from .common import Progress, recording, show

if TYPE_CHECKING:
    from ..app.requests import DiagnoseRequest
    from ..diagnosis.diagnose import Diagnosis


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``mr-ident diagnose``: where and why a model disagrees with data.

    The steps: the outputs' names checked, the diagnosis, the files written (each
    atomically, once everything is computed), the verdict and its findings printed.
    """
    from ..app.diagnose import diagnose_recording
    from ..diagnosis.report import report_dict
    from ..io.units import load_units

    _check_outputs(args)
    with Progress(quiet=args.quiet) as progress:
        outcome = diagnose_recording(_request(args), show, progress)
    d = outcome.diagnosis
    summary = report_dict(
        d, extended_model=str(args.out_model) if args.out_model else None, alpha=args.alpha
    )
    units = load_units(args.model)  # the model file's, for the report and the extended model
    _write_outputs(args, d, summary, units)
    _print_verdict(d)
    _print_findings(d)
    for path in (args.json, args.report, args.out_model):
        if path:
            print(f"wrote {path}")
    return 0


def _check_outputs(args: argparse.Namespace) -> None:
    """The report files' suffixes, before anything is computed."""
    if args.json is not None and args.json.suffix.lower() != ".json":
        raise ConfigError(f"--json must be a .json file, got {str(args.json)!r}")
    if args.report is not None and args.report.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"--report must be an .html file, got {str(args.report)!r}")


def _request(args: argparse.Namespace) -> DiagnoseRequest:
    """The application layer's request of the command line's arguments."""
    from ..app.requests import DiagnoseRequest

    return DiagnoseRequest(
        recording(args, args.data, args.topics),
        args.model,
        validate=args.validate[0] if args.validate else None,
        period=args.period,
        n=args.n,
        degree=args.degree,
        alpha=args.alpha,
        max_causes=args.max_causes,
        more=tuple(args.validate[1:]) if args.validate else (),
        injection=args.injection,
    )


def _write_outputs(
    args: argparse.Namespace, d: Diagnosis, summary: dict[str, Any], units: Any
) -> None:
    """The extended model, the JSON and the HTML report that were asked for."""
    import json

    from ..io.atomic import atomic_write

    if args.out_model:
        import yaml

        from ..io.modelfile import model_to_dict

        applied = ", ".join(
            [a.cause for a in d.applied] + (["a plant correction"] if d.corrected else [])
        )
        nothing = (
            "nothing (no extension validated)"
            if d.decision is not None and d.decision.candidates
            else "nothing (the model explains the data)"
        )
        extended = model_to_dict(d.extended)
        if units is not None:  # the nominal model's, carried over
            extended["units"] = {"u": units[0], "y": units[1]}
        text = yaml.safe_dump(extended, sort_keys=False)
        header = (
            f"# Extended by mr-ident diagnose from {args.model} on {args.data}.\n"
            f"# Applied: {applied or nothing}\n"
        )
        atomic_write(args.out_model, lambda fh: fh.write(header + text), binary=False)
    if args.json:
        atomic_write(args.json, lambda fh: json.dump(summary, fh, indent=2), binary=False)
    if args.report:
        from ..htmlreport import report_html

        ext = None
        if d.applied or d.corrected:
            ext = d.extended.plant_discrete().freqresp(d.evidence_before.frequency)
        title = f"mr-ident diagnose: {args.model.name} on {args.data.name}"
        page = report_html(d, summary, ext, title, units)
        atomic_write(args.report, lambda fh: fh.write(page), binary=False)


def _print_verdict(d: Diagnosis) -> None:
    """The cause, what was applied and the fits; the verdict; the causes found."""
    fu = (
        ""
        if d.fit_before.u is None
        else f"; fit u {d.fit_before.u:.1f} % -> {d.fit_after.u:.1f} %"
    )
    params = ", ".join(f"{k} = {v:.6g}" for k, v in d.parameters.items())
    print(
        f"cause: {d.cause}{' (' + params + ')' if params else ''}; applied: "
        f"{', '.join(a.cause for a in d.applied) or 'none'}; fit y {d.fit_before.y:.1f} % -> "
        f"{d.fit_after.y:.1f} %{fu}"
    )
    if d.headline is not None:
        print(f"  verdict: {d.headline.text}")
    for a in d.applied:
        spread = ", ".join(
            f"{k} ± {v:.2g}" for k, v in a.std.items() if v > 0 and k in a.parameters
        )
        print(f"  found: {a.description}" + (f" (std: {spread})" if spread else ""))
        for q in a.equivalents:
            print(f"    or, as well (BIC {q.delta_bic:+.1f}): {q.description}")
    v = d.decision
    if v is not None and v.candidates and not v.validated:
        print(f"  {v.text(corrected=d.corrected)}")
    if v is not None and v.candidates:
        for k in v.checks:
            status = "validated" if k.validated else "rejected on validation"
            print(
                f"  candidate {k.cause}: {status} (z = {k.gain.z:.2f}, fit y without "
                f"{k.fit_without:.1f} % -> with {k.fit_with:.1f} %): {k.description}"
            )


def _print_findings(d: Diagnosis) -> None:
    """What else the data show: a correction, distortion, time variation, the controller."""
    if d.correction is not None:
        print(f"  found: {d.correction.text()}")
    if d.nonlinear:
        print(f"  found: {d.distortion_text()}")
    elif d.spread:
        worst = max(b.level_db for b in d.spread)
        print(f"  {d.records} records compared as realizations: spread within the noise "
              f"(at most {worst:.1f} dB above it): no nonlinear distortion seen")  # fmt: skip
    if d.blind_text():
        print(f"  note: {d.blind_text()}")
    if d.segments is not None and d.time_varying:
        print(f"  found: {d.segments.text()}")
    if d.relation is not None:
        print(f"  controller: {d.relation.text()}")
    if d.controller is not None and d.controller.differs:
        print(f"  found: {d.controller.text()}")
