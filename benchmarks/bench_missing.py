# SPDX-License-Identifier: Apache-2.0
"""Benchmark: missing samples as unknowns of the fit, against none dropped and interpolation.

The paper's loop (config/paper_example.yaml), F = 3, one white r (seed 0), output noise
std 7e-7 (as `make bench-structured`), `structured` with its default window (n auto).
Per run fresh noise and fresh holes: the same samples of u and y dropped (a lost message
holds both), separate bursts of 1..5 samples at random until 1 % (then 5 %) of the record.
Printed per case, over the runs:

* the median over runs of the median relative error of P_h over the bins
  (0, fs_high/2], and its ratio to the error with nothing dropped;
* spread/std: sqrt(median over bins of the empirical variance of P_hat over the runs /
  median over bins of the mean reported variance), and the median over the bins of the
  per-bin ratio;
* the median time of one `identify` call.

"interpolated" fills the holes by linear interpolation and identifies as if complete.
"r, u, y 1 % each" drops u and y as "1 % unknowns" and, independently, 1 % of r's samples
(single lost messages): r is recovered from the loop (u - r held, the controller's
equation) where its u came, and guessed where it was lost too.
Noise-free with 1 % holes: the median relative error of every LPM method (600 s).

    .venv/bin/python benchmarks/bench_missing.py [--runs 50] [--duration 600]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from mr_ident.io.modelfile import load_model
from mr_ident.numerics.identify import identify
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
NOISE = 7e-7
METHOD = "structured"


def drop(n_samples: int, share: float, rng: np.random.Generator, burst: int = 5) -> np.ndarray:
    """Separate bursts of 1..burst dropped samples at random, up to ``share`` of the record."""
    mask = np.zeros(n_samples, bool)
    while mask.mean() < share:
        start = int(rng.integers(1, n_samples - burst - 1))
        stop = start + int(rng.integers(1, burst + 1))
        if not mask[start - 1 : stop + 1].any():
            mask[start:stop] = True
    return mask


def interpolate(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """x with its masked samples replaced by linear interpolation between the kept ones."""
    out = x.copy()
    t = np.arange(x.shape[0])
    for c in range(x.shape[1]):
        out[mask, c] = np.interp(t[mask], t[~mask], x[~mask, c])
    return out


def case_data(
    sim, mask: np.ndarray | None, how: str, r_mask: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """r, u and y of one case: holes as NaN ("unknowns", "r too") or interpolated."""
    if mask is None:
        return sim.r, sim.u, sim.y
    if how in ("unknowns", "r too"):
        r, u, y = sim.r.copy(), sim.u.copy(), sim.y.copy()
        u[mask], y[mask] = np.nan, np.nan
        if how == "r too" and r_mask is not None:
            r[r_mask] = np.nan
        return r, u, y
    return sim.r, interpolate(sim.u, mask), interpolate(sim.y, mask)


def monte_carlo(runs: int, duration: float) -> None:
    model = replace(load_model(ROOT / "config" / "paper_example.yaml"), noise_std=NOISE)
    clean = simulate(
        replace(model, noise_std=0.0), duration=duration, rng=np.random.default_rng(0)
    )
    N = clean.n_samples
    truth = model.plant_frf(N)[1:, 0, 0]
    cases = [
        ("nothing dropped", None, "unknowns"),
        ("1 % unknowns", 0.01, "unknowns"),
        ("1 % interpolated", 0.01, "interpolated"),
        ("r, u, y 1 % each", 0.01, "r too"),
        ("5 % unknowns", 0.05, "unknowns"),
        ("5 % interpolated", 0.05, "interpolated"),
    ]
    est = {c[0]: [] for c in cases}
    var = {c[0]: [] for c in cases}
    secs = {c[0]: [] for c in cases}
    for run in range(runs):
        rng = np.random.default_rng(1000 + run)
        noise = NOISE * rng.standard_normal(clean.y.shape)
        # output noise enters y and, through the loop, u
        sim = simulate(model, reference=clean.r, noise=noise)
        masks = {share: drop(N, share, rng) for share in (0.01, 0.05)}
        r_mask = rng.random(N) < 0.01
        for name, share, how in cases:
            r, u, y = case_data(sim, None if share is None else masks[share], how, r_mask)
            t0 = time.perf_counter()
            res = identify(r, u, y, fs_high=model.fs_high, ratio=model.ratio, method=METHOD,
                           keep_lifted=False)  # fmt: skip
            secs[name].append(time.perf_counter() - t0)
            est[name].append(res.plant.response[:, 0, 0])
            var[name].append(res.plant.std[:, 0, 0] ** 2)
    base = None
    print(f"\nMonte Carlo: {runs} runs, {duration:g} s ({N} samples), noise {NOISE:g}, {METHOD}, "
          "n auto")  # fmt: skip
    print(f"{'case':18s} {'median rel. err':>16s} {'x none':>7s} {'spread/std':>11s} "
          f"{'per-bin median':>15s} {'time [s]':>9s}")  # fmt: skip
    for name, _, _ in cases:
        P = np.array(est[name])
        err = float(np.median(np.median(np.abs(P - truth) / np.abs(truth), axis=1)))
        base = err if base is None else base
        emp = np.var(P - truth, axis=0) * runs / (runs - 1)
        rep = np.mean(var[name], axis=0)
        ratio = float(np.sqrt(np.median(emp) / np.median(rep)))
        per_bin = float(np.median(np.sqrt(emp / rep)))
        print(f"{name:18s} {err:16.3e} {err / base:7.2f} {ratio:11.3f} {per_bin:15.3f} "
              f"{np.median(secs[name]):9.3f}")  # fmt: skip


def noise_free() -> None:
    base = load_model(ROOT / "config" / "paper_example.yaml")
    print("\nNoise-free, 600 s, 1 % dropped (bursts up to 5), n = 8: median relative error")
    print(f"{'method':12s} {'complete':>10s} {'with holes':>11s}")
    for method in ("freq-lifted", "structured", "time-lifted", "lpm"):
        model = base if method != "lpm" else replace(base, ratio=1)  # lpm is exact at F = 1
        sim = simulate(model, duration=600.0, rng=np.random.default_rng(1))
        truth = model.plant_frf(sim.n_samples)[1:, 0, 0]
        mask = drop(sim.n_samples, 0.01, np.random.default_rng(2))
        cells = []
        for m in (None, mask):
            r, u, y = case_data(sim, m, "unknowns")
            res = identify(r, u, y, fs_high=model.fs_high, ratio=model.ratio, method=method,
                           n=8)  # fmt: skip
            cells.append(np.median(np.abs(res.plant.response[:, 0, 0] - truth) / np.abs(truth)))
        print(f"{method:12s} {cells[0]:10.1e} {cells[1]:11.1e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--duration", type=float, default=600.0)
    args = ap.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f} ({os.cpu_count()} CPUs)")
    t0 = time.time()
    noise_free()
    monte_carlo(args.runs, args.duration)
    print(f"\nload average at end: {os.getloadavg()[0]:.2f}; {time.time() - t0:.0f} s in all")


if __name__ == "__main__":
    main()
