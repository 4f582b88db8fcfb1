# SPDX-License-Identifier: Apache-2.0
"""Speed of one diagnosis of a 5-minute record: 300 s of 240 Hz data (72 000 samples).

The paper's plant (config/paper_example.yaml) under a softer lead controller (half gain),
F = 3, white r, output noise 2 % of y's std, and one case per effect: nothing hidden, a gain
change, an additive mode, a moved mode, a sensor low-pass, a controller notch, a control
delay, a gain change with an input delay at once, and the controller's gain 1.25 times
the model's. Prints the seconds per diagnosis
(whole ``diagnose``: identification, evidence, selection, validation) and what was found.

    .venv/bin/python benchmarks/bench_diagnose_speed.py [--duration 300] [--repeat 1]

``--cli``: the whole process instead, ``mr-ident diagnose MODEL DATA --validate DATA2
--json R.json --quiet`` on NPZ files (two records each, 300 s at 240 Hz, noise 2 %): white r
and a periodic odd multisine (1 s periods, ``--period 240``), each with nothing hidden, a
gain change, the controller's gain 1.25 times the model's, and a saturating actuator (at
the linear loop's rms of u: nonlinear, so the correction is tried); wall-clock seconds and
the process's CPU seconds per case.

    .venv/bin/python benchmarks/bench_diagnose_speed.py --cli [--duration 300]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mr_bench.beyond import simulate_actuated
from mr_ident.allocator import keep_freed_memory
from mr_ident.diagnosis import diagnose
from mr_ident.io.datafile import write_data
from mr_ident.io.modelfile import load_model, model_to_dict
from mr_ident.numerics.excitation.multisine import design
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.model import Model
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0, help="record seconds (300)")
    ap.add_argument("--repeat", type=int, default=1, help="diagnoses per case (best kept)")
    ap.add_argument("--cli", action="store_true", help="time the whole mr-ident process")
    args = ap.parse_args()
    keep_freed_memory()  # as the command line and the node do: no page faults per fit
    m = load_model(ROOT / "config" / "paper_example.yaml")
    m = replace(m, controller=TransferMatrix.siso([3000.0, -2700.0], [1.0, -0.3], 3 / 240.0))
    if args.cli:
        return whole_process(m, args.duration)
    cases = {
        "nothing hidden": m,
        "gain_error": replace(m, plant_gain=1.2),
        "additive_mode": replace(m, additive_modes=((90.0, 0.03, -5e-7, 0, 0),)),
        "mode_shift": replace(m, mode_changes=((55.4, 60.0, 0.04, 1.0),)),
        "series_lowpass": replace(m, series_dynamics=((30.0, 0.0, "output", 0),)),
        "controller_notch": replace(m, controller_notches=((20.0, 0.3, 0.1),)),
        "control_delay": replace(m, control_delay=2),
        "gain_error + input_delay": replace(m, plant_gain=1.2, input_delay=0.7 / 240),
        "controller_gain": replace(
            m, controller=TransferMatrix.siso([3750.0, -3375.0], [1.0, -0.3], 3 / 240.0)
        ),
    }
    y_std = simulate(m, duration=args.duration, rng=np.random.default_rng(0)).y.std()
    print(f"| hidden ({args.duration:g} s at 240 Hz, F = 3) | s per diagnosis | found |")
    print("| --- | ---: | --- |")
    times = []
    for name, true in cases.items():
        rec = simulate(
            replace(true, noise_std=0.02 * y_std),
            duration=args.duration,
            rng=np.random.default_rng(1),
        )
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            d = diagnose(m, rec)
            best = min(best, time.perf_counter() - t0)
        times.append(best)
        found = "; ".join(a.description for a in d.applied) or "nothing"
        print(f"| {name} | {best:.1f} | {found} |")
    print(f"\nmedian {np.median(times):.1f} s, worst {max(times):.1f} s per diagnosis")
    return 0


def _records(true: Model, r: np.ndarray, sat: float | None, seed: int) -> list:
    """Two records of ``true`` driven by the rows of ``r`` (realizations), noise 2 % of y."""
    rng = np.random.default_rng(seed)
    y_std = simulate(true, reference=r[0], noise=np.zeros((r.shape[1], 1))).y.std()
    out = []
    for k in range(2):
        v = 0.02 * y_std * rng.standard_normal((r.shape[1], 1))
        if sat is None:
            out.append(simulate(true, reference=r[k], noise=v))
        else:
            out.append(simulate_actuated(true, r[k], v, lambda u, dy: min(max(u, -sat), sat)))
    return out


def whole_process(m: Model, duration: float) -> int:
    """``mr-ident diagnose`` on files, timed as a process (module docstring)."""
    fs, F = m.fs_high, m.ratio
    N = int(round(duration * fs)) // F * F
    P = int(round(fs))  # 1 s periods
    white = np.random.default_rng(7).standard_normal((2, N, 1))
    ms = design(fs_high=fs, period=P, band=(fs / P, 0.45 * fs), kind="odd",
                periods=N // P, realizations=2, ratio=F, lifted=F > 1, seed=3)  # fmt: skip
    sigma_u = simulate(m, reference=white[0], noise=np.zeros((N, 1))).u.std()
    K125 = TransferMatrix.siso([3750.0, -3375.0], [1.0, -0.3], 3 / 240.0)
    cases = {
        "nothing hidden": (m, None),
        "gain_error 1.2": (replace(m, plant_gain=1.2), None),
        "controller gain 1.25": (replace(m, controller=K125), None),
        "saturation at rms u": (m, sigma_u),
    }
    exe = Path(sys.executable).with_name("mr-ident")
    print(f"| r ({duration:g} s at {fs:g} Hz, F = {F}) | hidden | wall s | CPU s | verdict |")
    print("| --- | --- | ---: | ---: | --- |")
    walls = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "m.yaml").write_text(json.dumps(model_to_dict(m)))
        for excitation, r, extra in (
            ("white", white, []),
            ("periodic", ms.r, ["--period", str(P)]),
        ):
            for name, (true, sat) in cases.items():
                recs = _records(true, r, sat, seed=11)
                files = [d / f"d{k}.npz" for k in range(2)]
                for f, rec in zip(files, recs, strict=True):
                    write_data(f, rec.r, rec.u, rec.y, fs_high=fs, ratio=F)
                cmd = [str(exe), "diagnose", str(d / "m.yaml"), str(files[0]), "--validate",
                       str(files[1]), "--json", str(d / "r.json"), "--quiet", *extra]  # fmt: skip
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                subprocess.run(cmd, check=True, capture_output=True)
                wall = time.perf_counter() - t0
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                verdict = json.loads((d / "r.json").read_text())["headline"]
                walls.append(wall)
                print(
                    f"| {excitation} | {name} | {wall:.1f} | {cpu:.1f} | {verdict} |", flush=True
                )
    print(f"\nmedian {np.median(walls):.1f} s, worst {max(walls):.1f} s per process")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
