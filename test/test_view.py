# SPDX-License-Identifier: Apache-2.0
"""The live view: its server against an analytic estimate, and the page in a real browser.

The browser test starts mr-ident-sim, mr-ident-node and mr-ident view (own domain,
localhost), loads the page in Debian's headless Chromium, waits until it has drawn an
estimate, and checks what it plotted (|P| in dB, phase, PFG) against ``/estimate.json`` of
the same version (1e-9 relative: the page's arithmetic in double precision). Skipped, with
the reason, where ``chromium`` is not installed.
"""

from __future__ import annotations

import base64
import json
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from conftest import console_script, domain_env

from mr_ident.errors import ConfigError
from mr_ident.view.server import ViewServer
from mr_ident.view.state import ViewState

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "paper_example.yaml"


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as err:
        return err.code, err.read()


def test_the_server_gives_the_estimate_it_was_given_and_waits_politely(tmp_path):
    """P = 1/(1 + j f/10) on 50 bins, std 1 % of |P|; the JSON has it to the last bit."""
    state = ViewState(source="test")
    server = ViewServer(state, port=0).start()
    try:
        code, body = _get(server.url + "estimate.json")
        assert code == 404 and json.loads(body) == {"error": "no estimate yet"}
        code, page = _get(server.url)
        assert code == 200 and b"no estimate yet" in page
        code, js = _get(server.url + "plotly.min.js")
        assert code == 200 and len(js) > 1_000_000  # from the plotly wheel, not the internet
        f = np.geomspace(0.1, 100.0, 50)
        P = 1.0 / (1.0 + 1j * f / 10.0)
        state.set_estimate(f, P, 0.01 * np.abs(P), pfg=np.ones(50), pfg_std=np.zeros(50))
        code, body = _get(server.url + "estimate.json")
        est = json.loads(body)
        assert code == 200 and est["shape"] == [1, 1]
        np.testing.assert_array_equal(est["frequency"], f)
        np.testing.assert_array_equal(np.array(est["P_re"]) + 1j * np.array(est["P_im"]), P)
        v = est["version"]
        state.set_estimate(f, 2 * P, 0.01 * np.abs(P))
        old = json.loads(_get(server.url + f"estimate.json?version={v}")[1])
        assert old["P_re"] == est["P_re"]  # an earlier version stays readable
        with pytest.raises(ConfigError, match=r"--port \d+: cannot listen"):
            ViewServer(state, port=server.server_address[1])
    finally:
        server.stop()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver")
CHROME_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--window-size=1400,1400",
]
PLOTTED = "return document.getElementById('plotted').textContent"


class WebDriver:
    """Debian's chromedriver over its W3C WebDriver HTTP API (JSON, no client library):
    a real Chromium, the page's server-sent events live."""

    def __init__(self, tmp_path: Path) -> None:
        port = _free_port()
        self.proc = subprocess.Popen(
            [CHROMEDRIVER, f"--port={port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        self.base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 20
        while True:
            try:
                self._call("GET", "/status")
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        args = [*CHROME_FLAGS, f"--user-data-dir={tmp_path / 'profile'}"]
        caps = {"alwaysMatch": {"goog:chromeOptions": {"binary": CHROMIUM, "args": args}}}
        self.session = self._call("POST", "/session", {"capabilities": caps})["sessionId"]

    def _call(self, method: str, path: str, body: object = None) -> dict:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path, data=data, method=method)
        req.add_header("Content-Type", "application/json")
        with urllib.request.urlopen(req, timeout=60) as r:
            value = json.loads(r.read())["value"]
        return value if isinstance(value, dict) else {"value": value}

    def get(self, url: str) -> None:
        self._call("POST", f"/session/{self.session}/url", {"url": url})

    def script(self, js: str) -> object:
        body = {"script": js, "args": []}
        return self._call("POST", f"/session/{self.session}/execute/sync", body)["value"]

    def screenshot(self, path: Path) -> None:
        png = self._call("GET", f"/session/{self.session}/screenshot")["value"]
        path.write_bytes(base64.b64decode(png))

    def close(self) -> None:
        try:
            self._call("DELETE", f"/session/{self.session}")
        finally:
            self.proc.terminate()
            self.proc.wait(10)


def _wait_for_estimate(url: str, procs: dict, tmp_path: Path) -> None:
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        time.sleep(1.0)
        for name, p in procs.items():
            assert p.poll() is None, (tmp_path / f"{name}.log").read_text()
        try:
            if _get(url + "estimate.json")[0] == 200:
                return
        except OSError:
            continue
    raise AssertionError("no estimate within 90 s")


@pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="no browser: install Debian's chromium and chromium-driver "
    "(apt install chromium chromium-driver)",
)
def test_the_page_in_a_real_browser_plots_the_nodes_estimate(tmp_path):
    from domain_coordinator import domain_id

    port = _free_port()
    with domain_id() as dom:
        env = domain_env(dom)
        params = [
            "--ros-args", "-p", "autostart:=true",
            "-p", "window_s:=60.0", "-p", "min_window_s:=10.0",
            "-p", "update_period_s:=1.0", "-p", "controller_num:=[6000.0, -5400.0]",
            "-p", "controller_den:=[1.0, -0.3]",
        ]  # fmt: skip
        logs = {k: open(tmp_path / f"{k}.log", "w") for k in ("sim", "node", "view")}
        commands = {
            "node": [console_script("mr-ident-node"), *params],
            "sim": [console_script("mr-ident-sim"), PAPER, "--rate", "20", "--wait", "20"],
            "view": [
                console_script("mr-ident"),
                "view",
                "--port",
                port,
                "--model",
                PAPER,
                "--wait",
                "60",
            ],
        }
        procs = {
            k: subprocess.Popen(
                [str(a) for a in argv], env=env, stdout=logs[k], stderr=subprocess.STDOUT
            )
            for k, argv in commands.items()
        }
        url = f"http://127.0.0.1:{port}/"
        try:
            _wait_for_estimate(url, procs, tmp_path)
            browser = WebDriver(tmp_path)
            try:
                browser.get(url)
                text = ""
                deadline = time.monotonic() + 60
                while not text and time.monotonic() < deadline:
                    time.sleep(0.5)  # the page draws on the next server-sent event
                    text = str(browser.script(PLOTTED))
                assert text, "the page drew no estimate within 60 s"
                plotted = json.loads(text)
                # the drawn estimate by its version (the server keeps the last 32), at once
                code, body = _get(url + f"estimate.json?version={plotted['version']}")
                shown = browser.script("return document.getElementById('waiting').style.display")
                assert shown == "none"  # "no estimate yet" is gone
                time.sleep(3.0)
                again = json.loads(str(browser.script(PLOTTED)))
                assert again["state_version"] > plotted["state_version"]  # redrawn, no reload
                shot = ROOT / "out" / "view_screenshot.png"
                shot.parent.mkdir(exist_ok=True)
                browser.screenshot(shot)
                assert shot.stat().st_size > 10_000
            finally:
                browser.close()
            assert code == 200, body
            drawn = json.loads(body)
            f = np.array(drawn["frequency"])
            K = f.size
            P = np.array(drawn["P_re"][:K]) + 1j * np.array(drawn["P_im"][:K])
            np.testing.assert_allclose(plotted["frequency"], f, rtol=1e-12)
            np.testing.assert_allclose(plotted["mag_db"], 20 * np.log10(np.abs(P)), rtol=1e-9)
            phase = np.degrees(np.angle(P))
            wrapped = (np.array(plotted["phase_deg"]) - phase + 180.0) % 360.0 - 180.0
            np.testing.assert_allclose(wrapped, 0.0, atol=1e-7)  # the page unwraps
            assert drawn["pfg"] is not None
            np.testing.assert_allclose(plotted["pfg"], drawn["pfg"], rtol=1e-12)
            assert drawn["sigma_error_median"] is not None  # the model was given
        finally:
            for p in procs.values():
                if p.poll() is None:
                    p.terminate()
            for p in procs.values():
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(5)
            for fh in logs.values():
                fh.close()
        assert procs["view"].returncode == 0, (tmp_path / "view.log").read_text()


R = '/ident/reference.position{name=="j1"}'
U = '/joint_states.effort{name=="j1"}'
Y = '/joint_states.position{name=="j1"}'


def test_a_bag_replays_its_estimates_into_the_view(tmp_path):
    """A rosbags-written JointState bag: the view's last estimate is the identification of
    the window it names, on the node's published grid (equal to 1e-12)."""
    from bagmaker import joint_state_bag, stamps

    from mr_ident.io.config import IdentConfig
    from mr_ident.io.modelfile import load_model
    from mr_ident.live.estimate import estimate, publish_grid
    from mr_ident.live.replay import bag_signals
    from mr_ident.numerics.signals import LoopData
    from mr_ident.numerics.systems.simulate import simulate

    model = load_model(PAPER)
    sim = simulate(model, duration=40.0, rng=np.random.default_rng(4))
    bag = joint_state_bag(tmp_path / "js", sim, stamps(sim.n_samples, 240.0))
    port = _free_port()
    argv = [console_script("mr-ident"), "view", str(bag), "--model", str(PAPER)]
    argv += ["--r", R, "--u", U, "--y", Y, "--speed", "0", "--port", str(port)]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = []
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            lines.append(line)
            if "estimates shown" in line or not line:
                break
        assert "estimates shown" in lines[-1], "".join(lines)
        est = json.loads(_get(f"http://127.0.0.1:{port}/estimate.json")[1])
    finally:
        proc.terminate()
        proc.wait(10)
    assert proc.returncode == 0
    data, _ = bag_signals(bag, {"r": [R], "u": [U], "y": [Y]}, ratio=3)
    first, n = est["window"]["estimate_first"], est["window"]["estimate_samples"]
    s = slice(first - data.first, first - data.first + n)
    cfg = IdentConfig().with_controller(model.controller)
    ref = estimate(LoopData(data.r[s], data.u[s], data.y[s], ratio=3, first=first), cfg)
    k = publish_grid(ref.identification.plant.frequency.size, cfg.publish_points)
    P = ref.identification.plant.response[k, 0, 0]
    np.testing.assert_allclose(np.array(est["P_re"]) + 1j * np.array(est["P_im"]), P, rtol=1e-12)
    np.testing.assert_allclose(est["pfg"], ref.identification.pfg.gain[k], rtol=1e-12)
    np.testing.assert_allclose(est["pfg_data"], ref.identification.pfg_data.gain[k], rtol=1e-12)


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    from domain_coordinator import domain_id

    mr = console_script("mr-ident")
    state = ViewState()
    server = ViewServer(state, port=0).start()
    taken = str(server.server_address[1])
    try:
        with domain_id() as dom:
            env = domain_env(dom)
            cases = {
                "port in use": ([mr, "view", "--port", taken], "error: --port"),
                "no node": (
                    [mr, "view", "--port", "0", "--wait", "1"],
                    "error: no node publishes",
                ),
                "bad bag": (
                    [mr, "view", str(tmp_path / "none.mcap"), "--port", "0", "--ratio", "3"],
                    "error: ",
                ),
            }
            for name, (argv, start) in cases.items():
                p = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=60)
                err = p.stderr.strip().splitlines()
                assert p.returncode == 2, (name, p.stdout, p.stderr)
                assert len(err) == 1 and err[0].startswith(start), (name, p.stderr)
    finally:
        server.stop()


def test_the_plant_status_and_drift_bands_reach_the_state():
    """Monitoring in the view: the plant status beside the identification's health, and the
    significant drift bins of ~/drift as bands (contiguous published bins joined)."""
    from mr_ident.view.state import ViewState

    st = ViewState()
    assert st.snapshot()["plant"] == {}
    f = np.array([1.0, 2.0, 3.0, 5.0, 8.0, 13.0])
    st.set_drift(f, [False, True, True, False, True, False])
    st.set_plant({"level": "1", "message": "drift 2.3 dB at 2-8 Hz"})
    snap = st.snapshot()["plant"]
    assert snap["bands"] == [[2.0, 3.0], [8.0, 8.0]] and snap["message"].startswith("drift")
    st.set_health({"level": "0", "message": "estimating"})
    assert st.snapshot()["plant"]["level"] == "1"  # not overwritten by the health


def test_an_identification_as_the_reference_is_drawn_with_its_std():
    """`view --reference RESULT.npz`: the reference interpolated onto the estimate's bins
    (nan outside its band), labelled, and the σ-error with both stds."""
    from mr_ident.numerics.results import FRF
    from mr_ident.view.state import ViewState

    f_ref = np.linspace(1.0, 10.0, 10)
    ref = FRF(f_ref, np.full((10, 1, 1), 2.0 + 0j), np.full((10, 1, 1), 0.3), "reference")
    st = ViewState(reference=ref)
    f = np.array([2.0, 5.5, 20.0])
    st.set_estimate(f, np.full((3, 1, 1), 2.5 + 0j), np.full((3, 1, 1), 0.4))
    est = st.estimate()
    assert est["model_label"] == "reference"
    assert est["model_re"][:2] == [2.0, 2.0] and est["model_re"][2] is None  # outside: none
    assert abs(est["sigma_error"][0] - 0.5 / 0.5) < 1e-12  # |2.5 - 2| / sqrt(0.4² + 0.3²)


def test_a_bla_reference_brings_its_noise_and_nonlinear_std_to_the_state_and_the_page(tmp_path):
    """`view --reference BLA.npz` (identify --period): the state carries the BLA's per-line
    |G|, σ, σ_noise and σ_NL in dB and its odd and even distortion above the noise; the
    page's script (run under node.js with a stub document and Plotly; skipped without node)
    draws the σ curves beside the estimate, the BLA alone before the first estimate, and
    the levels in the table."""
    from mr_ident.numerics.excitation.bla import BLA
    from mr_ident.view.state import ViewState

    f = np.array([1.0, 3.0, 5.0])
    bla = BLA(
        np.array([1, 3, 5]),
        np.array([1.0, 0.5j, -0.1]),
        np.array([0.1, 0.05, 0.02]),
        np.array([0.01, 0.01, 0.01]),
        np.array([0.1, 0.05, np.nan]),
        np.array([9.0]),
        np.array([0.0]),
        np.array([1.0]),
        4,
        6,
    )
    st = ViewState(reference_bla=(bla, f))
    ref = st.snapshot()["reference_bla"]
    assert ref["odd_db"] == 10.0 and ref["even_db"] == 0.0  # 10 log10((9 + 1) / 1)
    assert ref["nl_std_db"][:2] == [-20.0, 20 * np.log10(0.05)] and ref["nl_std_db"][2] is None
    assert ref["mag_db"][1] == 20 * np.log10(0.5) and (ref["realizations"], ref["periods"]) == (
        6,
        4,
    )
    assert ViewState().snapshot()["reference_bla"] is None
    node = shutil.which("node")
    if node is None:
        pytest.skip("node.js is not installed: the page's script not run")
    app = (ROOT / "mr_ident" / "view" / "page" / "app.js").read_text()
    before = dict(st.snapshot())
    st.set_estimate(f, np.full((3, 1, 1), 1.0 + 0j), np.full((3, 1, 1), 0.1))
    harness = tmp_path / "run.js"
    harness.write_text(
        "const drawn = {}, els = {};\n"
        "global.document = { getElementById: (id) => els[id] || (els[id] = { style: {} }) };\n"
        "global.Plotly = { react: (id, traces) => { drawn[id] = traces; } };\n"
        "global.performance = { now: () => 0 };\n"
        "global.EventSource = class { addEventListener() {} };\n"
        + app
        + "\nconst out = {};\n"
        + f"draw({json.dumps(before)}); out.alone = drawn.mag.map((t) => t.name);\n"
        + f"draw({json.dumps(st.snapshot())}); out.with = drawn.mag.map((t) => t.name);\n"
        + "out.nl = drawn.mag.find((t) => t.name === 'reference σ nonlinear').y;\n"
        + "out.table = els.health.innerHTML;\n"
        + "console.log(JSON.stringify(out));\n"
    )
    run = subprocess.run([node, str(harness)], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    assert out["alone"] == ["reference BLA", "reference σ noise", "reference σ nonlinear"]
    assert "reference σ noise" in out["with"] and "P̂_h" in out["with"]
    assert out["nl"] == ref["nl_std_db"]
    assert "odd lines 10.000, even lines 0.000" in out["table"]
