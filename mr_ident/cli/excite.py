"""``mr-ident excite``: design a multisine excitation and write it (NPZ or CSV)."""

from __future__ import annotations

import argparse

from ..errors import ConfigError


def cmd_excite(args: argparse.Namespace) -> int:
    """Design (:func:`~mr_ident.numerics.multisine.design`), check, write, and say what."""
    from ..io.excitefile import write_excitation
    from ..numerics.multisine import design

    if args.out.suffix.lower() not in (".npz", ".csv"):
        raise ConfigError(f"--out must end in .npz or .csv, got {str(args.out)!r}")
    if args.lifted and args.ratio == 1:
        raise ConfigError("--lifted needs --ratio F > 1 (the lifted aliases it keeps apart)")
    ms = design(
        fs_high=args.fs_high,
        period=args.period,
        band=args.band,
        kind=args.kind,
        rms=args.rms,
        periods=args.periods,
        realizations=args.realizations,
        inputs=args.inputs,
        ratio=args.ratio,
        lifted=args.lifted,
        slope_db_per_decade=args.slope,
        seed=args.seed,
    )
    write_excitation(args.out, ms, ratio=args.ratio)
    f = ms.frequencies
    M, n, n_in = ms.r.shape
    print(
        f"wrote {args.out}: {ms.kind} multisine, {f.size} lines from {f[0]:g} to {f[-1]:g} Hz "
        f"({ms.detection.size} detection lines), period {ms.period} samples "
        f"({ms.period / ms.fs_high:g} s), {n // ms.period} periods, {M} realization(s), "
        f"{n_in} input(s); crest factor {ms.crest_factor.min():.2f}-{ms.crest_factor.max():.2f}"
    )
    return 0
