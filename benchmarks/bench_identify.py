# SPDX-License-Identifier: Apache-2.0
"""Benchmark: the paper's full size, identified with freq-lifted and structured (P_h, std, PFG).

First the default path as a user meets it: the whole process ``mr-ident identify DATA.npz
--model config/paper_example.yaml --out R.npz`` (default options: freq-lifted, n = auto),
and with ``--n 8``, wall time and peak resident memory, best of ``--repeat``, beside the
straightforward reference's identification time. Then in-process:
6000 s at 240 Hz (N = 1.44 M samples), F = 3, n = 8, R = 2 (and both methods once more
with n = auto: the candidates on a probe, then one fit; freq-lifted also with the local
rational model, n = 8).
Runs our LPM engine and
a straightforward batched-QR numpy LPM (J and S fitted separately, as two LPMs; also
with one QR for both) through the same pipeline, in the same run, interleaved, and
prints wall time, peak traced memory and their ratio. Also times the simulator, and the
same N at F = 5 and F = 10 (the low rate kept at 80 Hz, the high rate 80 F Hz; the default
window n), where the lifted unknowns grow with F: time grows about as F^2 (Q^3 per bin,
Q ~ F, over N/F bins) while the chunk sizes keep the memory flat.

    make bench            # or: .venv/bin/python benchmarks/bench_identify.py [--duration S]
"""

from __future__ import annotations

import argparse
import functools
import os
import subprocess
import sys
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path
from unittest import mock

import numpy as np

from mr_ident.allocator import keep_freed_memory
from mr_ident.io.modelfile import load_model
from mr_ident.numerics.identify import default_n, identify  # (also loads the module patched below)
from mr_ident.numerics.systems.simulate import simulate
from mr_ident.numerics.threads import resolve_workers

ROOT = Path(__file__).resolve().parents[1]


def _straightforward_fit(Ua, Yg, n, degree):
    """One LPM the straightforward way: every window's regressor, batched QR, solve."""
    K = Ua.shape[0] - 2 * n
    L = 2 * n + 1
    r = np.arange(-n, n + 1) / n
    idx = np.arange(K)[:, None] + np.arange(L)[None, :]
    Uw = Ua[idx]  # (K, L, ni)
    Yw = Yg[idx]  # (K, L, no)
    cols = [Uw * (r**s)[None, :, None] for s in range(degree + 1)]
    cols.append(
        np.broadcast_to((r[:, None] ** np.arange(degree + 1)).astype(complex), (K, L, degree + 1))
    )
    Km = np.concatenate(cols, axis=2)  # (K, L, p)
    Q, Rr = np.linalg.qr(Km)
    theta = np.linalg.solve(Rr, np.conj(np.swapaxes(Q, 1, 2)) @ Yw)  # (K, p, no)
    return theta, Yw - Km @ theta, Rr


def straightforward_lpm_core(
    Ua, Ya, n, degree, q, workers=1, centres=None, offsets=0, *, split=None
):
    """Reference engine, bins-last out like ours. ``split``: fit outputs ``[:split]`` (J, r -> y)
    and ``[split:]`` (S, r -> u) as two LPMs, as a straightforward implementation of the
    indirect method does; None: one QR for both (the structure ours also exploits).
    ``centres``: every centre fitted, those kept. ``offsets`` h: each bin takes the window
    of its group's centre (``mr_ident.numerics.local.strided.groups``), its polynomial
    evaluated at the bin's offset, as the automatic window's strided fits do."""
    ni = Ua.shape[1]
    groups = [Ya] if split is None else [Ya[:, :split], Ya[:, split:]]
    fits = [_straightforward_fit(Ua, Yg, n, degree) for Yg in groups]
    theta = np.concatenate([f[0] for f in fits], axis=2)  # (K, p, no), rows (s, i), then T
    V = np.concatenate([f[1] for f in fits], axis=2)
    Rr = fits[0][2]
    Cv = np.swapaxes(V, 1, 2) @ np.conj(V) / q
    Ri = np.linalg.inv(Rr)
    Ai = Ri @ np.conj(np.swapaxes(Ri, 1, 2))  # (K^H K)^-1 of every window
    req = np.arange(theta.shape[0]) if centres is None else np.asarray(centres)
    if offsets:
        from mr_ident.numerics.local.strided import groups as cut

        solved, owner, off = cut(req, offsets)
        win = solved[owner]
    else:
        win, off = req, np.zeros(req.size)
    Xs = (off / n)[:, None] ** np.arange(degree + 1)[None, :]  # (K, R+1)
    w = np.zeros((req.size, theta.shape[1], ni))
    for s_ in range(degree + 1):
        w[:, s_ * ni : (s_ + 1) * ni, :] = Xs[:, s_, None, None] * np.eye(ni)
    G = np.swapaxes(np.swapaxes(w, 1, 2) @ theta[win], 1, 2)  # (K, no, ni)
    Ainv = np.swapaxes(w, 1, 2) @ Ai[win] @ w
    out = (G.transpose(1, 2, 0), Cv[win].transpose(1, 2, 0), Ainv.transpose(1, 2, 0))
    return (*out, 0)


def best_times(fns: dict, repeat: int) -> tuple[dict, dict]:
    """Best wall time of ``repeat`` untraced runs of each function, the runs interleaved
    (a, b, c, a, b, c, ...) so that a slow phase of a shared machine hits all alike;
    also the last result of each."""
    best = {k: np.inf for k in fns}
    out = {}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            out[k] = fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best, out


def peak_mb(fn) -> float:
    """Peak traced memory of one run (separate from timing: tracemalloc slows allocation)."""
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 2**20


#: Runs one command and prints its wall time (s) and peak resident memory (KB). The command
#: is started from this small process, not from the benchmark: a child's peak resident size
#: counts the memory of the process it was forked from (Linux records the forked copy's
#: high-water mark at exec), so started from the benchmark, holding the simulated record,
#: every command read about 370 MB whatever it used.
_SPAWN = """
import os, subprocess, sys, time
t0 = time.perf_counter()
proc = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)  # its stderr: ours
_, status, usage = os.wait4(proc.pid, 0)
dt = time.perf_counter() - t0
if status != 0:
    sys.exit(f"exit status {status}")
print(dt, usage.ru_maxrss)
"""


def whole_process(data: Path, out: Path, extra: list[str], repeat: int) -> tuple[float, float]:
    """Best wall time (s) and the largest peak resident memory (MB) of ``mr-ident identify``."""
    exe = Path(sys.executable).with_name("mr-ident")
    cmd = [str(exe), "identify", str(data), "--model", str(ROOT / "config" / "paper_example.yaml")]
    cmd += ["--out", str(out), *extra]
    # as installed: the modules' bytecode cached (pip compiles it on install; an editable
    # install writes it on first import unless PYTHONDONTWRITEBYTECODE forbids it)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    best, peak = np.inf, 0.0
    for _ in range(repeat):
        run = subprocess.run(
            [sys.executable, "-c", _SPAWN, *cmd], capture_output=True, text=True, env=env
        )
        if run.returncode != 0:
            raise SystemExit(f"error: {' '.join(cmd)} failed: {run.stderr}")
        dt, kb = run.stdout.split()
        best, peak = min(best, float(dt)), max(peak, float(kb) / 1024)
    return best, peak


def default_path(sim, args) -> dict[str, tuple[float, float]]:
    """The whole command at its defaults and with --n 8, runs interleaved."""
    work = ROOT / "out" / "bench"
    work.mkdir(parents=True, exist_ok=True)
    data = work / "paper_6000s.npz"
    np.savez(data, r=sim.r, u=sim.u, y=sim.y, fs_high=240.0, ratio=3)
    runs: dict[str, tuple[float, float]] = {}
    whole_process(data, work / "result.npz", ["--n", "8"], 1)  # warm-up: bytecode, page cache
    for _ in range(args.repeat):  # interleaved, one run each per round
        for key, extra in (("default", []), ("n8", ["--n", "8"])):
            t, m = whole_process(data, work / "result.npz", extra, 1)
            old = runs.get(key, (np.inf, 0.0))
            runs[key] = (min(old[0], t), max(old[1], m))
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--duration", type=float, default=6000.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument(
        "--skip-reference", action="store_true", help="do not run the straightforward LPM"
    )
    ap.add_argument(
        "--ratios",
        type=int,
        nargs="*",
        default=[5, 10],
        help="larger F to run at the same N (default: 5 10; none: skip)",
    )
    ap.add_argument(
        "--lengths",
        type=float,
        nargs="*",
        default=[20.0, 60.0, 200.0, 600.0, 2000.0],
        help="record lengths in s at which to time n = auto against n = 8 (none: skip)",
    )
    args = ap.parse_args()
    keep_freed_memory()  # as the mr-ident and mr-ident-node programs do
    model = load_model(ROOT / "config" / "paper_example.yaml")
    sim_fn = lambda: simulate(model, duration=args.duration, rng=np.random.default_rng(0))  # noqa: E731
    best, out = best_times({"sim": sim_fn}, args.repeat)
    t_sim, sim, m_sim = best["sim"], out["sim"], peak_mb(sim_fn)
    N = sim.r.shape[0]
    K_low = model.controller_frf(N // 3)

    def run(workers=None, method="freq-lifted", n=8, local="polynomial"):
        return identify(
            sim.r,
            sim.u,
            sim.y,
            fs_high=240.0,
            ratio=3,
            method=method,
            n=n,
            local=local,
            controller_low=K_low,
            keep_lifted=False,
            workers=workers,
        )

    def reference(split=3):  # split = F * n_y: J (r -> y) and S (r -> u) fitted separately
        with mock.patch.object(
            sys.modules["mr_ident.numerics.local.lpm"],
            "lpm_bins_last",
            functools.partial(straightforward_lpm_core, split=split),
        ):
            return run(1)

    identify(sim.r[:3000], sim.u[:3000], sim.y[:3000], fs_high=240.0, ratio=3)  # warm-up
    whole = default_path(sim, args)
    fns = {
        "ours": run,
        "one": lambda: run(1),
        "structured": lambda: run(method="structured"),
        "structured_one": lambda: run(1, method="structured"),
        "rational": lambda: run(local="rational"),
    }
    if not args.skip_reference:
        fns["ref"] = reference
        fns["ref_joint"] = lambda: reference(split=None)
    t, out = best_times(fns, args.repeat)
    mem = {k: peak_mb(fn) for k, fn in fns.items()}
    res = out["ours"]
    truth = model.plant_frf(N)[1:]
    err = np.median(np.abs(res.plant.response - truth) / np.abs(truth))
    load = os.getloadavg()[0]
    print(
        f"the default path: mr-ident identify DATA.npz --model ... --out R.npz (load {load:.2f})"
    )
    for key, label in (("default", "default (n = auto)"), ("n8", "--n 8")):
        tw, mw = whole[key]
        line = f"  {label:20s} {tw:7.3f} s   peak resident {mw:7.1f} MB"
        if "ref" in t:
            line += f"   (the reference's identification alone: {t['ref'] / tw:.1f} x this)"
        print(line)
    print(
        f"N = {N} samples ({args.duration:g} s at 240 Hz), F = 3, n = 8, R = 2; best of "
        f"{args.repeat} "
        f"interleaved runs each"
    )
    print(f"simulate              {t_sim:7.3f} s   peak {m_sim:7.1f} MB")
    print(
        f"identify freq-lifted  {t['ours']:7.3f} s   peak {mem['ours']:7.1f} MB   (P_h, std, "
        "PFG; median rel. "
        f"error {err:.1e}; {resolve_workers(None)} threads)"
    )
    print(f"  same, one thread    {t['one']:7.3f} s   peak {mem['one']:7.1f} MB")
    err_s = np.median(np.abs(out["structured"].plant.response - truth) / np.abs(truth))
    print(
        f"identify structured   {t['structured']:7.3f} s   peak {mem['structured']:7.1f} MB   "
        f"(same outputs; median rel. error {err_s:.1e})"
    )
    print(
        f"  same, one thread    {t['structured_one']:7.3f} s   peak "
        f"{mem['structured_one']:7.1f} MB"
    )
    err_r = np.median(np.abs(out["rational"].plant.response - truth) / np.abs(truth))
    print(
        f"freq-lifted rational  {t['rational']:7.3f} s   peak {mem['rational']:7.1f} MB   "
        f"(--local rational, n = 8; median rel. error {err_r:.1e})"
    )
    auto = {m: lambda m=m: run(method=m, n="auto") for m in ("freq-lifted", "structured")}
    auto["freq-lifted n8"] = run
    auto["structured n8"] = lambda: run(method="structured")
    ta, _ = best_times(auto, args.repeat)
    ma = {k: peak_mb(auto[k]) for k in ("freq-lifted", "structured")}
    for m in ("freq-lifted", "structured"):
        print(
            f"n auto {m:13s}  {ta[m]:7.3f} s   peak {ma[m]:7.1f} MB   "
            f"({ta[m] / ta[m + ' n8']:.2f} x the time of n = 8 in the same rounds, "
            f"{ma[m] / mem['ours' if m == 'freq-lifted' else 'structured']:.2f} x its peak)"
        )
    if not args.skip_reference:
        d = np.max(np.abs(out["ref"].plant.response - res.plant.response) / np.abs(truth))
        print(
            f"straightforward QR    {t['ref']:7.3f} s   peak {mem['ref']:7.1f} MB   (J and S "
            "fitted separately; "
            f"one thread; max rel. difference to ours {d:.1e})"
        )
        print(f"  one QR for J and S  {t['ref_joint']:7.3f} s   peak {mem['ref_joint']:7.1f} MB")
        print(
            f"speed-up ratio        {t['ref'] / t['ours']:7.1f} x   ({t['ref'] / t['one']:.1f} "
            "x on one thread each; "
            f"{t['ref_joint'] / t['ours']:.1f} x against the joint QR)"
        )
    for F in args.ratios:
        larger_ratio(model, N, F)
    auto_by_length(model, sim, args.lengths, args.repeat)


def auto_by_length(model, sim, lengths: list[float], repeat: int) -> None:
    """n = auto against n = 8 on the first ``lengths`` seconds of the record (interleaved)."""
    for seconds in lengths:
        N = 3 * int(seconds * model.fs_high / 3)
        if N > sim.r.shape[0]:
            continue
        part = (sim.r[:N], sim.u[:N], sim.y[:N])
        fns = {
            n: functools.partial(identify, *part, fs_high=240.0, ratio=3, n=n, keep_lifted=False)
            for n in ("auto", 8)
        }
        t, _ = best_times(fns, max(repeat, 5))  # short: more runs, the first warms up
        print(
            f"{seconds:6g} s record      n = auto {1e3 * t['auto']:7.1f} ms, n = 8 "
            f"{1e3 * t[8]:7.1f} ms: {t['auto'] / t[8]:.2f} x"
        )


def larger_ratio(model, N: int, F: int) -> None:
    """Identify N samples at ratio F (low rate 80 Hz, high rate 80 F Hz); one timed run."""
    m = replace(model, fs_high=80.0 * F, ratio=F)
    sim = simulate(m, n_samples=N - N % F, rng=np.random.default_rng(0))
    K_low = m.controller_frf(sim.r.shape[0] // F)

    def run():
        return identify(
            sim.r,
            sim.u,
            sim.y,
            fs_high=m.fs_high,
            ratio=F,
            n=None,  # the default rule's fixed window (not auto)
            controller_low=K_low,
            keep_lifted=False,
        )

    t, out = best_times({"F": run}, 1)
    mem = peak_mb(run)
    res = out["F"]
    truth = m.plant_frf(sim.r.shape[0])[1:]
    err = np.nanmedian(np.abs(res.plant.response - truth) / np.abs(truth))
    n = default_n("freq-lifted", 2, F, 1, 1)
    print(
        f"F = {F:<2d} (n = {n:2d}, {m.fs_high:g} Hz) {t['F']:7.3f} s   peak "
        f"{mem:7.1f} MB   (same N; median rel. error {err:.1e})"
    )


if __name__ == "__main__":
    main()
