# SPDX-License-Identifier: Apache-2.0
"""A model's plant as python-control systems: a Python file of matrices, no pickle.

``mr-ident fit --export python-control`` writes ``<stem>_control.py`` beside the model
file. Run or imported (``runpy.run_path``), it defines

- ``G``: the plant as fitted, ``control.ss`` in its own domain (continuous, or discrete at
  ``1/fs``), without the input delay;
- ``P_h``: the plant as identified, ``control.ss`` at ``dt = 1/fs``: the zero-order hold
  and the input delay (fractional samples exact) in state space, the realisation the
  simulator uses, so its response equals the model file's P_h to rounding;
- ``input_delay_s``, ``fs``.

python-control is an optional extra (``pip install control``, or the package's
``control`` extra); the export refuses, naming it, when it is not installed, and checks
the written file by loading it.
"""

from __future__ import annotations

import importlib.util
import runpy
from pathlib import Path

import numpy as np

from ..errors import ConfigError, ModelError
from ..numerics.systems.lti import StateSpace
from ..numerics.systems.model import Model
from .atomic import atomic_write

INSTALL = "pip install control (or the control extra: pip install 'mr_ident[control]')"


def require_control() -> None:
    """Raise ConfigError naming the ``pip install`` when python-control is absent."""
    if importlib.util.find_spec("control") is None:
        raise ConfigError(f"the python-control export needs python-control: {INSTALL}")


def control_path(path: str | Path) -> Path:
    """``MODEL.yaml`` -> ``MODEL_control.py``."""
    p = Path(path)
    return p.with_name(p.stem + "_control.py")


def _array(name: str, a: np.ndarray) -> str:
    rows = np.atleast_2d(np.asarray(a, dtype=float))
    body = ",\n    ".join("[" + ", ".join(repr(float(v)) for v in r) + "]" for r in rows)
    return f"{name} = np.array([\n    {body}\n]).reshape({rows.shape[0]}, {rows.shape[1]})\n"


def _system(name: str, S: StateSpace, doc: str) -> str:
    dt = "" if S.dt is None else f", dt={S.dt!r}"
    parts = [f"# {doc}\n"]
    parts += [_array(f"{name}_{m}", getattr(S, m)) for m in "ABCD"]
    parts.append(f"{name} = control.ss({name}_A, {name}_B, {name}_C, {name}_D{dt})\n\n")
    return "".join(parts)


def export_control(path: str | Path, model: Model, *, title: str = "") -> Path:
    """Write the model's plant as python-control systems to ``path`` (a .py file).

    Raises
    ------
    ConfigError
        python-control is not installed (the message names the ``pip install``).
    ModelError
        The written file does not reproduce the model's P_h (never expected).
    """
    require_control()
    p = Path(path)
    G, P = model.plant_ss(), model.plant_discrete()
    where = "continuous" if G.dt is None else f"discrete at dt = {G.dt!r} s"
    text = (
        "# SPDX-License-Identifier: Apache-2.0\n"
        f"# {title or 'a model of mr-ident'}: python-control systems (load: runpy.run_path)\n"
        "import numpy as np\nimport control\n\n"
        f"fs = {model.fs_high!r}\ninput_delay_s = {model.input_delay!r}\n\n"
        + _system("G", G, f"the plant as fitted ({where}), without the input delay")
        + _system("P_h", P, "P_h: zero-order hold and input delay included, dt = 1/fs")
    )
    atomic_write(p, lambda fh: fh.write(text), binary=False)
    _check(p, P)
    return p


def _check(path: Path, P: StateSpace) -> None:
    """The file's P_h against the model's at a few frequencies."""
    import control  # noqa: PLC0415 (the optional extra)

    sys_ = runpy.run_path(str(path))["P_h"]
    f = np.linspace(0.01, 0.49, 7) / float(P.dt or 1.0)
    want = P.freqresp(f)
    got = control.frequency_response(sys_, 2 * np.pi * f, squeeze=False).complex
    got = np.asarray(got).transpose(2, 0, 1)
    if not np.allclose(got, want, rtol=1e-8, atol=1e-12 * np.abs(want).max()):
        raise ModelError(f"{path}: its P_h differs from the model's (python-control check)")
