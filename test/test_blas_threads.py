# SPDX-License-Identifier: Apache-2.0
"""The process's BLAS thread limit (numerics.threads.one_blas_thread), shared by threads.

Contexts on several threads overlap and leave in any order (the node identifies on one
thread and diagnoses on another): while any is held every BLAS runs on one thread, SciPy's
too once a context asked for it, and after the last the libraries' own limits are back.
"""

from __future__ import annotations

import threading

import pytest

from mr_ident.numerics import threads

threadpoolctl = pytest.importorskip("threadpoolctl")


def _blas_threads() -> set[int]:
    info = threadpoolctl.ThreadpoolController().info()
    return {i["num_threads"] for i in info if i["user_api"] == "blas"}


def test_overlapping_contexts_leaving_out_of_order_restore_the_limits():
    before = _blas_threads()
    a = threads.one_blas_thread()
    b = threads.one_blas_thread(with_scipy=True)
    a.__enter__()
    b.__enter__()
    assert _blas_threads() == {1}
    a.__exit__(None, None, None)  # the first to enter leaves first: b still holds it
    assert _blas_threads() == {1}
    b.__exit__(None, None, None)
    assert _blas_threads() == before


def test_contexts_on_threads_hold_one_thread_throughout():
    before = _blas_threads()
    seen: list[set[int]] = []

    def work(scipy: bool) -> None:
        for _ in range(100):
            with threads.one_blas_thread(with_scipy=scipy):
                seen.append(_blas_threads())

    pool = [threading.Thread(target=work, args=(k % 2 == 0,)) for k in range(4)]
    for t in pool:
        t.start()
    for t in pool:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in pool)
    assert seen and all(s == {1} for s in seen)
    assert _blas_threads() == before
