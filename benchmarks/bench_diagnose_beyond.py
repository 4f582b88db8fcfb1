# SPDX-License-Identifier: Apache-2.0
"""Benchmark: diagnose on random loops beyond its vocabulary (nonlinear, unlisted effects).

Every case is a loop drawn by ``mr_bench.scenarios.draw_loop`` with one effect of
``mr_bench.beyond`` (a dead zone, a saturation, Coulomb friction or backlash at the plant's
input, at the levels of ``beyond.LEVELS``, excited by a periodic odd or full multisine, one
realization per record; or a pole-zero pair, a second delay path or a time-varying gain
under white r), two records, the second given as the validation record:
``diagnose(nominal, data, validation)``. Judged by ``verdict.judge_beyond``; the targets:

- nonlinearity named in >= 95 % of the nonlinear cases whose true distortion is at least
  ``verdict.NAMED_DB`` (6 dB) above the noise;
- an extension that validates worse than the nominal applied in 0 % of all cases;
- the unlisted time-invariant effects (the pole-zero pair, the second delay path) that
  change y by at least ``verdict.NAMED_DB`` above the noise (``beyond.effect_db``)
  described in >= 90 %: a correction offered and validating better than the nominal, or
  the listed causes validating better and fitting the validation record as the true loop
  does (residual within ``verdict.TRUTH_RATIO`` of the truth's: nothing left that any
  correction could fit); also shown: the correction alone, over every case;
- the time-varying gain, which no time-invariant model or correction describes: the plant
  named as changing within the record in >= 90 % (also shown: that finding in the other
  cases, where it is a false alarm).

    make bench-diagnose PART=D    # or: .venv/bin/python benchmarks/bench_diagnose_beyond.py
    .venv/bin/python benchmarks/bench_diagnose_beyond.py --per-cell 1 --per-effect 3
    .venv/bin/python benchmarks/bench_diagnose_beyond.py --case dead_zone:0.3:odd:5000001

Case seeds: ``seed * 10**6 + 1000 * cell + k``, cells numbered over (effect, level, design)
of the nonlinear effects, then the unlisted effects; ``--case`` re-runs one case.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

from mr_bench.beyond import DESIGNS, LEVELS, NONLINEAR, UNLISTED, draw_beyond
from mr_bench.verdict import NAMED_DB, judge_beyond

TARGETS = {"named": 95.0, "worse_applied": 0.0, "described": 90.0, "varying": 90.0}
#: The unlisted effects a time-invariant correction can describe (the correction's target).
INVARIANT = tuple(e for e in UNLISTED if e != "time_varying_gain")


def plan(per_cell: int, per_effect: int, seed: int, effects: list[str]) -> list[dict]:
    """Every case: effect, level, design and seed."""
    cells = list(itertools.product(NONLINEAR, LEVELS, DESIGNS)) + [
        (e, 0.0, "white") for e in UNLISTED
    ]  # numbered over every effect, so that a subset keeps its seeds
    cases = []
    for j, (e, lv, ds) in enumerate(cells):
        if e not in effects:
            continue
        k_max = per_cell if e in NONLINEAR else per_effect
        cases += [
            {"effect": e, "level": lv, "design": ds, "seed": seed * 10**6 + 1000 * j + k}
            for k in range(k_max)
        ]
    return cases


def run_case(case: dict, duration: float) -> dict:
    """Draw, diagnose and judge one case; a JSON-able record."""
    from mr_ident.diagnosis import diagnose
    from mr_ident.errors import DataError

    out = dict(case)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            kind = case["design"] if case["design"] != "white" else "odd"
            rng = np.random.default_rng(case["seed"])
            b = draw_beyond(
                case["effect"], rng, level=case["level"] or 0.3, kind=kind, duration=duration
            )
    except Exception:
        return out | {"status": "generator", "error": traceback.format_exc()}
    m = b.nominal
    out |= {
        "loop": f"{m.fs_high:g} Hz F={m.ratio}, {b.loop.form} order {b.loop.order}, "
        f"SNR {b.loop.snr_db:.0f} dB",
        "parameters": b.parameters,
        "distortion_db": None if math.isnan(b.distortion_db) else b.distortion_db,
        "effect_db": None if math.isnan(b.effect_db) else b.effect_db,
        "n_samples": b.data.n_samples,
        "draw_s": time.perf_counter() - t0,
    }
    t1 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = diagnose(m, b.data, b.validation)
    except DataError as err:
        return out | {"status": "data_error", "error": str(err)}
    except Exception:
        return out | {"status": "traceback", "error": traceback.format_exc()}
    truth = b.truth_fit()
    v = judge_beyond(b.nonlinear, b.distortion_db, d, b.effect_db, truth)
    c = d.correction
    return out | {
        "status": "ok",
        "seconds": time.perf_counter() - t1,
        "applied": [a.cause for a in d.applied],
        "fit_before": d.fit_before.y,
        "fit_after": d.fit_after.y,
        "truth_fit": None if math.isnan(truth) else truth,
        "correction": None if c is None else c.text(),
        "verdict": v.__dict__,
    }


def _pct(xs: list[bool]) -> str:
    return f"{100 * sum(xs) / len(xs):.0f} % ({sum(xs)}/{len(xs)})" if xs else "-"


def report(rows: list[dict]) -> str:
    """The markdown table, the targets and one line per miss."""
    ok = [r for r in rows if r["status"] == "ok"]
    lines = [
        "| effect | level | design | cases | named (>= 6 dB) | named (< 6 dB) | worse applied "
        "| correction offered | corrected | explained by causes | described (>= 6 dB) "
        "| time-varying named | median s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    keys = sorted({(r["effect"], r["level"], r["design"]) for r in rows})
    for e, lv, ds in keys:
        g = [r for r in ok if (r["effect"], r["level"], r["design"]) == (e, lv, ds)]
        n_all = sum(1 for r in rows if (r["effect"], r["level"], r["design"]) == (e, lv, ds))
        vs = [r["verdict"] for r in g]
        nl = e in NONLINEAR
        secs = np.median([r["seconds"] for r in g]) if g else math.nan
        lines.append(
            f"| {e} | {lv if nl else '-'} | {ds} | {len(g)}/{n_all} "
            f"| {_pct([v['named'] for v in vs if v['counts']]) if nl else '-'} "
            f"| {_pct([v['named'] for v in vs if not v['counts']]) if nl else '-'} "
            f"| {_pct([v['worse_applied'] for v in vs])} "
            f"| {_pct([v['offered'] for v in vs])} | {_pct([v['corrected'] for v in vs])} "
            f"| {_pct([v['explained'] for v in vs])} "
            f"| {'-' if nl else _pct([v['described'] for v in vs if v['counts']])} "
            f"| {_pct([v['varying'] for v in vs])} "
            f"| {secs:.0f} |"
        )
    vs = [r["verdict"] for r in ok]
    named = [
        r["verdict"]["named"] for r in ok if r["effect"] in NONLINEAR and r["verdict"]["counts"]
    ]
    worse = [v["worse_applied"] for v in vs]
    unl = [r["verdict"] for r in ok if r["effect"] in INVARIANT]
    tv = [r["verdict"]["varying"] for r in ok if r["effect"] == "time_varying_gain"]
    tv_false = [r["verdict"]["varying"] for r in ok if r["effect"] != "time_varying_gain"]
    corr = [v["corrected"] for v in unl]
    left = [v["corrected"] for v in unl if v["offered"]]
    seen = [v for v in unl if v["counts"]]
    desc = [v["described"] for v in seen]

    def rate(x: list[bool]) -> float:
        return 100 * sum(x) / len(x) if x else math.nan

    lines += [
        "",
        f"- nonlinearity named, distortion >= {NAMED_DB:g} dB above the noise: "
        f"{_pct(named)} (target >= {TARGETS['named']:g} %: "
        f"{'met' if rate(named) >= TARGETS['named'] else 'NOT met'})",
        f"- extension applied that validates worse than the nominal: {_pct(worse)} (target "
        f"{TARGETS['worse_applied']:g} %: {'met' if not any(worse) else 'NOT met'})",
        f"- unlisted time-invariant effects ({', '.join(INVARIANT)}) changing y >= "
        f"{NAMED_DB:g} dB above the noise, described (corrected, or the causes validating "
        f"better and fitting the validation record as the true loop does): {_pct(desc)} "
        f"(target >= "
        f"{TARGETS['described']:g} %: "
        f"{'met' if rate(desc) >= TARGETS['described'] else 'NOT met'}); of those, corrected: "
        f"{_pct([v['corrected'] for v in seen])}; effect below {NAMED_DB:g} dB: "
        f"{len(unl) - len(seen)} of {len(unl)}",
        f"- the same effects, every case: a correction offered and validating better than the "
        f"nominal {_pct(corr)}; of those where something was left after the causes: "
        f"{_pct(left)}; explained by the listed causes with nothing left: "
        f"{_pct([v['explained'] for v in unl])}; corrected or so explained: "
        f"{_pct([v['corrected'] or v['explained'] for v in unl])}",
        f"- time-varying gain, the plant named as changing within the record: {_pct(tv)} "
        f"(target >= {TARGETS['varying']:g} %: "
        f"{'met' if rate(tv) >= TARGETS['varying'] else 'NOT met'}); named so in the other "
        f"cases (false): {_pct(tv_false)}",
        f"- not run to the end: {len(rows) - len(ok)} "
        f"({', '.join(sorted({r['status'] for r in rows if r['status'] != 'ok'})) or 'none'})",
        "",
    ]
    for r in rows:
        v = r.get("verdict", {})
        if r["status"] != "ok":
            what = r["status"]
        elif v.get("worse_applied"):
            what = "an extension validating worse applied"
        elif r["effect"] in NONLINEAR and v.get("counts") and not v.get("named"):
            what = "not named"
        elif r["effect"] == "time_varying_gain" and not v.get("varying"):
            what = "not named time-varying"
        elif r["effect"] in INVARIANT and not v.get("corrected"):
            what = "not corrected" + (
                f", effect below {NAMED_DB:g} dB" if not v.get("counts")
                else ", described by the causes" if v.get("described") else ""
            )  # fmt: skip
        else:
            continue
        case = f"{r['effect']}:{r['level']}:{r['design']}:{r['seed']}"
        db = r.get("distortion_db") if r["effect"] in NONLINEAR else r.get("effect_db")
        lines.append(
            f"- {case} {what}: {r.get('loop', '')}; "
            f"{'-' if db is None else f'{db:.0f}'} dB; applied {r.get('applied')}; fit "
            f"{r.get('fit_before', math.nan):.1f} -> {r.get('fit_after', math.nan):.1f}; "
            f"{r.get('correction') or 'no correction'}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--per-cell", type=int, default=5, help="cases per nonlinear effect, level, design"
    )
    p.add_argument("--per-effect", type=int, default=20, help="cases per unlisted effect")
    p.add_argument("--effects", default=",".join(NONLINEAR + UNLISTED))
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--duration", type=float, default=10.0, help="s of each white-noise record")
    p.add_argument("--case", help="EFFECT:LEVEL:DESIGN:SEED, one case")
    p.add_argument("--shuffle", action="store_true", help="run the plan in a random order")
    p.add_argument("--max-seconds", type=float, default=math.inf, help="stop starting cases after")
    p.add_argument("--json", type=Path)
    a = p.parse_args(argv)
    effects = a.effects.split(",")
    unknown = set(effects) - set(NONLINEAR + UNLISTED)
    if unknown:
        known = ", ".join(NONLINEAR + UNLISTED)
        print(
            f"error: --effects must name effects of {known}, got {sorted(unknown)}",
            file=sys.stderr,
        )
        return 2
    if a.case:
        e, lv, ds, sd = a.case.split(":")
        cases = [{"effect": e, "level": float(lv), "design": ds, "seed": int(sd)}]
    else:
        cases = plan(a.per_cell, a.per_effect, a.seed, effects)
        if a.shuffle:
            order = np.random.default_rng(a.seed).permutation(len(cases))
            cases = [cases[i] for i in order]
    rows, t0 = [], time.perf_counter()
    for case in cases:
        if time.perf_counter() - t0 > a.max_seconds:
            break
        rows.append(run_case(case, a.duration))
    wall = time.perf_counter() - t0
    print(report(rows))
    print(f"\n{len(rows)} of {len(cases)} cases in {wall / 60:.1f} min")
    if a.json:
        a.json.write_text(json.dumps({"cases": rows, "wall_s": wall}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
