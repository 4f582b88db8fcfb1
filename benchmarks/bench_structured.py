# SPDX-License-Identifier: Apache-2.0
"""Benchmark: accuracy of every LPM method, fixed window (n = 8) and automatic (n = auto).

1. The paper's loop (config/paper_example.yaml), 600 s at 240 Hz, F = 3, white r, seeds
   0, 1, 2, noise-free and with output noise (std 7e-7 by default): the median over the
   bins (0, fs_high/2] of |P_h - P_hat| / |P_h|, per method and window, the median over
   the seeds.
2. Seeded random loops (mr_bench.scenarios.draw_loop: fs_high 240..1000 Hz,
   F in {2, 3, 5}, plants of order 2-6, SNR 20-60 dB), 120 s each: the same error per
   loop; printed: the median over loops of each method's error relative to lpm's with
   the fixed window, and how often structured beats lpm (both n auto).

"fixed" is the default rule's window (n = None: 8 up to F = 3, 12 at F = 5).
3. Honesty of the reported std (structured and freq-lifted, n = 8 and auto, paper's
   loop): 50 runs with one r and fresh noise; sqrt(median empirical variance / median
   reported variance) over the bins, and the median over the bins of the per-bin ratio.

    .venv/bin/python benchmarks/bench_structured.py [--loops 24] [--runs 50]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mr_bench.scenarios import draw_loop
from mr_ident.io.modelfile import load_model
from mr_ident.numerics.identify import identify
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("freq-lifted", "time-lifted", "lpm", "structured")
WINDOWS = (None, "auto")  # None: the default rule's fixed window (8 up to F = 3)


def errors(model, sim) -> dict[tuple[str, object], float]:
    """Median relative error of every method and window on one record."""
    truth = model.plant_frf(sim.n_samples)[1:]
    out = {}
    for m in METHODS:
        for w in WINDOWS:
            res = identify(sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=model.ratio,
                           method=m, n=w, keep_lifted=False)  # fmt: skip
            e = np.abs(res.plant.response - truth).max(axis=(1, 2))
            out[m, w] = float(np.nanmedian(e / np.abs(truth).max(axis=(1, 2))))
    return out


def paper_table(noise: float) -> None:
    model = load_model(ROOT / "config" / "paper_example.yaml")
    print("\n1. Paper's loop, 600 s, F = 3, median relative error of P_h, median of seeds 0-2")
    print(f"{'method':14s} {'noise-free n=8':>15s} {'n auto':>10s} "
          f"{f'noise {noise:g} n=8':>18s} {'n auto':>10s}")  # fmt: skip
    table = {}
    for std in (0.0, noise):
        runs = [
            errors(
                model,
                simulate(
                    replace(model, noise_std=std), duration=600.0, rng=np.random.default_rng(seed)
                ),
            )  # fmt: skip
            for seed in range(3)
        ]
        for key in runs[0]:
            table[std, key] = np.median([r[key] for r in runs])
    for m in METHODS:
        cells = [table[std, (m, w)] for std in (0.0, noise) for w in WINDOWS]
        print(f"{m:14s} {cells[0]:15.2e} {cells[1]:10.2e} {cells[2]:18.4f} {cells[3]:10.4f}")


def random_loops(count: int) -> None:
    print(f"\n2. {count} random loops, 120 s each, at their SNR (20-60 dB) and noise-free")
    rng = np.random.default_rng(2024)
    rel = {(noisy, k): [] for noisy in (False, True) for k in [(m, w) for m in METHODS
                                                              for w in WINDOWS]}  # fmt: skip
    wins = {False: 0, True: 0}
    for _ in range(count):
        loop = draw_loop(rng, duration=120.0, ratios=(2, 3, 5))
        for noisy in (False, True):
            model = loop.nominal if noisy else replace(loop.nominal, noise_std=0.0)
            sim = simulate(model, reference=loop.reference, rng=np.random.default_rng(1))
            e = errors(model, sim)
            for k, v in e.items():
                rel[noisy, k].append(v / e["lpm", None])
            wins[noisy] += e["structured", "auto"] <= e["lpm", "auto"]
    print(f"{'median error / lpm fixed':24s} {'noise-free fixed':>16s} {'n auto':>10s} "
          f"{'noisy fixed':>12s} {'n auto':>10s}")  # fmt: skip
    for m in METHODS:
        cells = [np.median(rel[noisy, (m, w)]) for noisy in (False, True) for w in WINDOWS]
        print(f"{m:24s} {cells[0]:16.3g} {cells[1]:10.3g} {cells[2]:12.3g} {cells[3]:10.3g}")
    print(f"structured auto <= lpm auto on {wins[False]}/{count} loops noise-free, "
          f"{wins[True]}/{count} noisy")  # fmt: skip


def honesty(runs: int, noise: float) -> None:
    model = replace(load_model(ROOT / "config" / "paper_example.yaml"), noise_std=noise)
    for method in ("structured", "freq-lifted"):  # freq-lifted: its widest window strided
        rng = np.random.default_rng(11)
        r = rng.standard_normal((3 * 20000, 1))  # 250 s
        print(f"\n3. Reported std, {method}, {runs} runs of 250 s, one r, fresh noise {noise:g}")
        for w in (8, "auto"):
            est, var = [], []
            for _ in range(runs):
                sim = simulate(model, reference=r, rng=rng)
                res = identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, method=method, n=w)
                est.append(res.plant.response[:, 0, 0])
                var.append(res.plant.std[:, 0, 0] ** 2)
            emp = np.var(np.array(est), axis=0, ddof=1)
            rep = np.mean(var, axis=0)
            ratio = np.sqrt(np.median(emp) / np.median(rep))
            print(f"n={w!s:5s} spread / reported std: {ratio:.3f} "
                  f"(per bin, median {np.median(np.sqrt(emp / rep)):.3f})")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--noise", type=float, default=7e-7)
    ap.add_argument("--loops", type=int, default=24)
    ap.add_argument("--runs", type=int, default=50)
    args = ap.parse_args()
    t0 = time.perf_counter()
    paper_table(args.noise)
    if args.loops:
        random_loops(args.loops)
    if args.runs:
        honesty(args.runs, args.noise)
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
