# SPDX-License-Identifier: Apache-2.0
"""Which span of a recording with gaps is used (``--span``), and errors that say what is
wrong with the data (too few messages, a topic with nothing on it, the spans and the gaps).

Bags written by ``rosbags`` (not by this project); the loop is the paper's example (240 Hz,
F = 3) simulated by mr_ident. Four cycles are dropped at samples 1000 and 12000 of 14400
(a hole of r longer than a block: not bridged): the spans are [0, 999), [1005, 12000) and
[12006, 14400) on the F grid, the longest
the middle one. Its P_h is held to the same tolerance as a clean bag's (median relative
error < 1e-4 against the exact model; 46 s of data).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from bagmaker import BagWriter, joint_state_bag, stamps
from test_bags import PAPER, R, U, Y

from mr_ident.cli import main
from mr_ident.cli.common import flag
from mr_ident.errors import ConfigError, DataError
from mr_ident.io.modelfile import load_model
from mr_ident.live.recordings import load_recording
from mr_ident.live.replay import bag_signals
from mr_ident.numerics.identify import identify
from mr_ident.numerics.systems.simulate import simulate

SPECS = {"r": [R], "u": [U], "y": [Y]}
DROPPED = {1000, 1001, 1002, 1003, 12000, 12001, 12002, 12003}


@pytest.fixture(scope="module")
def gappy(tmp_path_factory):
    model = load_model(PAPER)
    sim = simulate(model, duration=60.0, rng=np.random.default_rng(0))
    path = tmp_path_factory.mktemp("spans") / "gappy"
    joint_state_bag(path, sim, stamps(sim.n_samples, 240.0), skip=DROPPED)
    return model, sim, path


def test_the_longest_span_is_used_by_default_and_the_note_says_where_the_gaps_are(gappy):
    model, sim, path = gappy
    loaded = load_recording(path, specs=SPECS, ratio=3)
    data = loaded.data
    assert (data.first, data.end) == (1005, 12000)
    np.testing.assert_array_equal(data.y, sim.y[1005:12000])
    res = identify(data.r, data.u, data.y, fs_high=240.0, ratio=3)
    P = model.plant_discrete().freqresp(res.plant.frequency)
    assert float(np.median(np.abs(res.plant.response - P) / np.abs(P))) < 1e-4
    (note,) = loaded.notes
    assert "using the longest span [1005, 12000) of 10995 samples" in note
    assert "3 span(s)" in note and "gaps at [999, 1005), [12000, 12006)" in note
    # why: the messages that held r were dropped too (u, y alone would be bridged)
    assert "split at: reference: gap of 4 samples at [1000, 1004) (longer than 3 samples" in note
    assert re.search(r"\(bridged: holes of u, y at most \d+ samples a hole, 5.9 % of a", note)
    assert "of r, at most 3 samples)" in note


def test_span_latest_takes_the_last_and_all_is_an_error_naming_the_gaps(gappy):
    _, sim, path = gappy
    data, info = bag_signals(path, SPECS, ratio=3, span="latest")
    assert (data.first, data.end) == (12006, sim.n_samples) and "latest" in info.broken
    with pytest.raises(
        DataError, match=r": span all needs a recording without gaps too long.*gaps at"
    ) as err:
        bag_signals(path, SPECS, ratio=3, span="all")
    told = err.value.told(flag)  # the command line's words
    assert "--span all needs" in told and "(--span longest or latest uses one span)" in told
    with pytest.raises(ConfigError, match="span must be one of longest, latest, all, got 'first'"):
        load_recording(path, specs=SPECS, ratio=3, span="first")


def test_the_cli_flag_chooses_the_span_and_warns(gappy, tmp_path, capsys):
    _, _, path = gappy
    base = ["identify", str(path), "--r", R, "--u", U, "--y", Y, "--ratio", "3"]
    code = main([*base, "--out", str(tmp_path / "a.npz")])
    err = capsys.readouterr().err
    assert code == 0 and "warning:" in err and "longest span [1005, 12000)" in err, err
    code = main([*base, "--span", "all", "--out", str(tmp_path / "b.npz")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "gaps at" in err, err
    assert not (tmp_path / "b.npz").exists()


def _few(path, n: int, *, empty_topic: bool = False):
    t = stamps(max(n, 1), 240.0)
    with BagWriter(path) as bw:
        if empty_topic:  # a topic that was recorded but never published
            bw.conns["/ident/reference"] = bw.w.add_connection(
                "/ident/reference", "sensor_msgs/msg/JointState", typestore=bw.ts
            )
        for k in range(n):
            js = bw.joint_state(int(t[k]), ["j1"], position=[0.1 * k], effort=[0.2 * k])
            bw.write("/joint_states", "sensor_msgs/msg/JointState", js, t[k])
            if not empty_topic:
                bw.write("/ident/reference", "sensor_msgs/msg/JointState", js, t[k])
    return path


@pytest.mark.parametrize(
    ("n", "empty", "match"),
    [
        (2, False, r"too few messages: topic /ident/reference holds 2 \(source"),
        (3, False, r"too few samples for the LPM window: .* got N = 3"),
        (40, True, r"topic /ident/reference has no messages .*/joint_states \(40\)"),
    ],
    ids=["two-messages", "three-messages", "empty-topic"],
)
def test_too_little_data_is_an_error_saying_so(tmp_path, capsys, n, empty, match):
    """rosbag2's own test bags hold three messages: with the ratio given, the error says
    that three samples are too few; fewer than three messages cannot give the rate."""
    import re

    bag = _few(tmp_path / "few", n, empty_topic=empty)
    r, u, y = (
        "/ident/reference.position[0]",
        "/joint_states.effort[0]",
        "/joint_states.position[0]",
    )
    code = main(
        ["identify", str(bag), "--r", r, "--u", u, "--y", y, "--ratio", "3",
         "--out", str(tmp_path / "x.npz")]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and "Traceback" not in err
    assert re.search(match, err), err
    assert not (tmp_path / "x.npz").exists()


def test_batch_passes_the_span_and_its_rows_say_which_was_used(gappy, tmp_path, capsys):
    import csv

    _, _, path = gappy
    out = tmp_path / "b"
    args = ["batch", str(path), "--r", R, "--u", U, "--y", Y, "--ratio", "3", "--fs-high", "240"]
    code = main([*args, "--span", "latest", "--workers", "1", "--out-dir", str(out)])
    assert code == 0, capsys.readouterr().err
    (row,) = list(csv.DictReader(open(out / "summary.csv")))
    assert row["status"] == "ok" and row["first"] == "12006", row
    assert "using the latest span [12006, 14400)" in row["notes"]


def test_replay_is_the_nodes_latest_window_unless_span_says_otherwise(gappy, tmp_path, capsys):
    """The latest span [12006, 14400) is 9.98 s, under min_window_s = 10 s: replay as the
    node fails and lists the spans; --span longest identifies [1005, 12000)."""
    _, _, path = gappy
    base = ["replay", str(path), "--r", R, "--u", U, "--y", Y, "--ratio", "3"]
    code = main([*base, "--out", str(tmp_path / "a.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "no gap-free aligned window of at least 2400 samples" in err, err
    assert "the longest [1005, 12000) of 10995 samples; gaps at [999, 1005)" in err
    code = main([*base, "--span", "longest", "--out", str(tmp_path / "b.npz")])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "window [1005, 12000)" in out and "note: using the longest span" in err
