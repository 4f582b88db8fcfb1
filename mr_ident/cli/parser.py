# SPDX-License-Identifier: Apache-2.0
"""The argument parser of ``mr-ident``: every subcommand, its options and their checks."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..live.spans import DEFAULT_SPAN, SPANS
from ..numerics.catalog import LOCAL_MODELS, METHOD_NAMES
from .argtypes import frequencies, int_at_least, period_or_auto, positive_float, window_n
from .common import quiet_option
from .excite import add_excite_parser
from .fit_cmd import add_fit_parser

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def _sources(p: argparse.ArgumentParser) -> None:
    """--r/--u/--y: per-sample sources in a bag (docs/sources.md, "Message paths")."""
    for sig, what in (("r", "excitation"), ("u", "plant input"), ("y", "plant output")):
        p.add_argument(
            f"--{sig}",
            action="append",
            metavar="SPEC",
            dest=f"{sig}_source",
            help=f"{what} in a bag: topic and field path, e.g. '/joint_states.position"
            f'{{name=="j1"}}\' (repeat for MIMO)',
        )


def _y_rate(p: argparse.ArgumentParser, default: str) -> None:
    """--y-rate: y measured at the controller's rate.

    docs/method.md, "Outputs at the low rate".
    """
    p.add_argument(
        "--y-rate",
        choices=("high", "low"),
        help="low: y is measured at the low rate (a bag's y source read with .@hold: its "
        f"samples are where it changes); default: {default}",
    )


def _reading(p: argparse.ArgumentParser, default_span: str = DEFAULT_SPAN) -> None:
    """--span and --msg-path: how a recording is read (docs/sources.md, "Bags")."""
    p.add_argument(
        "--span",
        choices=SPANS,
        default=default_span,
        help="which span of a recording split by gaps too long to bridge: "
        f"{', '.join(SPANS)} (default "
        f"{default_span}; all: an error where there are gaps)",
    )
    p.add_argument(
        "--msg-path",
        action="append",
        type=Path,
        metavar="DIR",
        help="directory of .msg files (DIR/pkg/msg/Type.msg) for types a bag does not define "
        "and that are not installed (repeatable)",
    )


def _labels_option(p: argparse.ArgumentParser, when: str) -> None:
    """--excitation-index: the topic of an excitation's labels in a bag."""
    p.add_argument(
        "--excitation-index",
        metavar="TOPIC",
        help=f"{when}topic of the excitation's labels (mr-ident excite --publish TOPIC: "
        "TOPIC/excitation_index), read in the form of the signals and aligned with them; "
        "windows of whole periods give the best linear approximation",
    )


def _lpm_options(p: argparse.ArgumentParser) -> None:
    """--n and --degree: the LPM's window half-width and polynomial degree."""
    p.add_argument(
        "--n",
        type=window_n,
        default="auto",
        help="LPM window half-width: auto (default: chosen per frequency from candidates "
        "8, 12, 18, 27 by least estimated mean-squared error) or an integer",
    )
    p.add_argument(
        "--degree", type=int_at_least(0), default=2, help="LPM polynomial degree R (default 2)"
    )


def _injection(p: argparse.ArgumentParser) -> None:
    """--injection: where r entered, where the data cannot tell (docs: "Where r enters")."""
    p.add_argument(
        "--injection",
        choices=("plant_input", "setpoint"),
        help="where r entered the loop: added to the plant input, or as the controller's "
        "setpoint (sampled with y). Default: as the data show it (the held u or u - r); "
        "refused where it contradicts them",
    )


def _local_option(p: argparse.ArgumentParser) -> None:
    """--local: the local model of the LPM methods' windows.

    docs/method.md, "Local rational models".
    """
    p.add_argument(
        "--local",
        choices=LOCAL_MODELS,
        default=LOCAL_MODELS[0],
        help="local model per window: polynomial (LPM, default) or rational (a common "
        "denominator of order --degree: lightly damped modes with few bins across them)",
    )


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``mr-ident``: one builder per subcommand, in the help's order."""
    p = _Parser(
        prog="mr-ident", description="Identify multirate control loops in the frequency domain."
    )
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    _simulate_command(sub)
    _identify_command(sub)
    _paper_command(sub)
    _replay_command(sub)
    _record_command(sub)
    _diagnose_command(sub)
    _batch_command(sub)
    _view_command(sub)
    add_excite_parser(sub)
    add_fit_parser(sub)
    _demo_command(sub)
    return p


def _simulate_command(sub: Any) -> None:
    """``mr-ident simulate``: its arguments."""
    s = sub.add_parser("simulate", help="simulate a model's loop with white-noise excitation")
    s.add_argument("model", type=Path, help="model YAML")
    s.add_argument(
        "--duration",
        type=positive_float,
        required=True,
        help="seconds (rounded to whole low-rate periods)",
    )
    s.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    s.add_argument(
        "--injection",
        choices=("plant_input", "setpoint"),
        help="where the white r enters: added to the plant input, or as the controller's "
        "setpoint (default: the model's injection, else the plant input)",
    )
    s.add_argument("--out", type=Path, required=True, help="data file, .csv or .npz")


def _identify_command(sub: Any) -> None:
    """``mr-ident identify``: its arguments."""
    i = sub.add_parser("identify", help="identify P_h (and the PFG) from r, u, y data")
    i.add_argument(
        "data",
        type=Path,
        help="data: .csv, .npz, or a bag (rosbag2 directory, .mcap, .db3, .mcap.zstd)",
    )
    i.add_argument(
        "--fs-high",
        type=positive_float,
        help="high sample rate in Hz (else from the file or model)",
    )
    i.add_argument("--ratio", type=int_at_least(1), help="F (else from the file or model)")
    i.add_argument(
        "--model",
        type=Path,
        help="model YAML: gives the controller for the PFG and the reference curve",
    )
    i.add_argument("--method", choices=METHOD_NAMES, default="freq-lifted")
    _injection(i)
    _lpm_options(i)
    _local_option(i)
    _sources(i)
    _y_rate(i, "high, or low for an NPZ whose y has N/F samples")
    _reading(i)
    i.add_argument("--out", type=Path, required=True, help="result .npz")
    i.add_argument(
        "--plot", type=Path, help="Bode plot PNG (the PFG goes next to it as *_pfg.png)"
    )
    i.add_argument(
        "--period",
        type=period_or_auto,
        help="periodic data: the best linear approximation with its noise and nonlinear std. "
        "N samples per period, or auto (a bag: from the excitation's labels). An NPZ holds r, "
        "u, y of shape (M realizations, n); a bag is cut by the labels beside r "
        "(--excitation-index), else counted from its first sample",
    )
    i.add_argument(
        "--transient-periods",
        type=int_at_least(0),
        default=1,
        help="with --period: leading periods of each realization dropped as transient (default 1)",
    )
    _labels_option(i, "with --period on a bag: ")
    quiet_option(i)


def _paper_command(sub: Any) -> None:
    """``mr-ident paper``: its arguments."""
    q = sub.add_parser("paper", help="the paper's example end to end: figures and an error table")
    q.add_argument("--duration", type=positive_float, default=600.0, help="seconds (default 600)")
    q.add_argument(
        "--model", type=Path, default=None, help="model YAML (default: config/paper_example.yaml)"
    )
    q.add_argument(
        "--noise-std", type=float, default=None, help="override the model's output noise std"
    )
    q.add_argument("--seed", type=int, default=0)
    q.add_argument(
        "--out-dir",
        type=Path,
        default=Path("out/paper"),
        help="where to write (default out/paper)",
    )


def _replay_command(sub: Any) -> None:
    """``mr-ident replay``: its arguments."""
    rp = sub.add_parser(
        "replay", help="identify from a recording as the node would (or re-publish an MCAP file)"
    )
    rp.add_argument(
        "recording",
        type=Path,
        help="a bag: rosbag2 directory, .mcap, .db3 or .mcap.zstd (block topics, or --r/--u/--y)",
    )
    rp.add_argument(
        "--params",
        type=Path,
        help="node params file (ROS 2 form), e.g. config/node.yaml; default: the node's defaults",
    )
    rp.add_argument(
        "--topics",
        nargs=3,
        metavar=("R", "U", "Y"),
        help="recorded topic names of r, u, y (default: .../reference, .../input, .../output)",
    )
    rp.add_argument(
        "--stop",
        type=int_at_least(1),
        help="use the window ending at or before this sample index",
    )
    _sources(rp)
    _y_rate(rp, "y_rate of --params (high)")
    _reading(rp, default_span="latest")
    rp.add_argument(
        "--fs-high",
        type=positive_float,
        help="with --r/--u/--y: high rate in Hz (default: "
        "from --params, else read off the stamps)",
    )
    rp.add_argument(
        "--ratio",
        type=int_at_least(1),
        help="with --r/--u/--y: F (default: from --params, else from a .@hold source's stamps)",
    )
    _labels_option(rp, "(the node's excitation_index_topic) ")
    rp.add_argument("--out", type=Path, help="result .npz (same form as identify)")
    rp.add_argument("--plot", type=Path, help="Bode plot PNG (PFG next to it as *_pfg.png)")
    rp.add_argument("--model", type=Path, help="model YAML: reference curve in the plot")
    rp.add_argument(
        "--publish", action="store_true", help="re-publish the recording on its topics instead"
    )
    rp.add_argument(
        "--rate",
        type=positive_float,
        default=1.0,
        help="with --publish: times real time (default 1)",
    )
    quiet_option(rp)


def _record_command(sub: Any) -> None:
    """``mr-ident record``: its arguments."""
    rc = sub.add_parser("record", help="record topics to an MCAP file (rosbag2 form) until Ctrl-C")
    rc.add_argument("out", type=Path, help="MCAP file to write")
    rc.add_argument("topics", nargs="*", help="topics (default: reference input output)")
    rc.add_argument("--duration", type=positive_float, help="stop after this many seconds")


def _diagnose_command(sub: Any) -> None:
    """``mr-ident diagnose``: its arguments."""
    g = sub.add_parser(
        "diagnose", help="where and why a model disagrees with measured data; extended model"
    )
    g.add_argument("model", type=Path, help="nominal model YAML")
    g.add_argument(
        "data",
        type=Path,
        help="measured data: .csv, .npz or a bag (rosbag2 directory, .mcap, .db3, .mcap.zstd)",
    )
    g.add_argument(
        "--validate",
        type=Path,
        nargs="+",
        metavar="DATA2",
        help="independent validation data (default: the last 30 %% of DATA); the first "
        "validates the extension; all records given, DATA too, are compared as realizations "
        "of the excitation (nonlinear distortion across records)",
    )
    _sources(g)
    _reading(g)
    g.add_argument(
        "--json", type=Path, help="also write the report as .json (the verdict is printed)"
    )
    g.add_argument("--report", type=Path, help="report .html (self-contained, figures embedded)")
    g.add_argument("--out-model", type=Path, help="extended model YAML")
    g.add_argument(
        "--period",
        type=int_at_least(2),
        help="samples per period of a periodic excitation (noise from the periods; "
        "first period dropped)",
    )
    g.add_argument(
        "--topics", nargs=3, metavar=("R", "U", "Y"), help="MCAP topic names of r, u, y"
    )
    _lpm_options(g)
    g.add_argument(
        "--alpha",
        type=float,
        default=0.01,
        help="false-alarm level of the per-bin test (default 0.01)",
    )
    g.add_argument(
        "--max-causes",
        type=int_at_least(1),
        default=3,
        help="most causes applied in turn (default 3)",
    )
    _injection(g)
    quiet_option(g)


def _batch_command(sub: Any) -> None:
    """``mr-ident batch``: its arguments."""
    b = sub.add_parser(
        "batch",
        help="identify or diagnose many recordings: one summary table and a result each",
    )
    b.add_argument(
        "inputs",
        nargs="+",
        help="recordings: .csv/.npz/.mcap files, rosbag2 directories, directories holding "
        "them, or glob patterns (quoted)",
    )
    b.add_argument("--out-dir", type=Path, required=True, help="results and summary.csv")
    b.add_argument("--task", choices=("identify", "diagnose"), default="identify")
    b.add_argument("--model", type=Path, help="model YAML (rates, PFG, drift; diagnose needs it)")
    b.add_argument(
        "--reference",
        type=Path,
        help="result .npz of mr-ident identify to measure the drift against (else the model)",
    )
    b.add_argument(
        "--at",
        type=frequencies,
        help="frequencies (Hz, comma-separated) of the table's P_h columns (default: six, "
        "log-spaced from fs_low/100 to 0.4 fs_high)",
    )
    b.add_argument("--fs-high", type=positive_float, help="high sample rate in Hz")
    b.add_argument("--ratio", type=int_at_least(1), help="F")
    b.add_argument("--method", choices=METHOD_NAMES, default="freq-lifted")
    _injection(b)
    _lpm_options(b)
    _local_option(b)
    b.add_argument("--period", type=int_at_least(2), help="diagnose: samples per period")
    b.add_argument(
        "--topics", nargs=3, metavar=("R", "U", "Y"), help="block-contract topics of r, u, y"
    )
    _sources(b)
    _reading(b)
    b.add_argument(
        "--workers",
        type=int_at_least(1),
        help="worker processes of the local pool (default: one per CPU, at most one per file)",
    )
    b.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on an existing Dask distributed cluster (tcp://host:8786); needs the "
        "optional extra: pip install 'mr_ident[cluster]'",
    )
    quiet_option(b)


def _view_command(sub: Any) -> None:
    """``mr-ident view``: its arguments."""
    v = sub.add_parser(
        "view", help="a live page of the estimate (Bode, PFG, stream health) on localhost"
    )
    v.add_argument(
        "bag",
        type=Path,
        nargs="?",
        help="replay this bag's estimates instead of listening to a running node",
    )
    v.add_argument("--port", type=int_at_least(0), default=8765, help="HTTP port (default 8765)")
    v.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    v.add_argument("--model", type=Path, help="model YAML: its P_h and the sigma-error are shown")
    v.add_argument(
        "--reference",
        type=Path,
        help="result NPZ (identify/replay --out): drawn with the sigma-error instead of a model",
    )
    v.add_argument(
        "--node",
        default="mr_ident",
        help="the node's name, with its namespace: /arm/mr_ident (default mr_ident)",
    )
    v.add_argument(
        "--wait",
        type=positive_float,
        default=10.0,
        help="seconds to wait for the node to appear (default 10)",
    )
    v.add_argument("--params", type=Path, help="bag: node parameters file (window, method, ...)")
    v.add_argument(
        "--topics", nargs=3, metavar=("R", "U", "Y"), help="bag: block-contract topics of r, u, y"
    )
    _sources(v)
    _reading(v)
    v.add_argument("--fs-high", type=positive_float, help="bag: high sample rate in Hz")
    v.add_argument("--ratio", type=int_at_least(1), help="bag: F")
    v.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="bag: loop time per wall time (default 1: as live; 0: as fast as possible)",
    )


def _demo_command(sub: Any) -> None:
    """``mr-ident demo``: its arguments."""
    d = sub.add_parser(
        "demo", help="live demo: simulated loop + node over DDS, recording, replay, plots"
    )
    d.add_argument("--out-dir", type=Path, default=Path("out/demo"))
    d.add_argument(
        "--rate", type=positive_float, default=20.0, help="simulation speed-up (default 20)"
    )
    d.add_argument(
        "--timeout",
        type=positive_float,
        default=120.0,
        help="give up after this many s (default 120)",
    )
