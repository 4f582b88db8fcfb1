# SPDX-License-Identifier: Apache-2.0
"""False alarms of the plant monitoring: the loop as modelled, watched over a long run.

One long record of each loop (the paper's plant at 34 dB SNR, and loops drawn at random by
``mr_bench.scenarios.draw_loop`` at 240 Hz) is cut into the windows the node would
identify (``window_s`` long, one every ``update_period_s``: overlapping, as live), each held
against the loop's own model by :class:`~mr_ident.diagnosis.monitoring.monitor.PlantWatch` at
``monitor_alpha`` = 0.01. Prints, per loop, the estimates, those with a significant bin
(per-estimate false alarms; alpha bounds their rate), and the times the held status left
OK (``monitor_hold`` = 3).

    .venv/bin/python benchmarks/bench_monitor.py [--seconds 600] [--loops 4]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mr_bench.scenarios import draw_loop
from mr_ident.diagnosis.monitoring.drift import Reference
from mr_ident.diagnosis.monitoring.monitor import PlantWatch
from mr_ident.io.config import IdentConfig
from mr_ident.io.modelfile import load_model
from mr_ident.live.estimate import estimate
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.model import Model
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def watch(model: Model, seconds: float, seed: int, window_s: float, step_s: float) -> dict:
    """Watch ``seconds`` of ``model``'s loop against itself; counts."""
    sim = simulate(model, duration=seconds, rng=np.random.default_rng(seed))
    cfg = IdentConfig(
        fs_high=model.fs_high,
        ratio=model.ratio,
        window_s=window_s,
        min_window_s=window_s,
        update_period_s=step_s,
        monitor_model="m",
    )
    w = PlantWatch(Reference.of_model(model), None, cfg)
    F, N = model.ratio, sim.r.shape[0]
    step = F * max(1, round(step_s * model.fs_high / F))
    raw = held = 0
    n = 0
    for end in range(cfg.window_samples, N + 1, step):
        s0 = end - cfg.window_samples
        win = LoopData(sim.r[s0:end], sim.u[s0:end], sim.y[s0:end], ratio=F, first=s0)
        st = w.observe(estimate(win, cfg))
        raw += st.raw_level != "ok"
        held += st.changed and st.level != "ok"
        n += 1
    return {"estimates": n, "raw": raw, "alarms": held}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="record per loop (600)")
    ap.add_argument("--loops", type=int, default=4, help="random loops besides the paper's (4)")
    ap.add_argument("--window", type=float, default=20.0, help="window_s (20)")
    ap.add_argument("--step", type=float, default=2.0, help="update_period_s (2)")
    args = ap.parse_args()
    paper = load_model(ROOT / "config" / "paper_example.yaml")
    y = simulate(paper, duration=20.0, rng=np.random.default_rng(0)).y
    loops = {"paper (34 dB)": replace(paper, noise_std=0.02 * float(np.std(y)))}
    for k in range(args.loops):
        lp = draw_loop(np.random.default_rng(500 + k), duration=20.0, fs_choices=(240.0,))
        desc = f"random {k} (F={lp.nominal.ratio}, {lp.form}, {lp.snr_db:.0f} dB)"
        loops[desc] = lp.nominal
    print("| loop | estimates | with a significant bin | status left OK | s |")
    print("|---|---:|---:|---:|---:|")
    tot = {"estimates": 0, "raw": 0, "alarms": 0}
    for k, (name, m) in enumerate(loops.items()):
        t0 = time.perf_counter()
        c = watch(m, args.seconds, 900 + k, args.window, args.step)
        tot = {key: tot[key] + c[key] for key in tot}
        print(
            f"| {name} | {c['estimates']} | {c['raw']} | {c['alarms']} "
            f"| {time.perf_counter() - t0:.0f} |"
        )
    rate = tot["raw"] / max(tot["estimates"], 1)
    print(f"| all | {tot['estimates']} | {tot['raw']} ({100 * rate:.1f} %) | {tot['alarms']} | |")
    print(
        f"\n{args.seconds:g} s per loop, window {args.window:g} s every {args.step:g} s "
        "(overlapping), monitor_alpha 0.01, monitor_hold 3."
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
