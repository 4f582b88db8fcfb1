# SPDX-License-Identifier: Apache-2.0
"""Benchmark: the correction's false acceptance on exact models, its trigger bypassed.

On a model that is exact the correction's trigger (a significant bin, or the broadband
total) rarely fires, so the acceptance rule's own false rate goes unmeasured in the
diagnose benchmarks. Here it is forced: on random loops (``mr_bench.scenarios.draw_scenario``
with no cause: the nominal is the truth) ``selection.correction.correction(nominal, nominal,
...)`` is called with the broadband test made significant (its threshold replaced by -inf
in this script's process only; the product is untouched), so that every kind and order is
fitted, climbed and judged as when the trigger fires. Each loop twice: with a second record
of the same loop as validation data (``separate``), and with the last 30 % of the record
held out as diagnose does without one (``held-out``). Every acceptance is false (the truth
needs no correction); the target is at most alpha (1 %). Shown: acceptances with the order
and the criteria met, the orders the ladder reached, the candidates that met each criterion
of the acceptance (BIC margin, fit of y, gain z against the nominal), seconds per call
(the estimation record's identification and the correction, as diagnose calls them).

    nice -n 10 .venv/bin/python benchmarks/bench_correction_null.py    # 400 calls, 8 min at load 5
    .venv/bin/python benchmarks/bench_correction_null.py --n 10 --seed 3 --json out.json

Sizes: ``--n`` loops (default 200, so 400 calls), records of ``--duration`` s (10);
loop seeds ``seed * 10**6 + k``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import traceback
import warnings
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

import mr_ident.diagnosis.selection.correction as corr_mod
from mr_bench.scenarios import draw_scenario
from mr_ident.diagnosis.criterion.broadband import Broadband
from mr_ident.diagnosis.criterion.evidence import Evidence, identify_record
from mr_ident.diagnosis.diagnose import check_record, split
from mr_ident.diagnosis.selection.forward import ACCEPT_MARGIN
from mr_ident.numerics.identify import default_n
from mr_ident.numerics.systems.simulate import simulate
from mr_ident.numerics.threads import one_blas_thread

ALPHA, DEGREE, HOLDOUT = 0.01, 2, 0.3
_broadband = corr_mod.broadband
_seen: dict[str, bool] = {}


def _forced(ev: Evidence, **kw: Any) -> Broadband:
    """The broadband test, always significant (what it and the per-bin test said noted)."""
    bb = _broadband(ev, **kw)
    _seen["trigger"] = bool(ev.significant.any()) or bb.significant
    return replace(bb, threshold=-math.inf, n_terms=max(bb.n_terms, 1))


def run_call(seed: int, mode: str, duration: float) -> dict[str, Any]:
    """One loop, one validation mode: the forced correction's outcome."""
    rng = np.random.default_rng(seed)
    sc = draw_scenario([], rng, duration=duration)
    m, data = sc.nominal, sc.data
    second = simulate(m, n_samples=data.n_samples, rng=rng)  # drawn in both modes: same loop
    n = default_n("freq-lifted", DEGREE, m.ratio, m.n_u, max(m.n_u, m.n_y))
    row: dict[str, Any] = {"seed": seed, "mode": mode, "fs": m.fs_high, "ratio": m.ratio}
    if mode == "separate":
        est, val, start = data, second, 0
    else:
        start = split(data, 1.0 - HOLDOUT)
        est, val = data.part(0, start), data
    try:
        check_record(m, est, n=n, what="estimation")
        if start:
            check_record(m, val.part(start, val.n_samples), n=n, what="held-out")
        _seen.clear()
        t0 = time.perf_counter()
        with one_blas_thread(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ident = identify_record(est, m, n=n, degree=DEGREE)
            c = corr_mod.correction(m, m, est, ident, val, start, n=n, degree=DEGREE, alpha=ALPHA)
        row["seconds"] = time.perf_counter() - t0
    except Exception as err:  # noqa: BLE001 - a benchmark reports and goes on
        row["error"] = f"{type(err).__name__}: {err}"
        row["trace"] = traceback.format_exc(limit=3)
        return row
    row["trigger"] = _seen.get("trigger")
    if c is None or c.best is None:
        row.update(accepted=False, candidates=[])
        return row
    ref_bic, ref_fit = min(c.score_nominal, c.score_causes), max(c.fit_nominal, c.fit_causes)
    row.update(
        accepted=c.accepted,
        kind=c.best.kind,
        order=c.best.order,
        pole_radii=[abs(complex(q)) for q in c.best.correction.poles],  # |z|
        angles_hz=[
            float(np.angle(q)) * m.fs_high / (2 * math.pi) for q in c.best.correction.poles
        ],
        z_critical=c.z_critical,
        candidates=[
            {
                "kind": k.kind,
                "order": k.order,
                "p": k.n_params,
                "dbic": k.bic - ref_bic,  # < -ACCEPT_MARGIN passes
                "dfit": k.fit_y - ref_fit,  # > 0 passes
                "z": min(k.z_nominal, k.z_causes),  # > z_critical passes
            }
            for k in c.candidates
        ],
    )
    return row


def _passes(k: dict[str, Any], zc: float) -> tuple[bool, bool, bool]:
    return k["dbic"] < -ACCEPT_MARGIN, k["dfit"] > 0, k["z"] > zc


def report(rows: list[dict[str, Any]]) -> str:
    """The figures per mode."""
    out = []
    for mode in ("separate", "held-out"):
        rs = [r for r in rows if r["mode"] == mode]
        if not rs:
            continue
        ok = [r for r in rs if "error" not in r]
        acc = [r for r in ok if r.get("accepted")]
        n_ok = max(len(ok), 1)
        lo, hi = _wilson(len(acc), len(ok))
        secs = np.array([r["seconds"] for r in ok]) if ok else np.zeros(1)
        out.append(
            f"{mode}: {len(rs)} calls ({len(rs) - len(ok)} errors); accepted {len(acc)}/"
            f"{len(ok)} = {100 * len(acc) / n_ok:.1f} % (95 % CI {100 * lo:.1f}-{100 * hi:.1f} "
            f"%); trigger would have fired in {sum(bool(r.get('trigger')) for r in ok)}"
        )
        out.append(
            f"  seconds per call: median {np.median(secs):.2f}, mean {secs.mean():.2f}, "
            f"max {secs.max():.2f}"
        )
        reached: Counter[int] = Counter()
        crit: Counter[str] = Counter()
        for r in ok:
            cands = r.get("candidates", [])
            for kind in ("additive", "multiplicative"):
                orders = [k["order"] for k in cands if k["kind"] == kind]
                if orders:
                    reached[max(orders)] += 1
            zc = r.get("z_critical", math.inf)
            flags = [_passes(k, zc) for k in cands]
            for name, j in (("BIC", 0), ("fit", 1), ("z", 2)):
                crit[name] += any(f[j] for f in flags)
            crit["BIC+fit"] += any(f[0] and f[1] for f in flags)
            crit["BIC+z"] += any(f[0] and f[2] for f in flags)
            crit["fit+z"] += any(f[1] and f[2] for f in flags)
            crit["all"] += any(all(f) for f in flags)
        out.append(
            "  highest order reached per kind: "
            + ", ".join(f"{o}: {reached[o]}" for o in sorted(reached))
        )
        out.append(
            "  calls with some candidate meeting: "
            + ", ".join(f"{k} {crit[k]}" for k in ("BIC", "fit", "z", "BIC+fit", "BIC+z", "fit+z"))
            + f", all three {crit['all']}"
        )
        for r in acc:
            b = next(
                k for k in r["candidates"] if (k["kind"], k["order"]) == (r["kind"], r["order"])
            )
            out.append(
                f"  accepted: seed {r['seed']} fs {r['fs']:g} F {r['ratio']} {r['kind']} order "
                f"{r['order']} (p {b['p']}): dBIC {b['dbic']:+.1f}, dfit {b['dfit']:+.2f} %, "
                f"z {b['z']:.2f} (critical {r['z_critical']:.2f}), of "
                f"{len(r['candidates'])} candidates; poles |z| "
                + ", ".join(
                    f"{a:.5f} at {h:.3g} Hz"
                    for a, h in zip(r["pole_radii"], r["angles_hz"], strict=True)
                )
            )
        for r in rs:
            if "error" in r:
                out.append(f"  error: seed {r['seed']}: {r['error']}")
    return "\n".join(out)


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return 0.0, 1.0
    p, d = k / n, 1 + z * z / n
    c, h = (p + z * z / (2 * n)) / d, z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=200, help="loops (two calls each)")
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--duration", type=float, default=10.0, help="s of each record")
    p.add_argument("--modes", default="separate,held-out")
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    modes = a.modes.split(",")
    if set(modes) - {"separate", "held-out"}:
        print(f"error: --modes must name separate, held-out; got {modes}", file=sys.stderr)
        return 2
    corr_mod.broadband = _forced  # type: ignore[assignment]  # this process only
    rows, t0 = [], time.perf_counter()
    for k in range(a.n):
        for mode in modes:
            rows.append(run_call(a.seed * 10**6 + k, mode, a.duration))
    wall = time.perf_counter() - t0
    print(report(rows))
    print(f"\n{len(rows)} calls on {a.n} loops in {wall / 60:.1f} min")
    if a.json:
        a.json.write_text(json.dumps({"calls": rows, "wall_s": wall}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
