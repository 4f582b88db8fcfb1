# SPDX-License-Identifier: Apache-2.0
"""The BLA of a bag cut by the excitation's labels recorded with it (mr_ident.live.periodic).

Bags written with the independent ``rosbags`` library (test/bagmaker.py), holding r, u, y
and, on ``<r topic>/excitation_index``, each sample's labels (realization, period, sample)
in the form ``mr-ident excite --publish --as ...`` gives them: JointState per sample (the
labels under their names, the samples' stamps) or the block contract (3 channels at the
samples' indices). Loops: the open loop of test_bla.py (a lightly damped second-order plant
behind u + 0.3 u³, or linear, with output noise) played an odd-random multisine of M
realizations x P periods in turn; the paper's multirate closed loop (F = 3) played a lifted
odd design, y measured with noise. Tolerances at each check.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from bagmaker import BagWriter, stamps

from mr_ident.cli import main
from mr_ident.live.periodic import cut_by_labels, record_by_count
from mr_ident.live.replay import bag_signals
from mr_ident.numerics.excitation.bla import best_linear_approximation
from mr_ident.numerics.excitation.multisine import design
from mr_ident.numerics.excitation.schedule import LABELS, Schedule

N, M, P, FS = 256, 4, 4, 100.0
B, A = [0.0, 0.02, 0.018], [1.0, -1.7, 0.74]
JS = "sensor_msgs/msg/JointState"
R_TOPIC, LABEL_TOPIC = "/ident/reference", "/ident/reference/excitation_index"
SOURCES = [
    *("--r", '/ident/reference.position{name=="j1"}'),
    *("--u", '/joint_states.effort{name=="j1"}'),
    *("--y", '/joint_states.position{name=="j1"}'),
]
SPECS = {"r": [SOURCES[1]], "u": [SOURCES[3]], "y": [SOURCES[5]]}


def _plant(k):
    z = np.exp(2j * np.pi * k / N)
    return np.polyval(B[::-1], 1 / z) / np.polyval(A[::-1], 1 / z)


def _open_loop(nl, seed=0, noise=1e-3):
    """r = u (M*P*N,) played realization after realization, y, and every sample's labels."""
    ms = design(fs_high=FS, period=N, band=(1.0, 30.0), kind="odd-random", periods=P,
                realizations=M, seed=seed)  # fmt: skip
    sched = Schedule.of(ms.r, N)
    r = sched.take(ms.r, 0, sched.cycle)[:, 0]
    rng = np.random.default_rng(seed + 100)
    y = scipy.signal.lfilter(B, A, nl(r)) + noise * rng.standard_normal(r.size)
    return r, y, sched.labels(0, sched.cycle)


def _joint_state_bag(path, r, y, labels, *, keep=slice(None), label_shift_ns=0):
    """r on /ident/reference, u (= r) and y of joint j1 on /joint_states, the labels on
    /ident/reference/excitation_index (same stamps, shifted by ``label_shift_ns``); only the
    samples ``keep``."""
    t = stamps(r.size, FS)
    with BagWriter(path) as bw:
        for k in np.arange(r.size)[keep]:
            tk = int(t[k])
            bw.write(R_TOPIC, JS, bw.joint_state(tk, ["j1"], position=[r[k]]), tk + 300_000)
            lab = bw.joint_state(tk + label_shift_ns, LABELS, position=labels[k].astype(float))
            bw.write(LABEL_TOPIC, JS, lab, tk + 300_000)
            js = bw.joint_state(tk, ["j1"], position=[y[k]], effort=[r[k]])
            bw.write("/joint_states", JS, js, tk + 300_000)
    return path


@pytest.fixture(scope="module")
def cubic(tmp_path_factory):
    """The cubic open loop: its bag (labels with it), and the same samples as an NPZ."""
    d = tmp_path_factory.mktemp("cubic")
    r, y, labels = _open_loop(lambda u: u + 0.3 * u**3)
    npz = d / "realizations.npz"
    np.savez(npz, r=r.reshape(M, P * N), u=r.reshape(M, P * N), y=y.reshape(M, P * N),
             fs_high=FS)  # fmt: skip
    return _joint_state_bag(d / "bag", r, y, labels), npz, (r, y, labels)


def test_identify_period_auto_on_a_bag_equals_the_npz_path_on_the_same_samples(
    cubic, tmp_path, capsys
):
    """`identify BAG --period auto` reads N off the labels, cuts M = 4 realizations x 3
    periods (the first of each dropped) and writes the BLA that `identify DATA.npz --period N`
    writes from the same samples (to 1e-10: every array, the levels too); the cubic's
    nonlinear std is > 5 times the noise's, its odd distortion > 20 dB above the noise;
    `replay --excitation-index` (the node's path) writes the same BLA."""
    bag, npz, _ = cubic
    a, b, c = (tmp_path / f"{k}.npz" for k in "abc")
    argv = ["identify", str(bag), "--period", "auto", "--ratio", "1", *SOURCES, "--out", str(a)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert f"{M} realization(s) x {P - 1} period(s) of {N} samples by labels" in out, out
    assert main(["identify", str(npz), "--period", str(N), "--out", str(b)]) == 0
    argv = ["replay", str(bag), "--ratio", "1", *SOURCES, "--excitation-index", LABEL_TOPIC,
            "--out", str(c)]  # fmt: skip
    assert main(argv) == 0
    assert "periodic: BLA from" in capsys.readouterr().out
    za, zb, zc = (np.load(p) for p in (a, b, c))
    for key in ("frequency", "P", "P_std", "noise_std", "nl_std", "odd_level", "even_level",
                "noise_level", "lines"):  # fmt: skip
        np.testing.assert_allclose(za[key], zb[key], rtol=1e-10, atol=0, err_msg=key)
        np.testing.assert_allclose(zc[key], za[key], rtol=1e-10, atol=0, err_msg=key)
    assert int(za["period"]) == N and int(za["realizations"]) == M and int(za["periods"]) == P - 1
    assert np.median(za["nl_std"]) > 5 * np.median(za["noise_std"])
    assert 10 * np.log10(1 + za["odd_level"][0] / za["noise_level"][0]) > 20


def test_a_linear_loop_gives_the_plant_within_its_std(tmp_path, capsys):
    """A linear open loop: the BLA is the plant at the excited lines within its reported std
    (median error < 1.5 std, max < 5 std), no nonlinear part beyond the noise's."""
    r, y, labels = _open_loop(lambda u: u, seed=3, noise=3e-3)
    bag = _joint_state_bag(tmp_path / "bag", r, y, labels)
    out = tmp_path / "bla.npz"
    argv = ["identify", str(bag), "--period", "auto", "--ratio", "1", *SOURCES, "--out", str(out)]
    assert main(argv) == 0
    z = np.load(out)
    err = np.abs(z["P"][:, 0, 0] - _plant(z["lines"])) / z["P_std"][:, 0, 0]
    assert np.median(err) < 1.5 and err.max() < 5, (np.median(err), err.max())
    assert np.median(z["nl_std"]) < np.median(z["noise_std"])


def test_the_multirate_closed_loop_in_the_block_contract_gives_p_h_within_its_std(tmp_path):
    """The paper's loop (F = 3) played a lifted odd design (2 realizations x 3 periods of
    2400 samples), recorded in the block contract with the labels as a 3-channel block
    stream on reference/excitation_index, y measured with noise: `identify --period auto`
    (the default topics) gives P_h at the excited lines within its std; the even (detection)
    lines show no distortion (within 6 dB of the noise: the ratio keeps the lifted aliases
    out)."""
    from mr_ident.io.modelfile import load_model
    from mr_ident.numerics.excitation.sources import SimSource

    model = load_model("config/paper_example.yaml")
    n, p, m = 2400, 3, 2
    ms = design(fs_high=240.0, period=n, band=(0.5, 100.0), kind="odd", periods=p,
                realizations=m, ratio=3, lifted=True)  # fmt: skip
    sched = Schedule.of(ms.r, n)
    src = SimSource(model, block=240, excitation="signal", signal=sched.take(ms.r, 0, sched.cycle))
    blocks = [src.next() for _ in range(sched.cycle // 240)]
    r, u, y = (np.concatenate([b[i] for b in blocks]) for i in (1, 2, 3))
    y = y + 1e-4 * np.std(y) * np.random.default_rng(7).standard_normal(y.shape)
    labels = sched.labels(0, sched.cycle).astype(float)
    with BagWriter(tmp_path / "bag") as bw:
        for first in range(0, sched.cycle, 240):
            part = slice(first, first + 240)
            for topic, x in (("/reference", r), ("/input", u), ("/output", y),
                             ("/reference/excitation_index", labels)):  # fmt: skip
                msg = bw.block(first, x[part])
                bw.write(topic, "std_msgs/msg/Float64MultiArray", msg, 1000 + first)
    out = tmp_path / "bla.npz"
    argv = ["identify", str(tmp_path / "bag"), "--period", "auto", "--fs-high", "240",
            "--ratio", "3", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    z = np.load(out)
    assert int(z["realizations"]) == m and int(z["periods"]) == p - 1
    Ph = model.plant_discrete().freqresp(z["frequency"])[:, 0, 0]
    err = np.abs(z["P"][:, 0, 0] - Ph) / z["P_std"][:, 0, 0]
    assert np.median(err) < 1.5 and err.max() < 6, (np.median(err), err.max())
    assert 10 * np.log10(1 + z["even_level"][0] / z["noise_level"][0]) < 6


def test_without_labels_period_n_counts_periods_from_the_first_sample(cubic, tmp_path, capsys):
    """A bag without the labels' topic: `--period N` takes its record as one realization,
    whole periods from its first sample (the first dropped), and says so; the BLA is that of
    those samples; `--period auto` is refused, naming the topic it looked for."""
    _, _, (r, y, labels) = cubic
    keep = slice(0, 3 * N + 17)  # 3 whole periods and a part
    bag = tmp_path / "bag"
    t = stamps(r.size, FS)
    with BagWriter(bag) as bw:
        for k in np.arange(r.size)[keep]:
            tk = int(t[k])
            bw.write(R_TOPIC, JS, bw.joint_state(tk, ["j1"], position=[r[k]]), tk)
            bw.write("/joint_states", JS, bw.joint_state(tk, ["j1"], [y[k]], [], [r[k]]), tk)
    out = tmp_path / "bla.npz"
    argv = ["identify", str(bag), "--ratio", "1", *SOURCES, "--out", str(out), "--period"]
    assert main([*argv, str(N)]) == 0
    cap = capsys.readouterr()
    assert "counted from the record's first sample" in cap.err
    assert "273 samples left out" in cap.out  # a period dropped, and the 17 after the last
    want = best_linear_approximation(r[None, N : 3 * N], r[None, N : 3 * N],
                                     y[None, N : 3 * N], N)  # fmt: skip
    np.testing.assert_allclose(np.load(out)["P"][:, 0, 0], want.response, rtol=1e-10)
    assert main([*argv, "auto"]) == 2
    assert f"no topic {LABEL_TOPIC}" in capsys.readouterr().err


def test_labels_that_do_not_fit_are_refused_with_what_came(cubic, tmp_path, capsys):
    """A period disagreeing with the labels; a record with one whole period after the
    transient; labels whose stamps are off the samples' grid (not aligned): each an
    `error: ...` and exit 2 naming what came."""
    bag, _, (r, y, labels) = cubic
    out = str(tmp_path / "bla.npz")
    base = ["identify", "--ratio", "1", *SOURCES, "--out", out, "--period"]
    assert main([base[0], str(bag), *base[1:], str(2 * N)]) == 2
    assert f"disagrees with the labels: their periods have {N} samples" in capsys.readouterr().err
    short = _joint_state_bag(tmp_path / "short", r, y, labels, keep=slice(0, 2 * N + 5))
    assert main([base[0], str(short), *base[1:], "auto"]) == 2
    assert "1 realization(s) x 1 whole period(s)" in capsys.readouterr().err
    off = _joint_state_bag(
        tmp_path / "off", r[: 2 * N], y[: 2 * N], labels[: 2 * N], label_shift_ns=5_000_000
    )  # half a sample time late
    assert main([base[0], str(off), *base[1:], "auto"]) == 2
    err = capsys.readouterr().err
    assert "no aligned samples of r, u, y and the excitation's labels" in err, err


def test_the_labels_align_with_r_u_y_and_cut_a_record_that_starts_mid_realization(cubic, tmp_path):
    """A recording that starts inside a period: the labels are aligned sample by sample with
    r, u, y (bag_signals), and the cut keeps only whole periods after each run's first:
    realization 0 loses its partial period and the next (its transient in the record)."""
    _, _, (r, y, labels) = cubic
    start = N // 2 + 3
    bag = _joint_state_bag(tmp_path / "bag", r, y, labels, keep=slice(start, None))
    data, _ = bag_signals(bag, SPECS, fs_high=FS, ratio=1, labels=LABEL_TOPIC)
    np.testing.assert_array_equal(data.labels, labels[start:])
    np.testing.assert_array_equal(data.y[:, 0], y[start:])
    cut = cut_by_labels(data, None, transient=1)
    assert (cut.realizations, cut.periods) == (M, P - 2)  # realization 0: periods 2, 3 only
    np.testing.assert_array_equal(cut.y[0], y[2 * N : 4 * N])
    np.testing.assert_array_equal(cut.y[1], y[P * N + N : P * N + 3 * N])
    whole = record_by_count(data, N, transient=1)  # no labels used: one realization
    assert whole.realizations == 1 and whole.unused == N + data.n_samples % N
    np.testing.assert_array_equal(whole.y[0], y[start + N : start + data.n_samples // N * N])
