# SPDX-License-Identifier: Apache-2.0
"""``mr-ident fit``: a stable parametric model of an identified plant, as a model file."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .argtypes import auto_or_int, band
from .common import Progress, quiet_option


def _delay(text: str) -> float | str:
    """``auto`` or a number of samples >= 0."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        v = -1.0
    if not v >= 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f'expected "auto" or samples >= 0, got {text!r}')
    return v


def add_fit_parser(sub: Any) -> None:
    """The ``fit`` subcommand and its options."""
    p = sub.add_parser(
        "fit", help="a stable modal model of an identified plant (weighted by its std), as YAML"
    )
    p.add_argument("result", type=Path, help="result .npz of mr-ident identify")
    p.add_argument(
        "--order",
        type=auto_or_int(1),
        default="auto",
        help="states per input (a mode counts 2), or auto: the smallest order whose cost "
        "lies in its expected band (default auto)",
    )
    p.add_argument("--domain", choices=("continuous", "discrete"), default="continuous")
    p.add_argument(
        "--delay",
        type=_delay,
        default="auto",
        help="input delay in high-rate samples, or auto (default; whole samples if discrete)",
    )
    p.add_argument("--band", type=band, help="LO,HI in Hz: the bins fitted (default all)")
    p.add_argument("--max-order", type=auto_or_int(1), default=20, help="auto: the highest order")
    p.add_argument(
        "--controller",
        type=Path,
        help="model YAML whose controller (and loop settings) the written model takes",
    )
    p.add_argument("--out", type=Path, required=True, help="model YAML to write")
    p.add_argument(
        "--export",
        choices=("python-control",),
        help="also write <stem>_control.py: the plant as python-control systems G and P_h "
        "(needs python-control: pip install control)",
    )
    p.add_argument(
        "--plot",
        type=Path,
        help="Bode plot of data and model (.png); <stem>_residual.png: the residual in σ units",
    )
    quiet_option(p)


def cmd_fit(args: argparse.Namespace) -> int:
    """``mr-ident fit``."""
    from ..errors import ConfigError
    from ..io.datafile import read_identification
    from ..io.modelfile import load_model
    from ..numerics.fit.frf_fit import lpm_kernel
    from ..numerics.local.lpm import dof

    if args.max_order == "auto":
        raise ConfigError('--max-order must be an integer >= 1, got "auto"')
    if args.export == "python-control":  # before the fit, not after it
        from ..io.control_export import require_control

        require_control()
    controller = load_model(args.controller) if args.controller else None
    ident = read_identification(args.result)
    ratio = ident.ratio
    n_in = ident.plant.n_in
    q, kernel = None, None
    n = ident.median_window
    if n is not None:
        q = float(dof(n, 2, n_in * ratio)) if ident.local == "polynomial" else None
        q = q if q is not None and q > 1 else None
        kernel = lpm_kernel(n)
    with Progress(quiet=args.quiet) as progress:
        what = f"order {args.order}" if args.order != "auto" else f"orders up to {args.max_order}"
        progress(f"fitting {what} to {args.result.name}")
        fit = _fit(args, ident, q, kernel)
        if args.plot:
            progress(f"writing {args.plot}")
        return _report(args, ident, fit, controller)


def _fit(args: argparse.Namespace, ident: Any, q: float | None, kernel: Any) -> Any:
    from ..numerics.fit.frf_fit import fit_frf

    fs = ident.fs_high
    return fit_frf(
        ident.plant,
        fs=fs,
        order=args.order,
        domain=args.domain,
        delay=args.delay if args.delay == "auto" else args.delay / fs,
        band=args.band,
        max_order=args.max_order,
        noise_dof=q,
        noise_kernel=kernel,
    )


def _report(args: argparse.Namespace, ident: Any, fit: Any, controller: Any) -> int:
    """What the fit found, told; the model (and the plots) written."""
    import numpy as np

    from ..io.fitfile import fitted_model, write_fit

    fs, ratio = ident.fs_high, ident.ratio
    for r in fit.orders:
        mark = "  <- chosen" if r.order == fit.order else ""
        print(
            f"order {r.order:2d}: cost {r.cost:12.6g}  expected {r.expected:.6g} ± "
            f"{2 * r.sd:.3g}  AIC {r.aic:.6g}  MDL {r.mdl:.6g}  "
            f"{'stable' if r.stable else 'UNSTABLE'}{mark}"
        )
    if not fit.in_band:
        how = (
            "no order tried brings"
            if args.order == "auto"
            else f"order {fit.order} does not bring"
        )
        print(
            f"warning: {how} the cost into its expected band; the residual is more than "
            "the std explains (dynamics the model lacks, nonlinear distortion, or a std too "
            f"small){'; the order of least MDL is taken' if args.order == 'auto' else ''}",
            file=sys.stderr,
        )
    for k, p in enumerate(fit.plant.poles):
        s = p if fit.domain == "continuous" else np.log(p) * fs
        kind = "mode" if p.imag > 0 else "real pole"
        print(
            f"{kind}: {abs(s) / (2 * np.pi):.6g} ± {fit.frequency_std[k]:.2g} Hz, "
            f"damping {-s.real / abs(s):.4g} ± {fit.damping_std[k]:.2g}"
        )
    if fit.delay_determined:
        print(f"delay {fit.delay * fs:.4g} ± {fit.delay_std * fs:.2g} samples")
    else:
        print(
            f"delay: not determined by the data (free, its std was {fit.delay_std * fs:.2g} "
            "samples; at 0 the cost is within 2 sd of it): fixed at 0, the model fitted so"
        )
    res = np.abs(fit.residual)
    print(
        f"residual: rms {np.sqrt(np.mean(res**2)):.3g} σ, {np.mean(res > 2) * 100:.1f} % of "
        "bins past 2σ"
    )
    model = fitted_model(fit, ratio=ratio, controller=controller)
    from ..io.units import load_units

    units = load_units(args.controller)
    for path in write_fit(args.out, model, fit, units):
        print(f"wrote {path}")
    if args.export == "python-control":
        from ..io.control_export import control_path, export_control

        title = f"{args.out.name}, fitted by mr-ident fit from {args.result.name}"
        print(f"wrote {export_control(control_path(args.out), model, title=title)}")
    if args.plot:
        nyq = fs / ratio / 2 if ratio > 1 else None
        _plots(args.plot, ident.plant, fit, nyq, units)
    return 0


def _plots(
    path: Path, frf: Any, fit: Any, nyq: float | None, units: tuple[str, str] | None
) -> None:
    from ..numerics.results import FRF
    from ..plots import plot_bode, plot_errors

    model = FRF(frf.frequency, fit.response(frf.frequency), 0 * frf.std, "fit")
    bode = plot_bode(frf, path, model=model, nyquist_low=nyq, title="fit", units=units)
    print(f"wrote {bode}")
    errs = {
        f"[{o},{i}]": abs(fit.residual[:, o, i])
        for o in range(fit.residual.shape[1])
        for i in range(fit.residual.shape[2])
    }
    rp = path.with_name(path.stem + "_residual" + path.suffix)
    print(
        "wrote "
        + str(
            plot_errors(
                fit.frequency,
                errs,
                rp,
                ylabel="|P̂ - G| / σ",
                title="fit residual",
                nyquist_low=nyq,
            )
        )
    )
