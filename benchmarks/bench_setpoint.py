# SPDX-License-Identifier: Apache-2.0
"""Benchmark: r at the setpoint against r at the plant input, and Welch's indirect estimate.

The paper's loop (config/paper_example.yaml), F = 3, 600 s records. Both experiments put
the same power into the plant input: the setpoint is white with std 1 (y in its units,
as it tracks it); r at the plant input is white with the std that gives the same rms of u
(measured noise-free on one record). Output noise std 0.02 (0 for the noise-free rows).
Per run fresh r and noise.

Printed per band of the high-rate axis (below fs_low/2; fs_low/2 to fs_low; fs_low to
fs_high/2; the bins within 1 Hz of a hold's zero, i.e. of a multiple of fs_low, are a band
of their own and left out of the others):

* the median over runs of the median relative error |P_hat - P_h| / |P_h| in the band, for
  the plant-input identification (freq-lifted, n auto), the setpoint identification
  (identify with injection "setpoint", n auto), and Welch's indirect estimate
  ``S_ry / S_ru`` of the setpoint data at its best segment length for the band (the best
  of 300, 600, 1200 and 2400 samples, chosen per band on the medians: an oracle's choice);
* spread/std of the setpoint estimate: sqrt(mean over the band's bins of the empirical
  variance of P_hat over the runs / the mean reported variance);
* the median time of one identification of either kind (same process, alternating).

``--sums`` prints instead the time of the LPM's moment sums of one chunk (4096 bins, the four
kernels of a SISO setpoint fit, R = 2) per window half-width n: by the Toeplitz route alone
and by the route the cost rule picks (doubling for wide windows); the least CPU time of the
thread over 15 repetitions, one BLAS thread (robust to other work on the machine).

    .venv/bin/python benchmarks/bench_setpoint.py [--runs 50] [--duration 600] [--sums]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import signal

from mr_ident.io.modelfile import load_model
from mr_ident.numerics.identify import identify
from mr_ident.numerics.systems.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]
NOISE = 0.02
SEGMENTS = (300, 600, 1200, 2400)


def bands(f: np.ndarray, fs_low: float, fs_high: float) -> dict[str, np.ndarray]:
    """Masks of the frequencies ``f`` per band (see the module docstring)."""
    near = np.minimum(f % fs_low, fs_low - f % fs_low) <= 1.0
    near &= f > 1.0
    return {
        f"0-{fs_low / 2:g} Hz": (f < fs_low / 2) & ~near & (f > 0),
        f"{fs_low / 2:g}-{fs_low:g} Hz": (f >= fs_low / 2) & (f < fs_low) & ~near,
        f"{fs_low:g}-{fs_high / 2:g} Hz": (f >= fs_low) & ~near,
        "within 1 Hz of a hold zero": near,
    }


def welch(r: np.ndarray, u: np.ndarray, y: np.ndarray, fs: float, nper: int):
    """Welch's indirect estimate S_ry / S_ru on its own frequency grid."""
    fw, Sry = signal.csd(r[:, 0], y[:, 0], fs=fs, nperseg=nper)
    _, Sru = signal.csd(r[:, 0], u[:, 0], fs=fs, nperseg=nper)
    return fw, Sry / Sru


def sums_table(bins: int = 4096, repeats: int = 15) -> None:
    """The moment sums' time per half-width: the Toeplitz route against the chosen one."""
    from threadpoolctl import threadpool_limits

    from mr_ident.numerics.local import window_sums as ws

    rng = np.random.default_rng(0)

    def least(job) -> float:
        best = np.inf
        for _ in range(repeats):
            t0 = time.thread_time()
            job()
            best = min(best, time.thread_time() - t0)
        return best

    print(f"# moment sums of {bins} bins (ms of CPU); load {os.getloadavg()[0]:.1f} at the start")
    print("| n | Toeplitz | chosen | routes |")
    print("| --- | --- | --- | --- |")
    with threadpool_limits(1):
        for n in (8, 12, 18, 27, 41, 62, 93, 140, 210, 315, 473, 710):
            width = bins + 2 * n
            old = new = 0.0
            used = []
            # conj(U) U, conj(U) (1 signal each); conj(U) Y, Y (2 each): a SISO setpoint fit
            for kernel, C in zip(ws.kernels(n, 2)[1:], (1, 1, 2, 2), strict=True):
                Z = rng.standard_normal((C, width)) + 1j * rng.standard_normal((C, width))
                old += least(lambda Z=Z, k=kernel: ws._toeplitz_sums(Z, k, bins))
                new += least(lambda Z=Z, k=kernel: ws.window_sums(Z, k, bins))
                used.append(ws.route(kernel, bins))
            print(f"| {n} | {1e3 * old:.2f} | {1e3 * new:.2f} | {', '.join(sorted(set(used)))} |")
    print(f"\nload {os.getloadavg()[0]:.1f} at the end")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--sums", action="store_true", help="time the moment sums per n instead")
    args = ap.parse_args()
    if args.sums:
        sums_table()
        return
    base = load_model(ROOT / "config" / "paper_example.yaml")
    fs, F = base.fs_high, base.ratio
    plant_in = replace(base, injection="plant_input")
    setpoint = replace(base, injection="setpoint")
    rng = np.random.default_rng(0)
    probe = simulate(plant_in, duration=60.0, rng=rng)
    probe_sp = simulate(setpoint, duration=60.0, rng=rng)
    scale = float(np.std(probe_sp.u) / np.std(probe.u))  # equal rms of u
    plant_in = replace(plant_in, reference_std=scale)
    print(
        f"# {args.runs} runs of {args.duration:g} s, noise {NOISE}; r at the plant input with "
        f"std {scale:.4g}: the rms of u of a unit setpoint; {os.cpu_count()} CPUs, load "
        f"{os.getloadavg()[0]:.1f} at the start"
    )
    N = int(round(args.duration * fs / F)) * F
    P = base.plant_frf(N)[1:, 0, 0]
    f = np.arange(1, N // 2 + 1) * fs / N
    masks = bands(f, fs / F, fs)
    for noise in (0.0, NOISE):
        runs = args.runs if noise else 3
        err_pi, err_sp, est_sp, var_sp, t_pi, t_sp = [], [], [], [], [], []
        err_w = {n: [] for n in SEGMENTS}
        for i in range(runs):
            g = np.random.default_rng(1000 + i)
            a = simulate(replace(plant_in, noise_std=noise), n_samples=N, rng=g)
            b = simulate(replace(setpoint, noise_std=noise), n_samples=N, rng=g)
            t0 = time.perf_counter()
            ra = identify(a.r, a.u, a.y, fs_high=fs, ratio=F)
            t1 = time.perf_counter()
            rb = identify(b.r, b.u, b.y, fs_high=fs, ratio=F, injection="setpoint")
            t2 = time.perf_counter()
            t_pi.append(t1 - t0)
            t_sp.append(t2 - t1)
            err_pi.append(np.abs(ra.plant.response[:, 0, 0] - P) / np.abs(P))
            err_sp.append(np.abs(rb.plant.response[:, 0, 0] - P) / np.abs(P))
            est_sp.append(rb.plant.response[:, 0, 0])
            var_sp.append(rb.plant.std[:, 0, 0] ** 2)
            for nper in SEGMENTS:
                fw, Pw = welch(b.r, b.u, b.y, fs, nper)
                Pt = base.plant_discrete().freqresp(fw)[:, 0, 0]
                err_w[nper].append((fw, np.abs(Pw - Pt) / np.abs(Pt)))
        print(f"\n## noise {noise:g} ({runs} runs)\n")
        print(
            "| band | plant input | setpoint | Welch, setpoint data (best segment) "
            "| setpoint spread/std |"
        )
        print("| --- | --- | --- | --- | --- |")
        spread = np.var(np.array(est_sp), axis=0)
        reported = np.mean(np.array(var_sp), axis=0)
        for name, m in masks.items():
            e_pi = np.median([np.nanmedian(e[m]) for e in err_pi])
            e_sp = np.median([np.nanmedian(e[m]) for e in err_sp])
            best = None
            for nper in SEGMENTS:
                vals = []
                for fw, e in err_w[nper]:
                    mw = bands(fw, fs / F, fs)[name]
                    if mw.any():
                        vals.append(np.nanmedian(e[mw]))
                if vals:
                    v = float(np.median(vals))
                    if best is None or v < best[0]:
                        best = (v, nper)
            welch_txt = "-" if best is None else f"{best[0]:.3g} ({best[1]})"
            ok = m & np.isfinite(reported) & (reported > 0)
            ratio = np.sqrt(np.mean(spread[ok]) / np.mean(reported[ok])) if noise else np.nan
            print(
                f"| {name} | {e_pi:.3g} | {e_sp:.3g} | {welch_txt} | "
                f"{'-' if not noise else f'{ratio:.3f}'} |"
            )
        print(
            f"\nidentify, median of {runs}: plant input {np.median(t_pi):.3f} s, setpoint "
            f"{np.median(t_sp):.3f} s (ratio {np.median(t_sp) / np.median(t_pi):.2f}); load "
            f"{os.getloadavg()[0]:.1f} at the end"
        )


if __name__ == "__main__":
    main()
