# SPDX-License-Identifier: Apache-2.0
"""Plant monitoring over DDS: the node holds its estimates against a reference (issue 27).

Own domain, localhost only, every wait bounded (the helpers of test_ros_node). The loop is
the paper's plant with output noise 2 % of y's std (34 dB), F = 3, 240 Hz, a 20 s window.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import replace
from itertools import takewhile
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph import PAPER, await_subscribers, fast_params, publishers, wait_for  # noqa: E402
from rosgraph import graph as graph  # noqa: E402  (the fixture)
from std_msgs.msg import String  # noqa: E402

from mr_ident.diagnosis.monitoring.monitor import load_watch, watch_windows  # noqa: E402
from mr_ident.io.datafile import read_data  # noqa: E402
from mr_ident.io.modelfile import load_model  # noqa: E402
from mr_ident.live.replay import bag_windows  # noqa: E402
from mr_ident.numerics.excitation.sources import SimSource  # noqa: E402
from mr_ident.numerics.systems.simulate import simulate  # noqa: E402
from mr_ident.ros.messages import RESULT_QOS, block_msg  # noqa: E402
from mr_ident.ros.outputs import DriftMsg  # noqa: E402


class PlantListener:
    """The node's plant status, ~/drift and ~/diagnosis, as they come."""

    def __init__(self, graph):
        n = graph.node("plant_listener")
        self.plant: list[tuple[int, str, dict[str, str]]] = []
        self.drift: list = []  # mr_ident_msgs/Drift
        self.found: list[dict] = []

        def on_diag(m):
            for s in m.status:
                if s.name.endswith(": plant"):
                    level = s.level[0] if isinstance(s.level, bytes) else int(s.level)
                    self.plant.append((level, s.message, {kv.key: kv.value for kv in s.values}))

        n.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
        n.create_subscription(DriftMsg, "/mr_ident/drift", self.drift.append, RESULT_QOS)
        n.create_subscription(
            String, "/mr_ident/diagnosis", lambda m: self.found.append(json.loads(m.data)), 10
        )


#: Loop seconds of the changed plant sent at 10x real time, the rest at 2x: a whole
#: window (20 s) of it and half a window more, past the windows the replay below needs.
DRIFTED_FAST = 30.0


def _noisy(model):
    y = simulate(model, duration=20.0, rng=np.random.default_rng(0)).y
    return replace(model, noise_std=0.02 * float(np.std(y)))


def _send(
    pubs, src: SimSource, seconds: float, block: int = 240, pause: float = 0.1, stop=None,
    fast: float | None = None,
):  # fmt: skip
    """``seconds`` of the loop in 1 s blocks at 10x real time (estimates every 0.2 s wall),
    or until ``stop`` is set; with ``fast``, only its first ``fast`` seconds, then at 2x (an
    estimate every 0.5 s, well within the plant status' stale time of 2 s: the node is not
    kept estimating five times a second while it diagnoses)."""
    for k in range(int(seconds * src.model.fs_high / block)):
        if stop is not None and stop.is_set():
            return
        first, r, u, y = src.next()
        for p, x in zip(pubs, (r, u, y), strict=True):
            p.publish(block_msg(first, x))
        slow = fast is not None and k * block >= fast * src.model.fs_high
        time.sleep(0.5 * block / src.model.fs_high if slow else pause)


def test_node_reports_ok_then_the_drift_and_its_cause(graph, tmp_path: Path):
    """The loop as modelled: every plant status OK ("matches the reference") over >= 5
    checked estimates. Then the plant gain rises 30 % (the stream goes on, same indices):
    WARN or ERROR within 60 s, ~/drift published, and the cause named on ~/diagnosis and in
    the status message (gain within 3 %), the window kept beside record_path for offline
    diagnosis. Replay of the node's recording (every 4 s of loop time, the library path
    ``mr-ident replay --params`` takes; up to a window past the latest first drift allowed)
    gives the same: OK, then WARN/ERROR within two windows of the change, and the gain
    named."""
    nominal = _noisy(load_model(PAPER))
    rec = tmp_path / "run.mcap"
    params = fast_params(
        window_s=20.0, monitor_hold=2, monitor_error_db=6.0, record_path=str(rec)
    ) + [Parameter("monitor_model", value=str(PAPER))]
    node = graph.ident(params)
    lis = PlantListener(graph)
    pubs = publishers(graph)
    await_subscribers(pubs)
    src = SimSource(nominal, block=240, seed=5)
    _send(pubs, src, 36.0)
    wait_for(
        lambda: lis.plant and int(lis.plant[-1][2].get("estimates_checked", 0)) >= 5,
        60,
        "five checked estimates",
    )
    checked = [p for p in lis.plant if p[2].get("estimates_checked", "0") != "0"]
    # STALE (3): no estimate within the stale time, which a loaded machine's slow estimates
    # can cause between two of them; it is not a drift alarm. No WARN or ERROR, though.
    fresh = [p for p in checked if p[0] != 3]
    assert fresh and all(level == 0 for level, _, _ in fresh), fresh[-1]
    assert fresh[-1][1] == "matches the reference"
    d = lis.drift[-1]  # stamped as the estimate it compares, one value per published bin
    assert d.header.stamp.sec > 0 and d.window_last > 0
    assert len(d.frequency) == len(d.deviation) == len(d.sigma_error) == len(d.threshold) > 0

    drifted = SimSource(replace(nominal, plant_gain=1.3), block=240, seed=6)
    drifted.next_index = src.next_index  # the same stream goes on
    stop = threading.Event()
    feeder = threading.Thread(
        target=_send, args=(pubs, drifted, 200.0), kwargs={"stop": stop, "fast": DRIFTED_FAST}
    )
    feeder.start()
    try:
        wait_for(lambda: lis.found, 120, "a diagnosis on ~/diagnosis")
        status = wait_for(
            lambda: next((p for p in reversed(lis.plant) if "cause:" in p[1]), None),
            10,
            "the cause in the plant status",
        )
    finally:
        stop.set()
        feeder.join(10)
    found = lis.found[-1]
    assert found["cause"] == "gain_error", found
    assert abs(found["parameters"]["gain"] - 1.3) < 0.03 * 1.3, found
    assert status[0] in (1, 2) and "plant gain 1.3" in status[1], status
    event = Path(found["event_file"])
    assert event.exists() and event.parent == tmp_path
    data = read_data(event)
    assert data.n_samples == node.config.window_samples and data.ratio == 3

    # replay of the node's recording: the same statuses (OK, then the drift) and cause
    node.set_parameters([Parameter("record_path", value="")])  # the recording finalised
    cfg = node.config.replace(record_path="", update_period_s=4.0)
    watch = load_watch(cfg)
    change = 36.0  # s of loop time at which the gain rose
    # the windows up to a window past the latest first drift allowed (the recording goes on
    # while the node diagnoses; later windows only repeat the drift)
    until = change + 3 * cfg.window_s
    events = watch_windows(takewhile(lambda w: w[0] <= until, bag_windows(rec, cfg)), watch)
    levels = [e.level for e in events]
    assert levels[0] == "ok" and levels[-1] in ("warn", "error"), events
    first_drift = next(e.time_s for e in events if e.level != "ok")
    assert change < first_drift <= change + 2 * cfg.window_s, events
    assert "plant gain 1.3" in events[-1].text, events
    # (the same from the command line, mr-ident replay --params with monitor_model: the
    # same library path, tested on a bag in test_bags)


@pytest.mark.parametrize(
    "change,cause,key,true,tol",
    [
        ({"input_delay": 1.5 / 240.0}, "input_delay", "delay_s", 1.5 / 240.0, 0.1 / 240.0),
    ],
    ids=["input_delay"],  # a moved mode: the same path in-process, test_drift
)
def test_node_names_a_moved_mode_and_a_delay(graph, tmp_path: Path, change, cause, key, true, tol):
    """Over DDS as above, the paper's plant under the softer lead controller of
    test_validate (the paper's own loop is near instability with 1.5 samples more delay):
    OK while the loop is as modelled, then, after the change in the running stream, the
    cause named on ~/diagnosis with its value within tolerance (frequency 2 %, delay 0.1
    sample) and WARN or ERROR."""
    from mr_ident.io.modelfile import model_to_dict
    from mr_ident.numerics.systems.lti import TransferMatrix

    soft = replace(
        load_model(PAPER),
        controller=TransferMatrix.siso([3000.0, -2700.0], [1.0, -0.3], 3 / 240.0),
    )
    path = tmp_path / "soft.yaml"
    path.write_text(yaml.safe_dump(model_to_dict(soft), sort_keys=False))
    params = [
        Parameter(k, value=v)
        for k, v in dict(
            window_s=20.0,
            min_window_s=20.0,
            update_period_s=0.2,
            monitor_hold=2,
            monitor_model=str(path),
            controller_num=[3000.0, -2700.0],
            controller_den=[1.0, -0.3],
        ).items()
    ]
    graph.ident(params)
    lis = PlantListener(graph)
    pubs = publishers(graph)
    await_subscribers(pubs)
    nominal = _noisy(soft)
    src = SimSource(nominal, block=240, seed=7)
    _send(pubs, src, 26.0)
    wait_for(
        lambda: lis.plant and lis.plant[-1][2].get("estimates_checked", "0") != "0", 60, "a check"
    )
    checked = [level for level, _, v in lis.plant if v.get("estimates_checked", "0") != "0"]
    assert all(level in (0, 3) for level in checked), checked  # no WARN/ERROR (3: STALE)
    drifted = SimSource(replace(nominal, **change), block=240, seed=8)
    drifted.next_index = src.next_index
    stop = threading.Event()
    feeder = threading.Thread(
        target=_send, args=(pubs, drifted, 200.0), kwargs={"stop": stop, "fast": DRIFTED_FAST}
    )
    feeder.start()
    try:
        wait_for(lambda: lis.found, 120, "a diagnosis on ~/diagnosis")
    finally:
        stop.set()
        feeder.join(10)
    found = lis.found[-1]
    assert found["cause"] == cause and abs(found["parameters"][key] - true) <= tol, found
    assert any(level in (1, 2) for level, _, _ in lis.plant)
