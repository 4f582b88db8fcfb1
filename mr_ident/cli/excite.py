# SPDX-License-Identifier: Apache-2.0
"""``mr-ident excite``: design a multisine excitation, write it (NPZ or CSV), stream it.

``--publish TOPIC`` streams a design (``--design FILE.npz`` or the one designed here) on
a ROS topic (:mod:`mr_ident.ros.excite_pub`); rclpy is imported only then.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..numerics.catalog import EXCITATION_FORMS
from .argtypes import band, int_at_least, positive_float

#: The design's own options: given with --design they would be ignored, so they are refused.
DESIGN_OPTIONS = ("fs_high", "band", "period")


def add_excite_parser(sub: Any) -> None:
    """The ``excite`` subcommand's options on the subparsers ``sub``."""
    x = sub.add_parser(
        "excite", help="design a multisine excitation (NPZ or CSV), or stream one on a topic"
    )
    x.add_argument("--fs-high", type=positive_float, help="sample rate in Hz")
    x.add_argument("--band", type=band, help="LO,HI: the excited band in Hz")
    x.add_argument("--period", type=int_at_least(4), help="samples per period")
    x.add_argument("--periods", type=int_at_least(1), default=1, help="P periods (default 1)")
    x.add_argument(
        "--realizations", type=int_at_least(1), default=1, help="M random-phase realizations"
    )
    x.add_argument(
        "--kind",
        choices=("full", "odd", "odd-random"),
        default="odd-random",
        help="lines: every one in the band, the odd ones, or odd with one detection line "
        "left out at random per group of 3 (default)",
    )
    x.add_argument("--rms", type=positive_float, default=1.0, help="RMS of each input (1)")
    x.add_argument("--inputs", type=int_at_least(1), default=1, help="orthogonal inputs (1)")
    x.add_argument("--ratio", type=int_at_least(1), default=1, help="F (for --lifted)")
    x.add_argument(
        "--lifted",
        action="store_true",
        help="keep only lines whose F lifted aliases do not collide (needs --ratio)",
    )
    x.add_argument(
        "--rotate",
        action="store_true",
        help="with --lifted: realization m's lines moved m places along their alias "
        "families, so F realizations excite every alias of every lifted bin (for a y "
        "measured at the low rate; --kind full, --realizations a multiple of F)",
    )
    x.add_argument(
        "--slope", type=float, default=0.0, help="amplitude slope in dB/decade (0: flat)"
    )
    x.add_argument("--seed", type=int, default=0, help="random phases' seed")
    x.add_argument("--out", type=Path, help="FILE.npz or FILE.csv (needed unless --publish)")
    x.add_argument(
        "--design", type=Path, help="stream this design (FILE.npz of mr-ident excite --out)"
    )
    x.add_argument(
        "--publish",
        metavar="TOPIC",
        help="stream the design on TOPIC at fs_high, the labels on TOPIC/excitation_index",
    )
    x.add_argument(
        "--as",
        dest="form",
        choices=EXCITATION_FORMS,
        default="block",
        help="message form: the block contract (default), a JointState position, a "
        "Float64MultiArray command (forward_command_controller), or a MultiDOFCommand "
        "setpoint (pid_controller's ~/reference; needs control_msgs)",
    )
    x.add_argument(
        "--joint",
        action="append",
        metavar="NAME",
        help="joint name per input (JointState names; default j0, j1, ...)",
    )
    x.add_argument("--rate", type=positive_float, default=1.0, help="times real time (default 1)")
    x.add_argument(
        "--loops",
        type=int_at_least(0),
        default=1,
        help="times through every realization and period (default 1; 0: until Ctrl-C)",
    )
    x.add_argument(
        "--tick",
        type=positive_float,
        help="timer period in s (default: one sample for per-sample forms, else 0.01)",
    )
    x.add_argument(
        "--block", type=int_at_least(1), default=1000, help="most samples per block message"
    )
    x.add_argument(
        "--wait",
        type=float,
        default=5.0,
        help="wait up to this many s for subscribers before the first sample (default 5)",
    )
    x.add_argument(
        "--subscribers",
        type=int_at_least(0),
        default=1,
        help="subscribers to wait for on TOPIC (default 1)",
    )
    x.add_argument(
        "--paused",
        action="store_true",
        help="start stopped: publish from a call of the node's ~/start service (std_srvs/"
        "Trigger; ~/stop stops; the status is on /diagnostics)",
    )


def cmd_excite(args: argparse.Namespace) -> int:
    """Design (or read) the excitation, write it, and stream it with ``--publish``."""
    if args.out is None and args.publish is None:
        raise ConfigError("excite needs --out FILE.npz|FILE.csv or --publish TOPIC (or both)")
    if args.out is not None and args.out.suffix.lower() not in (".npz", ".csv"):
        raise ConfigError(f"--out must end in .npz or .csv, got {str(args.out)!r}")
    if args.design is not None:
        given = [f"--{k.replace('_', '-')}" for k in DESIGN_OPTIONS if getattr(args, k)]
        if given:
            raise ConfigError(f"--design FILE gives the design; {', '.join(given)} not with it")
        from ..io.excitefile import read_excitation

        r, fs, period = read_excitation(args.design)
    else:
        missing = [f"--{k.replace('_', '-')}" for k in DESIGN_OPTIONS if not getattr(args, k)]
        if missing:
            raise ConfigError(
                f"excite needs {', '.join(missing)} to design (or --design FILE.npz)"
            )
        r, fs, period = _design(args)
    if args.publish is not None:
        return _publish(args, r, fs, period)
    return 0


def _design(args: argparse.Namespace) -> tuple[Any, float, int]:
    """Design per the options, write ``--out`` if given, say what; (r, fs_high, period)."""
    from ..io.excitefile import write_excitation
    from ..numerics.excitation.multisine import design

    if args.lifted and args.ratio == 1:
        raise ConfigError("--lifted needs --ratio F > 1 (the lifted aliases it keeps apart)")
    if args.rotate and not (args.lifted and args.kind == "full"):
        raise ConfigError(
            "--rotate needs --lifted and --kind full (and --realizations a multiple of F)"
        )
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
        rotate=args.rotate,
    )
    f = ms.frequencies
    M, n, n_in = ms.r.shape
    what = (
        f"{ms.kind} multisine, {f.size} lines from {f[0]:g} to {f[-1]:g} Hz "
        f"({ms.detection.size} detection lines), period {ms.period} samples "
        f"({ms.period / ms.fs_high:g} s), {n // ms.period} periods, {M} realization(s), "
        f"{n_in} input(s); crest factor {ms.crest_factor.min():.2f}-{ms.crest_factor.max():.2f}"
    )
    if args.out is not None:
        write_excitation(args.out, ms, ratio=args.ratio)
        print(f"wrote {args.out}: {what}")
    else:
        print(f"designed {what}")
    return ms.r, ms.fs_high, ms.period


def _publish(args: argparse.Namespace, r: Any, fs: float, period: int) -> int:
    """Stream on ``--publish`` until the loops are done or a signal; say what went out."""
    from ..io.labels import index_topic
    from ..ros.excite_pub import publish
    from ..ros.program import handle_signals, ros_context

    stop = handle_signals()
    with ros_context() as rclpy:
        node = rclpy.create_node("mr_ident_excite")
        try:
            played = publish(
                node,
                args.publish,
                r,
                fs_high=fs,
                period=period,
                form=args.form,
                joints=args.joint,
                rate=args.rate,
                loops=args.loops,
                tick=args.tick,
                block=args.block,
                wait=args.wait,
                subscribers=args.subscribers,
                stop=stop,
                paused=args.paused,
            )
        finally:
            node.destroy_node()
    print(
        f"published {played.samples} samples ({played.samples / fs:g} s at {fs:g} Hz) in "
        f"{played.messages} messages on {args.publish} and {index_topic(args.publish)} "
        f"({args.form}); stamps from t0 = {played.t0} ns; {played.late_ticks} of "
        f"{played.ticks} ticks late by more than a tick",
        file=sys.stdout,
    )
    return 0
