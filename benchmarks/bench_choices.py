# SPDX-License-Identifier: Apache-2.0
"""The measurements behind choices the code states without their figures.

Each line names the choice (and the module that makes it) and times both sides of it:

- the allocator setting (``mr_ident.allocator.keep_freed_memory``): the paper's full size
  (6000 s at 240 Hz, F = 3, ``freq-lifted``, n = 8, P_h and the PFG, one worker), five
  identifications in one fresh process with it and five in one without; the first of each
  process is the cold one the node's warm-up pays (``mr_ident.live.estimate.warm_up``);
- the controller's response cached per window length (``live.estimate``): K_l of the
  paper's controller on 480 000 low-rate bins;
- a sample block's ``Float64MultiArray.data`` as an ``array.array`` from bytes against a
  numpy array (``ros/messages.py``; skipped without ``std_msgs``);
- the imports kept off the start-up path (``numerics/catalog.py``, ``numerics/systems/lti.py``
  and ``simulate.py``): ``python -X importtime``, cumulative, best of three fresh processes;
- ``project_out`` by its normal equations against the SVD of the scaled columns
  (``diagnosis/criterion/objective.py``), m = 42 000, k = 10;
- the simulator's modal drive as two real products against one real-by-complex product
  (``numerics/systems/simulate.py``).

Timings are the best of several runs on one BLAS thread (the identifications: each run).

    .venv/bin/python benchmarks/bench_choices.py [--skip-identify]
"""

from __future__ import annotations

import argparse
import array
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]

#: One process's five paper-size identifications: argv[1] "keep" or "plain", argv[2] the data.
_IDENTIFY = """
import sys, time
import numpy as np
if sys.argv[1] == "keep":
    from mr_ident.allocator import keep_freed_memory
    keep_freed_memory()
from mr_ident.io.modelfile import load_model
from mr_ident.numerics.identify import identify
m = load_model(sys.argv[3])
z = np.load(sys.argv[2])
r, u, y = z["r"], z["u"], z["y"]
Kl = m.controller.dft_response(r.shape[0] // 3)
for _ in range(5):
    t = time.perf_counter()
    identify(r, u, y, fs_high=240.0, ratio=3, n=8, controller_low=Kl, keep_lifted=False,
             workers=1)
    print(f"{time.perf_counter() - t:.2f}", end=" ", flush=True)
"""


def best(f: Callable[[], object], k: int = 5) -> float:
    """The least wall time of ``k`` calls after one warm-up call."""
    f()
    times = []
    for _ in range(k):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return min(times)


def allocator() -> None:
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.systems.simulate import simulate

    model = ROOT / "config" / "paper_example.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "paper.npz"
        s = simulate(load_model(model), duration=6000.0, rng=np.random.default_rng(0))
        np.savez(data, r=s.r, u=s.u, y=s.y)
        for mode in ("keep", "plain", "keep", "plain"):
            out = subprocess.run(
                [sys.executable, "-c", _IDENTIFY, mode, str(data), str(model)],
                capture_output=True,
                text=True,
                check=True,
                cwd=ROOT,
            ).stdout
            what = "keep_freed_memory" if mode == "keep" else "glibc's defaults "
            print(f"paper size, one worker, {what}: {out.strip()} s (the first: cold)")


def import_times() -> None:
    for module in (
        "scipy.signal",
        "scipy.linalg",
        "scipy.fft",
        "mr_ident.numerics.lifted.methods",
        "mr_ident.numerics.catalog",
    ):
        runs = []
        for _ in range(3):
            err = subprocess.run(
                [sys.executable, "-X", "importtime", "-c", f"import numpy; import {module}"],
                capture_output=True,
                text=True,
                check=True,
                cwd=ROOT,
            ).stderr
            line = next(x for x in err.splitlines() if x.rstrip().endswith(f"| {module}"))
            runs.append(int(line.split("|")[1]) / 1e6)
        print(f"import {module} after numpy: {min(runs) * 1e3:.1f} ms (cumulative, best of 3)")


def messages() -> None:
    try:
        from std_msgs.msg import Float64MultiArray
    except ImportError:
        print("std_msgs not installed: the message line skipped")
        return
    msg = Float64MultiArray()
    for n in (1000, 3000):
        data = np.random.default_rng(0).standard_normal(n)

        def from_bytes(data: np.ndarray = data) -> None:
            msg.data = array.array("d", np.ascontiguousarray(data, dtype=np.float64).tobytes())

        def from_numpy(data: np.ndarray = data) -> None:
            msg.data = data

        ta, tb = best(from_bytes, 7), best(from_numpy, 7)
        print(
            f"Float64MultiArray.data, {n} samples: array.array {ta * 1e6:.1f} us, numpy "
            f"array {tb * 1e6:.1f} us ({tb / ta:.0f}x)"
        )


def kernels() -> None:
    from mr_ident.diagnosis.criterion.objective import project_out
    from mr_ident.io.modelfile import load_model

    rng = np.random.default_rng(0)
    m = load_model(ROOT / "config" / "paper_example.yaml")
    t = best(lambda: m.controller.dft_response(480_000), 3)
    print(f"K_l of the paper's controller on 480 000 low-rate bins: {t * 1e3:.1f} ms")
    A, b = rng.standard_normal((42_000, 10)), rng.standard_normal(42_000)

    def by_svd() -> np.ndarray:
        U = np.linalg.svd(A / np.linalg.norm(A, axis=0), full_matrices=False)[0]
        return b - U @ (U.T @ b)

    tp, ts = best(lambda: project_out(A, b)), best(by_svd)
    print(
        f"project_out, m = 42 000, k = 10: normal equations {tp * 1e3:.2f} ms, SVD "
        f"{ts * 1e3:.2f} ms ({ts / tp:.1f}x)"
    )
    for M, n_in, n in ((144_000, 1, 8), (144_000, 3, 24)):
        w = rng.standard_normal((M, n_in))
        B = rng.standard_normal((n, n_in)) + 1j * rng.standard_normal((n, n_in))
        tc = best(lambda w=w, B=B: w @ B.T)
        tr = best(lambda w=w, B=B: w @ B.real.T + 1j * (w @ B.imag.T))
        print(
            f"modal drive, {M} samples, {n_in} inputs, {n} modes: one real-by-complex "
            f"product {tc * 1e3:.2f} ms, two real products {tr * 1e3:.2f} ms"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-identify", action="store_true", help="not the allocator's runs")
    args = ap.parse_args()
    print(f"numpy {np.__version__}")
    with threadpool_limits(1):
        kernels()
        messages()
    import_times()
    if not args.skip_identify:
        allocator()


if __name__ == "__main__":
    main()
