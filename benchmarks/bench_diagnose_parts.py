# SPDX-License-Identifier: Apache-2.0
"""Benchmark: diagnose on random loops whose controller differs, or nonlinear under white r.

Parts (``--part``):

- ``controller``: a loop of ``mr_bench.scenarios.draw_loop`` whose machine controller is
  not the model's: its gain U(0.7, 0.85) or U(1.15, 1.4) times the model's, its output
  applied 1..F high-rate samples later, a notch the model lacks, a retuned controller
  (each numerator coefficient 5-20 % off), or the gain and the plant's gain
  (U(0.75, 0.9)) both wrong. Two records of white r. Named: the controller-side cause
  applied (for ``both``, the plant's gain too); a plant cause applied where the plant is
  the model's counts as a plant cause for a controller difference.
- ``nonlinear``: ``mr_bench.beyond.draw_random_nonlinear``: a saturation or dead zone at
  the plant's input (level 1: the saturation at σ_u, the dead zone 2σ_u wide) or a sensor
  that clips 5 % of y, two records of white r. Named: the verdict (JSON ``cause``) is
  ``nonlinear_distortion``, or the distortion is among the findings; named a plant that
  changes in time: a false finding.
- ``linear``: loops with nothing wrong (the model exact), white r: the false alarms of the
  higher-order correlation test (``diagnosis.criterion.correlation``, level 1e-3) and of
  the verdict (anything but ``none``).

Every case also checks the verdict's rule: never ``none`` where the model leaves part of y
unexplained beyond the noise. Seeds ``seed * 10**6 + 1000 * kind + k``.

    .venv/bin/python benchmarks/bench_diagnose_parts.py --part controller --per-kind 5

``--jsonl FILE`` appends each case's row to FILE as it is judged (a long run keeps what it
has done); ``--report-from FILE ...`` prints the tables of such files.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import traceback
import warnings
from dataclasses import replace

import numpy as np

from mr_bench.beyond import RANDOM_NONLINEAR, draw_random_nonlinear
from mr_bench.scenarios import draw_loop

CONTROLLER_KINDS = ("gain", "delay", "notch", "retuned", "both")
CONTROLLER_SIDE = {"controller_gain", "control_delay", "controller_notch", "controller_retuned"}
EXPECTED = {
    "gain": "controller_gain",
    "delay": "control_delay",
    "notch": "controller_notch",
    "retuned": "controller_retuned",
    "both": "controller_gain",
}


def _controller_case(kind: str, rng: np.random.Generator, duration: float):
    """(nominal, data, validation, truth's plant gain) of one controller case."""
    from mr_ident.diagnosis.causes.cause import Choice
    from mr_ident.diagnosis.causes.registry import CAUSES
    from mr_ident.numerics.systems.simulate import loop_poles, simulate

    for _ in range(100):
        m = draw_loop(rng, duration=duration).nominal
        if kind == "retuned" and (m.n_u != 1 or m.controller_notches):
            continue
        plant_gain = 1.0
        if kind in ("gain", "both"):
            g = rng.uniform(0.7, 0.85) if rng.random() < 0.5 else rng.uniform(1.15, 1.4)
            true = CAUSES["controller_gain"].apply(m, Choice("controller_gain", (g,)))
            if kind == "both":
                plant_gain = rng.uniform(0.75, 0.9)
                true = replace(true, plant_gain=plant_gain)
        elif kind == "delay":
            true = replace(m, control_delay=m.control_delay + int(rng.integers(1, m.ratio + 1)))
        elif kind == "notch":
            f = float(np.exp(rng.uniform(np.log(m.fs_low / 40), np.log(0.4 * m.fs_low))))
            c = Choice("controller_notch", (f, rng.uniform(0.1, 0.5), rng.uniform(0.05, 0.3)))
            true = CAUSES["controller_notch"].apply(m, c)
        else:
            K = m.controller
            b = np.array(K.num[0][0], float)
            nz = b != 0
            b[nz] *= 1 + rng.uniform(0.05, 0.2, nz.sum()) * rng.choice([-1, 1], nz.sum())
            true = replace(m, controller=type(K)(((tuple(b),),), K.den, K.dt))
        if np.max(np.abs(loop_poles(true))) >= 0.999:
            continue
        recs = [simulate(true, duration=duration, rng=rng) for _ in range(2)]
        return m, recs[0], recs[1], plant_gain
    raise RuntimeError(f"no stable loop drawn for {kind}")


def _rule_ok(d) -> bool:
    """The verdict never reads none where y is left unexplained beyond the noise."""
    return not (d.cause == "none" and d.unexplained is not None and d.unexplained.significant)


def run_case(part: str, kind: str, seed: int, duration: float) -> dict:
    """One case, judged."""
    from mr_ident.diagnosis import diagnose
    from mr_ident.diagnosis.causes.registry import CAUSES
    from mr_ident.diagnosis.report import report_dict
    from mr_ident.numerics.systems.simulate import simulate

    out: dict = {"part": part, "kind": kind, "seed": seed}
    rng = np.random.default_rng(seed)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if part == "controller":
                m, data, val, plant_gain = _controller_case(kind, rng, duration)
            elif part == "nonlinear":
                b = draw_random_nonlinear(kind, rng, level=1.0, duration=duration)
                m, data, val = b.nominal, b.data, b.validation
            else:
                m = draw_loop(rng, duration=duration).nominal
                data, val = (simulate(m, duration=duration, rng=rng) for _ in range(2))
            t0 = time.perf_counter()
            d = diagnose(m, data, val)
            out["seconds"] = time.perf_counter() - t0
    except Exception:
        return out | {"status": "error", "error": traceback.format_exc(limit=3)}
    applied = [a.cause for a in d.applied]
    rep = report_dict(d, extended_model=None, alpha=0.01)
    c = d.correlation
    out |= {
        "status": "ok",
        "loop": f"{m.fs_high:g} Hz F={m.ratio}",
        "cause": d.cause,
        "applied": applied,
        "json_agrees": rep["cause"] == d.cause,
        "rule_ok": _rule_ok(d),
        "hos_p": None if c is None else c.p,
        "hos_run": c is not None,
        "time_varying": d.time_varying,
        "fit": (d.fit_before.y, d.fit_after.y),
    }
    if part == "controller":
        want = EXPECTED[kind]
        plant = [a for a in applied if a in CAUSES and CAUSES[a].plant_side]
        named = want in applied and (kind != "both" or "gain_error" in applied)
        out["named"] = named
        out["plant_for_controller"] = (
            bool(plant) if kind != "both" else bool(set(plant) - {"gain_error"})
        )
    elif part == "nonlinear":
        out["named"] = d.cause == "nonlinear_distortion" or d.nonlinear
        out["headline_named"] = d.cause == "nonlinear_distortion"
    else:
        out["false_hos"] = bool(c is not None and c.detected)
        out["false_verdict"] = d.cause != "none"
    return out


def _pct(xs: list[bool]) -> str:
    return f"{100 * sum(xs) / len(xs):.0f} % ({sum(xs)}/{len(xs)})" if xs else "-"


def report(rows: list[dict]) -> str:
    """A markdown table per kind, and the misses."""
    lines = [
        "| part | kind | cases | named | verdict names it | plant cause for a controller "
        "difference | test run | false NL | false verdict | time-varying named | rule kept "
        "| median s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for part, kind in sorted({(r["part"], r["kind"]) for r in rows}):
        g = [r for r in rows if (r["part"], r["kind"]) == (part, kind) and r["status"] == "ok"]
        n_all = sum(1 for r in rows if (r["part"], r["kind"]) == (part, kind))
        med = np.median([r["seconds"] for r in g]) if g else math.nan

        def col(key: str, g: list[dict] = g) -> str:
            return _pct([bool(r[key]) for r in g if key in r])

        lines.append(
            f"| {part} | {kind} | {len(g)}/{n_all} | {col('named')} | {col('headline_named')} "
            f"| {col('plant_for_controller')} | {col('hos_run')} "
            f"| {_pct([bool(r['false_hos']) for r in g if 'false_hos' in r and r['hos_run']])} "
            f"| {col('false_verdict')} | {col('time_varying')} | {col('rule_ok')} | {med:.1f} |"
        )
    lines.append("")
    for r in rows:
        if r["status"] != "ok":
            lines.append(f"- {r['part']}:{r['kind']}:{r['seed']} {r['status']}: {r['error']}")
        elif r.get("named") is False or r.get("plant_for_controller") or r.get("false_hos"):
            lines.append(
                f"- {r['part']}:{r['kind']}:{r['seed']} {r['loop']}: cause {r['cause']}, "
                f"applied {r['applied']}, fit {r['fit'][0]:.1f} -> {r['fit'][1]:.1f}, "
                f"NL p {r['hos_p']}"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--part", choices=("controller", "nonlinear", "linear"))
    p.add_argument("--per-kind", type=int, default=10)
    p.add_argument("--seed", type=int, default=9)
    p.add_argument("--duration", type=float, default=20.0, help="s of each record (20)")
    p.add_argument("--case", help="KIND:SEED, one case")
    p.add_argument("--jsonl", help="append each case's row to this file as it is judged")
    p.add_argument("--report-from", nargs="+", help="print the tables of these --jsonl files")
    a = p.parse_args(argv)
    if a.report_from:
        rows = [json.loads(line) for f in a.report_from for line in open(f) if line.strip()]
        print(report(rows))
        return 0
    if a.part is None:
        p.error("--part is required (or --report-from)")
    kinds = {
        "controller": CONTROLLER_KINDS,
        "nonlinear": RANDOM_NONLINEAR,
        "linear": ("exact",),
    }[a.part]
    if a.case:
        kind, seed = a.case.split(":")
        plan = [(kind, int(seed))]
    else:
        plan = [
            (k, a.seed * 10**6 + 1000 * j + i)
            for j, k in enumerate(kinds)
            for i in range(a.per_kind)
        ]
    t0 = time.perf_counter()
    rows = []
    for kind, seed in plan:
        rows.append(run_case(a.part, kind, seed, a.duration))
        if a.jsonl:
            with open(a.jsonl, "a") as f:
                f.write(json.dumps(rows[-1], default=float) + "\n")
        print(f"{kind}:{seed} {rows[-1].get('cause', rows[-1]['status'])}", file=sys.stderr)
    print(report(rows))
    print(f"\n{len(rows)} cases in {(time.perf_counter() - t0) / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
