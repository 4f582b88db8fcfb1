# SPDX-License-Identifier: Apache-2.0
"""Commands around ROS and recordings: ``replay``, ``record``, ``view``, ``demo``.

Imports are lazy (inside each command); rclpy is imported only by the ROS ones.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ..errors import ConfigError
from .common import Progress, describe_pfgs, recording, show, write_plots

if TYPE_CHECKING:
    from ..app.replay import Replayed


def cmd_replay(args: argparse.Namespace) -> int:
    """``mr-ident replay``: a recording through the node's steps, or re-published."""
    from ..app.replay import replay_recording
    from ..app.requests import ReplayRequest

    if args.publish:
        from ..ros.record import publish_recording

        n = publish_recording(args.recording, rate=args.rate)
        print(f"published {n} messages from {args.recording}")
        return 0
    if args.out is None:
        raise ConfigError("replay needs --out RESULT.npz (or --publish)")
    if args.out.suffix.lower() != ".npz":
        raise ConfigError(f"--out must be a .npz file, got {str(args.out)!r}")
    req = ReplayRequest(
        recording(args, args.recording, args.topics),
        params=args.params,
        fs_high=args.fs_high,
        ratio=args.ratio,
        stop=args.stop,
        y_rate=args.y_rate,
        excitation_index=args.excitation_index,
    )
    with Progress(quiet=args.quiet) as progress:
        progress(f"replaying {args.recording} through the node's steps")
        replayed = replay_recording(req, show)
        return _report_replayed(args, replayed, progress)


def _report_replayed(args: argparse.Namespace, replayed: Replayed, progress: Progress) -> int:
    """Tell and write what the replay found; then the plant's events (monitoring)."""
    from ..app.replay import plant_events
    from ..io.datafile import write_result

    res, cfg = replayed.result, replayed.config
    info, est = res.info, res.estimate
    counts = ", ".join(f"{k} {v}" for k, v in info.messages.items())
    print(
        f"read {counts} messages; window [{est.first}, {est.first + est.n_samples}) "
        f"({est.n_samples / cfg.fs_high:g} s), lifting phase {est.phase} ({est.phase_source}), "
        f"{est.compute_s:.3f} s"
    )
    if est.periodic:
        print(f"periodic: {est.periodic}")
    if est.bla is not None:
        from .periodic import write_bla_report

        write_bla_report(args.out, est.bla, est.period, cfg.fs_high, cfg.ratio, plot=args.plot)
        return 0
    write_result(args.out, est.identification)
    print(
        f"wrote {args.out} ({est.identification.plant.frequency.size} bins, method {cfg.method})"
    )
    for line in describe_pfgs(est.identification):
        print(line)
    if args.plot:
        from ..io.modelfile import load_model
        from ..io.units import load_units

        progress(f"writing {args.plot}")
        model = load_model(args.model) if args.model else None
        fs, F, N = cfg.fs_high, cfg.ratio, est.n_samples
        write_plots(est.identification, args.plot, fs, F, N, model, units=load_units(args.model))
    for line in plant_events(replayed, str(args.recording), progress):
        print(line, flush=True)
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
    reference, reference_bla = None, None
    if args.reference is not None:
        from ..io.datafile import read_result
        from ..io.periodicfile import read_bla

        if model is not None:
            raise ConfigError("give --model or --reference, not both")
        reference = read_result(args.reference)
        reference_bla = read_bla(args.reference)  # a BLA: its noise and nonlinear parts too
    from ..io.units import load_units

    state = ViewState(model, source, reference, reference_bla, load_units(args.model))
    server = ViewServer(state, args.host, args.port).start()
    print(f"view: {server.url}  (Ctrl-C to stop)", flush=True)
    try:
        if args.bag is None:
            from ..ros.view import run_live_view

            return run_live_view(server, args.node, args.wait, stop)
        from ..app.replay import estimates_in_time
        from ..app.requests import ReplayRequest
        from ..live.estimate import publish_grid

        req = ReplayRequest(
            recording(args, args.bag, args.topics),
            params=args.params,
            fs_high=args.fs_high,
            ratio=args.ratio,
        )
        cfg, estimates = estimates_in_time(req, model)
        t_wall = time.monotonic()
        n = 0
        for t_loop, est in estimates:
            if args.speed > 0:
                stop.wait(t_wall + t_loop / args.speed - time.monotonic())
            if stop.requested:
                return 0
            ident = est.identification
            pfg, pfd = ident.pfg, ident.pfg_data
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
                pfg_data=None if pfd is None else pfd.gain[k],
                pfg_data_std=None if pfd is None else pfd.std[k],
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
