"""What the command groups share: the --r/--u/--y sources, reading a recording, rates, plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, DataError

if TYPE_CHECKING:
    from ..numerics.results import Identification
    from ..numerics.signals import LoopData
    from ..numerics.systems.model import Model


def resolve_rates(
    args: argparse.Namespace, data: LoopData, model: Model | None
) -> tuple[float, int]:
    """fs_high and F from the flags, the data file, the model, or the samples' stamps."""
    from ..live.recordings import settle_rates

    return settle_rates(data, fs_high=args.fs_high, ratio=args.ratio, model=model)


def source_specs(args: argparse.Namespace) -> dict[str, list[str]] | None:
    """The --r/--u/--y sources, or None when none was given (all three needed otherwise)."""
    specs = {sig: getattr(args, f"{sig}_source", None) or [] for sig in ("r", "u", "y")}
    if not any(specs.values()):
        return None
    missing = [f"--{sig}" for sig, v in specs.items() if not v]
    if missing:
        raise ConfigError(f"give all of --r, --u, --y with a bag; missing {', '.join(missing)}")
    return specs


def reading(args: argparse.Namespace) -> dict[str, Any]:
    """--span and --msg-path as keyword arguments of the library's readers."""
    out: dict[str, Any] = {"msg_path": tuple(getattr(args, "msg_path", None) or ())}
    if getattr(args, "span", None) is not None:
        out["span"] = args.span
    return out


def read_loop(
    path: Path,
    specs: dict[str, list[str]] | None,
    fs_high: float | None,
    ratio: int | None,
    topics: list[str] | None = None,
    **options: Any,
) -> LoopData:
    """r, u, y of a data file or a bag (per-sample sources, or the block contract: ``topics``).

    ``options``: :func:`reading`. What the reading noticed goes to stderr as warnings.
    """
    from ..live.recordings import load_recording

    loaded = load_recording(
        path, specs=specs, topics=topics, fs_high=fs_high, ratio=ratio, **options
    )
    for note in loaded.notes:
        print(f"warning: {note}", file=sys.stderr)
    return loaded.data


def write_plots(
    ident: Identification, path: Path, fs: float, F: int, N: int, model: Model | None
) -> None:
    """Bode plot of P_h at ``path`` (model drawn when given); with a PFG, ``<path>_pfg``.

    The PFG plot shows the PFG from data and, with a controller, the one from P_h and it.
    """
    from ..numerics.lifted.pfg import pfg_of_model
    from ..plots import plot_bode, plot_pfg

    nyq = fs / F / 2 if F > 1 else None
    mfrf = model.plant_result(N) if model is not None else None
    print(f"wrote {plot_bode(ident.plant, path, model=mfrf, nyquist_low=nyq)}")
    shown = [g for g in (ident.pfg_data, ident.pfg) if g is not None]
    if shown:
        ref = (
            pfg_of_model(model, N) if model is not None and model.controller is not None else None
        )
        pfg_path = path.with_name(path.stem + "_pfg" + path.suffix)
        print(f"wrote {plot_pfg(shown[0], pfg_path, model=ref, also=shown[1:])}")


def describe_pfgs(ident: Identification) -> list[str]:
    """Lines on the PFGs of a result: each one's peak and std; with both, their agreement."""
    import numpy as np

    from ..numerics.lifted.pfg_check import COVERAGE, check_controller

    lines = []
    for g, what in ((ident.pfg_data, "from data (lifted r->y)"), (ident.pfg, "from P_h and K_l")):
        if g is None or not np.isfinite(g.gain).any():
            continue
        k = int(np.nanargmax(g.gain))
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = float(np.nanmedian(g.std / g.gain))
        lines.append(
            f"PFG {what}: peak {20 * np.log10(g.gain[k]):.1f} dB at {g.frequency[k]:.4g} Hz, "
            f"median std {100 * rel:.2g} % of the gain"
        )
    n = 0 if ident.n_used is None else int(np.min(ident.n_used))
    check = check_controller(ident, n)
    if check is not None:
        lines.append(
            f"the two PFGs differ by more than {COVERAGE:g} std over {100 * check.fraction:.2g} % "
            "of the band (log axis)" + ("; " + check.text().split(":")[0] if check.differs else "")
        )
    return lines


def read_for_diagnosis(
    path: Path,
    model: Model,
    period: int | None,
    topics: list[str] | None,
    specs: dict[str, list[str]] | None = None,
    **options: Any,
) -> LoopData:
    """Data for diagnose from a file or a bag; rates from the file where given, else the model."""
    from dataclasses import replace

    from ..live.recordings import is_bag

    data = read_loop(path, specs, model.fs_high, model.ratio, topics, **options)
    if is_bag(path):  # a bag's rates are the model's
        fs, F = model.fs_high, model.ratio
    else:
        fs = data.fs_high if data.fs_high is not None else model.fs_high
        F = data.ratio if data.ratio is not None else model.ratio
    if data.n_samples % F:
        raise DataError(f"{path}: N = {data.n_samples} samples is not a multiple of ratio F={F}")
    return replace(data, fs_high=float(fs), ratio=int(F), period=period)
