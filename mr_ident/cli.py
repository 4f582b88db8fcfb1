"""Command line: ``mr-ident simulate | identify | paper | diagnose | replay | record | demo``.

``record``, ``replay --publish`` and ``demo`` need rclpy (imported only for them).

User errors print ``error: ...`` to stderr and exit with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import math
import sys
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

from ._alloc import keep_freed_memory
from .errors import ConfigError, DataError, MrIdentError

if TYPE_CHECKING:
    from .model import Model
    from .results import Identification

EXIT_USAGE = 2


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _int_at_least(low: int):  # type: ignore[no-untyped-def]
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {v}")
        return v
    return parse


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        print(f"error: {message}", file=sys.stderr)
        raise SystemExit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    from .identify import METHODS
    p = _Parser(prog="mr-ident", description="Identify multirate control loops in the frequency domain.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    s = sub.add_parser("simulate", help="simulate a model's loop with white-noise excitation")
    s.add_argument("model", type=Path, help="model YAML")
    s.add_argument("--duration", type=_positive_float, required=True, help="seconds (rounded to whole low-rate periods)")
    s.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    s.add_argument("--out", type=Path, required=True, help="data file, .csv or .npz")

    i = sub.add_parser("identify", help="identify P_h (and the PFG) from r, u, y data")
    i.add_argument("data", type=Path, help="data file, .csv or .npz")
    i.add_argument("--fs-high", type=_positive_float, help="high sample rate in Hz (else from the file or model)")
    i.add_argument("--ratio", type=_int_at_least(1), help="F (else from the file or model)")
    i.add_argument("--model", type=Path, help="model YAML: gives the controller for the PFG and the reference curve")
    i.add_argument("--method", choices=METHODS, default="freq-lifted")
    i.add_argument("--n", type=_int_at_least(1), default=8, help="LPM window half-width (default 8)")
    i.add_argument("--degree", type=_int_at_least(0), default=2, help="LPM polynomial degree R (default 2)")
    i.add_argument("--out", type=Path, required=True, help="result .npz")
    i.add_argument("--plot", type=Path, help="Bode plot PNG (the PFG goes next to it as *_pfg.png)")

    q = sub.add_parser("paper", help="the paper's example end to end: figures and an error table")
    q.add_argument("--duration", type=_positive_float, default=600.0, help="seconds (default 600)")
    q.add_argument("--model", type=Path, default=None, help="model YAML (default: config/paper_example.yaml)")
    q.add_argument("--noise-std", type=float, default=None, help="override the model's output noise std")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--out-dir", type=Path, default=Path("out/paper"), help="where to write (default out/paper)")

    rp = sub.add_parser("replay", help="identify from an MCAP recording as the node would (or re-publish it)")
    rp.add_argument("recording", type=Path, help="MCAP file (recorded by mr-ident record or the node)")
    rp.add_argument("--params", type=Path, help="node params file (ROS 2 form), e.g. config/node.yaml; "
                    "default: the node's defaults")
    rp.add_argument("--topics", nargs=3, metavar=("R", "U", "Y"),
                    help="recorded topic names of r, u, y (default: .../reference, .../input, .../output)")
    rp.add_argument("--stop", type=_int_at_least(1), help="use the window ending at or before this sample index")
    rp.add_argument("--out", type=Path, help="result .npz (same form as identify)")
    rp.add_argument("--plot", type=Path, help="Bode plot PNG (PFG next to it as *_pfg.png)")
    rp.add_argument("--model", type=Path, help="model YAML: reference curve in the plot")
    rp.add_argument("--publish", action="store_true", help="re-publish the recording on its topics instead")
    rp.add_argument("--rate", type=_positive_float, default=1.0, help="with --publish: times real time (default 1)")

    rc = sub.add_parser("record", help="record topics to an MCAP file (rosbag2 form) until Ctrl-C")
    rc.add_argument("out", type=Path, help="MCAP file to write")
    rc.add_argument("topics", nargs="*", help="topics (default: reference input output)")
    rc.add_argument("--duration", type=_positive_float, help="stop after this many seconds")

    g = sub.add_parser("diagnose", help="where and why a model disagrees with measured data; extended model")
    g.add_argument("model", type=Path, help="nominal model YAML")
    g.add_argument("data", type=Path, help="measured data: .csv, .npz or .mcap (recording)")
    g.add_argument("--validate", type=Path, help="independent validation data (default: the last 30 %% of DATA)")
    g.add_argument("--json", type=Path, required=True, help="report .json")
    g.add_argument("--report", type=Path, help="report .html (self-contained, figures embedded)")
    g.add_argument("--out-model", type=Path, help="extended model YAML")
    g.add_argument("--period", type=_int_at_least(2),
                   help="samples per period of a periodic excitation (noise from the periods; first period dropped)")
    g.add_argument("--topics", nargs=3, metavar=("R", "U", "Y"), help="MCAP topic names of r, u, y")
    g.add_argument("--n", type=_int_at_least(1), default=8, help="LPM window half-width (default 8)")
    g.add_argument("--degree", type=_int_at_least(0), default=2, help="LPM polynomial degree R (default 2)")
    g.add_argument("--alpha", type=float, default=0.01, help="false-alarm level of the per-bin test (default 0.01)")
    g.add_argument("--max-causes", type=_int_at_least(1), default=3, help="most causes applied in turn (default 3)")

    d = sub.add_parser("demo", help="live demo: simulated loop + node over DDS, recording, replay, plots")
    d.add_argument("--out-dir", type=Path, default=Path("out/demo"))
    d.add_argument("--rate", type=_positive_float, default=20.0, help="simulation speed-up (default 20)")
    d.add_argument("--timeout", type=_positive_float, default=120.0, help="give up after this many s (default 120)")
    return p


def cmd_simulate(args: argparse.Namespace) -> int:
    import numpy as np

    from .data import write_data
    from .model import load_model
    from .simulate import simulate
    model = load_model(args.model)
    sim = simulate(model, duration=args.duration, rng=np.random.default_rng(args.seed))
    write_data(args.out, sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=model.ratio)
    print(f"wrote {args.out} ({sim.r.shape[0]} samples at {model.fs_high:g} Hz, F = {model.ratio})")
    return 0


def _resolve_rates(args: argparse.Namespace, file_fs: float | None, file_ratio: int | None,
                   model: Model | None) -> tuple[float, int]:
    fs_sources = [(n, v) for n, v in (("--fs-high", args.fs_high), ("the data file", file_fs),
                                       ("the model", model.fs_high if model else None)) if v is not None]
    r_sources = [(n, v) for n, v in (("--ratio", args.ratio), ("the data file", file_ratio),
                                      ("the model", model.ratio if model else None)) if v is not None]
    if not fs_sources:
        raise ConfigError("fs_high unknown: pass --fs-high or --model, or use an NPZ/CSV that gives it")
    if not r_sources:
        raise ConfigError("ratio F unknown: pass --ratio or --model, or use an NPZ that gives it")
    fs = fs_sources[0][1]
    for name, v in fs_sources[1:]:
        if abs(v - fs) > 1e-6 * fs:
            raise ConfigError(f"fs_high disagrees: {fs_sources[0][0]} says {fs:g} Hz, {name} says {v:g} Hz")
    F = r_sources[0][1]
    for name, v in r_sources[1:]:
        if v != F:
            raise ConfigError(f"ratio disagrees: {r_sources[0][0]} says {F}, {name} says {v}")
    return float(fs), int(F)


def cmd_identify(args: argparse.Namespace) -> int:
    from .data import read_data, write_result
    from .identify import identify
    from .model import load_model
    if args.out.suffix.lower() != ".npz":
        raise ConfigError(f"--out must be a .npz file, got {str(args.out)!r}")
    model = load_model(args.model) if args.model else None
    data = read_data(args.data)
    fs, F = _resolve_rates(args, data.fs_high, data.ratio, model)
    N = data.r.shape[0]
    K_low = None
    if model is not None:
        if model.n_y != data.y.shape[1] or model.n_u != data.u.shape[1]:
            raise DataError(f"model is {model.n_y}x{model.n_u} (n_y x n_u) but the data has "
                            f"{data.y.shape[1]} output and {data.u.shape[1]} input channel(s)")
        if model.controller is not None and N % F == 0:
            K_low = model.controller_frf(N // F)
    ident = identify(data.r, data.u, data.y, fs_high=fs, ratio=F, method=args.method, n=args.n,
                     degree=args.degree, controller_low=K_low,
                     phase=model.sample_phase if model else 0, delay=model.control_delay if model else 0,
                     keep_lifted=False)                    # the result file holds P_h and the PFG only
    write_result(args.out, ident)
    print(f"wrote {args.out} ({ident.plant.frequency.size} bins, method {args.method})")
    if args.plot:
        _write_plots(ident, args.plot, fs, F, N, model)
    return 0


def _write_plots(ident: Identification, path: Path, fs: float, F: int, N: int, model: Model | None) -> None:
    """Bode plot of P_h at ``path`` (model drawn when given); with a PFG, ``<path>_pfg``."""
    from .pfg import pfg_of_model
    from .plots import plot_bode, plot_pfg
    nyq = fs / F / 2 if F > 1 else None
    mfrf = model.plant_result(N) if model is not None else None
    print(f"wrote {plot_bode(ident.plant, path, model=mfrf, nyquist_low=nyq)}")
    if ident.pfg is not None:
        ref = pfg_of_model(model, N) if model is not None and model.controller is not None else None
        pfg_path = path.with_name(path.stem + "_pfg" + path.suffix)
        print(f"wrote {plot_pfg(ident.pfg, pfg_path, model=ref)}")


def cmd_paper(args: argparse.Namespace) -> int:
    from .model import load_model
    from .paper import run_paper
    from .config import share_file
    model = load_model(args.model or share_file("config/paper_example.yaml", "; pass --model"))
    if args.noise_std is not None and not (math.isfinite(args.noise_std) and args.noise_std >= 0):
        raise ConfigError(f"--noise-std must be >= 0, got {args.noise_std}")
    run = run_paper(model, args.out_dir, duration=args.duration, seed=args.seed, noise_std=args.noise_std)
    print(run.table)
    for name, path in run.files.items():
        print(f"{name:12s} {path}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from .config import IdentConfig, load_params
    from .data import write_result
    from .recording import replay
    if args.publish:
        from .ros.record import publish_recording
        n = publish_recording(args.recording, rate=args.rate)
        print(f"published {n} messages from {args.recording}")
        return 0
    if args.out is None:
        raise ConfigError("replay needs --out RESULT.npz (or --publish)")
    if args.out.suffix.lower() != ".npz":
        raise ConfigError(f"--out must be a .npz file, got {str(args.out)!r}")
    cfg = load_params(args.params) if args.params else IdentConfig()
    res = replay(args.recording, cfg, topics=args.topics, stop=args.stop)
    info, est = res.info, res.estimate
    if info.truncated:
        print(f"warning: {args.recording} is cut short; recovered {sum(info.messages.values())} messages "
              f"({info.bytes_read} of {info.file_bytes} bytes) ({info.reason})", file=sys.stderr)
    for note in res.anomalies[:20]:
        print(f"note: {note}", file=sys.stderr)
    write_result(args.out, est.identification)
    counts = ", ".join(f"{k} {v}" for k, v in info.messages.items())
    print(f"read {counts} messages; window [{est.first}, {est.first + est.n_samples}) "
          f"({est.n_samples / cfg.fs_high:g} s), lifting phase {est.phase} ({est.phase_source}), "
          f"{est.compute_s:.3f} s")
    print(f"wrote {args.out} ({est.identification.plant.frequency.size} bins, method {cfg.method})")
    if args.plot:
        from .model import load_model
        model = load_model(args.model) if args.model else None
        _write_plots(est.identification, args.plot, cfg.fs_high, cfg.ratio, est.n_samples, model)
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from .ros.record import record
    counts = record(args.out, args.topics, duration=args.duration)
    print(f"wrote {args.out}: " + (", ".join(f"{t} {n}" for t, n in counts.items()) or "nothing") + " messages")
    return 0


def _read_record(path: Path, model: Model, period: int | None, topics: list[str] | None) -> Any:
    """A validate.Record from a data file; rates from the file where it gives them, else the model."""
    from .validate import Record
    if path.suffix.lower() == ".mcap":
        from .recording import recorded_signals
        r, u, y, info = recorded_signals(path, model.ratio, topics=topics)
        if info.truncated:
            print(f"warning: {path} is truncated ({info.reason}); using the {r.shape[0]} samples read", file=sys.stderr)
        if info.broken:
            print(f"warning: {path}: using the latest gap-free span [{info.span[0]}, {info.span[1]}) "
                  f"of {r.shape[0]} samples ({info.broken})", file=sys.stderr)
        fs, F = model.fs_high, model.ratio
    else:
        from .data import read_data
        data = read_data(path)
        r, u, y = data.r, data.u, data.y
        fs = data.fs_high if data.fs_high is not None else model.fs_high
        F = data.ratio if data.ratio is not None else model.ratio
    if r.shape[0] % F:
        raise DataError(f"{path}: N = {r.shape[0]} samples is not a multiple of ratio F={F}")
    return Record(r, u, y, float(fs), int(F), period)


def cmd_diagnose(args: argparse.Namespace) -> int:
    import json

    import yaml

    from .data import _atomic_write
    from .model import model_to_dict
    from .report import report_dict, report_html
    from .model import load_model
    from .validate import diagnose
    if args.json.suffix.lower() != ".json":
        raise ConfigError(f"--json must be a .json file, got {str(args.json)!r}")
    if args.report is not None and args.report.suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"--report must be an .html file, got {str(args.report)!r}")
    if not 0.0 < args.alpha < 1.0:
        raise ConfigError(f"--alpha must be in (0, 1), got {args.alpha}")
    model = load_model(args.model)
    data = _read_record(args.data, model, args.period, args.topics)
    val = _read_record(args.validate, model, args.period, args.topics) if args.validate else None
    d = diagnose(model, data, val, n=args.n, degree=args.degree, alpha=args.alpha, max_causes=args.max_causes,
                 names=(str(args.data), str(args.validate)))
    summary = report_dict(d, extended_model=str(args.out_model) if args.out_model else None, alpha=args.alpha)
    # Everything is computed; now write (each file atomically).
    if args.out_model:
        text = yaml.safe_dump(model_to_dict(d.extended), sort_keys=False)
        header = (f"# Extended by mr-ident diagnose from {args.model} on {args.data}.\n"
                  f"# Applied: {', '.join(a.cause for a in d.applied) or 'nothing (the model explains the data)'}\n")
        _atomic_write(args.out_model, lambda fh: fh.write(header + text), binary=False)
    _atomic_write(args.json, lambda fh: json.dump(summary, fh, indent=2), binary=False)
    if args.report:
        ext = None
        if d.applied:
            ext = d.extended.plant_discrete().freqresp(d.evidence_before.frequency)
        page = report_html(d, summary, ext, f"mr-ident diagnose: {args.model.name} on {args.data.name}")
        _atomic_write(args.report, lambda fh: fh.write(page), binary=False)
    fu = "" if d.fit_before.u is None else f"; fit u {d.fit_before.u:.1f} % -> {d.fit_after.u:.1f} %"
    params = ", ".join(f"{k} = {v:.6g}" for k, v in d.parameters.items())
    print(f"cause: {d.cause}{' (' + params + ')' if params else ''}; applied: "
          f"{', '.join(a.cause for a in d.applied) or 'none'}; fit y {d.fit_before.y:.1f} % -> {d.fit_after.y:.1f} %{fu}")
    for path in (args.json, args.report, args.out_model):
        if path:
            print(f"wrote {path}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .ros.demo import run_demo
    return run_demo(args.out_dir, rate=args.rate, timeout=args.timeout)


def _ros_program(argv: Sequence[str]) -> bool:
    """Whether the command line runs a ROS program (record, demo, replay --publish)."""
    command = next((a for a in argv if not a.startswith("-")), None)
    return command in ("record", "demo") or (command == "replay" and "--publish" in argv)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if _ros_program(argv):
        from .ros.program import handle_signals
        handle_signals()                  # before anything slow: a signal from now on stops cleanly
    args = build_parser().parse_args(argv)
    keep_freed_memory()
    commands = {"simulate": cmd_simulate, "identify": cmd_identify, "paper": cmd_paper, "replay": cmd_replay,
                "record": cmd_record, "demo": cmd_demo, "diagnose": cmd_diagnose}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.simplefilter("ignore", DeprecationWarning)    # third-party import noise (lark)
            return commands[args.command](args)
    except MrIdentError as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except OSError as err:
        print(f"error: {err.filename or ''}: {err.strerror or err}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
