# SPDX-License-Identifier: Apache-2.0
"""What the command groups share: the recording as asked, notices, plots, the PFGs told."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import NamesFields

if TYPE_CHECKING:
    from ..app.requests import Notice, Reading
    from ..numerics.results import Identification
    from ..numerics.systems.model import Model


def sources(args: argparse.Namespace) -> dict[str, list[str]]:
    """The --r/--u/--y sources as given (empty lists for those not given)."""
    return {sig: list(getattr(args, f"{sig}_source", None) or []) for sig in ("r", "u", "y")}


def source_specs(args: argparse.Namespace) -> dict[str, list[str]] | None:
    """The --r/--u/--y sources, or None when none was given (all three needed otherwise)."""
    from ..app.requests import source_specs as checked

    return checked(sources(args))


def reading(args: argparse.Namespace) -> dict[str, Any]:
    """--span and --msg-path as keyword arguments of the library's readers."""
    out: dict[str, Any] = {"msg_path": tuple(getattr(args, "msg_path", None) or ())}
    if getattr(args, "span", None) is not None:
        out["span"] = args.span
    return out


def recording(
    args: argparse.Namespace, path: Path, topics: Sequence[str] | None = None
) -> Reading:
    """The recording at ``path`` and how to read it: the sources, --span, --msg-path."""
    from ..app.requests import Reading

    return Reading(
        path,
        sources(args),
        topics,
        getattr(args, "span", None),
        tuple(getattr(args, "msg_path", None) or ()),
    )


def show(notice: Notice) -> None:
    """A notice of the application: about the reading to stderr, about the result to stdout."""
    print(notice.line(flag), file=sys.stderr if notice.about == "reading" else sys.stdout)


def write_plots(
    ident: Identification,
    path: Path,
    fs: float,
    F: int,
    N: int,
    model: Model | None,
    *,
    units: tuple[str, str] | None = None,
) -> None:
    """Bode plot of P_h at ``path`` (model drawn when given); with a PFG, ``<path>_pfg``.

    The PFG plot shows the PFG from data and, with a controller, the one from P_h and it.
    ``units``: (u's, y's), the model file's (:func:`~mr_ident.io.units.load_units`).
    """
    from ..numerics.lifted.pfg import pfg_of_model
    from ..plots import plot_bode, plot_pfg

    nyq = fs / F / 2 if F > 1 else None
    mfrf = model.plant_result(N) if model is not None else None
    bode = plot_bode(
        ident.plant,
        path,
        model=mfrf,
        nyquist_low=nyq,
        undetermined=ident.undetermined,
        units=units,
    )
    print(f"wrote {bode}")
    shown = [g for g in (ident.pfg_data, ident.pfg) if g is not None]
    if shown:
        ref = (
            pfg_of_model(model, N) if model is not None and model.controller is not None else None
        )
        pfg_path = path.with_name(path.stem + "_pfg" + path.suffix)
        pfg = plot_pfg(shown[0], pfg_path, model=ref, also=shown[1:], nyquist_low=nyq)
        print(f"wrote {pfg}")


def describe_pfgs(ident: Identification) -> list[str]:
    """Lines on the PFGs of a result: each one's peak and std; with both, their agreement."""
    import numpy as np

    from ..numerics.lifted.pfg_check import COVERAGE, check_controller

    lines = []
    for g, what in ((ident.pfg_data, "from data (lifted r->y)"), (ident.pfg, "from P_h and K_l")):
        if g is None or not np.isfinite(g.gain).any():
            continue
        k = int(np.nanargmax(g.gain))
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = float(np.nanmedian(g.std / g.gain))
        lines.append(
            f"PFG {what}: peak {20 * np.log10(g.gain[k]):.1f} dB at {g.frequency[k]:.4g} Hz, "
            f"median std {100 * rel:.2g} % of the gain"
        )
    n = 0 if ident.n_used is None else int(np.min(ident.n_used))
    check = check_controller(ident, n)
    if check is not None:
        lines.append(
            f"the two PFGs differ by more than {COVERAGE:g} std over {100 * check.fraction:.2g} % "
            "of the band (log axis)" + ("; " + check.text().split(":")[0] if check.differs else "")
        )
    return lines


def quiet_option(p: argparse.ArgumentParser) -> None:
    """--quiet: no progress (:class:`Progress`, the one progress display of every command)."""
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress on stderr (shown only where stderr is a terminal, for steps over 2 s)",
    )


class Progress:
    """Steps of a long computation told on stderr, each only once it has run 2 s.

    A timer per step: a step that ends within :attr:`after` seconds prints nothing; one that
    runs longer prints ``mr-ident: <step> ... (<t> s in)``, and again every :attr:`every`
    seconds while it lasts. Silent where stderr is not a terminal or ``quiet`` (as such tools
    do). Use as a context manager; call it with each step's name as the step begins. The one
    progress display of every command (identify, replay, diagnose, fit, batch).
    """

    after = 2.0
    every = 10.0

    def __init__(self, *, quiet: bool = False):
        import threading
        import time

        self._on = not quiet and sys.stderr.isatty()
        self._t0 = time.monotonic()
        self._timer: threading.Timer | None = None
        self._step = ""
        self._lock = threading.Lock()

    def __call__(self, step: str) -> None:
        """``step`` begins (the one before it ends)."""
        if not self._on:
            return
        with self._lock:
            self._step = step
            self._arm(step, self.after)

    def _arm(self, step: str, delay: float) -> None:
        import threading

        if self._timer is not None:
            self._timer.cancel()
        self._timer = threading.Timer(delay, self._show, (step,))
        self._timer.daemon = True
        self._timer.start()

    def _show(self, step: str) -> None:
        import time

        with self._lock:
            if step != self._step or self._timer is None:
                return  # ended meanwhile
            print(
                f"mr-ident: {step} ... ({time.monotonic() - self._t0:.0f} s in)",
                file=sys.stderr,
                flush=True,
            )
            self._arm(step, self.every)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        with self._lock:
            self._step = ""
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None


def flag(field: str) -> str:
    """The command line's spelling of a request's field (``y_rate`` -> ``--y-rate``)."""
    return "--" + field.replace("_", "-")


def told(err: Exception) -> str:
    """An error as the command line says it: a request's fields as its flags."""
    return err.told(flag) if isinstance(err, NamesFields) else str(err)
