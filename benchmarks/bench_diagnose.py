# SPDX-License-Identifier: Apache-2.0
"""Benchmark: diagnose on seeded random loops with hidden causes.

Every case is a loop drawn by ``mr_bench.scenarios.draw_scenario`` (fs_high in
{240, 500, 1000} Hz, F in {1, 2, 3, 5}, plants of order 2-6 in modal and cascaded form,
with and without integrators, random stabilising low-rate controllers, SNR 20-60 dB), a
record of ``--duration`` seconds, and one hidden cause, a pair of two different causes
(drawn uniformly from the pairs of the causes run) or nothing. ``diagnose(nominal,
data)`` must name it (a pair: apply both and nothing else; nothing hidden: apply
nothing), with every parameter within ``verdict.TOLERANCES``, and leave a validation fit
of y within ``verdict.MAX_FIT_GAP`` points of the true model's. Exceptions other than
DataError are tracebacks. A parameter outside its tolerance is also tested against the
data: the case counts as *credible* when the true model's likelihood ratio against the
fit (``verdict.likelihood_ratio``) is within the chi-square quantile at
``verdict.CONFIDENCE`` (the record cannot tell the truth from the fit). Before looking at
the answer, each case is also classed *determinable* when the record holds the hidden
values to their tolerances at all: every tolerance at least ``information.DETERMINED``
Cramér-Rao std at the truth (``information.truth_std``, on the diagnosis's criterion and,
for the controller's path, the controller's own equation); the
success rate among those is what an estimator can be asked for. Prints a markdown
table (per cause, pairs, none), the targets, and one line per failure; ``--json`` writes
every case. Targets: >= 95 % per single cause, >= 85 % for pairs, >= 95 % of the "none"
loops without a false cause, zero tracebacks.

    make bench-diagnose    # or: .venv/bin/python benchmarks/bench_diagnose.py [options]
    .venv/bin/python benchmarks/bench_diagnose.py --per-cause 5 --pairs 5 --none 5
    .venv/bin/python benchmarks/bench_diagnose.py --case gain_error+control_delay:1900003
    .venv/bin/python benchmarks/bench_diagnose.py --report A.json B.json C.json  # merged

The whole plan (1200 cases) takes about 45 min on 2 cores;
``make bench-diagnose`` runs it in three parts (``PART=A``: nothing hidden and the first
five causes, ``B``: the other five, ``C``: the pairs), each its own JSON, and prints them
merged.

Case seeds: ``seed * 10**6 + 10**4 * (1 + index of the cause) + k`` for single causes,
``seed * 10**6 + k`` for "none", ``seed * 10**6 + 900000 + k`` for pairs; ``--case``
re-runs one case from its causes and seed, as the failure lines print them.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
import traceback
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

from mr_bench.information import determinable, truth_std
from mr_bench.scenarios import Scenario, draw_scenario
from mr_bench.verdict import (
    CAUSE_NAMES,
    CONFIDENCE,
    COVERAGE,
    MAX_FIT_GAP,
    TOLERANCES,
    in_region,
    judge,
    likelihood_ratio,
)
from mr_ident.errors import DataError

TARGETS = {"single": 95.0, "pairs": 85.0, "none": 95.0}


def known_causes() -> tuple[set[str] | None, str]:
    """The causes the diagnosis knows (its CAUSES registry), or None and why not."""
    try:
        try:
            from mr_ident.diagnosis.causes.cause import CAUSES
        except ImportError:
            from mr_ident.diagnosis.causes.registry import CAUSES  # the registry's newer home
        return set(CAUSES), ""
    except Exception as err:  # the core does not import: no case can run
        return None, f"{type(err).__name__}: {err}"


def plan(
    causes: list[str], per_cause: int, pairs: int, none: int, seed: int, skip: int = 0
) -> list[dict]:
    """Every case: group ("none", a cause name or "pairs"), hidden causes and seed.

    ``skip``: each group's first cases left out (a plan run in pieces keeps its seeds).
    """
    base = seed * 10**6
    cases = [{"group": "none", "causes": [], "seed": base + k} for k in range(none)]
    for c in causes:
        j = CAUSE_NAMES.index(c)
        cases += [
            {"group": c, "causes": [c], "seed": base + 10**4 * (1 + j) + k}
            for k in range(per_cause)
        ]
    all_pairs = list(itertools.combinations(causes, 2))
    rng = np.random.default_rng([seed, 2])
    for k in range(pairs if all_pairs else 0):
        pair = all_pairs[int(rng.integers(len(all_pairs)))]
        cases.append({"group": "pairs", "causes": list(pair), "seed": base + 900000 + k})
    seen: dict[str, int] = {}
    kept = []
    for case in cases:
        seen[case["group"]] = seen.get(case["group"], 0) + 1
        if seen[case["group"]] > skip:
            kept.append(case)
    return kept


def describe(sc: Scenario) -> str:
    """One line on the loop: rates, plant, controller and SNR."""
    lp, m = sc.loop, sc.nominal
    return (
        f"{m.fs_high:g} Hz F={m.ratio}, {lp.form} order {lp.order} ({lp.integrators} int, "
        f"{len(lp.modes)} modes), {lp.controller_kind} at {lp.gain_fraction:.2f} of "
        f"critical, SNR {lp.snr_db:.0f} dB"
    )


def _text(cause: str, p: dict[str, float]) -> str:
    return cause + "(" + ", ".join(f"{k}={x:.4g}" for k, x in p.items()) + ")"


def run_case(case: dict, duration: float) -> dict:
    """Draw the case's scenario, diagnose it, judge it; a JSON-able record."""
    from mr_ident.diagnosis import diagnose
    from mr_ident.diagnosis.criterion.prediction import time_fit

    out = dict(case)
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the generator's simulations
            sc = draw_scenario(
                case["causes"], np.random.default_rng(case["seed"]), duration=duration
            )
    except Exception:
        return out | {"status": "generator", "error": traceback.format_exc()}
    out |= {
        "loop": describe(sc),
        "hidden": [{"cause": h.cause, "parameters": h.parameters} for h in sc.hidden],
        "changes": list(sc.changes),
        "n_samples": sc.data.n_samples,
        "draw_s": time.perf_counter() - t0,
    }
    t1 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            d = diagnose(sc.nominal, sc.data)
            status, error = "ok", ""
        except DataError as err:
            status, error = "data_error", f"DataError: {err}"
        except Exception:
            status, error = "traceback", traceback.format_exc()
    out |= {
        "seconds": time.perf_counter() - t1,
        "warnings": sorted({f"{w.category.__name__}: {w.message}" for w in caught}),
        "status": status,
        "error": error,
    }
    if status != "ok":
        return out
    try:
        applied = [(c.cause, {k: float(v) for k, v in c.parameters.items()}) for c in d.applied]
        fit_true = time_fit(sc.true, sc.data, d.traces["start"]).y
        stds = [{k: float(v) for k, v in c.std.items()} for c in d.applied]
        equivalents = [
            [(q.cause, dict(q.parameters), dict(q.std), q.delta_bic) for q in c.equivalents]
            for c in d.applied
        ]
        rel = d.relation
        settled = {c.cause for c in rel.choices} if rel is not None and rel.settles else set()
        lr = likelihood_ratio(d, sc.true)
        bounds = truth_std(sc.nominal, sc.hidden, d.criterion, d.criterion.rec)
        v = judge(
            sc,
            applied,
            fit_true - d.fit_after.y,
            stds,
            [[e[:3] for e in q] for q in equivalents],
            lr,
        )
    except Exception:
        return out | {"status": "traceback", "error": traceback.format_exc()}
    return out | {
        "applied": [
            {
                "cause": c,
                "parameters": p,
                "std": sd,
                "settled": c in settled,  # by the controller's own equation, to rounding
                "equivalents": [
                    {"cause": e, "parameters": ep, "std": es, "delta_bic": db}
                    for e, ep, es, db in eq
                ],
            }
            for (c, p), sd, eq in zip(applied, stds, equivalents, strict=True)
        ],
        "fit_before": d.fit_before.y,
        "fit_after": d.fit_after.y,
        "fit_true": fit_true,
        "fit_gap": v.fit_gap,
        "named": v.named,
        "parameters_ok": v.parameters_ok,
        "success": v.success,
        "consistent": v.consistent,
        "stated": v.stated,
        "credible": v.credible,
        "fixed": v.fixed,
        "likelihood_ratio": lr,
        "truth_in_region": in_region(sc, lr),
        "truth_std": bounds,
        "determinable": determinable(sc.hidden, bounds, sc.nominal.fs_high),
        "misses": list(v.misses),
    }


_LIMITS: list[Any] = []  # keeps the worker's thread limit alive


def _worker_init() -> None:
    """One BLAS thread per worker process: the pool's processes share the cores."""
    from threadpoolctl import threadpool_limits

    _LIMITS.append(threadpool_limits(limits=1, user_api="blas"))


def _pct(xs: list[bool]) -> str:
    return f"{100 * np.mean(xs):.0f} %" if xs else "–"


def _med(xs: list[float], q: float = 50.0, fmt: str = ".2f") -> str:
    return format(float(np.percentile(xs, q)) + 0.0, fmt).replace("-0.00", "0.00") if xs else "–"


def table(records: list[dict], groups: list[str]) -> tuple[str, dict[str, float]]:
    """The markdown table and each group's success rate (%)."""
    head = (
        "| hidden | cases | named first | parameters in tolerance | success | success, damped "
        "pairs' frequency to a fixed 2 % | success or truth in "
        f"{100 * CONFIDENCE:g} % region | success within {COVERAGE:g} std | with stated "
        "equivalents | determinable | success where determinable | median fit gap | median s "
        "| p95 s |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    )
    rows, rates = [head], {}
    for g in groups:
        rs = [r for r in records if r["group"] == g]
        if not rs:
            continue
        ok = [r for r in rs if r.get("status") == "ok"]
        named = [bool(r.get("named")) for r in rs]
        params = [bool(r.get("parameters_ok")) for r in rs] if g != "none" else []
        success = [bool(r.get("success")) for r in rs]
        credible = [bool(r.get("success") or r.get("credible")) for r in rs]
        fixed = [bool(r.get("fixed")) for r in rs]
        loose = [bool(r.get("success") or r.get("consistent")) for r in rs]
        stated = [bool(r.get("success") or r.get("consistent") or r.get("stated")) for r in rs]
        det = [r for r in rs if r.get("determinable")]
        has_det = any("determinable" in r for r in rs) and g != "none"
        gaps = [r["fit_gap"] for r in ok]
        secs = [r["seconds"] for r in ok]  # diagnoses that ran to the end
        rates[g] = 100 * float(np.mean(success))
        label = "none (nothing named)" if g == "none" else g
        rows.append(
            f"| {label} | {len(rs)} | {_pct(named)} | {_pct(params)} | {_pct(success)} "
            f"| {_pct(fixed) if any('fixed' in r for r in rs) else '–'} "
            f"| {_pct(credible) if any('credible' in r for r in rs) else '–'} "
            f"| {_pct(loose)} | {_pct(stated)} "
            f"| {_pct([bool(r.get('determinable')) for r in rs]) if has_det else '–'} "
            f"| {_pct([bool(r.get('success')) for r in det]) if has_det else '–'} "
            f"| {_med(gaps)} | {_med(secs, fmt='.1f')} | {_med(secs, 95, '.1f')} |"
        )
    return "\n".join(rows), rates


def failure_line(r: dict) -> str:
    """One line per failed case: seed, what was hidden and named, the misses, the gap."""
    hidden = (
        ", ".join(_text(h["cause"], h["parameters"]) for h in r.get("hidden", [])) or "nothing"
    )
    where = f"`{'+'.join(r['causes']) or 'none'}:{r['seed']}` ({r.get('loop', '?')}): hid {hidden}"
    if r.get("status") != "ok":
        last = r.get("error", "").strip().splitlines()[-1:] or ["?"]
        return f"- {where}; {r.get('status')}: {last[0]}"

    def said(a: dict) -> str:
        alts = " or ".join(_text(q["cause"], q["parameters"]) for q in a.get("equivalents", []))
        return _text(a["cause"], a["parameters"]) + (f" (or, as well, {alts})" if alts else "")

    named = ", ".join(said(a) for a in r["applied"]) or "nothing"
    line = f"- {where}; named {named}; fit gap {r['fit_gap']:.2f}"
    if "likelihood_ratio" in r:
        line += f"; truth's likelihood ratio {r['likelihood_ratio']:.1f}" + (
            " (within the region)" if r.get("credible") else ""
        )
    if r.get("determinable") is False:
        crlb = "; ".join(
            f"{h['cause']}.{k} ± {sd:.2g}"
            for h, sds in zip(r.get("hidden", []), r.get("truth_std", []), strict=False)
            for k, sd in sds.items()
        )
        line += f"; not determinable by the record (Cramér-Rao at the truth: {crlb})"
    return line + (f"; out of tolerance: {'; '.join(r['misses'])}" if r["misses"] else "")


def z_scores(records: list[dict]) -> np.ndarray:
    """(estimate - truth) / reported std of every found continuous parameter.

    Not of those the controller's own equation fixed: their std is rounding's, not noise's.
    """
    out = []
    for r in records:
        if not r.get("named"):
            continue
        for h in r.get("hidden", []):
            got = next((a for a in r["applied"] if a["cause"] == h["cause"]), None)
            if got is None or got.get("settled"):  # the equation's std: rounding, not noise
                continue
            for key, true in h["parameters"].items():
                sd = (got.get("std") or {}).get(key)
                if sd and math.isfinite(sd) and key in got["parameters"]:
                    out.append((got["parameters"][key] - true) / sd)
    return np.asarray(out, float)


def report(records: list[dict], groups: list[str], wall: float, meta: dict) -> str:
    """The whole markdown report."""
    text, rates = table(records, groups)
    status = {
        s: sum(r.get("status") == s for r in records)
        for s in ("traceback", "data_error", "generator")
    }
    singles = {g: v for g, v in rates.items() if g not in ("pairs", "none")}
    lines = [
        f"{len(records)} cases, {meta['duration']:g} s records, seed {meta['seed']}, "
        f"{meta['jobs']} jobs, "
        f"{wall / 60:.1f} min wall ({os.cpu_count()} CPUs)",
        "",
        text,
        "",
        "Named first: for pairs, both hidden causes applied and no other; for none, nothing "
        "applied. Fit gap: the true model's validation fit % of y minus the extended model's. "
        "Seconds: per diagnose call that ran to the end (no DataError).",
        "",
        f"Tracebacks: {status['traceback']}; DataErrors: {status['data_error']}; "
        f"generator errors: {status['generator']}.",
    ]

    def check(what: str, rate: float, target: float) -> str:
        return f"{what} >= {target:g} %: {'met' if rate >= target else 'NOT met'} ({rate:.0f} %)"

    checks = []
    if singles:
        worst = min(singles, key=singles.__getitem__)
        checks.append(check(f"single causes (lowest: {worst})", singles[worst], TARGETS["single"]))
    checks += [check(g, rates[g], TARGETS[g]) for g in ("pairs", "none") if g in rates]
    checks.append(f"zero tracebacks: {'met' if not status['traceback'] else 'NOT met'}")
    lines += ["Targets: " + "; ".join(checks) + ".", ""]
    tol = "; ".join(
        f"{c}: " + ", ".join(f"{k} {t}" for k, t in TOLERANCES[c].items()) for c in CAUSE_NAMES
    )
    lines += [f"Tolerances: {tol}; fit gap < {MAX_FIT_GAP:g} point.", ""]
    z = z_scores(records)
    if z.size:
        within = ", ".join(f"{100 * np.mean(np.abs(z) <= k):.0f} % within {k}" for k in (1, 2, 3))
        lines += [
            f"Reported std: of {z.size} found continuous parameters, {within} std of the "
            "truth (a Gaussian: 68, 95, 99.7 %).",
            "",
        ]
    lrs = [r for r in records if r.get("named") and r.get("hidden") and "likelihood_ratio" in r]
    if lrs:
        inside = [bool(r.get("truth_in_region")) for r in lrs if r.get("success")]
        lines += [
            f"Truth's likelihood ratio: of {len(inside)} successful cases, {_pct(inside)} have "
            f"the truth within the data's {100 * CONFIDENCE:g} % region (Wilks: "
            f"{100 * CONFIDENCE:g} %; a check of the criterion's noise scale); of "
            f"{len(lrs) - len(inside)} named cases with a parameter out of tolerance, "
            f"{sum(bool(r.get('credible')) for r in lrs if not r.get('success'))} have it.",
            "",
        ]
    failed = [r for r in records if not r.get("success")]
    lines.append(f"Failures ({len(failed)}):" if failed else "Failures: none.")
    lines += [failure_line(r) for r in failed]
    return "\n".join(lines)


def parse_case(text: str) -> dict:
    """``cause[+cause]:seed`` (``none:seed`` for nothing hidden) as a case."""
    names, _, seed = text.rpartition(":")
    causes = [] if names in ("", "none") else names.split("+")
    group = "none" if not causes else causes[0] if len(causes) == 1 else "pairs"
    return {"group": group, "causes": causes, "seed": int(seed)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--per-cause", type=int, default=100, help="cases per single cause (100)")
    ap.add_argument("--pairs", type=int, default=100, help="cases with a pair of causes (100)")
    ap.add_argument("--none", type=int, default=100, help="cases with nothing hidden (100)")
    ap.add_argument("--causes", default="", help="comma-separated subset (default: all known)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--skip",
        type=int,
        default=0,
        help="leave out each group's first K cases (--per-cause 100 --skip 50: cases 50-99)",
    )
    ap.add_argument("--duration", type=float, default=30.0, help="record seconds (30)")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (2)")
    ap.add_argument("--json", type=Path, help="write every case to this JSON file")
    ap.add_argument("--case", help="re-run one case, cause[+cause]:seed (none:seed)")
    ap.add_argument(
        "--report",
        type=Path,
        nargs="+",
        help="print the report of --json files again (several: the parts of one plan, merged)",
    )
    args = ap.parse_args(argv)
    if args.report:
        saved = [json.loads(p.read_text()) for p in args.report]
        rs = [r for s in saved for r in s["cases"]]
        present = {r["group"] for r in rs}
        groups = [g for g in (*CAUSE_NAMES, "pairs", "none") if g in present]
        wall = sum(s.get("wall_s", float("nan")) for s in saved)
        print(report(rs, groups, wall, saved[0]["args"]))
        return 0
    known, why = known_causes()
    if known is None:
        print(f"error: the diagnosis does not import ({why})", file=sys.stderr)
        return 1
    if args.case:
        try:
            case = parse_case(args.case)
            if any(c not in CAUSE_NAMES for c in case["causes"]):
                raise ValueError(case["causes"])
        except ValueError:
            print(
                f"error: --case must be cause[+cause]:seed with causes of "
                f"{', '.join(CAUSE_NAMES)} (or none:seed), got {args.case!r}",
                file=sys.stderr,
            )
            return 2
        r = run_case(case, args.duration)
        print(json.dumps(r, indent=1, default=float))
        print(failure_line(r) if not r.get("success") else "success")
        return 0
    wanted = [c for c in args.causes.split(",") if c] or list(CAUSE_NAMES)
    unknown = [c for c in wanted if c not in CAUSE_NAMES]
    if unknown:
        print(
            f"error: --causes must name {', '.join(CAUSE_NAMES)}; got {unknown}", file=sys.stderr
        )
        return 2
    causes = [c for c in wanted if c in known]
    skipped = [c for c in wanted if c not in known]
    if skipped:
        print(f"not run (the diagnosis does not know them yet): {', '.join(skipped)}")
    cases = plan(causes, args.per_cause, args.pairs, args.none, args.seed, args.skip)
    groups = [*causes, "pairs", "none"]
    t0 = time.perf_counter()
    records: list[dict] = []

    def progress(r: dict) -> None:
        records.append(r)
        status = r.get("status", "?")
        mark = "ok" if r.get("success") else "FAIL" if status == "ok" else status
        print(
            f"[{len(records):4d}/{len(cases)}] {'+'.join(r['causes']) or 'none'}:{r['seed']} "
            f"{mark} {r.get('seconds', 0.0):.1f} s",
            file=sys.stderr,
            flush=True,
        )

    if args.jobs <= 1:
        _worker_init()
        for c in cases:
            progress(run_case(c, args.duration))
    else:
        with ProcessPoolExecutor(max_workers=args.jobs, initializer=_worker_init) as pool:
            for fut in as_completed([pool.submit(run_case, c, args.duration) for c in cases]):
                progress(fut.result())
    wall = time.perf_counter() - t0
    order = {(c["group"], c["seed"]): i for i, c in enumerate(cases)}
    records.sort(key=lambda r: order[(r["group"], r["seed"])])
    meta = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
    print(report(records, groups, wall, meta))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        saved = {"args": meta, "wall_s": wall, "groups": groups, "cases": records}
        args.json.write_text(json.dumps(saved, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
