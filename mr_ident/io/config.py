# SPDX-License-Identifier: Apache-2.0
"""Identification settings shared by the ROS node, ``mr-ident replay`` and the CLI.

One frozen dataclass, :class:`IdentConfig`, validated on construction; the
node declares one ROS parameter per field (with the description and range of
:data:`PARAMETERS`), validates every set through :meth:`IdentConfig.replace`, and
``mr-ident replay --params`` reads the same ``config/node.yaml``.

Params file form (the ROS 2 one)::

    mr_ident:                 # node name (or "/**" for every node)
      ros__parameters:
        fs_high: 240.0
        ratio: 3
        ...
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ..errors import ConfigError, yaml_problem
from ..numerics.identify import AUTO, METHODS, check_options, default_n
from ..numerics.identify import min_samples as record_minimum
from ..numerics.structure import INJECTIONS
from ..numerics.systems.lti import TransferMatrix
from .paths import parse_source


@dataclass(frozen=True)
class Param:
    """Description of one parameter: text, and the closed range for numbers."""

    description: str
    low: float | None = None
    high: float | None = None


#: Every field of :class:`IdentConfig`, described once (the node's descriptors).
PARAMETERS: dict[str, Param] = {
    "fs_high": Param("high sample rate of r, u, y in Hz", 1e-3, 1e9),
    "ratio": Param("F = h_l / h_h: high-rate samples per controller sample", 1, 1000),
    "method": Param(f"identification method: one of {', '.join(METHODS)}"),
    "n": Param(
        "LPM window half-width (bins each side); 0: automatic, chosen per frequency by "
        "least estimated mean-squared error from 8 (more where F or the channels need it) "
        "up to 4 times that",
        0,
        1000,
    ),
    "degree": Param("LPM polynomial degree R of G and of the transient", 0, 10),
    "local": Param(
        "local model per window: polynomial (LPM) or rational (a common denominator of "
        "order degree: lightly damped modes with few bins across them; slower)"
    ),
    "window_s": Param("length of the sliding window identified, in seconds", 1e-3, 1e7),
    "min_window_s": Param(
        "first estimate once the aligned window holds this many seconds", 1e-3, 1e7
    ),
    "update_period_s": Param(
        "re-identify every this many seconds of the ROS clock (/clock with use_sim_time), "
        "when new data came",
        1e-3,
        1e5,
    ),
    "lifting_phase": Param(
        'high-rate index (mod F) at which the controller samples y: "auto" or 0..F-1'
    ),
    "control_delay": Param(
        "high-rate samples between the controller sampling and its held output", 0, 1000
    ),
    "injection": Param(
        'where r enters the loop: "auto" (as the data show it: the held u - r, r added at '
        'the plant input, or the held u, r the controller\'s setpoint), "plant_input" or '
        '"setpoint"; a value the data contradict fails the estimate, saying why'
    ),
    "controller_num": Param(
        "low-rate controller K_l numerator, descending powers of z; MIMO: the entries' "
        "numerators one after another (row-major, each padded with leading zeros to one "
        "length); empty: no PFG"
    ),
    "controller_den": Param(
        "low-rate controller K_l denominator, descending powers of z; MIMO: per entry, as "
        "controller_num"
    ),
    "controller_rows": Param("rows of K_l: plant inputs n_u (1: SISO)", 1, 64),
    "controller_cols": Param("columns of K_l: plant outputs n_y (1: SISO)", 1, 64),
    "publish_points": Param(
        "at most this many log-spaced bins published per estimate", 2, 1_000_000
    ),
    "record_path": Param(
        "MCAP file the node records its input topics (and the labels' topic) to, or a new "
        "name beside it when it exists (never overwritten); while recording, the file being "
        "written; empty: off"
    ),
    "reorder_blocks": Param(
        "blocks held per stream waiting for a missing one before it is a gap", 0, 10_000
    ),
    "stall_timeout_s": Param("a stream silent this long is reported as stalled", 1e-3, 1e5),
    "r_source": Param(
        "sources of r: topic + field path each (one channel each; docs: Sources and "
        "bags); all three empty: the block topics reference, input, output"
    ),
    "u_source": Param("sources of u (plant input), as r_source"),
    "y_source": Param("sources of y (plant output), as r_source"),
    "stamp_tolerance": Param(
        "a stamp further than this many sample times from its grid point is dropped (a gap)",
        0.01,
        0.5,
    ),
    "identify_threads": Param(
        "threads each identification runs on (0: every CPU available to the "
        "process); ingestion has its own thread",
        0,
        1024,
    ),
    "monitor_model": Param(
        "model file whose plant each estimate is held against "
        "(docs/monitoring.md, 'Monitoring against a reference'); the "
        "diagnosis names the cause of a drift from it; empty: no monitoring"
    ),
    "monitor_reference": Param(
        "result file (identify/replay --out) each estimate is held against, with its std; "
        "overrides monitor_model as the reference (the model still names causes)"
    ),
    "monitor_alpha": Param(
        "false-alarm probability per estimate of the drift test over the whole band", 1e-9, 0.5
    ),
    "monitor_error_db": Param(
        "drift size (dB, 20 log10(1 + relative deviation)) at which the plant status is ERROR",
        0.01,
        100.0,
    ),
    "monitor_hold": Param(
        "consecutive estimates that must agree before the plant status changes", 1, 1000
    ),
    "y_rate": Param(
        'rate at which y is measured: "high", or "low" (a y source at the controller\'s '
        "rate, read with .@hold: identified from its samples, freq-lifted only)"
    ),
    "excitation_index_topic": Param(
        "topic of the labels of a periodic excitation (mr-ident excite --publish TOPIC puts "
        "them on TOPIC/excitation_index), aligned with r, u, y; a window holding whole "
        "periods is identified as the best linear approximation from the period means "
        "(docs/excitation.md, 'Periodic bags and the node'); empty: off"
    ),
    "transient_periods": Param(
        "with excitation_index_topic: leading whole periods of every run of one realization "
        "in the window dropped as the loop's transient",
        0,
        1000,
    ),
}


def _typed(name: str, type_: Any, v: Any) -> tuple[Any, bool]:
    """A parameter's value as its field's type, and whether its range applies.

    Numbers finite, integers integral, strings strings; ``*_source`` a tuple of source
    strings (each parsed: an error points at the mistake); coefficient lists tuples of finite
    floats. ConfigError naming the parameter and the value otherwise.
    """
    if type_ in ("float", float):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{name} must be a finite number, got {v!r}")
        return float(v), True
    if type_ in ("int", int):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ConfigError(f"{name} must be an integer, got {v!r}")
        return int(v), True
    if type_ in ("str", str):
        if not isinstance(v, str):
            raise ConfigError(f"{name} must be a string, got {v!r}")
        return v, True
    if name.endswith("_source"):
        if isinstance(v, (str, bytes)) or not hasattr(v, "__iter__"):
            raise ConfigError(f"{name} must be a list of source strings, got {v!r}")
        texts = tuple(v)
        for t in texts:
            parse_source(t)  # raises, pointing at the mistake
        return texts, False
    if isinstance(v, (str, bytes)) or not hasattr(v, "__iter__"):  # coefficient tuples
        raise ConfigError(f"{name} must be a list of numbers, got {v!r}")
    vals = tuple(v)
    for j, c in enumerate(vals):
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c):
            raise ConfigError(f"{name}[{j}] must be a finite number, got {c!r}")
    return tuple(float(c) for c in vals), False


@dataclass(frozen=True)
class IdentConfig:
    """Validated identification settings. Errors name the parameter."""

    fs_high: float = 240.0
    ratio: int = 3
    method: str = "freq-lifted"
    n: int = 0
    degree: int = 2
    local: str = "polynomial"
    window_s: float = 60.0
    min_window_s: float = 10.0
    update_period_s: float = 2.0
    lifting_phase: str = "auto"
    control_delay: int = 0
    injection: str = "auto"
    controller_num: tuple[float, ...] = ()
    controller_den: tuple[float, ...] = ()
    controller_rows: int = 1
    controller_cols: int = 1
    publish_points: int = 1000
    record_path: str = ""
    reorder_blocks: int = 8
    stall_timeout_s: float = 2.0
    r_source: tuple[str, ...] = ()
    u_source: tuple[str, ...] = ()
    y_source: tuple[str, ...] = ()
    stamp_tolerance: float = 0.25
    identify_threads: int = 0
    monitor_model: str = ""
    monitor_reference: str = ""
    monitor_alpha: float = 0.01
    monitor_error_db: float = 6.0
    monitor_hold: int = 3
    y_rate: str = "high"
    excitation_index_topic: str = ""
    transient_periods: int = 1

    def __post_init__(self) -> None:
        """Every field typed and in its range, then the fields that go together."""
        for f in dataclasses.fields(self):
            value, ranged = _typed(f.name, f.type, getattr(self, f.name))
            object.__setattr__(self, f.name, value)
            spec = PARAMETERS[f.name]
            if ranged and spec.low is not None and not (spec.low <= value <= spec.high):
                raise ConfigError(
                    f"{f.name} must be in [{spec.low:g}, {spec.high:g}], got {value!r}"
                )
        self._check_choices()
        self._check_controller_and_sources()
        self._check_windows()

    def _check_choices(self) -> None:
        """The method, y's rate, the injection point and the lifting phase."""
        if self.method not in METHODS:
            raise ConfigError(f"method must be one of {', '.join(METHODS)}; got {self.method!r}")
        if self.y_rate not in ("high", "low"):
            raise ConfigError(f'y_rate must be "high" or "low", got {self.y_rate!r}')
        if self.y_rate == "low" and self.method != "freq-lifted":
            raise ConfigError(
                f'y_rate "low" is identified by freq-lifted only; got method {self.method!r}'
            )
        if self.injection not in ("auto", *INJECTIONS):
            raise ConfigError(
                f'injection must be "auto", {", ".join(map(repr, INJECTIONS))}, got '
                f"{self.injection!r}"
            )
        if self.lifting_phase != "auto":
            try:
                p = int(self.lifting_phase)
            except ValueError:
                p = -1
            if not 0 <= p < self.ratio:
                raise ConfigError(
                    f'lifting_phase must be "auto" or an integer in 0..{self.ratio - 1} '
                    f"(F = {self.ratio}), got {self.lifting_phase!r}"
                )

    def _check_controller_and_sources(self) -> None:
        """K_l's coefficients together, the sources together, and their channels agree."""
        if bool(self.controller_num) != bool(self.controller_den):
            raise ConfigError(
                "controller_num and controller_den must be given together (or both empty), got "
                f"{len(self.controller_num)} and {len(self.controller_den)} coefficients"
            )
        if self.controller_den:
            self._controller_entries()  # raises naming the entry
        given = [bool(x) for x in (self.r_source, self.u_source, self.y_source)]
        if any(given) and not all(given):
            raise ConfigError(
                "r_source, u_source and y_source are given together (or all empty: the "
                f"block topics); got {sum(given)} of 3"
            )
        if self.controller_num and self.r_source:
            got = (len(self.u_source), len(self.y_source))
            if got != (self.controller_rows, self.controller_cols):
                raise ConfigError(
                    f"K_l is {self.controller_rows}x{self.controller_cols} (controller_rows x "
                    f"controller_cols) but the sources give n_u x n_y = {got[0]}x{got[1]}"
                )
        if len(self.r_source) != len(self.u_source):
            raise ConfigError(
                f"r_source and u_source need as many sources (r excites u): "
                f"{len(self.r_source)} and {len(self.u_source)}"
            )

    def _check_windows(self) -> None:
        """The windows' lengths against each other and against what the method needs."""
        if self.min_window_s > self.window_s:
            raise ConfigError(
                f"min_window_s ({self.min_window_s:g}) must not exceed window_s "
                f"({self.window_s:g})"
            )
        check_options(
            self.method, self.lpm_n(1, 1), self.degree, self.ratio, 1, 1, local=self.local
        )
        if self.method != "etfe":
            need = record_minimum(self.method, self.lpm_n(1, 1), self.ratio)
            if self.min_samples < need:
                raise ConfigError(
                    f"min_window_s = {self.min_window_s:g} s gives {self.min_samples} samples at "
                    f"fs_high = {self.fs_high:g} Hz; {self.method} with n = {self.n} needs at "
                    f"least {need} "
                    f"(raise min_window_s to >= {need / self.fs_high:g} s)"
                )

    # -- derived -----------------------------------------------------------------
    @property
    def window_samples(self) -> int:
        """Window length in high-rate samples: a multiple of F."""
        return self.ratio * max(1, int(self.window_s * self.fs_high + 1e-6) // self.ratio)

    @property
    def min_samples(self) -> int:
        """``min_window_s`` in samples, a multiple of F."""
        return self.ratio * max(
            1, int(math.ceil(self.min_window_s * self.fs_high - 1e-9)) // self.ratio
        )

    def lpm_n(self, n_in: int, n_out: int) -> int:
        """The window half-width for ``n_in`` excitation and ``n_out`` output channels.

        ``n``, or the default rule (:func:`~mr_ident.numerics.identify.default_n`) for
        0.
        """
        return self.n or default_n(self.method, self.degree, self.ratio, n_in, n_out, self.local)

    @property
    def identify_n(self) -> int | str:
        """``identify(n=...)``: ``n``, or "auto" for 0 (:mod:`~.numerics.local.bandwidth`)."""
        return self.n or AUTO

    @property
    def phase(self) -> int | None:
        """The configured lifting phase, None for "auto"."""
        return None if self.lifting_phase == "auto" else int(self.lifting_phase)

    @property
    def workers(self) -> int | None:
        """``identify(workers=...)``: None (every CPU) for ``identify_threads = 0``."""
        return self.identify_threads or None

    @property
    def sources(self) -> dict[str, tuple[str, ...]] | None:
        """The r, u, y sources, or None for the block topics."""
        if not self.r_source:
            return None
        return {"r": self.r_source, "u": self.u_source, "y": self.y_source}

    def _controller_entries(self) -> list[list[tuple[tuple[float, ...], tuple[float, ...]]]]:
        """K_l's (num, den) per entry, rows x cols; ConfigError naming the entry at fault."""
        rows, cols = self.controller_rows, self.controller_cols
        k = rows * cols
        for name in ("controller_num", "controller_den"):
            n = len(getattr(self, name))
            if n % k:
                raise ConfigError(
                    f"{name} has {n} coefficients, not a multiple of the {k} entries of a "
                    f"{rows}x{cols} K_l (controller_rows x controller_cols)"
                )
        ln, ld = len(self.controller_num) // k, len(self.controller_den) // k
        out = []
        for o in range(rows):
            row = []
            for i in range(cols):
                e = o * cols + i
                at = "" if k == 1 else f" of entry [{o},{i}]"
                num = np.trim_zeros(np.array(self.controller_num[e * ln : (e + 1) * ln]), "f")
                den = np.trim_zeros(np.array(self.controller_den[e * ld : (e + 1) * ld]), "f")
                if den.size == 0:
                    raise ConfigError(f"controller_den{at} is all zeros")
                if k == 1 and self.controller_den[0] == 0.0:
                    raise ConfigError("controller_den[0] must not be 0 (leading coefficient)")
                if num.size > den.size:
                    raise ConfigError(
                        f"controller is improper{at}: controller_num has a higher degree than "
                        "controller_den"
                    )
                row.append((tuple(num) or (0.0,), tuple(den)))
            out.append(row)
        return out

    @property
    def controller(self) -> TransferMatrix | None:
        """K_l (n_u x n_y), discrete at the low rate, or None.

        From ``controller_num``/``controller_den`` and ``controller_rows``/``controller_cols``.
        """
        if not self.controller_num:
            return None
        entries = self._controller_entries()
        return TransferMatrix(
            tuple(tuple(num for num, _ in row) for row in entries),
            tuple(tuple(den for _, den in row) for row in entries),
            self.ratio / self.fs_high,
        )

    def with_controller(self, K: TransferMatrix) -> IdentConfig:
        """A copy whose K_l is ``K`` (discrete at the low rate; entries padded to one length)."""
        rows, cols = K.shape
        ln = max(len(e) for row in K.num for e in row)
        ld = max(len(e) for row in K.den for e in row)
        num = [c for row in K.num for e in row for c in (0.0,) * (ln - len(e)) + tuple(e)]
        den = [c for row in K.den for e in row for c in (0.0,) * (ld - len(e)) + tuple(e)]
        return self.replace(
            controller_rows=rows,
            controller_cols=cols,
            controller_num=tuple(num),
            controller_den=tuple(den),
        )

    def replace(self, **changes: Any) -> IdentConfig:
        """A validated copy with ``changes``; unknown names are an error."""
        unknown = set(changes) - set(PARAMETERS)
        if unknown:
            raise ConfigError(
                f"unknown parameter(s) {sorted(unknown)}; known: {sorted(PARAMETERS)}"
            )
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, Any]:
        """Every parameter by name (tuples as lists, for ROS and YAML)."""
        return {
            f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
            for f in dataclasses.fields(self)
        }


def share_dirs() -> list[Path]:
    """Where an installed mr_ident keeps its shipped files: ``<prefix>/share/mr_ident``.

    The prefix this package is installed under (a colcon install space), the interpreter's
    (a venv), then those of ``AMENT_PREFIX_PATH`` (a sourced workspace).
    """
    site = Path(__file__).resolve().parents[2]  # the directory holding the package
    prefixes = [site.parents[2]] if site.name in ("site-packages", "dist-packages") else []
    prefixes.append(Path(sys.prefix))
    prefixes += [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    return list(dict.fromkeys(p / "share" / "mr_ident" for p in prefixes))


def share_file(rel: str, hint: str = "") -> Path:
    """A shipped file (``config/...``): from the source tree, else :func:`share_dirs`."""
    dirs = share_dirs()
    for cand in [Path(__file__).resolve().parents[2] / rel, *(d / rel for d in dirs)]:
        if cand.is_file():
            return cand
    where = ", ".join(str(d) for d in dirs)
    raise ConfigError(f"{rel} not found (looked in the source tree and {where}){hint}")


def load_params(path: str | Path, node_name: str = "mr_ident") -> IdentConfig:
    """Read a ROS 2 params file (``node: ros__parameters: {...}``) into a config.

    Entries under ``/**`` apply first, then those under ``node_name`` (with or
    without a leading ``/``). Unknown parameter names are an error.
    """
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as err:
        raise ConfigError(f"cannot read params file {str(p)!r}: {err.strerror}") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{p}: not valid YAML: {yaml_problem(err)}") from None
    if not isinstance(doc, dict):
        raise ConfigError(f"{p}: expected a mapping of node names to {{ros__parameters: ...}}")
    values: dict[str, Any] = {}
    found = False
    for key in ("/**", node_name, "/" + node_name):
        entry = doc.get(key)
        if entry is None:
            continue
        if not isinstance(entry, dict) or not isinstance(entry.get("ros__parameters"), dict):
            raise ConfigError(f"{p}: {key!r} must hold a 'ros__parameters' mapping")
        values.update(entry["ros__parameters"])
        found = True
    if not found:
        raise ConfigError(
            f"{p}: no entry for node {node_name!r} (nor '/**'); top-level keys: {sorted(doc)}"
        )
    try:
        return IdentConfig().replace(**values)
    except ConfigError as err:
        raise ConfigError(f"{p}: {err}") from err
