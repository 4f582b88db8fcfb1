# SPDX-License-Identifier: Apache-2.0
"""Speed of one diagnosis of a 5-minute record: 300 s of 240 Hz data (72 000 samples).

The paper's plant (config/paper_example.yaml) under a softer lead controller (half gain),
F = 3, white r, output noise 2 % of y's std, and one case per effect: nothing hidden, a gain
change, an additive mode, a moved mode, a sensor low-pass, a controller notch, a control
delay, a gain change with an input delay at once, and the controller's gain 1.25 times
the model's. Prints the seconds per diagnosis
(whole ``diagnose``: identification, evidence, selection, validation) and what was found.

    .venv/bin/python benchmarks/bench_diagnose_speed.py [--duration 300] [--repeat 1]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mr_ident.diagnosis import diagnose
from mr_ident.io.modelfile import load_model
from mr_ident.numerics.systems.lti import TransferMatrix
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=300.0, help="record seconds (300)")
    ap.add_argument("--repeat", type=int, default=1, help="diagnoses per case (best kept)")
    args = ap.parse_args()
    m = load_model(ROOT / "config" / "paper_example.yaml")
    m = replace(m, controller=TransferMatrix.siso([3000.0, -2700.0], [1.0, -0.3], 3 / 240.0))
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


if __name__ == "__main__":
    raise SystemExit(main())
