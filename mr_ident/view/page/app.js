// SPDX-License-Identifier: Apache-2.0
// mr_ident live view: draws the state the server sends (server-sent events, /events).
"use strict";

const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"];
const LOGX = { type: "log", title: { text: "frequency (Hz)" }, exponentformat: "power" };
const LAYOUT = (title, ytitle) => ({
  title: { text: title, font: { size: 14 } },
  xaxis: LOGX, yaxis: { title: { text: ytitle } },
  margin: { l: 60, r: 10, t: 30, b: 40 }, legend: { orientation: "h", y: -0.25 },
});

function db(x) { return 20 * Math.log10(x); }
function unwrap(deg) {
  const out = deg.slice();
  for (let k = 1; k < out.length; k++) {
    let d = out[k] - out[k - 1];
    out[k] -= 360 * Math.round(d / 360);
  }
  return out;
}
function entry(flat, shape, o, i, K) {
  const start = (o * shape[1] + i) * K;
  return flat.slice(start, start + K);
}

function bodeTraces(est) {
  const f = est.frequency, K = f.length, [ny, nu] = est.shape;
  const mag = [], phase = [], plotted = {};
  for (let o = 0; o < ny; o++) for (let i = 0; i < nu; i++) {
    const re = entry(est.P_re, est.shape, o, i, K), im = entry(est.P_im, est.shape, o, i, K);
    const sd = entry(est.P_std, est.shape, o, i, K);
    const a = re.map((r, k) => Math.hypot(r, im[k]));
    const m = a.map(db), p = unwrap(re.map((r, k) => Math.atan2(im[k], r) * 180 / Math.PI));
    const hi = a.map((x, k) => db(x + 2 * sd[k]));
    const lo = a.map((x, k) => db(Math.max(x - 2 * sd[k], x * 1e-3)));
    const dp = a.map((x, k) => (2 * sd[k] < x ? Math.asin(2 * sd[k] / x) * 180 / Math.PI : 180));
    const name = ny * nu > 1 ? `P̂[${o},${i}]` : "P̂_h";
    const c = COLORS[(o * nu + i) % COLORS.length];
    const band = { line: { width: 0 }, fillcolor: c + "33", hoverinfo: "skip", showlegend: false };
    mag.push({ x: f, y: lo, mode: "lines", ...band });
    mag.push({ x: f, y: hi, mode: "lines", fill: "tonexty", ...band, name: "±2σ", showlegend: o + i === 0 });
    mag.push({ x: f, y: m, mode: "lines", name, line: { color: c, width: 1.5 } });
    phase.push({ x: f, y: p.map((x, k) => x - dp[k]), mode: "lines", ...band });
    phase.push({ x: f, y: p.map((x, k) => x + dp[k]), mode: "lines", fill: "tonexty", ...band });
    phase.push({ x: f, y: p, mode: "lines", name, line: { color: c, width: 1.5 }, showlegend: false });
    if (o === 0 && i === 0) plotted.mag_db = m, plotted.phase_deg = p;
    if (est.model_re) {
      const mr = entry(est.model_re, est.shape, o, i, K), mi = entry(est.model_im, est.shape, o, i, K);
      const dash = { color: "#000", width: 1, dash: "dash" };
      const label = est.model_label || "model P_h";
      const mname = ny * nu > 1 ? `${label} [${o},${i}]` : label;
      mag.push({ x: f, y: mr.map((r, k) => db(Math.hypot(r, mi[k]))), mode: "lines", name: mname, line: dash });
      phase.push({ x: f, y: unwrap(mr.map((r, k) => Math.atan2(mi[k], r) * 180 / Math.PI)), mode: "lines", line: dash, showlegend: false });
    }
  }
  return { mag, phase, plotted };
}

// a BLA reference (identify --period): its noise and nonlinear std per line, in dB
function referenceTraces(ref, withMag) {
  if (!ref) return [];
  const f = ref.frequency, out = [];
  if (withMag) out.push({ x: f, y: ref.mag_db, mode: "lines", name: "reference BLA", line: { color: "#000", width: 1, dash: "dash" } });
  const dots = (y, color, name) => ({ x: f, y, mode: "markers", name, marker: { color, size: 3 } });
  out.push(dots(ref.noise_std_db, "#2ca02c", "reference σ noise"));
  out.push(dots(ref.nl_std_db, "#d62728", "reference σ nonlinear"));
  return out;
}

// The PFGs: identified from data alone (pfg_data) and from P_h and the controller (pfg).
function pfgTraces(est) {
  const f = est.frequency, traces = [];
  const shown = [["pfg_data", "PFG from data (lifted r→y)", "#ff7f0e"], ["pfg", "PFG from P_h and K_l", "#1f77b4"]];
  for (const [key, name, color] of shown) {
    const g = est[key];
    if (!g) continue;
    const s = est[key + "_std"] || g.map(() => 0);
    const band = { line: { width: 0 }, fillcolor: color + "33", hoverinfo: "skip" };
    traces.push(  // in dB, as the PNGs; the band's floor at -60 dB of the gain
      { x: f, y: g.map((x, k) => db(Math.max(x - 2 * s[k], x * 1e-3))), mode: "lines", ...band, showlegend: false },
      { x: f, y: g.map((x, k) => db(x + 2 * s[k])), mode: "lines", fill: "tonexty", ...band, name: "±2σ" },
      { x: f, y: g.map(db), mode: "lines", name, line: { color, width: 1.5 } },
    );
  }
  return traces.length ? traces : null;
}

function fmt(v) {
  if (v === null || v === undefined) return "–";
  if (typeof v === "number") return Math.abs(v) >= 1e4 || (v !== 0 && Math.abs(v) < 1e-3) ? v.toExponential(3) : v.toFixed(3);
  return String(v);
}

const SHOWN = [
  ["message", "status"], ["window_fill", "window fill"],
  ["lifting_phase", "lifting phase"], ["lifting_phase_source", "lifting phase from"],
  ["estimate_samples", "estimate samples"], ["compute_s", "compute (s)"],
  ["estimates", "estimates"], ["window_restarts", "window restarts"],
  ["recent_anomalies", "recent anomalies"],
];

const rate = { t: null, n: 0, value: null };

function drawHealth(state) {
  const h = state.health || {}, est = state.estimate, rows = [];
  const level = h.level === undefined ? null : Number(h.level);
  const st = document.getElementById("status");
  st.textContent = level === null ? (est ? "estimate received" : "waiting for the node…")
    : ["OK", "WARN", "ERROR", "STALE"][level] || `level ${level}`;
  st.className = level === null ? "" : level === 0 ? "ok" : level === 1 ? "warn" : "error";
  document.getElementById("source").textContent = state.source || "";
  rows.push(["age of the last estimate (s)", fmt(state.estimate_age_s)]);
  if ("samples_in" in h) {  // the rate, from the node's running count
    const now = performance.now() / 1000, n = Number(h.samples_in);
    if (rate.t !== null && now > rate.t && n >= rate.n) rate.value = (n - rate.n) / (now - rate.t);
    if (rate.t === null || now - rate.t > 2) { rate.t = now; rate.n = n; }
    rows.push(["samples/s (all streams)", fmt(rate.value)]);
    const gaps = Object.entries(h).filter(([k]) => k.endsWith(".gaps")).reduce((a, [, v]) => a + Number(v), 0);
    rows.push(["gaps (all streams)", String(gaps)]);
  }
  const plant = state.plant || {};
  if ("message" in plant) {  // monitoring against a reference: the plant status
    const names = ["OK", "WARN", "ERROR", "STALE"];
    rows.push(["plant", `${names[Number(plant.level)] || plant.level}: ${plant.message}`]);
    if (plant.bands && plant.bands.length)
      rows.push(["drift bands (Hz)", plant.bands.map(([a, b]) => `${fmt(a)}–${fmt(b)}`).join(", ")]);
  }
  const ref = state.reference_bla;
  if (ref) rows.push([`reference BLA (${ref.realizations} realizations x ${ref.periods} periods): distortion above noise (dB)`,
    `odd lines ${fmt(ref.odd_db)}, even lines ${fmt(ref.even_db)}`]);
  if (est && est.sigma_error_median !== undefined) rows.push(["σ-error vs model (median)", fmt(est.sigma_error_median)]);
  if (est && est.window) for (const [k, v] of Object.entries(est.window)) rows.push([`window ${k}`, fmt(v)]);
  for (const [k, label] of SHOWN) if (k in h) rows.push([label, fmt(h[k])]);
  // the rest of the node's keys, per stream only what says whether it is healthy
  const perStream = /\.(samples|gaps|gap_samples|late|malformed|restarts)$/;
  for (const [k, v] of Object.entries(h)) {
    if (SHOWN.some(([s]) => s === k) || k === "level" || (k.includes(".") && !perStream.test(k))) continue;
    rows.push([k, fmt(v)]);
  }
  document.getElementById("health").innerHTML =
    rows.map(([k, v]) => `<tr><td>${k}</td><td>${String(v).replace(/</g, "&lt;")}</td></tr>`).join("");
}

function draw(state) {
  drawHealth(state);
  const est = state.estimate, waiting = document.getElementById("waiting");
  const ref = state.reference_bla;
  if (!est) {  // nothing estimated yet: a BLA reference is drawn alone
    waiting.style.display = "";
    if (ref) Plotly.react("mag", referenceTraces(ref, true), LAYOUT("magnitude (reference)", "|G| (dB)"));
    return;
  }
  waiting.style.display = "none";
  const { mag, phase, plotted } = bodeTraces(est);
  mag.push(...referenceTraces(ref, false));
  plotted.reference_nl_std_db = ref ? ref.nl_std_db : null;
  // the monitoring's significant drift bands, shaded behind the Bode plots
  const bands = (state.plant && state.plant.bands) || [];
  const shade = bands.map(([lo, hi]) => ({
    type: "rect", xref: "x", yref: "paper", x0: lo, x1: hi, y0: 0, y1: 1,
    fillcolor: "#cf222e22", line: { width: 0 }, layer: "below",
  }));
  // the conventions of the PNGs (mr_ident.plots): |P_h| in dB in the model's units, the
  // phase unwrapped, the PFG in dB
  Plotly.react("mag", mag, { ...LAYOUT("magnitude", state.magnitude_label || "|P_h| [dB]"), shapes: shade });
  Plotly.react("phase", phase, { ...LAYOUT("phase", "phase [deg] (unwrapped)"), shapes: shade });
  plotted.drift_bands = bands;
  const pfg = pfgTraces(est);
  if (pfg) Plotly.react("pfg", pfg, LAYOUT("Performance frequency gain", "PFG r→y [dB]"));
  if (est.sigma_error) {  // |P̂ − P_model| / σ per bin: above 2-3 the model is contradicted
    const K = est.frequency.length, [ny, nu] = est.shape, traces = [];
    for (let o = 0; o < ny; o++) for (let i = 0; i < nu; i++) {
      traces.push({
        x: est.frequency, y: entry(est.sigma_error, est.shape, o, i, K), mode: "lines",
        name: ny * nu > 1 ? `[${o},${i}]` : "|P̂ − P| / σ", line: { width: 1, color: COLORS[(o * nu + i) % COLORS.length] },
      });
    }
    traces.push({ x: [est.frequency[0], est.frequency[K - 1]], y: [2, 2], mode: "lines", name: "2", line: { color: "#888", dash: "dot", width: 1 } });
    const layout = LAYOUT("σ-error against the model", "|P̂ − P| / σ");
    layout.yaxis.type = "log";
    Plotly.react("sigma", traces, layout);
  }
  plotted.frequency = est.frequency; plotted.pfg = est.pfg; plotted.pfg_data = est.pfg_data;
  plotted.version = est.version;  // the estimate's own: the server keeps it by this
  plotted.state_version = state.version;  // any change (health, plant) redraws
  document.getElementById("plotted").textContent = JSON.stringify(plotted);
}

const events = new EventSource("events");
const conn = document.getElementById("conn");
events.addEventListener("state", (e) => { conn.textContent = ""; draw(JSON.parse(e.data)); });
events.onerror = () => {
  // EventSource reconnects by itself; say so only while it is not connected
  if (events.readyState !== EventSource.OPEN) conn.textContent = "(view server not reachable, retrying)";
};
