// The pack page: each pack's health points against equivalent cycles, its trend and retirement
// forecast (GET /packs, /packs/{id}), the slot assignments (PUT /packs/assignments) and the
// flights (GET /flights). Plain SVG: no library, no network beyond this service.
"use strict";
const $ = (id) => document.getElementById(id);
const TOKEN_KEY = "gcs-pdm-token";  // the same session token as the vehicle page
const fmt = (x, d = 3) => (x === null || x === undefined ? "unknown" : Number(x).toPrecision(d));

async function getJSON(url) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: ${r.status}`);
  return r.json();
}

function forecastText(f) {
  if (!f || f.cycles === null) return `unknown${f && f.why ? " (" + f.why + ")" : ""}`;
  const lo = f.low === null ? "?" : f.low.toFixed(0);
  const hi = f.high === null ? "beyond reach" : f.high.toFixed(0);
  return `${f.threshold} at ${f.cycles.toFixed(0)} cycles (${lo}–${hi}, ${(f.interval * 100).toFixed(0)} % interval)`;
}

async function loadPacks() {
  const packs = await getJSON("/packs");
  const body = $("pack-table").querySelector("tbody");
  body.textContent = "";
  $("pack-empty").hidden = packs.length > 0;
  for (const p of packs) {
    const tr = document.createElement("tr");
    tr.className = "pack-row";
    tr.dataset.pack = p.pack_id;
    const lat = p.latest || {};
    const cells = [p.pack_id, p.identity.join(", "), p.flights, p.equivalent_cycles.toFixed(1),
      lat.capacity_ah == null ? "unknown" : `${fmt(lat.capacity_ah)} ± ${fmt(lat.capacity_sd_ah, 1)}`,
      lat.resistance_25c_ohm == null ? "unknown"
        : `${fmt(lat.resistance_25c_ohm * 1e3)} ± ${fmt(lat.resistance_sd_ohm * 1e3, 1)}`,
      forecastText(p.retirement)];
    for (const c of cells) { const td = document.createElement("td"); td.textContent = c; tr.appendChild(td); }
    tr.addEventListener("click", () => showPack(p.pack_id));
    body.appendChild(tr);
    if (p.thresholds) {
      $("thresholds").textContent = `Retirement at ${(p.thresholds.capacity_fraction * 100).toFixed(0)} % of the first ` +
        `capacity or ${p.thresholds.resistance_factor}× the first resistance (settings).`;
    }
  }
  if (packs.length && $("pack-detail").hidden) showPack(packs[0].pack_id);
}

function svg(tag, attrs, parent) {
  const el = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  if (parent) parent.appendChild(el);
  return el;
}

// points: [{x, y, sd}], fit: {y0, a, b, sign} or null, threshold: y value, forecast: {cycles, low, high}
function plot(el, points, fit, threshold, forecast, scale) {
  el.textContent = "";
  const W = 460, H = 240, L = 50, R = 10, T = 10, B = 30;
  const known = points.filter((p) => p.y !== null);
  if (!known.length) {
    svg("text", { x: 20, y: 120, class: "tick" }, el).textContent = "unknown in every flight (see the pack's flights)";
    return;
  }
  let xmax = Math.max(1, ...points.map((p) => p.x));
  if (forecast && forecast.cycles !== null) xmax = Math.max(xmax, Math.min(forecast.high ?? forecast.cycles, forecast.cycles * 2));
  const ys = known.flatMap((p) => [p.y - (p.sd || 0), p.y + (p.sd || 0)]).concat(threshold !== null ? [threshold] : []);
  let ymin = Math.min(...ys), ymax = Math.max(...ys);
  const pad = (ymax - ymin) * 0.1 || Math.abs(ymax) * 0.05 || 1;
  ymin -= pad; ymax += pad;
  const X = (x) => L + (x / xmax) * (W - L - R);
  const Y = (y) => H - B - ((y - ymin) / (ymax - ymin)) * (H - T - B);
  svg("line", { x1: L, y1: H - B, x2: W - R, y2: H - B, class: "axis" }, el);
  svg("line", { x1: L, y1: T, x2: L, y2: H - B, class: "axis" }, el);
  for (let k = 0; k <= 4; k++) {
    const xv = (xmax * k) / 4, yv = ymin + ((ymax - ymin) * k) / 4;
    svg("text", { x: X(xv) - 8, y: H - B + 14, class: "tick" }, el).textContent = xv.toFixed(0);
    svg("text", { x: 4, y: Y(yv) + 3, class: "tick" }, el).textContent = (yv * scale).toPrecision(3);
  }
  if (forecast && forecast.cycles !== null && forecast.low !== null) {
    const hi = forecast.high === null ? xmax : Math.min(forecast.high, xmax);
    svg("rect", { x: X(forecast.low), y: T, width: Math.max(1, X(hi) - X(forecast.low)), height: H - T - B, class: "interval" }, el);
  }
  if (threshold !== null) svg("line", { x1: L, y1: Y(threshold), x2: W - R, y2: Y(threshold), class: "threshold" }, el);
  if (fit) {
    let d = "";
    for (let k = 0; k <= 60; k++) {
      const x = (xmax * k) / 60, y = fit.y0 * (1 + fit.sign * fit.a * Math.pow(x, fit.b));
      d += `${k ? "L" : "M"}${X(x).toFixed(1)},${Y(Math.min(Math.max(y, ymin), ymax)).toFixed(1)}`;
    }
    svg("path", { d, class: "fit" }, el);
  }
  for (const p of known) {
    if (p.sd) svg("line", { x1: X(p.x), y1: Y(p.y - p.sd), x2: X(p.x), y2: Y(p.y + p.sd), class: "bar" }, el);
    svg("circle", { cx: X(p.x), cy: Y(p.y), r: 3, class: "point" }, el);
  }
}

async function showPack(id) {
  const p = await getJSON(`/packs/${encodeURIComponent(id)}`);
  for (const tr of document.querySelectorAll("tr.pack-row")) tr.classList.toggle("selected", tr.dataset.pack === id);
  $("pack-detail").hidden = false;
  $("pack-title").textContent = `${p.pack_id}: ${p.flights} flight(s), ${p.equivalent_cycles.toFixed(1)} equivalent cycles`;
  $("pack-warning").hidden = !p.warning;
  $("pack-warning").textContent = p.warning || "";
  const t = p.trend;
  const cap = p.history.map((h) => ({ x: h.cycles, y: h.capacity_ah, sd: h.capacity_sd_ah }));
  const res = p.history.map((h) => ({ x: h.cycles, y: h.resistance_25c_ohm, sd: h.resistance_sd_ohm }));
  const cf = t.capacity_fit, rf = t.resistance_fit;
  plot($("plot-capacity"), cap, cf && { ...cf, sign: -1 }, cf ? cf.y0 * p.thresholds.capacity_fraction : null, t.capacity_forecast, 1);
  plot($("plot-resistance"), res, rf && { ...rf, sign: 1 }, rf ? rf.y0 * p.thresholds.resistance_factor : null, t.resistance_forecast, 1e3);
  $("forecast").textContent = `Capacity: ${forecastText(t.capacity_forecast)}. Resistance: ${forecastText(t.resistance_forecast)}. ` +
    `Retirement: ${forecastText(t.retirement)}.`;
}

// one line per vehicle slot in the list ``id``: what ``line(slot, value)`` says of it
function fillSlotList(id, bySlot, line) {
  const ul = $(id);
  ul.textContent = "";
  for (const [slot, value] of Object.entries(bySlot)) {
    const li = document.createElement("li");
    li.textContent = line(slot, value);
    ul.appendChild(li);
  }
}

async function loadAssignments() {
  fillSlotList("assignments", await getJSON("/packs/assignments"), (slot, row) => `${slot}: ${row.pack_id}`);
}

async function loadPriors() {
  fillSlotList("slot-priors", await getJSON("/packs/priors"), (slot, p) => p === null
    ? `${slot}: no flight of its pack has told its health: the vehicle description's values`
    : `${slot}: pack ${p.pack_id}, capacity ${fmt(p.capacity_ah)} ± ${fmt(p.capacity_sd_ah, 2)} Ah, ` +
      `resistance at 25 °C ${fmt(p.resistance_25c_ohm === null ? null : p.resistance_25c_ohm * 1e3)} mΩ`);
}

$("assign-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  let token = sessionStorage.getItem(TOKEN_KEY);
  if (!token) {
    token = window.prompt("API token (gcs-pdm serve prints it, or api_token in its settings)") || "";
    if (token) sessionStorage.setItem(TOKEN_KEY, token);
  }
  const slot = $("assign-slot").value.trim(), pack = $("assign-pack").value.trim();
  const r = await fetch("/packs/assignments", {
    method: "PUT", headers: { "Content-Type": "application/json", Authorization: `Bearer ${token}` },
    body: JSON.stringify({ slot, pack_id: pack, note: "console" }),
  });
  if (r.status === 401) sessionStorage.removeItem(TOKEN_KEY);
  $("assign-message").textContent = r.ok ? `slot ${slot}: pack ${pack}` : `refused: ${r.status} ${(await r.text()).slice(0, 200)}`;
  loadAssignments();
  loadPriors();
});

async function loadFlights() {
  const flights = await getJSON("/flights");
  const body = $("flight-table").querySelector("tbody");
  body.textContent = "";
  for (const f of flights) {
    const detail = await getJSON(`/flights/${f.id}`);
    const tr = document.createElement("tr");
    const faults = detail.faults.map((x) => `${x.kind} ${x.target ?? ""}${x.active ? " (active)" : ""}`).join("; ") || "none";
    for (const c of [f.id, fmt(f.started_s, 5), f.open ? "open" : fmt(f.ended_s, 5), f.begin_reason, f.end_reason ?? "", faults]) {
      const td = document.createElement("td"); td.textContent = c; tr.appendChild(td);
    }
    body.appendChild(tr);
  }
}

Promise.all([loadPacks(), loadAssignments(), loadPriors(), loadFlights()]).catch((e) => console.error(e));
