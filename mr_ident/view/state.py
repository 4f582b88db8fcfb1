# SPDX-License-Identifier: Apache-2.0
"""What the view shows: the latest estimate, the model beside it, the streams' health.

Thread-safe: the ROS listener or the bag replay writes, the HTTP handlers read and wait
for the next version. Arrays in, JSON-ready dicts out (lists of floats; NaN as null).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..diagnosis.monitoring.drift import Reference
from ..numerics.arrays import FloatArray
from ..numerics.excitation.bla import BLA
from ..numerics.results import FRF
from ..numerics.systems.model import Model


def _list(a: ArrayLike) -> list[float | None]:
    return [None if not math.isfinite(v) else float(v) for v in np.asarray(a, float).ravel()]


def bla_parts(bla: BLA, frequency: FloatArray) -> dict[str, Any]:
    """A BLA reference as the page draws it: per line |G| and its std parts in dB, levels.

    ``frequency``, ``mag_db``, ``std_db``, ``noise_std_db``, ``nl_std_db`` (lists, nan as
    null), ``odd_db``, ``even_db`` (the distortion at the unexcited lines above the noise),
    ``realizations``, ``periods``.
    """

    def db(x: ArrayLike) -> list[float | None]:
        with np.errstate(divide="ignore"):
            return _list(20.0 * np.log10(np.abs(x)))

    def level(x: FloatArray) -> float | None:
        v = float(x[0])
        return v if math.isfinite(v) else None

    return {
        "frequency": _list(frequency),
        "mag_db": db(bla.response),
        "std_db": db(bla.std),
        "noise_std_db": db(bla.noise_std),
        "nl_std_db": db(bla.nl_std),
        "odd_db": level(bla.odd_db),
        "even_db": level(bla.even_db),
        "realizations": bla.realizations,
        "periods": bla.periods,
    }


class ViewState:
    """The latest estimate and health; ``version`` grows with every change.

    The last :attr:`HISTORY` estimates stay readable by the version they came with (a page
    or a script compares what it drew with the estimate it drew).
    """

    HISTORY = 32

    def __init__(
        self,
        model: Model | None = None,
        source: str = "",
        reference: FRF | None = None,
        reference_bla: tuple[BLA, FloatArray] | None = None,
        units: tuple[str, str] | None = None,
    ) -> None:
        from ..io.units import magnitude_label

        self.model = model
        self.magnitude_label = magnitude_label(units, 0, 0, 1, 1)  # the model file's units
        self.reference = reference  # an identification to draw instead of a model
        self._reference_bla = None if reference_bla is None else bla_parts(*reference_bla)
        self.source = source
        self._cond = threading.Condition()
        self._estimate: dict[str, Any] | None = None
        self._health: dict[str, str] = {}
        self._plant: dict[str, Any] = {}  # the plant status (monitoring) and drift bands
        self._version = 0
        self._received = 0.0
        self._history: dict[int, dict[str, Any]] = {}  # the last HISTORY estimates by version

    def set_estimate(
        self,
        frequency: ArrayLike,
        P: ArrayLike,
        P_std: ArrayLike,
        pfg: ArrayLike | None = None,
        pfg_std: ArrayLike | None = None,
        window: dict[str, Any] | None = None,
        *,
        pfg_data: ArrayLike | None = None,
        pfg_data_std: ArrayLike | None = None,
    ) -> None:
        """A new estimate: frequency (K,), P and P_std (K, n_y, n_u), the PFGs (K,).

        ``pfg``: from P_h and the controller; ``pfg_data``: identified from data alone.
        """
        f = np.asarray(frequency, float)
        Pa = np.asarray(P, complex)
        Sa = np.asarray(P_std, float)
        if Pa.ndim == 1:
            Pa, Sa = Pa[:, None, None], Sa[:, None, None]
        if Pa.shape[0] != f.size or Sa.shape != Pa.shape:
            raise ValueError(f"P {Pa.shape} and P_std {Sa.shape} must be (K={f.size}, n_y, n_u)")
        est: dict[str, Any] = {
            "frequency": _list(f),
            "shape": list(Pa.shape[1:]),
            "P_re": _list(np.transpose(Pa.real, (1, 2, 0))),  # n_y x n_u x K, K innermost
            "P_im": _list(np.transpose(Pa.imag, (1, 2, 0))),
            "P_std": _list(np.transpose(Sa, (1, 2, 0))),
            "pfg": None if pfg is None else _list(pfg),
            "pfg_std": None if pfg_std is None else _list(pfg_std),
            "pfg_data": None if pfg_data is None else _list(pfg_data),
            "pfg_data_std": None if pfg_data_std is None else _list(pfg_data_std),
            "window": window or {},
        }
        ref: tuple[Any, Any, str] | None = None
        if self.model is not None and (self.model.n_y, self.model.n_u) == Pa.shape[1:]:
            ref = (self.model.plant_discrete().freqresp(f), 0.0, "model P_h")
        elif self.reference is not None and self.reference.response.shape[1:] == Pa.shape[1:]:
            Pr, Sr = Reference.of_frf(self.reference).at(f)  # nan outside its band
            ref = (Pr, Sr, "reference")
        if ref is not None:
            Pm, Sm, label = ref
            est["model_re"] = _list(np.transpose(Pm.real, (1, 2, 0)))
            est["model_im"] = _list(np.transpose(Pm.imag, (1, 2, 0)))
            est["model_label"] = label
            with np.errstate(divide="ignore", invalid="ignore"):
                sig = np.abs(Pa - Pm) / np.sqrt(Sa**2 + np.square(Sm))
            finite = sig[np.isfinite(sig)]
            est["sigma_error_median"] = float(np.median(finite)) if finite.size else None
            est["sigma_error"] = _list(np.transpose(sig, (1, 2, 0)))
        with self._cond:
            self._version += 1
            est["version"] = self._version
            self._estimate = est
            self._received = time.time()
            self._history[self._version] = est
            if len(self._history) > self.HISTORY:
                self._history.pop(next(iter(self._history)))  # the oldest estimate
            self._cond.notify_all()

    def set_plant(self, values: dict[str, str]) -> None:
        """The node's plant status (monitoring): its key-values, level and message."""
        with self._cond:
            self._plant = dict(values) | {"bands": self._plant.get("bands", [])}
            self._version += 1
            self._cond.notify_all()

    def set_drift(self, frequency: ArrayLike, significant: ArrayLike) -> None:
        """The latest ~/drift: significant bins become bands [[f_lo, f_hi], ...] (Hz)."""
        f = np.asarray(frequency, float)
        sig = np.asarray(significant, bool)
        idx = np.flatnonzero(sig)
        bands: list[list[float]] = []
        if idx.size:
            cut = np.flatnonzero(np.diff(idx) > 1)
            starts = np.concatenate([[idx[0]], idx[cut + 1]])
            ends = np.concatenate([idx[cut], [idx[-1]]])
            bands = [[float(f[a]), float(f[b])] for a, b in zip(starts, ends, strict=True)]
        with self._cond:
            self._plant = self._plant | {"bands": bands}
            self._version += 1
            self._cond.notify_all()

    def set_health(self, values: dict[str, str]) -> None:
        """The node's /diagnostics key-values (level and message included)."""
        with self._cond:
            self._health = dict(values)
            self._version += 1
            self._cond.notify_all()

    def snapshot(self) -> dict[str, Any]:
        """The state as JSON-ready dict.

        Keys: version, source, estimate (None before the first), health, plant (the
        monitoring status and its drift ``bands``; empty without monitoring),
        estimate_age_s, reference_bla (a BLA reference's parts, :func:`bla_parts`; None
        without), magnitude_label (the magnitude axis' label, in the model's units).
        """
        with self._cond:
            age = time.time() - self._received if self._estimate is not None else None
            return {
                "version": self._version,
                "source": self.source,
                "estimate": self._estimate,
                "health": dict(self._health),
                "plant": dict(self._plant),
                "estimate_age_s": age,
                "reference_bla": self._reference_bla,
                "magnitude_label": self.magnitude_label,
            }

    def estimate(self, version: int | None = None) -> dict[str, Any] | None:
        """The latest estimate, or the one of ``version`` while it is kept (else None)."""
        with self._cond:
            return self._estimate if version is None else self._history.get(version)

    def wait(self, version: int, timeout: float) -> int:
        """Block until the version passes ``version`` (or ``timeout`` s); the version."""
        with self._cond:
            self._cond.wait_for(lambda: self._version > version, timeout=timeout)
            return self._version

    def wake(self) -> None:
        """Wake every waiter (at shutdown) without a change."""
        with self._cond:
            self._cond.notify_all()
