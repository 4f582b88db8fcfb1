# SPDX-License-Identifier: Apache-2.0
"""Benchmark: ``fit_frf`` on drawn modal plants against the Cramér–Rao bound.

Plants: ``m`` modes (order 2m, m drawn 1..15: order 2-30), frequencies log-uniform over
[fs/500, 0.4 fs], damping log-uniform over [0.005, 0.3], complex residues per entry
(magnitude log-uniform over two decades, scaled so each mode peaks alike), SISO and 3x3;
behind a ZOH at fs = 1000 Hz, K bins on (0, fs/2); circular Gaussian noise of std 5 % of
each entry's median magnitude, independent per bin, ``--draws`` draws of it per plant.
For each plant and draw, at the true order (delay 0 given): each pole's error |p̂ - p|
over the Cramér–Rao std ``sqrt(tr cov)`` of that pole (cov: ``(JᵀJ)⁻¹`` at the truth,
noise-free data), the cost inside its band ``E{V} ± 2 sd{V}``, every pole stable, the
time. On the first draw of the first ``--auto-plants`` plants, ``order="auto"`` (delay
auto) too: the order chosen against the truth, the time.

Printed per shape: the median and 90th percentile of the pole errors in CRB units (an
efficient estimator: 1.52-1.64 at the 90th, 0.67-0.83 the median: a 2-D Gaussian error
over ``sqrt(tr cov)``, isotropic to one-dimensional), the share of fits with the cost in
its band with its binomial 95 % interval (Clopper-Pearson; the fits taken as independent:
the draws of one plant share its modes, so a share that depends on the plant, *local*, is
known less well than its interval says), beside it *truth*: the share
whose minimum reached from the true poles is in that band (what any estimator reaches:
the rest is the noise's draw) and *local*: the share whose cost lies above that minimum
by more than :data:`LOCAL_TOL` (a local minimum). Then the band itself checked: the
truth's own cost ``V₀ = Σ |noise|²/σ²`` (χ²(2N)/2: ``N ± 2 sqrt(N)``, its own band with
p = 0) and the drop from it to the minimum from the truth, ``V₀ - V̂`` (χ²(p)/2 to first
order: its mean over p/2 is 1 when ``E{V} = N - p/2`` is right). Then the automatic
order: the share of orders found, chosen below the truth, and *missed*: below the truth
although the fit at the true order lowers V by more than 2 sd{V} (a miss of the order
search; otherwise the missing modes change the cost by less than the band, and the data
cannot tell them), stability, time. ``--tail X`` lists the poles whose error exceeds X
CRB (which mode, its CRB relative to |p|, whether that fit is a local minimum).

Then a large case (``--speed-bins``, default 1e5): one drawn 3x3 plant of 20
modes (order 40), the order and delay given, wall and CPU time of ``fit_frf`` on every
CPU (threads over the entries), the cost against its band, the load average beside it.

Beside it, on the same data (``--compare``, default on, ``--auto-plants`` further
plants): scikit-rf's ``VectorFitting``
(common poles, stable by pole flipping, unweighted, a rational model in s: no hold), at
the true order, strictly proper, the DC point not enforced (no DC bin). Its cost V on
P_h's bins against the band, its pole errors in the same CRB units, stability and time;
and once more on the plant's own G(jω) with the same noise (its own model class, no hold:
its best case). python-control has no FRF fit (its request is open since 2021): it is
the target of ``mr-ident fit --export python-control``, not a competitor.

    .venv/bin/python benchmarks/bench_fit.py [--plants 100] [--draws 2] [--auto-plants 8]
        [--bins 1000] [--seed 0] [--tail X] [--speed-bins 100000] [--no-auto]
        [--no-speed] [--no-compare]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from mr_ident.numerics.fit.frf_fit import fit_frf, hold_response
from mr_ident.numerics.fit.refine import Problem, covariance
from mr_ident.numerics.results import FRF
from mr_ident.numerics.systems.modal import ModalPlant
from mr_ident.numerics.threads import one_blas_thread

FS = 1000.0

#: A fit's cost above the minimum reached from the truth by more than this is a local minimum.
LOCAL_TOL = 1.0


def draw(rng: np.random.Generator, n_modes: int, shape: tuple[int, int]) -> ModalPlant:
    f = np.sort(np.exp(rng.uniform(np.log(FS / 500), np.log(0.4 * FS), n_modes)))
    z = np.exp(rng.uniform(np.log(0.005), np.log(0.3), n_modes))
    w = 2 * np.pi * f
    p = -z * w + 1j * w * np.sqrt(1 - z * z)
    mag = np.exp(rng.uniform(0, np.log(100), (n_modes, *shape)))
    R = mag * np.exp(1j * rng.uniform(0, 2 * np.pi, (n_modes, *shape)))
    R *= (z * w / 1e3)[:, None, None]  # peak |R|/(ζ w) alike across modes
    return ModalPlant(p, R, np.zeros(shape))


def crb(truth: ModalPlant, f, sd) -> np.ndarray:
    """Cramér–Rao std of each pole (sqrt of the trace of its 2x2 covariance)."""
    h = 1 / FS
    P = hold_response(truth, 0.0, "continuous", FS, f)
    no, ni = truth.shape
    prob = Problem(
        np.exp(2j * np.pi * f * h),
        P.reshape(-1, no * ni),
        1 / sd.reshape(-1, no * ni),
        "continuous",
        h,
        2 * np.pi * f[-1],
        False,
    )
    from mr_ident.numerics.fit.basis import from_params, to_params

    x, cov, _ = covariance(prob, truth.poles, 0.0, free_delay=False)
    u = to_params(truth.poles, "continuous", h, prob.w_ref)
    pair = [True] * truth.poles.size
    G = np.empty((2 * truth.poles.size, u.size))
    for j in range(u.size):
        du = np.zeros(u.size)
        du[j] = 1e-7
        d = (
            from_params(u + du, pair, "continuous", h, prob.w_ref)
            - from_params(u - du, pair, "continuous", h, prob.w_ref)
        ) / 2e-7
        G[:, j] = np.concatenate([d.real, d.imag])
    C = G @ cov[: u.size, : u.size] @ G.T
    n = truth.poles.size
    return np.sqrt(np.diag(C)[:n] + np.diag(C)[n:])


def from_truth(truth: ModalPlant, data: FRF) -> float:
    """V at the minimum reached from the true poles (the order and delay given)."""
    from mr_ident.numerics.fit.refine import refine

    no, ni = truth.shape
    f = data.frequency
    prob = Problem(
        np.exp(2j * np.pi * f / FS),
        data.response.reshape(-1, no * ni),
        1 / data.std.reshape(-1, no * ni),
        "continuous",
        1 / FS,
        2 * np.pi * f[-1],
        False,
    )
    return refine(prob, truth.poles, 0.0, free_delay=False, max_delay=0.0).cost


def interval(k: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95 % interval of a share k/n (exact binomial, conservative)."""
    from scipy.stats import beta

    lo = float(beta.ppf(0.025, k, n - k + 1)) if k > 0 else 0.0
    hi = float(beta.ppf(0.975, k + 1, n - k)) if k < n else 1.0
    return lo, hi


def share(flags: list[bool]) -> str:
    """``k/n`` as a percentage with its 95 % interval."""
    k, n = int(sum(flags)), len(flags)
    lo, hi = interval(k, n)
    return f"{100 * k / n:5.1f}% [{100 * lo:4.1f}-{100 * hi:5.1f}]"


def plant(rng, shape, bins: int):
    """A drawn plant: (modes, truth, bins, P_h, σ per bin and entry)."""
    m = int(rng.integers(1, 16))
    truth = draw(rng, m, shape)
    f = np.arange(1, bins + 1) * FS / (2 * bins + 2)
    P = hold_response(truth, 0.0, "continuous", FS, f)
    sd = 0.05 * np.median(np.abs(P), axis=0)[None] * np.ones(P.shape)
    return m, truth, f, P, sd


def one(rng, shape, bins: int, draws: int, auto: bool) -> list[dict]:
    """One drawn plant: ``draws`` noise draws fitted at the true order (the first also auto)."""
    m, truth, f, P, sd = plant(rng, shape, bins)
    bound = crb(truth, f, sd)
    out = []
    for k in range(draws):
        noise = sd * (rng.standard_normal(P.shape) + 1j * rng.standard_normal(P.shape))
        noise /= np.sqrt(2)
        data = FRF(f, P + noise, sd, "bench")
        t0 = time.perf_counter()
        fit = fit_frf(data, fs=FS, order=2 * m, delay=0.0)
        t_fix = time.perf_counter() - t0
        est = fit.plant.poles
        err = np.array([np.min(np.abs(est - p)) for p in truth.poles])
        v_truth = from_truth(truth, data)
        r = {
            "order": 2 * m,
            "err_crb": err / bound,
            "in_band": abs(fit.cost - fit.expected) <= 2 * fit.expected_sd,
            # the minimum reached from the truth: in its band (what any estimator can
            # reach), and the fit's cost above it (a local minimum)
            "truth_band": abs(v_truth - fit.expected) <= 2 * fit.expected_sd,
            "local": fit.cost > v_truth + LOCAL_TOL,
            # the band checked: the truth's own cost in N ± 2 sqrt(N), and V₀ - V̂ over p/2
            "own_band": abs(float(np.sum(np.abs(noise / sd) ** 2)) - P.size)
            <= 2 * np.sqrt(P.size),
            "drop": (float(np.sum(np.abs(noise / sd) ** 2)) - v_truth) / (fit.n_params / 2),
            "z_truth": (v_truth - fit.expected) / fit.expected_sd,
            "stable": bool(np.all(est.real < 0)),
            "t_fixed": t_fix,
            "tail": [
                (abs(p) / (2 * np.pi), -p.real / abs(p), b / abs(p), e, fit.cost - v_truth)
                for p, b, e in zip(truth.poles, bound, err / bound, strict=True)
            ],
        }
        if auto and k == 0:
            t0 = time.perf_counter()
            fa = fit_frf(data, fs=FS, order="auto", delay="auto", max_order=2 * m + 4)
            r.update(
                t_auto=time.perf_counter() - t0,
                found=fa.order == 2 * m,
                under=fa.order < 2 * m,
                # below the truth although the true order lowers V by more than 2 sd{V}:
                # a miss of the order search (else the data cannot tell the missing modes)
                missed=fa.order < 2 * m and fa.cost - fit.cost > 2 * fa.expected_sd,
                stable_auto=bool(np.all(fa.plant.poles.real < 0)),
            )
        out.append(r)
    return out


def _vf_skrf(f, H, n_pairs: int):
    """scikit-rf's VectorFitting of H (K, n, n) at n_pairs complex pairs: poles, response."""
    import skrf
    from skrf.vectorFitting import VectorFitting

    freq = skrf.Frequency.from_f(f, unit="hz")
    vf = VectorFitting(skrf.Network(frequency=freq, s=H))
    vf.vector_fit(
        n_poles_real=0, n_poles_cmplx=n_pairs, init_pole_spacing="log",
        fit_constant=False, fit_proportional=False, enforce_dc=False,
    )  # fmt: skip
    n = H.shape[1]
    G = np.stack(
        [np.stack([vf.get_model_response(i, j, f) for j in range(n)], -1) for i in range(n)], 1
    )
    return np.asarray(vf.poles), G


def _judge(ctx, poles, G, data, t):
    """(V - E{V})/sd{V}, pole errors / CRB, stable, time of one fitted model."""
    truth, bound, sd, expected, sd_v = ctx
    v = float(np.sum(np.abs((data - G) / sd) ** 2))
    err = np.array([np.min(np.abs(poles - p)) for p in truth.poles]) / bound
    return ((v - expected) / sd_v, err, bool(np.all(poles.real < 0)), t)


def compare(rng, shape, bins: int, plants: int) -> list[str]:
    """Ours and scikit-rf's VectorFitting on the same drawn plants: table rows."""
    import logging

    logging.getLogger("skrf").setLevel(logging.ERROR)
    rows: dict[str, list] = {"mr-ident fit": [], "skrf on P_h": [], "skrf on G(jω)": []}
    for _ in range(plants):
        m, truth, f, P, sd = plant(rng, shape, bins)
        noise = sd * (rng.standard_normal(P.shape) + 1j * rng.standard_normal(P.shape))
        noise /= np.sqrt(2)
        bound = crb(truth, f, sd)
        n_e = P[0].size
        expected = P.size - (2 * m + 2 * m * n_e) / 2  # E{V}: N - p/2
        sd_v = np.sqrt(expected)

        ctx = (truth, bound, sd, expected, sd_v)
        t0 = time.perf_counter()
        fit = fit_frf(FRF(f, P + noise, sd, "bench"), fs=FS, order=2 * m, delay=0.0)
        t = time.perf_counter() - t0
        rows["mr-ident fit"].append(_judge(ctx, fit.plant.poles, fit.response(f), P + noise, t))
        for name, data in (("skrf on P_h", P + noise), ("skrf on G(jω)", None)):
            if data is None:
                data = truth.freqresp(f) + noise
            t0 = time.perf_counter()
            poles, G = _vf_skrf(f, data, m)
            rows[name].append(_judge(ctx, poles, G, data, time.perf_counter() - t0))
    out = []
    for name, rs in rows.items():
        band = np.array([r[0] for r in rs])
        e = np.concatenate([r[1] for r in rs])
        out.append(
            f"{shape[0]}x{shape[1]:<4d} {name:14s} {np.median(band):+10.1f} "
            f"{np.mean(np.abs(band) <= 2) * 100:6.0f}% {np.median(e):9.2f} "
            f"{np.quantile(e, 0.9):9.2f} {sum(r[2] for r in rs):3d}/{len(rs):<3d} "
            f"{np.median([r[3] for r in rs]):7.2f}s"
        )
    return out


def speed(rng, bins: int, order: int = 40) -> None:
    """One 3x3 plant of ``order`` at ``bins`` bins: time and cost band."""
    truth = draw(rng, order // 2, (3, 3))
    f = np.arange(1, bins + 1) * FS / (2 * bins + 2)
    P = hold_response(truth, 0.0, "continuous", FS, f)
    sd = 0.05 * np.median(np.abs(P), axis=0)[None] * np.ones(P.shape)
    noise = sd * (rng.standard_normal(P.shape) + 1j * rng.standard_normal(P.shape)) / np.sqrt(2)
    data = FRF(f, P + noise, sd, "bench")
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    fit = fit_frf(data, fs=FS, order=order, delay=0.0)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    band = (fit.cost - fit.expected) / fit.expected_sd
    print(
        f"speed: {bins} bins, 3x3, order {order}: {wall:.1f} s wall, {cpu:.1f} s CPU "
        f"(load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after); "
        f"cost {fit.cost:.0f} = E{{V}} {band:+.1f} sd; stable "
        f"{bool(np.all(fit.plant.poles.real < 0))}; largest condition number of a linear "
        f"step {fit.max_condition:.3g}"
    )


def report(shape, rows: list[dict], plants: int, tail: float | None) -> None:
    """The tables of one shape: at the true order, the band checked, the automatic order."""
    e = np.concatenate([r["err_crb"] for r in rows])
    orders = [r["order"] for r in rows]
    name = f"{shape[0]}x{shape[1]}"
    shares = " ".join(
        f"{share([r[k] for r in rows]):>20s}" for k in ("in_band", "truth_band", "local")
    )
    t_fixed = np.median([r["t_fixed"] for r in rows])
    print(
        f"{name:5s} {len(rows):4d} {plants:6d} {min(orders):3d}-{max(orders):<3d} "
        f"{np.median(e):11.2f} {np.quantile(e, 0.9):5.2f} {shares} "
        f"{str(all(r['stable'] for r in rows)):>6s} {t_fixed:6.2f}s"
    )
    z = np.array([r["z_truth"] for r in rows])
    print(
        f"      the band checked: truth's own cost in N ± 2 sqrt(N) "
        f"{share([r['own_band'] for r in rows])}; (V0 - V̂)/(p/2) mean "
        f"{np.mean([r['drop'] for r in rows]):.3f}; (V̂ - E{{V}})/sd{{V}} mean {z.mean():+.2f}, "
        f"sd {z.std():.2f}"
    )
    auto = [r for r in rows if "t_auto" in r]
    if auto:
        found = np.mean([r["found"] for r in auto])
        print(
            f"      order auto on {len(auto)} plants: found {found:.0%}"
            f", below the truth {np.mean([r['under'] for r in auto]):.0%}, missed "
            f"{np.mean([r['missed'] for r in auto]):.0%}, stable "
            f"{all(r['stable_auto'] for r in auto)}, time median "
            f"{np.median([r['t_auto'] for r in auto]):.1f} s"
        )
    if tail is not None:
        for i, r in enumerate(rows):
            for f0, zeta, rel, err, dv in r["tail"]:
                if err > tail:
                    print(
                        f"      fit {i:3d} order {r['order']:2d}: mode {f0:7.2f} Hz ζ {zeta:.3f}, "
                        f"CRB/|p| {rel:.1e}, error {err:5.1f} CRB, V - V(truth's min) {dv:+6.1f}"
                        f"{' (local)' if r['local'] else ''}"
                    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plants", type=int, default=100, help="plants per shape")
    ap.add_argument("--draws", type=int, default=2, help="noise draws per plant")
    ap.add_argument(
        "--auto-plants", type=int, default=8, help="plants fitted with order auto (first draw)"
    )
    ap.add_argument("--bins", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--tail", type=float, default=None, help="list poles past this many CRB")
    ap.add_argument("--no-auto", action="store_true", help="skip the automatic order")
    ap.add_argument("--speed-bins", type=int, default=100_000)
    ap.add_argument("--no-speed", action="store_true", help="skip the 1e5-bin fit")
    ap.add_argument("--no-compare", action="store_true", help="skip scikit-rf beside ours")
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    print(
        f"{'shape':5s} {'fits':>4s} {'plants':>6s} {'orders':>7s} {'err/CRB med':>11s} "
        f"{'p90':>5s} {'in band [95 % int.]':>20s} {'truth [95 % int.]':>20s} "
        f"{'local [95 % int.]':>20s} {'stable':>6s} {'t fixed':>7s}"
    )
    with one_blas_thread():
        for shape in ((1, 1), (3, 3)):
            rows = []
            for i in range(a.plants):
                auto = not a.no_auto and i < a.auto_plants
                rows += one(rng, shape, a.bins, a.draws, auto)
            report(shape, rows, a.plants, a.tail)
    if not a.no_compare:
        rng = np.random.default_rng(a.seed + 1)
        print(
            f"\n{'shape':6s} {'fit':14s} {'(V-E)/sd med':>12s} {'in band':>7s} "
            f"{'err/CRB med':>11s} {'p90':>9s} {'stable':>7s} {'time':>8s}"
        )
        with one_blas_thread():
            for shape in ((1, 1), (3, 3)):
                print("\n".join(compare(rng, shape, a.bins, a.auto_plants)))
    if not a.no_speed:
        speed(np.random.default_rng(a.seed), a.speed_bins)


if __name__ == "__main__":
    main()
