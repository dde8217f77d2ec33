// rtsid lab page: one card per robot/joint fed by Server-Sent Events from `rtsid watch --web`.
// Leads with the tracked stiffness K_track and its 95 % band (K_track ± 1.96 standard errors);
// the window's own K is shown beside it as "K (300 ms window)". B and I with their 95 % bands,
// or, when the stream holds them, as held values ("B 0.800 (held)", no band). VAF over the last
// WINDOW_S seconds, withheld windows marked (red points on the VAF plot, listed with their
// reason), the link and deadline counters of the daemon's status message, and how many
// malformed messages the server refused.
//
// Data, never markup: every message field reaches the page through textContent (or a DOM
// attribute set by code), never parsed as markup; the server's Content-Security-Policy forbids inline
// script besides.
"use strict";

const Z95 = 1.96;
let WINDOW_S = 30;
const joints = new Map(); // name -> {points, status, channels, el, fields, plots, dirty}
const PLOTS = [
  { field: "K_track", label: "K_track N·m/rad", color: "#1f77b4", band: true, also: "K" },
  { field: "B", label: "B N·m·s/rad", color: "#2ca02c", band: true },
  { field: "I", label: "I kg·m²", color: "#9467bd", band: true },
  { field: "vaf", label: "VAF %", color: "#444", band: false },
];
const DIGITS = { K_track: 1, K: 1, B: 3, I: 5 };

function fmt(v, digits) {
  return typeof v !== "number" || !isFinite(v) ? "–" : v.toFixed(digits);
}

function isHeld(p, f) {
  // I_held / B_held; messages before those fields: a value without a standard error.
  const held = p[f + "_held"];
  if (held !== null && held !== undefined) return held === true;
  return typeof p[f] === "number" && (p[f + "_se"] === null || p[f + "_se"] === undefined);
}

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "field") node.dataset.field = v;
    else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c); // strings become text nodes
  return node;
}

function card(name) {
  const fields = {};
  const val = (f) => (fields[f] = el("span", { class: "val", field: f }));
  const band = (f) => (fields[f + "_band"] = el("span", { class: "band", field: f + "_band" }));
  const kWindow = (fields.K_label = el("span", { field: "K_label" }, "K (window)"));
  const section = el(
    "section",
    { class: "joint" },
    el("h2", {}, name),
    el(
      "div",
      { class: "values" },
      el("span", { class: "lead" }, "K_track ", val("K_track"), " ", band("K_track"), " N·m/rad"),
      el("span", {}, kWindow, " ", val("K"), " ", band("K"), " N·m/rad"),
      el("span", {}, "B ", val("B"), " ", band("B"), " N·m·s/rad"),
      el("span", {}, "I ", val("I"), " ", band("I"), " kg·m²"),
      el("span", {}, "VAF ", val("vaf"), " %"),
      el("span", {}, "latency ", val("latency_ms"), " ms"),
      (fields.state = el("span", { class: "state", field: "state" })),
    ),
    (fields.counters = el("div", { class: "counters", field: "counters" }, "no status yet")),
    (fields.plots = el("div", { class: "plots" })),
    (fields.withheld = el("ul", { class: "withheld-list", field: "withheld" })),
    (fields.channels = el("div", { class: "channels", field: "channels" })),
  );
  section.dataset.joint = name;
  return { section, fields };
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
    if (spec.also) series.push({ label: "K (window)", stroke: "#999", width: 0.8 });
  } else {
    series.push({ label: "withheld", stroke: "#d00", width: 0, points: { show: true, size: 6, fill: "#d00" } });
  }
  return new uPlot(opts, series.map(() => []), container);
}

function joint(name) {
  let j = joints.get(name);
  if (j) return j;
  const waiting = document.getElementById("waiting");
  if (waiting) waiting.remove();
  const { section, fields } = card(name);
  const main = document.getElementById("joints");
  const after = [...main.children].find((c) => c.dataset.joint > name);
  main.insertBefore(section, after || null);
  const plots = PLOTS.map((spec) => {
    const div = document.createElement("div");
    fields.plots.appendChild(div);
    return { spec, plot: makePlot(div, spec) };
  });
  j = { points: [], status: null, channels: {}, channelDivs: new Map(), el: section, fields, plots, dirty: true };
  joints.set(name, j);
  return j;
}

function addPoint(j, p) {
  const last = j.points[j.points.length - 1];
  if (last && p.seq !== null && last.seq !== null && p.seq <= last.seq && p.t <= last.t) return;
  j.points.push(p);
  j.dirty = true;
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

function bandOf(p, f, seField) {
  // [lower, upper] of the 95 % band; nulls when held or without a standard error.
  const y = p.ok ? p[f] : null;
  const se = p[seField];
  if (typeof y !== "number" || typeof se !== "number" || isHeld(p, f)) return [null, null];
  return [y - Z95 * se, y + Z95 * se];
}

function plotData(spec, pts, xs) {
  if (!spec.band) return [xs, pts.map((p) => (p.ok ? p[spec.field] : null)), pts.map((p) => (p.ok ? null : 0))];
  const ys = pts.map((p) => (p.ok ? p[spec.field] : null));
  const bands = pts.map((p) => bandOf(p, spec.field, spec.field + "_se"));
  const data = [xs, ys, bands.map((b) => b[0]), bands.map((b) => b[1])];
  if (spec.also) data.push(pts.map((p) => (p.ok ? p[spec.also] : null)));
  return data;
}

function showValue(j, p, f) {
  j.fields[f].textContent = fmt(p[f], DIGITS[f]);
  const se = p[f + "_se"];
  let band = "";
  if ((f === "B" || f === "I") && isHeld(p, f)) band = "(held)";
  else if (typeof se === "number") band = "± " + fmt(Z95 * se, DIGITS[f]);
  j.fields[f + "_band"].textContent = band;
}

function render(name, j) {
  const now = Date.now() / 1000;
  const newest = j.points.length ? j.points[j.points.length - 1].t : now;
  const from = Math.max(now, newest) - WINDOW_S;
  while (j.points.length && j.points[0].t < from) j.points.shift();
  const pts = j.points;
  const xs = pts.map((p) => p.t);
  for (const { spec, plot } of j.plots) {
    plot.setData(plotData(spec, pts, xs), false);
    plot.setScale("x", { min: from, max: from + WINDOW_S });
  }
  const latest = pts[pts.length - 1];
  const lastOk = [...pts].reverse().find((p) => p.ok);
  if (lastOk) {
    for (const f of ["K_track", "K", "B", "I"]) showValue(j, lastOk, f);
    j.fields.vaf.textContent = fmt(lastOk.vaf, 1);
    if (typeof lastOk.window_ms === "number") j.fields.K_label.textContent = `K (${fmt(lastOk.window_ms, 0)} ms window)`;
  }
  if (latest) {
    j.fields.latency_ms.textContent = fmt(latest.latency_ms, 1);
    const flags = Array.isArray(latest.flags) && latest.flags.length ? ` [${latest.flags.join(",")}]` : "";
    j.fields.state.textContent = latest.ok ? "ok" + flags : `withheld: ${latest.reason}`;
    j.fields.state.className = "state" + (latest.ok ? "" : " state-withheld");
  }
  const withheld = pts.filter((p) => !p.ok).slice(-20).reverse();
  j.fields.withheld.replaceChildren(
    ...withheld.map((p) => el("li", {}, `${new Date(p.t * 1000).toLocaleTimeString()} seq ${p.seq}: ${p.reason}`)),
  );
  if (j.status) j.fields.counters.textContent = counters(j.status);
  renderChannels(j);
  j.dirty = false;
}

function renderChannels(j) {
  // Any other channel the daemon publishes: its latest message's scalar fields.
  const skip = new Set(["robot", "joint", "host_time_ns"]);
  for (const [channel, message] of Object.entries(j.channels)) {
    let div = j.channelDivs.get(channel);
    if (!div) {
      div = el("div", { class: "channel" });
      div.dataset.channel = channel;
      j.fields.channels.appendChild(div);
      j.channelDivs.set(channel, div);
    }
    if (channel === "marker") {
      // the newest trial markers, as text: a label is data, never markup
      const recent = (j.markers || [message]).map((m) => `"${m.label}" at t=${fmt(m.t_s, 3)} s`);
      div.textContent = `/marker: ${recent.join(" · ")}`;
      continue;
    }
    const fields = Object.entries(message)
      .filter(([k, v]) => !skip.has(k) && (v === null || typeof v !== "object"))
      .map(([k, v]) => `${k} ${typeof v === "number" ? +v.toPrecision(4) : v}`);
    div.textContent = `/${channel}: ${fields.join(", ")}`;
  }
}

function note(text) {
  document.getElementById("notes").appendChild(el("li", {}, String(text)));
}

function showRejected(count, last) {
  const node = document.getElementById("rejected");
  node.textContent = `rejected ${count} malformed message${count === 1 ? "" : "s"}`;
  node.title = last ? `last: ${last}` : "";
  node.dataset.state = count > 0 ? "some" : "none";
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
    document.getElementById("notes").replaceChildren();
    for (const n of msg.notes || []) note(n);
    showRejected(msg.rejected || 0, msg.last_rejection);
  } else if (msg.type === "estimate") {
    addPoint(joint(msg.joint), msg.point);
  } else if (msg.type === "status") {
    const j = joint(msg.joint);
    j.status = msg.status;
    j.dirty = true;
  } else if (msg.type === "channel") {
    const j = joint(msg.joint);
    j.channels[msg.channel] = msg.message;
    if (msg.channel === "marker") j.markers = [...(j.markers || []), msg.message].slice(-5);
    j.dirty = true;
  } else if (msg.type === "gone") {
    const j = joints.get(msg.joint);
    if (j) { j.el.remove(); joints.delete(msg.joint); }
    note(msg.note);
  } else if (msg.type === "rejected") {
    showRejected(msg.count, msg.last);
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
