"""Benchmark: the paper's full size, identified with freq-lifted (P_h, std and PFG).

6000 s at 240 Hz (N = 1.44 M samples), F = 3, n = 8, R = 2. Runs our LPM engine and
a straightforward batched-QR numpy LPM through the same pipeline, in the same run,
and prints wall time, peak traced memory and their ratio. Also times the simulator.

    make bench            # or: .venv/bin/python benchmarks/bench_identify.py [--duration S]
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from pathlib import Path
from unittest import mock

import numpy as np

import sys
from mr_ident._parallel import resolve_workers
from mr_ident.identify import identify  # noqa: E402  (also loads the module patched below)
from mr_ident.model import load_model
from mr_ident.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def straightforward_lpm_core(Ua, Ya, n, degree, q, workers=1):
    """Reference engine: build every window's regressor, batched QR, solve. Bins-last out."""
    K = Ua.shape[0] - 2 * n
    ni = Ua.shape[1]
    L = 2 * n + 1
    r = np.arange(-n, n + 1) / n
    idx = np.arange(K)[:, None] + np.arange(L)[None, :]
    Uw = Ua[idx]                                                     # (K, L, ni)
    Yw = Ya[idx]                                                     # (K, L, no)
    cols = [Uw * (r ** s)[None, :, None] for s in range(degree + 1)]
    cols.append(np.broadcast_to((r[:, None] ** np.arange(degree + 1)).astype(complex), (K, L, degree + 1)))
    Km = np.concatenate(cols, axis=2)                                 # (K, L, p)
    Q, Rr = np.linalg.qr(Km)
    theta = np.linalg.solve(Rr, np.conj(np.swapaxes(Q, 1, 2)) @ Yw)   # (K, p, no)
    V = Yw - Km @ theta
    Cv = np.swapaxes(V, 1, 2) @ np.conj(V) / q
    Ri = np.linalg.inv(Rr)
    Ainv = (Ri @ np.conj(np.swapaxes(Ri, 1, 2)))[:, :ni, :ni]
    G = np.swapaxes(theta[:, :ni, :], 1, 2)
    return G.transpose(1, 2, 0), Cv.transpose(1, 2, 0), Ainv.transpose(1, 2, 0), 0


def measure(fn, repeat: int):
    """Best wall time of ``repeat`` untraced runs, then peak traced memory of one more run.

    Timing and memory are separate passes: tracemalloc slows allocation-heavy code.
    """
    best = np.inf
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return best, peak / 2**20, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=6000.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-reference", action="store_true", help="do not run the straightforward LPM")
    args = ap.parse_args()
    model = load_model(ROOT / "config" / "paper_example.yaml")
    t_sim, m_sim, sim = measure(lambda: simulate(model, duration=args.duration, rng=np.random.default_rng(0)),
                                args.repeat)
    N = sim.r.shape[0]
    K_low = model.controller_frf(N // 3)
    def run(workers=None):
        return identify(sim.r, sim.u, sim.y, fs_high=240.0, ratio=3, controller_low=K_low,
                        keep_lifted=False, workers=workers)

    identify(sim.r[:3000], sim.u[:3000], sim.y[:3000], fs_high=240.0, ratio=3)   # warm-up
    t_ours, m_ours, res = measure(run, args.repeat)
    t_one, m_one, _ = measure(lambda: run(1), args.repeat)
    truth = model.plant_frf(N)[1:]
    err = np.median(np.abs(res.plant.response - truth) / np.abs(truth))
    print(f"N = {N} samples ({args.duration:g} s at 240 Hz), F = 3, n = 8, R = 2")
    print(f"simulate              {t_sim:7.3f} s   peak {m_sim:7.1f} MB")
    print(f"identify freq-lifted  {t_ours:7.3f} s   peak {m_ours:7.1f} MB   (P_h, std, PFG; median rel. error {err:.1e}; "
          f"{resolve_workers(None)} threads)")
    print(f"  same, one thread    {t_one:7.3f} s   peak {m_one:7.1f} MB")
    if not args.skip_reference:
        with mock.patch.object(sys.modules["mr_ident.identify"], "_lpm_core", straightforward_lpm_core):
            t_ref, m_ref, ref = measure(lambda: run(1), 1)
        d = np.max(np.abs(ref.plant.response - res.plant.response) / np.abs(truth))
        print(f"straightforward QR    {t_ref:7.3f} s   peak {m_ref:7.1f} MB   (one thread; max rel. difference to ours {d:.1e})")
        print(f"speed-up ratio        {t_ref / t_ours:7.1f} x   ({t_ref / t_one:.1f} x on one thread each)")


if __name__ == "__main__":
    main()
