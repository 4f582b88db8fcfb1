# SPDX-License-Identifier: Apache-2.0
"""Threads over independent blocks of frequency bins.

NumPy and SciPy release the GIL inside their loops, so blocks of bins run in
parallel on threads. OpenBLAS's own threads are limited to one while the block
threads run: the two kinds of threads would otherwise compete for the cores, and the
block threads would gain nothing.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import numpy  # noqa: F401  (loads OpenBLAS before the controller below looks for it)

from ..errors import ConfigError

try:  # optional: no rosdep key (pip install threadpoolctl); without it BLAS is not limited
    from threadpoolctl import ThreadpoolController
except ImportError:  # pragma: no cover - the tests run with it
    ThreadpoolController = None

#: The BLAS libraries, found once at import. Finding them walks the loaded libraries
#: (``dl_iterate_phdr``, a Python callback under the loader's lock); done per call, it
#: deadlocked when another thread loaded an extension module meanwhile (the node's worker
#: identifying while the main thread imported a message type).
_BLAS = ThreadpoolController() if ThreadpoolController is not None else None

#: Why BLAS threads are not limited while bins run on threads ("" when they are): said
#: once by the programs that run identifications (the node's log, the CLI's notes).
BLAS_UNLIMITED = (
    ""
    if _BLAS is not None
    else "threadpoolctl is not installed (pip install threadpoolctl): OpenBLAS threads are "
    "not limited while bins run on threads, which can make identifications several times "
    "slower on a machine with many cores"
)

T = TypeVar("T")
R = TypeVar("R")


def resolve_workers(workers: int | None) -> int:
    """Number of threads: ``None`` means every CPU this process may run on."""
    if workers is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # not on Linux
            return max(1, os.cpu_count() or 1)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be None or an integer >= 1, got {workers!r}")
    return workers


def one_blas_thread(*, with_scipy: bool = False) -> Any:
    """Context: OpenBLAS on one thread.

    NumPy's BLAS, found at import and never searched again. ``with_scipy``: SciPy's own
    BLAS as well, which ``scipy.linalg`` loads (:func:`find_scipy_blas`, on the first such
    call unless done before): least squares' SVDs and SciPy's solvers run on it.
    Its threads cost more than they give on the small batched products of the LPM, and on
    the thin matrices of a least-squares fit they only compete with each other
    (docs/benchmarks.md, "Diagnosis speed").

    The limit is the process's: contexts on several threads (the node identifying on one
    and diagnosing on another) share one, counted. The first to enter sets it, the last
    to leave restores the libraries' own limits, whatever order they leave in; once
    SciPy's BLAS is found, the limit holds it too.
    """
    if _BLAS is None:
        return contextlib.nullcontext()
    return _shared_limit(with_scipy)


#: NumPy's and SciPy's BLAS (:func:`find_scipy_blas`).
_WITH_SCIPY: list[Any] = []
#: Guards the shared limit's count and the search for SciPy's BLAS.
_LOCK = threading.Lock()


class _Held:
    """The shared limit: how many contexts hold it, and the limiter that set it."""

    count = 0
    limiter: Any = None
    scipy = False


@contextlib.contextmanager
def _shared_limit(with_scipy: bool) -> Iterator[None]:
    with _LOCK:
        if with_scipy:
            _find_scipy_blas()
        scipy = bool(_WITH_SCIPY)
        if _Held.count == 0 or (scipy and not _Held.scipy):
            if _Held.limiter is not None:  # widened to SciPy's BLAS: set again from the start
                _Held.limiter.restore_original_limits()
            controller: Any = _WITH_SCIPY[0] if scipy else _BLAS
            _Held.limiter = controller.limit(limits=1, user_api="blas")
            _Held.scipy = scipy
        _Held.count += 1
    try:
        yield
    finally:
        with _LOCK:
            _Held.count -= 1
            if _Held.count == 0:
                _Held.limiter.restore_original_limits()
                _Held.limiter, _Held.scipy = None, False


def find_scipy_blas() -> None:
    """Load SciPy's BLAS and find the libraries again, once (for ``one_blas_thread``).

    The search walks the loaded libraries under the loader's lock (see :data:`_BLAS`): a
    program with threads calls this before they start (the node at configure).
    """
    with _LOCK:
        _find_scipy_blas()


def _find_scipy_blas() -> None:
    if ThreadpoolController is not None and not _WITH_SCIPY:
        import scipy.linalg  # noqa: F401, PLC0415 (loads SciPy's BLAS before the scan)

        _WITH_SCIPY.append(ThreadpoolController())


def thread_map(fn: Callable[[T], R], items: Iterable[T], workers: int) -> list[R]:
    """``[fn(i) for i in items]``, on ``workers`` threads when more than one, in order."""
    todo = list(items)
    if workers <= 1 or len(todo) <= 1:
        return [fn(i) for i in todo]
    with (
        one_blas_thread(),
        ThreadPoolExecutor(
            max_workers=min(workers, len(todo)), thread_name_prefix="mr_ident"
        ) as pool,
    ):
        return list(pool.map(fn, todo))
