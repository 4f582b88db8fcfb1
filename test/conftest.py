# SPDX-License-Identifier: Apache-2.0
"""Shared fixtures: the paper model, a brute-force per-sample loop simulator, periodic runs,
the environment of a ROS process in its own domain."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from mr_ident.io.modelfile import load_model
from mr_ident.numerics.systems.model import Model

ROOT = Path(__file__).resolve().parents[1]


def ros_settings() -> dict[str, str]:
    """What every ROS process of the tests runs with: localhost discovery only, its logs
    under out/ros_log unless ROS_LOG_DIR says otherwise (no ROS import here)."""
    log_dir = os.environ.get("ROS_LOG_DIR", str(ROOT / "out" / "ros_log"))
    return {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_LOG_DIR": log_dir}


def domain_env(dom: int) -> dict[str, str]:
    """The environment of a ROS child process in domain ``dom`` (:func:`ros_settings`)."""
    return dict(os.environ, **ros_settings(), ROS_DOMAIN_ID=str(dom))


def console_script(name: str) -> str:
    """The path of this package's console script ``name`` (``mr-ident``, ``mr-ident-node``...).

    Searched on PATH, then in the lib/mr_ident of the prefixes a colcon workspace names
    (COLCON_PREFIX_PATH, AMENT_PREFIX_PATH: where `colcon build` installs an ament_python
    package's scripts; before the interpreter's own bin, which in `colcon test` is the venv's
    and may hold another install's), then beside the interpreter (a venv's bin: `make test`).
    """
    found = shutil.which(name)
    if found:
        return found
    prefixes = [
        p
        for var in ("COLCON_PREFIX_PATH", "AMENT_PREFIX_PATH")
        for p in os.environ.get(var, "").split(os.pathsep)
        if p
    ]
    candidates = [Path(p) / "lib" / "mr_ident" / name for p in prefixes]
    candidates.append(Path(sys.executable).parent / name)
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
    raise FileNotFoundError(
        f"console script {name!r} not found on PATH nor in {[str(c) for c in candidates]}"
    )


#: The modules holding the suite's longest tests (a ROS graph, a diagnosis, a console
#: script's chain; 5-20 s each alone), longest first. They are collected first, so that
#: pytest-xdist hands them out at the start and the run ends on short tests, not on one
#: worker finishing a 20 s test while the other idles. Each module keeps its own order
#: (its shared fixtures and caches stay with one worker).
FIRST = (
    "test_ros_monitor.py",
    "test_diagnose_random.py",
    "test_ros_lifecycle.py",
    "test_fit.py",
    "test_view.py",
    "test_docs.py",
    "test_ros_excite.py",
    "test_validation_decides.py",
    "test_ros_node.py",
    "test_diagnose_holes.py",
    "test_validate.py",
    "test_ros_sources.py",
    "test_ros_names.py",
    "test_batch.py",
    "test_correction.py",
    "test_bags.py",
)


#: The modules that run ROS nodes or programs in real time (their waits are bounded in
#: wall time), besides ``test_ros_*``. They form one pytest-xdist group (``--dist
#: loadgroup`` in ``make test``): one worker runs them one after another, mostly waiting,
#: while the others (one per core) run the computing tests; two nodes of two tests never
#: compete for the cores. On the 2-core machine: 3 min 35 s with three workers, 4 min 6 s
#: with two (the group's worker then also computes), 4 min 15 s without the group.
ROS_GROUP = ("test_msgs.py", "test_signals.py", "test_view.py")


def require_interfaces(*type_names: str) -> None:
    """Skip the test unless the ROS 2 interfaces ``type_names`` (``pkg/msg/Type``) are
    installed: the ROS 2 wheels of requirements.txt bring them, an environment without ROS
    (``make test-apt``) has none."""
    from mr_ident.errors import MrIdentError
    from mr_ident.io.msgdef import message_definition

    for name in type_names:
        try:
            message_definition(name)
        except MrIdentError as err:
            pytest.skip(f"ROS 2 interfaces not installed: {err}")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "xdist_group(name): tests one xdist worker runs")
    config.addinivalue_line(
        "markers",
        "realtime: a claim about timing that a loaded machine cannot judge (the test skips "
        "there, saying why); make test runs these after the rest, alone",
    )
    config.addinivalue_line(
        "markers",
        "ros: runs ROS 2 nodes or programs over DDS, or the browser (the modules of the ROS "
        "group, set by the suite itself); -m 'not ros' is the numerics part, which "
        "make test-numerics and make test-apt run",
    )


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The modules of :data:`FIRST` first, in its order; the rest as collected. The ROS
    modules (``test_ros_*`` and :data:`ROS_GROUP`) in one xdist group, marked ``ros``."""
    rank = {name: i for i, name in enumerate(FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(FIRST)))
    for item in items:
        name = item.path.name
        if name.startswith("test_ros_") or name in ROS_GROUP:
            item.add_marker(pytest.mark.xdist_group("ros"))
            item.add_marker(pytest.mark.ros)


@pytest.fixture(scope="session")
def paper_model() -> Model:
    return load_model(ROOT / "config" / "paper_example.yaml")


@pytest.fixture(scope="session")
def mimo_model() -> Model:
    """A 2x2 closed loop at F = 2: a coupled second-order plant, a diagonal first-order K_l."""
    from mr_ident.io.modelfile import model_from_dict

    return model_from_dict(
        {
            "fs_high": 100.0,
            "ratio": 2,
            "plant": {"num": [[[1.0], [0.2]], [[0.1], [2.0]]], "den": [1.0, 3.0, 10.0]},
            "controller": {"num": [[[0.5, 0.0], [0.0]], [[0.0], [0.4, 0.0]]], "den": [1.0, -0.5]},
        }
    )


def lpm_regressor(Uw: np.ndarray, n: int, R: int) -> np.ndarray:
    """The LPM regressor of one window, spelled out: ``U_i (r/n)^s`` then ``(r/n)^s``.

    ``Uw`` (2n+1, n_in) the window's inputs; returns (2n+1, (R+1)(n_in+1)), the columns
    (s, i) for s = 0..R, then the transient's powers.
    """
    r = np.arange(-n, n + 1) / n
    ni = Uw.shape[1]
    return np.stack(
        [Uw[:, i] * r**s for s in range(R + 1) for i in range(ni)]
        + [r**s + 0j for s in range(R + 1)],
        axis=1,
    )


def brute_force_loop(
    model: Model, r: np.ndarray, v: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the multirate loop sample by sample, straight from its definition.

    u_h[n] = r_h[n] - u_c[m] held from sample mF + phase + delay; the controller
    samples y_h + v at mF + phase. With the model's injection "setpoint" r is instead the
    controller's reference: u_c[m] = K (y_h + v - r_h) at mF + phase, u_h[n] = -u_c[m].
    Only for plants without feedthrough (D = 0).
    """
    P = model.plant_discrete()
    assert np.allclose(P.D, 0)
    F, ny, nu = model.ratio, model.n_y, model.n_u
    N = r.shape[0]
    v = np.zeros((N, ny)) if v is None else v
    Kc = model.controller_ss() if model.controller is not None else None
    x = np.zeros(P.A.shape[0])
    xk = np.zeros(Kc.A.shape[0]) if Kc is not None else None
    setpoint = model.injection == "setpoint"
    pending: dict[int, np.ndarray] = {}
    held = np.zeros(nu)
    u = np.zeros((N, nu))
    y = np.zeros((N, ny))
    for n in range(N):
        y[n] = P.C @ x + v[n]
        if Kc is not None and n % F == model.sample_phase:
            e = y[n] - r[n] if setpoint else y[n]
            uc = Kc.C @ xk + Kc.D @ e
            xk = Kc.A @ xk + Kc.B @ e
            pending[n + model.control_delay] = uc
        if n in pending:
            held = pending.pop(n)
        u[n] = -held if setpoint else r[n] - held
        x = P.A @ x + P.B @ u[n]
    return u, y


def periodic_runs(
    model: Model, signals: np.ndarray, period: int, periods: int, skip: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each realization's one-period excitation ``signals[m]`` through the loop, repeated.

    ``periods`` periods from rest (:class:`~mr_ident.numerics.excitation.sources.SimSource`), the
    first ``skip`` dropped; r, u, y each (realizations, (periods - skip) * period).
    """
    from mr_ident.numerics.excitation.sources import SimSource

    runs = []
    for sig in signals:
        src = SimSource(model, block=period, excitation="signal", signal=np.reshape(sig, (-1, 1)))
        blocks = [src.next() for _ in range(periods)]
        runs.append(
            [np.concatenate([b[i] for b in blocks])[skip * period :, 0] for i in (1, 2, 3)]
        )
    r, u, y = (np.stack([run[i] for run in runs]) for i in range(3))
    return r, u, y
