# SPDX-License-Identifier: Apache-2.0
"""The motor bench case (model validation on measured data), reproducible in one command.

Reads ../shared/data/motor_bench/MultisineType{A,B}.mat (MATLAB files from the FdiTools
project, see the README there), writes them as NPZ data files (r = iq_refx, the current
reference; u = iq_adx, the measured motor current; y = omega_max, the motor-side velocity;
fs_high = 2500 Hz, ratio 1), checks the shipped state-space model Pv_11 against the data,
and runs ``mr-ident diagnose config/motor_bench.yaml`` with Type A as estimation data and
Type B as validation data (periodic: 2500 samples per period). Then a model from the data:
Type A's periodic BLA (``identify --period``), ``mr-ident fit`` at the automatic
order and at order 4, each fitted model held against the same data by ``diagnose`` (one
cause at most), and the validation fit of y on Type B printed beside the hand-written
model's.

    make motor-bench    # or: .venv/bin/python scripts/motor_bench.py [--data-dir D] [--out-dir O]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import scipy.io
import scipy.signal

ROOT = Path(__file__).resolve().parents[1]


def load(path: Path) -> dict:
    d = scipy.io.loadmat(path, squeeze_me=True)
    return {k: d[k] for k in ("iq_refx", "iq_adx", "omega_max", "fs", "nrofs")}


def to_npz(d: dict, out: Path) -> None:
    np.savez(
        out,
        r=np.asarray(d["iq_refx"], float),
        u=np.asarray(d["iq_adx"], float),
        y=np.asarray(d["omega_max"], float),
        fs_high=float(d["fs"]),
        ratio=1,
    )


def check_shipped_model(data_dir: Path, d: dict) -> None:
    """Print how the shipped Pv_11 compares with the measured FRF (period means, excited lines)."""
    m = scipy.io.loadmat(data_dir / "ident_python.mat", squeeze_me=True, struct_as_record=False)[
        "models"
    ].Pv_11
    P, fs = int(d["nrofs"]), float(d["fs"])
    per = lambda x: np.fft.rfft(np.asarray(x, float).reshape(-1, P)[1:], axis=1).mean(axis=0)  # noqa: E731
    U, Y = per(d["iq_adx"]), per(d["omega_max"])
    lines = np.array([11, 30, 53, 77, 150, 250])
    G = Y[lines] / U[lines]
    sys_ = scipy.signal.StateSpace(
        m.A, np.atleast_2d(m.B).T, np.atleast_2d(m.C), np.atleast_2d(m.D)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's "badly conditioned" note on this model
        _, H = scipy.signal.freqresp(sys_, 2 * np.pi * lines * fs / P)
    print("check of the shipped model Pv_11 (current -> motor velocity) against MultisineTypeA:")
    for f, g, h in zip(lines * fs / P, G, H, strict=False):
        print(
            f"  {f:5.0f} Hz  measured {abs(g):8.4f} {np.degrees(np.angle(g)):7.1f} deg   "
            f"Pv_11 {abs(h):8.4f} {np.degrees(np.angle(h)):7.1f} deg   ratio {abs(g / h):6.2f}"
        )
    poles = np.linalg.eigvals(m.A)
    print(
        "  Pv_11 modes [Hz]:",
        ", ".join(f"{abs(p) / 2 / np.pi:.1f}" for p in poles if p.imag > 0),
        "- measured: anti-resonance ~53 Hz, resonance ~77 Hz. Not used as the nominal model.",
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--data-dir", type=Path, default=ROOT.parent / "shared" / "data" / "motor_bench"
    )
    ap.add_argument("--out-dir", type=Path, default=ROOT / "out" / "motor_bench")
    args = ap.parse_args(argv)
    if not (args.data_dir / "MultisineTypeA.mat").exists():
        print(
            f"error: {args.data_dir}/MultisineTypeA.mat not found (pass --data-dir)",
            file=sys.stderr,
        )
        return 2
    args.out_dir.mkdir(parents=True, exist_ok=True)
    a, b = load(args.data_dir / "MultisineTypeA.mat"), load(args.data_dir / "MultisineTypeB.mat")
    to_npz(a, args.out_dir / "typeA.npz")
    to_npz(b, args.out_dir / "typeB.npz")
    check_shipped_model(args.data_dir, a)
    from mr_ident.cli import main as cli

    o = args.out_dir
    # the nonlinear distortion of the odd-odd Type B: its unexcited lines against the noise
    period = str(int(b["nrofs"]))
    bla = ["identify", str(o / "typeB.npz"), "--period", period, "--out", str(o / "typeB_bla.npz"),
           "--plot", str(o / "typeB_bla.png")]  # fmt: skip
    if cli(bla) != 0:
        return 2
    rc = cli(
        [
            "diagnose",
            str(ROOT / "config" / "motor_bench.yaml"),
            str(o / "typeA.npz"),
            "--validate",
            str(o / "typeB.npz"),
            "--period",
            str(int(a["nrofs"])),
            "--json",
            str(o / "report.json"),
            "--report",
            str(o / "report.html"),
            "--out-model",
            str(o / "motor_bench_extended.yaml"),
        ]
    )
    return rc if rc != 0 else fitted_models(cli, o, str(int(a["nrofs"])))


def fitted_models(cli, o: Path, period: str) -> int:
    """Models fitted to Type A's BLA, validated on Type B beside the hand-written one."""
    import json

    hand = ROOT / "config" / "motor_bench.yaml"
    if cli(["identify", str(o / "typeA.npz"), "--period", period,
            "--out", str(o / "typeA_bla.npz")]) != 0:  # fmt: skip
        return 2
    rows = [("config/motor_bench.yaml (hand-written)", o / "report.json")]
    for order in ("auto", "4"):
        model, report = o / f"fit_{order}.yaml", o / f"fit_{order}_report.json"
        if cli(["fit", str(o / "typeA_bla.npz"), "--order", order, "--controller", str(hand),
                "--out", str(model), "--plot", str(o / f"fit_{order}.png")]) != 0:  # fmt: skip
            return 2
        if cli(["diagnose", str(model), str(o / "typeA.npz"), "--validate", str(o / "typeB.npz"),
                "--period", period, "--max-causes", "1", "--json", str(report)]) != 0:  # fmt: skip
            return 2
        rows.append((f"fit --order {order}", report))
    print("\nvalidation fit of y on Type B (the model as it is, before any cause):")
    for name, path in rows:
        d = json.loads(path.read_text())
        after = f"(after the diagnosis: {d['fit_after']:.1f} %)"
        print(f"  {name:40s} {d['fit_before']:7.1f} %   {after}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
