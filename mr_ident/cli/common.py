"""What the command groups share: the --r/--u/--y sources, reading a recording, rates, plots."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, DataError

if TYPE_CHECKING:
    from ..numerics.model import Model
    from ..numerics.results import Identification
    from ..numerics.signals import LoopData


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
    """Bode plot of P_h at ``path`` (model drawn when given); with a PFG, ``<path>_pfg``."""
    from ..numerics.pfg import pfg_of_model
    from ..plots import plot_bode, plot_pfg

    nyq = fs / F / 2 if F > 1 else None
    mfrf = model.plant_result(N) if model is not None else None
    print(f"wrote {plot_bode(ident.plant, path, model=mfrf, nyquist_low=nyq)}")
    if ident.pfg is not None:
        ref = (
            pfg_of_model(model, N) if model is not None and model.controller is not None else None
        )
        pfg_path = path.with_name(path.stem + "_pfg" + path.suffix)
        print(f"wrote {plot_pfg(ident.pfg, pfg_path, model=ref)}")


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
