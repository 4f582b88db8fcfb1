# SPDX-License-Identifier: Apache-2.0
"""Benchmark: the calibration of the test for a plant that changes within the record.

The test (``mr_ident.diagnosis.criterion.timevarying.within``, docs/diagnose.md, "A plant
that changes within the record") has three parts, each shown alone and together: the mean
per-line spread of the segments' estimates over their noise (the level, named above
``VARYING_DB``), the pooled relative gain change (an F test, named below
``POOLED_ALPHA``) and the segments' gains in time (``criterion.gain_drift``, an F test
named below ``DRIFT_ALPHA``). Run on

- time-invariant records, where every naming is a false alarm: the loops of
  ``mr_bench.scenarios.draw_scenario`` with nothing or one cause hidden (each cause of
  ``verdict.CAUSE_NAMES`` alike), and the time-invariant unlisted effects of
  ``mr_bench.beyond.draw_beyond`` (a pole-zero pair, a second delay path; its first
  record), white r, ``--durations`` s each;
- time-varying gains (``draw_beyond``'s ``time_varying_gain``: 1 + a sin(2π t / T), a
  U(0.1, 0.3), T U(0.3, 1) of the record), ``--varying-durations`` s, where the test
  should name them.

``--missing q``: every record loses a share q of its samples of u and of y (as a bag
that dropped messages): half as single samples, drawn for u and y apart, half in bursts
of 5-50 samples of both at once (:func:`drop`); 0, the complete records.

Printed per group: the records, how many the pooled test could judge (it needs two
blocks of lines), the level's largest value and how many exceed its threshold, the pooled
test's smallest p, how many fall below 0.05, 0.01, 1e-3 and ``POOLED_ALPHA`` (a calibrated
test: those shares of the judged records, within their binomial scatter) and how many the
test names in all; then the time-domain gains' test
(``mr_ident.diagnosis.criterion.gain_drift``): how many it judged, its smallest p, how many
fall below 0.05, 0.01 and ``DRIFT_ALPHA``, and the named share with and without it; a
Kolmogorov-Smirnov test of each test's p against uniform over every time-invariant
record.

    .venv/bin/python benchmarks/bench_timevarying.py        # the figures of docs/diagnose.md
    .venv/bin/python benchmarks/bench_timevarying.py --per-kind 2 --per-varying 5
    .venv/bin/python benchmarks/bench_timevarying.py --case time_varying_gain:10:1026066
    .venv/bin/python benchmarks/bench_timevarying.py --missing 0.02

Seeds: ``seed * 10**6 + 1000 * group + k``, the groups numbered over (duration, kind) of
the time-invariant records, then the time-varying durations.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from mr_bench.beyond import draw_beyond
from mr_bench.scenarios import draw_scenario
from mr_bench.verdict import CAUSE_NAMES
from mr_ident.numerics.signals import LoopData

#: The time-invariant kinds: nothing hidden, one cause, an unlisted time-invariant effect.
KINDS: tuple[str, ...] = ("none", *CAUSE_NAMES, "pole_zero_pair", "second_delay_path")
#: The p values whose exceedance counts are shown (the last is the test's own alpha).
LEVELS: tuple[float, ...] = (0.05, 0.01, 1e-3)


def plan(
    per_kind: int, per_varying: int, seed: int, durations: list[float], varying: list[float]
) -> list[dict]:
    """Every record: kind, duration and seed (module docstring)."""
    groups = [(kind, d) for d in durations for kind in KINDS]
    groups += [("time_varying_gain", d) for d in varying]
    cases = []
    for j, (kind, d) in enumerate(groups):
        n = per_varying if kind == "time_varying_gain" else per_kind * (2 if kind == "none" else 1)
        cases += [
            {"kind": kind, "duration": d, "seed": seed * 10**6 + 1000 * j + k} for k in range(n)
        ]
    return cases


def draw(case: dict) -> tuple:
    """The record and the model the diagnosis is given: ``(data, nominal, text)``."""
    rng = np.random.default_rng(case["seed"])
    kind, d = case["kind"], case["duration"]
    if kind in ("pole_zero_pair", "second_delay_path", "time_varying_gain"):
        b = draw_beyond(kind, rng, duration=d)
        p = ", ".join(f"{k} {v:.3g}" for k, v in b.parameters.items())
        return b.data, b.nominal, p
    sc = draw_scenario([] if kind == "none" else [kind], rng, duration=d)
    return sc.data, sc.nominal, ""


def drop(data: LoopData, share: float, rng: np.random.Generator) -> LoopData:
    """``data`` with a ``share`` of its samples of u and y missing (NaN; module docstring)."""
    N = data.n_samples
    u, y = data.u.copy(), data.y.copy()
    for x in (u, y):  # single samples, u and y apart
        x[rng.random(N) < share / 2] = np.nan
    lost = 0
    while lost < share / 2 * N:  # bursts of both
        b = int(rng.integers(5, 51))
        a = int(rng.integers(0, N - b))
        u[a : a + b], y[a : a + b] = np.nan, np.nan
        lost += b
    return dataclasses.replace(data, u=u, y=y)


def run_case(case: dict) -> dict:
    """One record through :func:`within`, with diagnose's window; a JSON-able row.

    ``case["missing"]``: the share of samples dropped (:func:`drop`), if any; ``refused``:
    a segment's holes were more than its lifted fit carries, the time-domain gains alone.
    """
    from mr_ident.diagnosis.criterion.timevarying import within
    from mr_ident.numerics.identify import default_n

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data, nominal, text = draw(case)
        if case.get("missing"):
            data = drop(data, case["missing"], np.random.default_rng([case["seed"], 41]))
        t0 = time.perf_counter()
        m = nominal
        n = default_n("freq-lifted", 2, m.ratio, m.n_u, max(m.n_u, m.n_y))
        got = within(data, m, n=n)
    refused = got is not None and not got.bands  # the time-domain gains alone
    pool = None if got is None else got.pooled
    drift = None if got is None else got.drift
    return case | {
        "loop": f"{m.fs_high:g} Hz F={m.ratio}",
        "effect": text,
        "seconds": time.perf_counter() - t0,
        "judged": got is not None,
        "level_db": None if got is None else got.level_db,
        "p": None if pool is None else pool.p,
        "blocks": None if pool is None else pool.blocks,
        "dof": None if pool is None else list(pool.dof),
        "change": None if pool is None else pool.change,
        "refused": refused,
        "named": got is not None and got.varying,
        "p_drift": None if drift is None else drift.p,
        "drift_change": None if drift is None else drift.change,
        "named_without_drift": got is not None and dataclasses.replace(got, drift=None).varying,
    }


def _count(xs: list[bool]) -> str:
    return f"{sum(xs)}/{len(xs)}" if xs else "-"


def report(rows: list[dict]) -> str:
    """The markdown tables (module docstring)."""
    import scipy.stats

    from mr_ident.diagnosis.criterion.timevarying import POOLED_ALPHA, VARYING_DB

    alphas = (*LEVELS, POOLED_ALPHA)
    head = (
        "| records | duration s | n | pooled judged | blocks (median, min) "
        f"| level max dB | level > {VARYING_DB:g} dB | pooled p min "
        + " ".join(f"| p < {a:g}" for a in alphas)
        + " | named |"
    )
    lines = [head, "|" + "---|" * (9 + len(alphas))]
    invariant = [r for r in rows if r["kind"] != "time_varying_gain"]
    groups: list[tuple[str, float, list[dict]]] = []
    for d in sorted({r["duration"] for r in invariant}):
        g = [r for r in invariant if r["duration"] == d]
        groups.append(("time-invariant", d, g))
    if len({r["duration"] for r in invariant}) > 1:
        groups.append(("time-invariant", math.nan, invariant))
    for d in sorted({r["duration"] for r in rows if r["kind"] == "time_varying_gain"}):
        g = [r for r in rows if r["kind"] == "time_varying_gain" and r["duration"] == d]
        groups.append(("time-varying gain", d, g))
    for name, d, g in groups:
        ps = [r["p"] for r in g if r["p"] is not None]
        lv = [
            r["level_db"] for r in g if r["level_db"] is not None and math.isfinite(r["level_db"])
        ]
        bl = [r["blocks"] for r in g if r["blocks"] is not None]
        lines.append(
            f"| {name} | {'all' if math.isnan(d) else f'{d:g}'} | {len(g)} | {len(ps)} "
            f"| {np.median(bl) if bl else '-'}, {min(bl) if bl else '-'} "
            f"| {max(lv) if lv else math.nan:.2f} | {_count([x > VARYING_DB for x in lv])} "
            f"| {min(ps) if ps else math.nan:.2g} "
            + " ".join(f"| {_count([p < a for p in ps])}" for a in alphas)
            + f" | {_count([r['named'] for r in g])} |"
        )
    ps = [r["p"] for r in invariant if r["p"] is not None]
    out = ["\n".join(lines), "", _drift_table(groups), ""]
    for what, key in (("pooled", "p"), ("time-domain gains'", "p_drift")):
        ps = [r[key] for r in invariant if r.get(key) is not None]
        if len(ps) > 1:
            ks = scipy.stats.kstest(ps, "uniform")
            out.append(
                f"- time-invariant: the {what} p against uniform, Kolmogorov-Smirnov "
                f"D {ks.statistic:.3f}, p {ks.pvalue:.2g} ({len(ps)} records)"
            )
    for r in rows:
        miss = r["kind"] == "time_varying_gain" and not r["named"]
        false = r["kind"] != "time_varying_gain" and r["named"]
        if miss or false:
            pv = "-" if r["p"] is None else f"{r['p']:.2g}"
            pv += "" if r.get("p_drift") is None else f", time-domain p {r['p_drift']:.2g}"
            lvl = "-" if r["level_db"] is None else f"{r['level_db']:.2f}"
            out.append(
                f"- {'not named' if miss else 'false alarm'}: {r['kind']}:{r['duration']:g}:"
                f"{r['seed']} {r['loop']} {r['effect']}; level {lvl} dB, p {pv}, blocks "
                f"{r['blocks']}"
            )
    return "\n".join(out)


def _drift_table(groups: list[tuple[str, float, list[dict]]]) -> str:
    """The time-domain gains' test per group (``gain_drift``): judged, smallest p, the
    counts below 0.05, 0.01 and ``DRIFT_ALPHA``, named with it and without it."""
    from mr_ident.diagnosis.criterion.timevarying import DRIFT_ALPHA

    alphas = (0.05, 0.01, DRIFT_ALPHA)
    lines = [
        "| records | duration s | n | time-domain judged | p min "
        + " ".join(f"| p < {a:g}" for a in alphas)
        + " | named | named without it |",
        "|" + "---|" * (7 + len(alphas)),
    ]
    for name, d, g in groups:
        ps = [r["p_drift"] for r in g if r.get("p_drift") is not None]
        lines.append(
            f"| {name} | {'all' if math.isnan(d) else f'{d:g}'} | {len(g)} | {len(ps)} "
            f"| {min(ps) if ps else math.nan:.2g} "
            + " ".join(f"| {_count([p < a for p in ps])}" for a in alphas)
            + f" | {_count([r['named'] for r in g])} "
            f"| {_count([r.get('named_without_drift', r['named']) for r in g])} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    p.add_argument(
        "--per-kind",
        type=int,
        default=40,
        help="time-invariant records per kind and duration (twice for nothing hidden)",
    )
    p.add_argument("--per-varying", type=int, default=100, help="time-varying gains per duration")
    p.add_argument("--durations", default="10,30", help="s of the time-invariant records")
    p.add_argument("--varying-durations", default="10,30", help="s of the time-varying ones")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--missing", type=float, default=0.0, help="share of u's and y's samples dropped"
    )
    p.add_argument("--case", help="KIND:DURATION:SEED, one record")
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    try:
        durations = [float(x) for x in a.durations.split(",") if x]
        varying = [float(x) for x in a.varying_durations.split(",") if x]
    except ValueError:
        print(
            "error: --durations and --varying-durations must be numbers separated by commas, "
            f"got {a.durations!r}, {a.varying_durations!r}",
            file=sys.stderr,
        )
        return 2
    if not 0.0 <= a.missing < 0.5:
        print(f"error: --missing must be a share in [0, 0.5), got {a.missing}", file=sys.stderr)
        return 2
    if a.case:
        kind, _, rest = a.case.partition(":")
        d, _, seed = rest.partition(":")
        if kind not in (*KINDS, "time_varying_gain") or not seed.isdigit():
            print(
                f"error: --case must be KIND:DURATION:SEED, KIND one of {', '.join(KINDS)}, "
                f"time_varying_gain; got {a.case!r}",
                file=sys.stderr,
            )
            return 2
        cases = [{"kind": kind, "duration": float(d), "seed": int(seed)}]
    else:
        cases = plan(a.per_kind, a.per_varying, a.seed, durations, varying)
    t0 = time.perf_counter()
    rows = [run_case(c | {"missing": a.missing}) for c in cases]
    wall = time.perf_counter() - t0
    print(report(rows))
    refused = sum(r["refused"] for r in rows)
    if refused:
        print(f"\n{refused} records: a segment refused by the frequency-domain estimates")
    print(f"\n{len(rows)} records in {wall / 60:.1f} min")
    if a.json:
        a.json.write_text(json.dumps({"records": rows, "wall_s": wall}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
