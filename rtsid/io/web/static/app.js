// rtsid lab page: one card per robot/joint fed by Server-Sent Events from `rtsid watch --web`.
// K, B, I with 95 % bands (value ± 1.96 standard errors) and VAF over the last WINDOW_S seconds,
// withheld windows marked (red points on the VAF plot, listed with their reason), and the link
// and deadline counters of the daemon's status message.
"use strict";

const Z95 = 1.96;
let WINDOW_S = 30;
const joints = new Map(); // name -> {points, status, el, plots, dirty}
const PLOTS = [
  { field: "K", label: "K N·m/rad", color: "#1f77b4", band: true },
  { field: "B", label: "B N·m·s/rad", color: "#2ca02c", band: true },
  { field: "I", label: "I kg·m²", color: "#9467bd", band: true },
  { field: "vaf", label: "VAF %", color: "#444", band: false },
];

function fmt(v, digits) {
  return v === null || v === undefined || !isFinite(v) ? "–" : Number(v).toFixed(digits);
}

function card(name) {
  const el = document.createElement("section");
  el.className = "joint";
  el.dataset.joint = name;
  el.innerHTML = `
    <h2>${name}</h2>
    <div class="values">
      <span>K <span class="val" data-field="K"></span> ± <span class="band" data-field="K_band"></span> N·m/rad</span>
      <span>B <span class="val" data-field="B"></span> ± <span class="band" data-field="B_band"></span> N·m·s/rad</span>
      <span>I <span class="val" data-field="I"></span> ± <span class="band" data-field="I_band"></span> kg·m²</span>
      <span>VAF <span class="val" data-field="vaf"></span> %</span>
      <span>latency <span class="val" data-field="latency_ms"></span> ms</span>
      <span class="state" data-field="state"></span>
    </div>
    <div class="counters" data-field="counters">no status yet</div>
    <div class="plots"></div>
    <ul class="withheld-list" data-field="withheld"></ul>
    <div class="channels" data-field="channels"></div>`;
  return el;
}

function makePlot(container, spec) {
  const series = [{}, { label: spec.label, stroke: spec.color, width: 1.5 }];
  const opts = {
    width: 330,
    height: 160,
    scales: { x: { time: true } },
    legend: { show: false },
    cursor: { show: false },
    series,
    axes: [{}, { label: spec.label, size: 70, values: (u, vals) => vals.map((v) => +v.toPrecision(4)) }],
  };
  if (spec.band) {
    series.push({ label: "lower 95 %", stroke: spec.color + "55", width: 0.5 });
    series.push({ label: "upper 95 %", stroke: spec.color + "55", width: 0.5 });
    opts.bands = [{ series: [3, 2], fill: spec.color + "30" }];
  } else {
    series.push({ label: "withheld", stroke: "#d00", width: 0, points: { show: true, size: 6, fill: "#d00" } });
  }
  return new uPlot(opts, spec.band ? [[], [], [], []] : [[], [], []], container);
}

function joint(name) {
  let j = joints.get(name);
  if (j) return j;
  const waiting = document.getElementById("waiting");
  if (waiting) waiting.remove();
  const el = card(name);
  const main = document.getElementById("joints");
  const after = [...main.children].find((c) => c.dataset.joint > name);
  main.insertBefore(el, after || null);
  const holder = el.querySelector(".plots");
  const plots = PLOTS.map((spec) => {
    const div = document.createElement("div");
    holder.appendChild(div);
    return { spec, plot: makePlot(div, spec) };
  });
  j = { points: [], status: null, channels: {}, el, plots, dirty: true };
  joints.set(name, j);
  return j;
}

function addPoint(j, p) {
  const last = j.points[j.points.length - 1];
  if (last && p.seq !== null && last.seq !== null && p.seq <= last.seq && p.t <= last.t) return;
  j.points.push(p);
  j.dirty = true;
}

function setText(root, field, text) {
  const el = root.querySelector(`[data-field="${field}"]`);
  if (el) el.textContent = text;
}

function counters(status) {
  const a = status.acquisition || {};
  const w = status.worker || {};
  const withheld = Object.entries(w.withheld || {}).map(([k, v]) => `${k}:${v}`).join(", ") || "0";
  return (
    `link: samples ${a.samples ?? "–"}, gaps ${a.gaps ?? "–"}, lost ${a.lost_samples ?? "–"}, ` +
    `bus errors ${a.bus_errors ?? "–"} · worker: estimates ${w.estimates ?? "–"}, withheld ${withheld}, ` +
    `deadline misses ${w.deadline_misses ?? "–"}, overruns ${w.overruns ?? "–"} · ` +
    `cpu ${fmt(status.cpu_percent, 0)} %`
  );
}

function render(name, j) {
  const now = Date.now() / 1000;
  const newest = j.points.length ? j.points[j.points.length - 1].t : now;
  const from = Math.max(now, newest) - WINDOW_S;
  while (j.points.length && j.points[0].t < from) j.points.shift();
  const pts = j.points;
  const xs = pts.map((p) => p.t);
  for (const { spec, plot } of j.plots) {
    const ys = pts.map((p) => (p.ok ? p[spec.field] : null));
    let data;
    if (spec.band) {
      const se = pts.map((p) => (p.ok ? p[spec.field + "_se"] : null));
      const lo = ys.map((y, i) => (y === null || se[i] === null ? null : y - Z95 * se[i]));
      const hi = ys.map((y, i) => (y === null || se[i] === null ? null : y + Z95 * se[i]));
      data = [xs, ys, lo, hi];
    } else {
      data = [xs, ys, pts.map((p) => (p.ok ? null : 0))];
    }
    plot.setData(data, false);
    plot.setScale("x", { min: from, max: from + WINDOW_S });
  }
  const latest = pts[pts.length - 1];
  const lastOk = [...pts].reverse().find((p) => p.ok);
  if (lastOk) {
    for (const f of ["K", "B", "I"]) {
      const digits = { K: 1, B: 3, I: 5 }[f];
      setText(j.el, f, fmt(lastOk[f], digits));
      setText(j.el, f + "_band", lastOk[f + "_se"] === null ? "held" : fmt(Z95 * lastOk[f + "_se"], digits));
    }
    setText(j.el, "vaf", fmt(lastOk.vaf, 1));
  }
  if (latest) {
    setText(j.el, "latency_ms", fmt(latest.latency_ms, 1));
    const state = j.el.querySelector('[data-field="state"]');
    state.textContent = latest.ok ? "ok" + (latest.flags && latest.flags.length ? ` [${latest.flags.join(",")}]` : "") : `withheld: ${latest.reason}`;
    state.className = "state" + (latest.ok ? "" : " state-withheld");
  }
  const withheld = pts.filter((p) => !p.ok).slice(-20).reverse();
  j.el.querySelector('[data-field="withheld"]').innerHTML = withheld
    .map((p) => `<li>${new Date(p.t * 1000).toLocaleTimeString()} seq ${p.seq}: ${p.reason}</li>`)
    .join("");
  if (j.status) setText(j.el, "counters", counters(j.status));
  renderChannels(j);
  j.dirty = false;
}

function renderChannels(j) {
  // Any other channel the daemon publishes: its latest message's scalar fields.
  const holder = j.el.querySelector('[data-field="channels"]');
  for (const [channel, message] of Object.entries(j.channels)) {
    let div = holder.querySelector(`[data-channel="${channel}"]`);
    if (!div) {
      div = document.createElement("div");
      div.className = "channel";
      div.dataset.channel = channel;
      holder.appendChild(div);
    }
    const skip = new Set(["robot", "joint", "host_time_ns"]);
    const fields = Object.entries(message)
      .filter(([k, v]) => !skip.has(k) && (v === null || typeof v !== "object"))
      .map(([k, v]) => `${k} ${typeof v === "number" ? +v.toPrecision(4) : v}`);
    div.textContent = `/${channel}: ${fields.join(", ")}`;
  }
}

function note(text) {
  const li = document.createElement("li");
  li.textContent = text;
  document.getElementById("notes").appendChild(li);
}

function handle(msg) {
  if (msg.type === "snapshot") {
    WINDOW_S = msg.window_s || WINDOW_S;
    for (const [name, j] of joints) if (!(name in msg.joints)) { j.el.remove(); joints.delete(name); }
    for (const [name, data] of Object.entries(msg.joints)) {
      const j = joint(name);
      j.points = [];
      for (const p of data.points) addPoint(j, p);
      j.status = data.status;
      j.channels = data.channels || {};
      j.dirty = true;
    }
    document.getElementById("notes").innerHTML = "";
    for (const n of msg.notes || []) note(n);
  } else if (msg.type === "estimate") {
    addPoint(joint(msg.joint), msg.point);
  } else if (msg.type === "status") {
    const j = joint(msg.joint);
    j.status = msg.status;
    j.dirty = true;
  } else if (msg.type === "channel") {
    const j = joint(msg.joint);
    j.channels[msg.channel] = msg.message;
    j.dirty = true;
  } else if (msg.type === "gone") {
    const j = joints.get(msg.joint);
    if (j) { j.el.remove(); joints.delete(msg.joint); }
    note(msg.note);
  }
}

function tick() {
  for (const [name, j] of joints) render(name, j); // also slides the 30 s window
}

const connection = document.getElementById("connection");
const source = new EventSource("/events");
source.onopen = () => { connection.textContent = "live"; connection.dataset.state = "open"; };
source.onerror = () => { connection.textContent = "disconnected (retrying)"; connection.dataset.state = "closed"; };
source.onmessage = (e) => {
  handle(JSON.parse(e.data));
  for (const [name, j] of joints) if (j.dirty && j.points.length < 3) render(name, j);
};
setInterval(tick, 250);
