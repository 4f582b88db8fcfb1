# SPDX-License-Identifier: Apache-2.0
"""Offline commands: ``simulate``, ``identify``, ``paper``, ``batch``.

Imports are lazy (inside each command), so that ``mr-ident --help`` starts at once.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ConfigError
from .common import (
    Progress,
    describe_pfgs,
    reading,
    recording,
    show,
    source_specs,
    write_plots,
)

if TYPE_CHECKING:
    from ..app.identify import Identified
    from ..app.periodic import PeriodicBLA, SlowPlant
    from ..app.requests import IdentifyRequest


def cmd_simulate(args: argparse.Namespace) -> int:
    """``mr-ident simulate``: simulate a model's loop and write CSV/NPZ."""
    import numpy as np

    from ..io.datafile import write_data
    from ..io.modelfile import load_model
    from ..numerics.systems.simulate import simulate

    model = load_model(args.model)
    if args.injection:
        from dataclasses import replace

        model = replace(model, injection=args.injection)
    sim = simulate(model, duration=args.duration, rng=np.random.default_rng(args.seed))
    write_data(args.out, sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=model.ratio)
    print(
        f"wrote {args.out} ({sim.r.shape[0]} samples at {model.fs_high:g} Hz, F = {model.ratio})"
    )
    return 0


def identify_request(args: argparse.Namespace) -> IdentifyRequest:
    """The request of ``mr-ident identify``'s arguments."""
    from ..app.requests import IdentifyRequest

    return IdentifyRequest(
        recording(args, args.data),
        model=args.model,
        fs_high=args.fs_high,
        ratio=args.ratio,
        method=args.method,
        n=args.n,
        degree=args.degree,
        local=args.local,
        y_rate=args.y_rate,
        period=args.period,
        transient_periods=args.transient_periods,
        excitation_index=args.excitation_index,
        injection=args.injection,
    )


def cmd_identify(args: argparse.Namespace) -> int:
    """``mr-ident identify``: identify P_h (and the PFG) from a data file or a bag."""
    from ..app.identify import identify_recording

    if args.out.suffix.lower() != ".npz":
        raise ConfigError(f"--out must be a .npz file, got {str(args.out)!r}")
    with Progress(quiet=args.quiet) as progress:
        outcome = identify_recording(identify_request(args), show, progress)
        progress(f"writing {args.out}" + (f" and {args.plot}" if args.plot else ""))
        return _report_identified(args, outcome)


def _report_identified(
    args: argparse.Namespace, outcome: Identified | PeriodicBLA | SlowPlant
) -> int:
    """Write and tell what ``identify`` found: the result file, its lines, the plots."""
    from ..app.identify import Identified
    from ..app.periodic import PeriodicBLA  # noqa: F811 (the class, beyond its annotation)
    from ..io.datafile import write_result

    if isinstance(outcome, PeriodicBLA):
        from .periodic import report_periodic

        report_periodic(args.out, outcome, args.plot)
        return 0
    if not isinstance(outcome, Identified):
        from .periodic import report_slow

        report_slow(args.out, outcome, args.plot)
        return 0
    ident = outcome.identification
    missing = ident.n_missing
    if missing is not None and missing.any():
        ny = ident.plant.response.shape[1]
        print(
            f"note: {int(missing[:ny].sum())} samples of y and {int(missing[ny:].sum())} of u "
            f"missing (NaN) of {outcome.n_samples}: estimated as unknowns of the fit"
        )
    if ident.r_recovered or ident.r_unknown:
        print(
            f"note: {ident.r_recovered + ident.r_unknown} samples of r missing: "
            f"{ident.r_recovered} recovered exactly from the loop, {ident.r_unknown} not "
            "determined by the data (guessed; their error is part of the std)"
        )
    write_result(args.out, ident, outcome.structure)
    print(f"wrote {args.out} ({ident.plant.frequency.size} bins, method {outcome.method})")
    for line in describe_pfgs(ident):
        print(line)
    if args.plot:
        fs, F, N = outcome.fs_high, outcome.ratio, outcome.n_samples
        from ..io.units import load_units

        write_plots(ident, args.plot, fs, F, N, outcome.model, units=load_units(args.model))
    return 0


def cmd_paper(args: argparse.Namespace) -> int:
    """``mr-ident paper``: the paper's example end to end."""
    from ..io.config import share_file
    from ..io.modelfile import load_model
    from ..io.units import load_units
    from ..paper import run_paper

    path = args.model or share_file("config/paper_example.yaml", "; pass --model")
    model = load_model(path)
    if args.noise_std is not None and not (math.isfinite(args.noise_std) and args.noise_std >= 0):
        raise ConfigError(f"--noise-std must be >= 0, got {args.noise_std}")
    run = run_paper(
        model,
        args.out_dir,
        duration=args.duration,
        seed=args.seed,
        noise_std=args.noise_std,
        units=load_units(path),
    )
    print(run.table)
    for name, path in run.files.items():
        print(f"{name:12s} {path}")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    """``mr-ident batch``: many recordings, one summary table (``mr_ident.batch``)."""
    import numpy as np

    from .. import batch
    from ..io.datafile import read_result
    from ..io.modelfile import load_model

    model = load_model(args.model) if args.model else None
    reference = read_result(args.reference) if args.reference else None
    recordings = batch.find_recordings(args.inputs)
    freqs = args.at
    if freqs is None:
        fs = args.fs_high or (model.fs_high if model else None)
        F = args.ratio or (model.ratio if model else None)
        if fs is None or F is None:
            raise ConfigError("pass --at HZ,HZ,... (or --model, or --fs-high and --ratio)")
        freqs = tuple(float(f"{f:.3g}") for f in np.geomspace(fs / F / 100, 0.4 * fs, 6))
    workers = args.workers or batch.default_workers(len(recordings))
    opts = batch.BatchOptions(
        task=args.task,
        out_dir=str(args.out_dir),
        frequencies=freqs,
        model=model,
        reference=reference,
        specs=source_specs(args),
        topics=tuple(args.topics) if args.topics else None,
        fs_high=args.fs_high,
        ratio=args.ratio,
        method=args.method,
        n=args.n,
        degree=args.degree,
        local=args.local,
        period=args.period,
        injection=args.injection,
        **reading(args),
        threads=1 if args.scheduler else batch.threads_per_job(workers),
    )
    args.out_dir.mkdir(parents=True, exist_ok=True)
    jobs = batch.plan(recordings, args.out_dir, args.task)
    with Progress(quiet=args.quiet) as progress:
        where = f"on {args.scheduler}" if args.scheduler else f"on {workers} worker(s)"
        progress(f"{len(jobs)} recordings {where}, 0 done")
        told = batch_progress(progress, where)
        if args.scheduler:
            client = batch.dask_client(args.scheduler)
            try:
                result = batch.run_batch(jobs, opts, client.get_executor(), told)
            finally:
                client.close()
        else:
            with batch.local_pool(workers) as pool:
                result = batch.run_batch(jobs, opts, pool, told)
    table = args.out_dir / "summary.csv"
    batch.write_table(result, table)
    print(batch.summary_text(result))
    print(f"wrote {table} ({len(result.rows)} recordings, {result.failed} failed)")
    return 1 if result.failed else 0


def batch_progress(
    progress: Callable[[str], None], where: str
) -> Callable[[int, int, dict[str, str]], None]:
    """What a batch tells as its recordings finish.

    A failure at once (always, on stderr); the count as :class:`~.common.Progress`'s step
    (on a terminal, while the next runs).
    """

    def told(done: int, total: int, row: dict[str, str]) -> None:
        if row["status"] != "ok":
            print(f"{Path(row['recording']).name}: error: {row['error']}", file=sys.stderr)
        if done < total:
            progress(f"{total} recordings {where}, {done} done")

    return told
