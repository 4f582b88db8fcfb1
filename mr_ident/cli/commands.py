"""The subcommands of ``mr-ident``: each reads its inputs, calls the library, writes its outputs.

Imports are lazy (inside each command), so that ``mr-ident --help`` starts at once.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, DataError

if TYPE_CHECKING:
    from ..numerics.model import Model
    from ..numerics.results import Identification
    from ..numerics.signals import LoopData


def cmd_simulate(args: argparse.Namespace) -> int:
    """``mr-ident simulate``: simulate a model's loop and write CSV/NPZ."""
    import numpy as np

    from ..io.datafile import write_data
    from ..io.modelfile import load_model
    from ..numerics.simulate import simulate

    model = load_model(args.model)
    sim = simulate(model, duration=args.duration, rng=np.random.default_rng(args.seed))
    write_data(args.out, sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=model.ratio)
    print(
        f"wrote {args.out} ({sim.r.shape[0]} samples at {model.fs_high:g} Hz, F = {model.ratio})"
    )
    return 0


def _resolve_rates(
    args: argparse.Namespace, data: LoopData, model: Model | None
) -> tuple[float, int]:
    from ..live.recordings import settle_rates

    return settle_rates(data, fs_high=args.fs_high, ratio=args.ratio, model=model)


def _specs(args: argparse.Namespace) -> dict[str, list[str]] | None:
    """The --r/--u/--y sources, or None when none was given (all three needed otherwise)."""
    specs = {sig: getattr(args, f"{sig}_source", None) or [] for sig in ("r", "u", "y")}
    if not any(specs.values()):
        return None
    missing = [f"--{sig}" for sig, v in specs.items() if not v]
    if missing:
        raise ConfigError(f"give all of --r, --u, --y with a bag; missing {', '.join(missing)}")
    return specs


def cmd_identify(args: argparse.Namespace) -> int:
    """``mr-ident identify``: identify P_h (and the PFG) from a data file or a bag."""
    from ..io.datafile import write_result
    from ..io.modelfile import load_model
    from ..numerics.identify import identify

    if args.out.suffix.lower() != ".npz":
        raise ConfigError(f"--out must be a .npz file, got {str(args.out)!r}")
    model = load_model(args.model) if args.model else None
    data = _read(
        args.data,
        _specs(args),
        args.fs_high or (model.fs_high if model else None),
        args.ratio or (model.ratio if model else None),
    )
    fs, F = _resolve_rates(args, data, model)
    N = data.n_samples
    loop: dict[str, Any] = {}
    if model is not None:
        if model.n_y != data.y.shape[1] or model.n_u != data.u.shape[1]:
            raise DataError(
                f"model is {model.n_y}x{model.n_u} (n_y x n_u) but the data has "
                f"{data.y.shape[1]} output and {data.u.shape[1]} input channel(s)"
            )
        loop = model.identify_arguments(N)
    ident = identify(
        data.r,
        data.u,
        data.y,
        fs_high=fs,
        ratio=F,
        method=args.method,
        n=args.n,
        degree=args.degree,
        keep_lifted=False,
        **loop,
    )  # the result holds P_h and the PFG
    write_result(args.out, ident)
    print(f"wrote {args.out} ({ident.plant.frequency.size} bins, method {args.method})")
    if args.plot:
        _write_plots(ident, args.plot, fs, F, N, model)
    return 0


def _read(
    path: Path,
    specs: dict[str, list[str]] | None,
    fs_high: float | None,
    ratio: int | None,
    topics: list[str] | None = None,
) -> LoopData:
    """r, u, y of a data file or a bag (per-sample sources, or the block contract: ``topics``).

    What the reading noticed goes to stderr as warnings.
    """
    from ..live.recordings import load_recording

    loaded = load_recording(path, specs=specs, topics=topics, fs_high=fs_high, ratio=ratio)
    for note in loaded.notes:
        print(f"warning: {note}", file=sys.stderr)
    return loaded.data


def _write_plots(
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


def cmd_paper(args: argparse.Namespace) -> int:
    """``mr-ident paper``: the paper's example end to end."""
    from ..io.config import share_file
    from ..io.modelfile import load_model
    from ..paper import run_paper

    model = load_model(args.model or share_file("config/paper_example.yaml", "; pass --model"))
    if args.noise_std is not None and not (math.isfinite(args.noise_std) and args.noise_std >= 0):
        raise ConfigError(f"--noise-std must be >= 0, got {args.noise_std}")
    run = run_paper(
        model, args.out_dir, duration=args.duration, seed=args.seed, noise_std=args.noise_std
    )
    print(run.table)
    for name, path in run.files.items():
        print(f"{name:12s} {path}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    """``mr-ident replay``: a recording through the node's steps, or re-published."""
    from ..io.config import IdentConfig, load_params
    from ..io.datafile import write_result
    from ..live.replay import replay

    if args.publish:
        from ..ros.record import publish_recording

        n = publish_recording(args.recording, rate=args.rate)
        print(f"published {n} messages from {args.recording}")
        return 0
    if args.out is None:
        raise ConfigError("replay needs --out RESULT.npz (or --publish)")
    if args.out.suffix.lower() != ".npz":
        raise ConfigError(f"--out must be a .npz file, got {str(args.out)!r}")
    cfg = load_params(args.params) if args.params else IdentConfig()
    specs = _specs(args)
    if specs is not None:
        from ..live.replay import replay_bag

        fs = args.fs_high or (cfg.fs_high if args.params else None)
        F = args.ratio or (cfg.ratio if args.params else None)
        res = replay_bag(args.recording, cfg, specs, fs_high=fs, ratio=F, stop=args.stop)
        cfg = cfg.replace(
            fs_high=res.estimate.identification.fs_high, ratio=res.estimate.identification.ratio
        )
    else:
        res = replay(args.recording, cfg, topics=args.topics, stop=args.stop)
    info, est = res.info, res.estimate
    if info.truncated:
        print(
            f"warning: {args.recording} is cut short; recovered {sum(info.messages.values())} "
            "messages "
            f"({info.bytes_read} of {info.file_bytes} bytes) ({info.reason})",
            file=sys.stderr,
        )
    for note in res.anomalies[:20]:
        print(f"note: {note}", file=sys.stderr)
    write_result(args.out, est.identification)
    counts = ", ".join(f"{k} {v}" for k, v in info.messages.items())
    print(
        f"read {counts} messages; window [{est.first}, {est.first + est.n_samples}) "
        f"({est.n_samples / cfg.fs_high:g} s), lifting phase {est.phase} ({est.phase_source}), "
        f"{est.compute_s:.3f} s"
    )
    print(
        f"wrote {args.out} ({est.identification.plant.frequency.size} bins, method {cfg.method})"
    )
    if args.plot:
        from ..io.modelfile import load_model

        model = load_model(args.model) if args.model else None
        _write_plots(est.identification, args.plot, cfg.fs_high, cfg.ratio, est.n_samples, model)
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    """``mr-ident record``: record topics to MCAP until stopped."""
    from ..ros.record import record

    counts = record(args.out, args.topics, duration=args.duration)
    print(
        f"wrote {args.out}: "
        + (", ".join(f"{t} {n}" for t, n in counts.items()) or "nothing")
        + " messages"
    )
    return 0


def _read_record(
    path: Path,
    model: Model,
    period: int | None,
    topics: list[str] | None,
    specs: dict[str, list[str]] | None = None,
) -> LoopData:
    """Data for diagnose from a file or a bag; rates from the file where given, else the model."""
    from dataclasses import replace

    from ..live.recordings import is_bag

    data = _read(path, specs, model.fs_high, model.ratio, topics)
    if is_bag(path):  # a bag's rates are the model's
        fs, F = model.fs_high, model.ratio
    else:
        fs = data.fs_high if data.fs_high is not None else model.fs_high
        F = data.ratio if data.ratio is not None else model.ratio
    if data.n_samples % F:
        raise DataError(f"{path}: N = {data.n_samples} samples is not a multiple of ratio F={F}")
    return replace(data, fs_high=float(fs), ratio=int(F), period=period)


def cmd_diagnose(args: argparse.Namespace) -> int:
    """``mr-ident diagnose``: where and why a model disagrees with data."""
    import json

    import yaml

    from ..diagnosis import diagnose
    from ..diagnosis.report import report_dict
    from ..htmlreport import report_html
    from ..io.atomic import atomic_write
    from ..io.modelfile import load_model, model_to_dict

    if args.json.suffix.lower() != ".json":
        raise ConfigError(f"--json must be a .json file, got {str(args.json)!r}")
    if args.report is not None and args.report.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"--report must be an .html file, got {str(args.report)!r}")
    if not 0.0 < args.alpha < 1.0:
        raise ConfigError(f"--alpha must be in (0, 1), got {args.alpha}")
    model = load_model(args.model)
    specs = _specs(args)
    data = _read_record(args.data, model, args.period, args.topics, specs)
    val = (
        _read_record(args.validate, model, args.period, args.topics, specs)
        if args.validate
        else None
    )
    d = diagnose(
        model,
        data,
        val,
        n=args.n,
        degree=args.degree,
        alpha=args.alpha,
        max_causes=args.max_causes,
        names=(str(args.data), str(args.validate)),
    )
    summary = report_dict(
        d, extended_model=str(args.out_model) if args.out_model else None, alpha=args.alpha
    )
    applied = ", ".join(a.cause for a in d.applied)
    # Everything is computed; now write (each file atomically).
    if args.out_model:
        text = yaml.safe_dump(model_to_dict(d.extended), sort_keys=False)
        header = (
            f"# Extended by mr-ident diagnose from {args.model} on {args.data}.\n"
            f"# Applied: {applied or 'nothing (the model explains the data)'}\n"
        )
        atomic_write(args.out_model, lambda fh: fh.write(header + text), binary=False)
    atomic_write(args.json, lambda fh: json.dump(summary, fh, indent=2), binary=False)
    if args.report:
        ext = None
        if d.applied:
            ext = d.extended.plant_discrete().freqresp(d.evidence_before.frequency)
        page = report_html(
            d, summary, ext, f"mr-ident diagnose: {args.model.name} on {args.data.name}"
        )
        atomic_write(args.report, lambda fh: fh.write(page), binary=False)
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
    for a in d.applied:
        print(f"  found: {a.description}")
    for path in (args.json, args.report, args.out_model):
        if path:
            print(f"wrote {path}")
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
        specs=_specs(args),
        topics=tuple(args.topics) if args.topics else None,
        fs_high=args.fs_high,
        ratio=args.ratio,
        method=args.method,
        n=args.n,
        degree=args.degree,
        period=args.period,
        threads=1 if args.scheduler else batch.threads_per_job(workers),
    )
    args.out_dir.mkdir(parents=True, exist_ok=True)
    jobs = batch.plan(recordings, args.out_dir, args.task)
    if args.scheduler:
        client = batch.dask_client(args.scheduler)
        try:
            result = batch.run_batch(jobs, opts, client.get_executor(), batch.progress_bar())
        finally:
            client.close()
    else:
        with batch.local_pool(workers) as pool:
            result = batch.run_batch(jobs, opts, pool, batch.progress_bar())
    table = args.out_dir / "summary.csv"
    batch.write_table(result, table)
    print(batch.summary_text(result))
    print(f"wrote {table} ({len(result.rows)} recordings, {result.failed} failed)")
    return 1 if result.failed else 0


def cmd_view(args: argparse.Namespace) -> int:
    """``mr-ident view``: serve the live page; listen to the node, or replay a bag."""
    import time

    from ..io.modelfile import load_model
    from ..ros.program import handle_signals
    from ..view.server import ViewServer
    from ..view.state import ViewState

    stop = handle_signals()
    model = load_model(args.model) if args.model else None
    if args.speed < 0:
        raise ConfigError(f"--speed must be >= 0, got {args.speed:g}")
    source = f"bag {args.bag}" if args.bag else f"node /{args.node.strip('/')}"
    server = ViewServer(ViewState(model, source), args.host, args.port).start()
    print(f"view: {server.url}  (Ctrl-C to stop)", flush=True)
    try:
        if args.bag is None:
            from ..ros.view import run_live_view

            return run_live_view(server, args.node, args.wait, stop)
        from ..io.config import IdentConfig, load_params
        from ..live.estimate import publish_grid
        from ..live.replay import bag_estimates

        specs = _specs(args)
        cfg = load_params(args.params) if args.params else IdentConfig()
        if model is not None:
            cfg = cfg.replace(fs_high=model.fs_high, ratio=model.ratio)
            if model.controller is not None and not cfg.controller_num:
                cfg = cfg.with_controller(model.controller)  # the PFG from the model's K_l
        t_wall = time.monotonic()
        n = 0
        fs_high = args.fs_high or (model.fs_high if model else None)
        ratio = args.ratio or (model.ratio if model else None)
        for t_loop, est in bag_estimates(
            args.bag, cfg, specs, topics=args.topics, fs_high=fs_high, ratio=ratio
        ):
            if args.speed > 0:
                stop.wait(t_wall + t_loop / args.speed - time.monotonic())
            if stop.requested:
                return 0
            ident = est.identification
            pfg = ident.pfg
            k = publish_grid(ident.plant.frequency.size, cfg.publish_points)  # as the node
            server.state.set_estimate(
                ident.plant.frequency[k],
                ident.plant.response[k],
                ident.plant.std[k],
                None if pfg is None else pfg.gain[k],
                None if pfg is None else pfg.std[k],
                {
                    "estimate_first": est.first,
                    "estimate_samples": est.n_samples,
                    "loop_time_s": t_loop,
                },
            )
            n += 1
        print(
            f"view: the bag's {n} estimates shown; serving the last one until Ctrl-C", flush=True
        )
        while not stop.wait(1.0):
            pass
        return 0
    finally:
        server.stop()


def cmd_demo(args: argparse.Namespace) -> int:
    """``mr-ident demo``: the live pipeline end to end."""
    from ..ros.demo import run_demo

    return run_demo(args.out_dir, rate=args.rate, timeout=args.timeout)
