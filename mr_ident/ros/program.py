# SPDX-License-Identifier: Apache-2.0
"""One shutdown path for the package's ROS programs.

``mr-ident record``, ``mr-ident-node``, ``mr-ident-sim``, ``mr-ident demo`` and
``mr-ident replay --publish`` all stop the same way on SIGINT or SIGTERM: finish
what they are writing, then exit 0.

Why not rclpy's own handlers: they shut the context down from the signal handler's
thread, at whatever point the main thread happens to be. Between a check of
``rclpy.ok()`` and the executor creating the timer of ``spin_once(timeout_sec=...)``
that gives ``RCLError: failed to create timer: the given context is not valid`` and a
traceback. Here the handlers only *record* the request (:class:`Stop`); the program's
loop sees it, returns, finalises its outputs, and only then is rclpy shut down, by
the program itself, once (:func:`ros_context`).

Waking a loop that is blocked inside ``rcl_wait`` (no Python bytecode runs there, so
a Python signal handler would wait for the next message): Python's C-level handler
writes the signal number to a wakeup fd (:func:`signal.set_wakeup_fd`); a watcher
thread reads it, sets the stop request and calls the registered wakers, e.g.
:meth:`rclpy.guard_condition.GuardCondition.trigger` of a guard condition the
executor waits on.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Stop:
    """A stop request, set by SIGINT/SIGTERM (see :func:`handle_signals`) or by the program.

    Loops poll :attr:`requested`, sleep with :meth:`wait` (returns at once on a request),
    and register :meth:`on_request` wakers for anything that blocks elsewhere.
    """

    def __init__(self) -> None:
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._wakers: list[Callable[[], Any]] = []
        self.signal: int | None = None

    @property
    def requested(self) -> bool:
        """Whether a stop was requested."""
        return self._event.is_set()

    def request(self, signum: int | None = None) -> None:
        """Request a stop (idempotent); ``signum`` records the first signal that asked."""
        with self._lock:
            if self.signal is None and signum is not None:
                self.signal = signum
            self._event.set()
            wakers = list(self._wakers)
        for wake in wakers:
            try:
                wake()
            except Exception:  # noqa: BLE001 - a waker of an entity already destroyed
                pass

    def on_request(self, wake: Callable[[], Any]) -> None:
        """Call ``wake()`` on a request (at once when one was already made)."""
        with self._lock:
            self._wakers.append(wake)
            already = self._event.is_set()
        if already:
            with contextlib.suppress(Exception):
                wake()

    def wait(self, timeout: float) -> bool:
        """Sleep up to ``timeout`` s, less when a stop is requested; return whether it was."""
        return self._event.wait(max(0.0, timeout))


_PROCESS_STOP: Stop | None = None
_INSTALL_LOCK = threading.Lock()


def handle_signals() -> Stop:
    """Install the process's SIGINT/SIGTERM handling once and return its :class:`Stop`.

    From then on both signals only request the stop (no KeyboardInterrupt, no default
    termination); programs call this first thing in ``main``. Outside the main thread
    (where Python cannot install handlers) it returns a Stop that only the caller sets.
    """
    global _PROCESS_STOP
    with _INSTALL_LOCK:
        if _PROCESS_STOP is not None:
            return _PROCESS_STOP
        stop = Stop()
        if threading.current_thread() is not threading.main_thread():
            return stop
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        for sig in STOP_SIGNALS:
            signal.signal(sig, lambda signum, _frame: stop.request(signum))
        signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)

        def watch() -> None:
            while True:
                try:
                    data = os.read(read_fd, 64)
                except OSError:
                    return
                if not data:
                    return
                for signum in data:
                    if signum in STOP_SIGNALS:
                        stop.request(signum)

        threading.Thread(target=watch, name="mr_ident-signals", daemon=True).start()
        # At exit the interpreter resets Python-level handlers to SIG_DFL (but leaves
        # SIG_IGN alone), so a signal during finalisation (DDS teardown can take a second)
        # killed a finished program with -2. Its work is done then: ignore the signals.
        atexit.register(_ignore_stop_signals)
        _PROCESS_STOP = stop
        return stop


def _ignore_stop_signals() -> None:
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_IGN)


@contextlib.contextmanager
def ros_context(args: Sequence[str] | None = None) -> Iterator[Any]:
    """``rclpy.init`` without rclpy's signal handlers; ``rclpy.try_shutdown`` on exit.

    Yields the rclpy module. Use inside :func:`handle_signals`'s regime: the context is
    shut down only here, after the program has finalised its outputs.
    """
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(
        args=list(args) if args is not None else None,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    try:
        yield rclpy
    finally:
        rclpy.try_shutdown()


def spin_until_stopped(executor: Any, node: Any, stop: Stop) -> None:
    """Spin ``executor`` until ``stop`` is requested; a guard condition of ``node`` wakes it.

    No timeout per spin (no timer created per callback, which would cost at thousands of
    messages per second, and no timer to race a shutdown).
    """
    guard = node.create_guard_condition(lambda: None)
    stop.on_request(guard.trigger)
    while not stop.requested:
        executor.spin_once()


def wants_help(argv: Sequence[str]) -> bool:
    """Whether ``-h``/``--help`` comes before any ``--ros-args`` (ROS's own arguments)."""
    for arg in argv:
        if arg == "--ros-args":
            return False
        if arg in ("-h", "--help"):
            return True
    return False
