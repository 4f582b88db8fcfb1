# SPDX-License-Identifier: Apache-2.0
"""Benchmark: where the PFG from data and P_h from a low-rate y reach 1e-4, noise-free.

Seeded random loops (``scenarios.draw_loop`` at 240/500 Hz; F in {2, 3, 5} for the PFG,
{2, 3} for a low-rate y, taken at q = 0), noise-free, ``--duration`` s each. Per local
model (polynomial R = 2, the default; rational R = 2; rational R = 3), the fraction of
the bins (0, fs_high/2] within 1e-4 relative of the exact value, per decade of the alias
range rho (:mod:`mr_ident.numerics.lifted.alias_range`), and the median of error / rho. Bins
where the exact value is not finite are left out (the multiples of fs_low with an
integrating controller or plant), and for a low-rate y with an integrating controller
the multiples of fs_low themselves (S(0) is singular there: the indirect step has no
estimate).

``--steady`` simulates the record as the last of 20 periods of a periodic r (no
transient): the same figures, so the transient is not the cause.

    .venv/bin/python benchmarks/bench_alias_range.py [--loops 10] [--duration 60] [--steady]
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace

import numpy as np

from mr_bench.scenarios import draw_loop
from mr_ident.numerics.identify import default_n, identify
from mr_ident.numerics.lifted.alias_range import pfg_alias_range, row_alias_range
from mr_ident.numerics.lifted.pfg import pfg_of_model
from mr_ident.numerics.signals import LoopData
from mr_ident.numerics.systems.simulate import simulate

CONFIGS = (("polynomial", 2), ("rational", 2), ("rational", 3))
DECADES = range(0, 8)


def record(seed: int, ratios: tuple[int, ...], duration: float, steady: bool):
    loop = draw_loop(
        np.random.default_rng(seed), duration=duration, fs_choices=(240.0, 500.0), ratios=ratios
    )
    model = replace(loop.nominal, noise_std=0.0)
    r = loop.reference
    if not steady:
        return loop, model, simulate(model, reference=r, noise=np.zeros_like(r))
    P, N = 20, r.shape[0]
    big = simulate(model, reference=np.tile(r, (P, 1)), noise=np.zeros((P * N, 1)))
    return loop, model, LoopData(big.r[-N:], big.u[-N:], big.y[-N:], model.fs_high, model.ratio)


def pfg_errors(seed: int, local: str, degree: int, duration: float, steady: bool):
    """Relative error of the PFG from data and rho on the bins where the model's is finite."""
    _, model, sim = record(seed, (2, 3, 5), duration, steady)
    N = sim.r.shape[0]
    res = identify(sim.r, sim.u, sim.y, fs_high=model.fs_high, ratio=model.ratio,
                   local=local, degree=degree, keep_lifted=False)  # fmt: skip
    truth = pfg_of_model(model, N).gain
    rho = pfg_alias_range(model, N, default_n("freq-lifted", degree, model.ratio, 1, 1, local))
    ok = np.isfinite(truth) & np.isfinite(rho)
    return (np.abs(res.pfg_data.gain - truth) / truth)[ok], rho[ok]


def slow_errors(seed: int, local: str, degree: int, duration: float, steady: bool):
    """Relative error of P_h from y at the low rate and rho of its lifted row."""
    loop, model, sim = record(seed, (2, 3), duration, steady)
    F, N = model.ratio, sim.r.shape[0]
    res = identify(sim.r, sim.u, sim.y[::F], fs_high=model.fs_high, ratio=F,
                   local=local, degree=degree, keep_lifted=False)  # fmt: skip
    P = model.plant_frf(N)
    rho = row_alias_range(P, F, N, default_n("freq-lifted", degree, F, 1, 1, local))
    truth = P[1:, 0, 0]
    ok = np.isfinite(truth) & np.isfinite(rho)
    if loop.controller_kind in ("pi", "pid"):
        ok &= np.arange(1, N // 2 + 1) % (N // F) != 0
    return (np.abs(res.plant.response[:, 0, 0] - truth) / np.abs(truth))[ok], rho[ok]


def table(name: str, fn, seeds: range, duration: float, steady: bool) -> None:
    print(
        f"\n{name}: fraction of the bins within 1e-4 [bins; median error / rho] per decade of rho"
    )
    print(f"{'rho':>10s} " + " ".join(f"{f'{lo}-{d}':>31s}" for lo, d in CONFIGS))
    runs = {c: [fn(s, *c, duration, steady) for s in seeds] for c in CONFIGS}
    joined = {c: tuple(np.concatenate(x) for x in zip(*runs[c], strict=True)) for c in CONFIGS}
    for lo in DECADES:
        cells = []
        for c in CONFIGS:
            rel, rho = joined[c]
            sel = (rho >= 10**lo) & (rho < 10 ** (lo + 1))
            cells.append(
                f"{np.mean(rel[sel] <= 1e-4):.4f} [{int(sel.sum()):5d}; "
                f"{np.median(rel[sel] / rho[sel]):7.1e}]"
                if sel.any()
                else "-"
            )
        print(f"{f'1e{lo}..1e{lo + 1}':>10s} " + " ".join(f"{c:>31s}" for c in cells))
    for c in CONFIGS:
        rel, rho = joined[c]
        per_loop = [float(np.mean(e <= 1e-4)) for e, _ in runs[c]]
        reach = [float(np.min(r[e > 1e-4], initial=np.inf)) for e, r in runs[c]]
        print(f"{c[0]}-{c[1]}: all bins {np.mean(rel <= 1e-4):.4f} within 1e-4 (per loop "
              f"{min(per_loop):.3f}..{max(per_loop):.3f}), median {np.median(rel):.1e}; "
              f"least rho beyond 1e-4 {min(reach):.1e}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loops", type=int, default=10)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--steady", action="store_true")
    a = ap.parse_args()
    warnings.simplefilter("ignore", RuntimeWarning)  # the model's PFG at DC aliases
    t0 = time.perf_counter()
    seeds = range(a.loops)
    what = "steady state" if a.steady else "one record"
    print(f"{a.loops} loops, {a.duration:g} s, noise-free, {what}")
    table("PFG from data", pfg_errors, seeds, a.duration, a.steady)
    table("P_h from a low-rate y", slow_errors, seeds, a.duration, a.steady)
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
