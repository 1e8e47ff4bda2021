// gcs-pdm operator console. Plain JavaScript, no build step; every request goes to this service.
// Data: /status (polled each second: the service publishes no status events), the SSE stream
// /events (faults, plans, uploads, mission, link, jobs), and the REST reads in docs/api.md.
// Contract of optional fields the page shows when present: docs/console.md.
"use strict";

const STATUS_PERIOD_MS = 1000;
const STALE_AFTER_S = 5;          // wall seconds without the vehicle's message time advancing
const SERIES_MAX = 900;           // points kept per plot
const TIMELINE_MAX = 400;
const RECENT_WARNING_S = 300;     // a model-mismatch event stays a banner this long (wall time)
const EARTH_R = 6371008.8;

const S = {
  status: null, statusOk: false, statusError: null,
  msgTime: null, msgAdvancedAt: Date.now(), firstStatusAt: null,
  settings: null, instance: null,
  mission: null, proposed: [], history: [], uploads: [], faults: [], jobs: [], paramsets: [],
  track: [], series: {}, events: [], lastSeq: 0,
  sse: "connecting", es: null, mismatch: null, planFailure: null,
  jobResults: {}, decision: {},   // plan id -> {state, text}
  waypointNames: {},              // "lat,lon" (rounded) -> catalogue number, from plans' scenarios
};

// ---------- small helpers ----------
const $ = (id) => document.getElementById(id);
const esc = (s) => String(s).replace(/[&<>"']/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]));
const num = (v) => typeof v === "number" && isFinite(v);
const fmt = (v, d = 1) => num(v) ? v.toFixed(d) : null;
const unknown = (why) => `<span class="unknown" title="${esc(why)}">unknown (${esc(why)})</span>`;
const val = (v, d, unit, why) => num(v) ? `${v.toFixed(d)}${unit}` : unknown(why);
const pm = (v, sd, d, unit, why) => !num(v) ? unknown(why) :
  `${v.toFixed(d)}${unit}` + (num(sd) ? ` ± ${sd.toFixed(d)}${unit}` : ` <span class="unknown">(spread unknown)</span>`);
const clock = (wall) => new Date(wall * 1000).toLocaleTimeString([], {hour12: false});
const tstamp = (t) => num(t) ? `t=${t.toFixed(0)} s` : "";
const route = (r) => Array.isArray(r) && r.length ? r.join(" → ") : "home";

async function getJSON(path) {
  const r = await fetch(path, {cache: "no-store"});
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return r.json();
}

// ---------- token (once per browser session) ----------
const TOKEN_KEY = "gcs-pdm-token";
let tokenWaiter = null;
function askToken(message) {
  $("token-message").textContent = message || "";
  $("token-input").value = "";
  if (!$("token-dialog").open) $("token-dialog").showModal();
  return new Promise((resolve) => { tokenWaiter = resolve; });
}
$("token-dialog").addEventListener("close", () => {
  const ok = $("token-dialog").returnValue === "save" && $("token-input").value.trim();
  if (ok) sessionStorage.setItem(TOKEN_KEY, $("token-input").value.trim());
  updateTokenButton();
  if (tokenWaiter) { const w = tokenWaiter; tokenWaiter = null; w(ok ? sessionStorage.getItem(TOKEN_KEY) : null); }
});
$("token-button").addEventListener("click", () => askToken());
function updateTokenButton() {
  $("token-button").textContent = sessionStorage.getItem(TOKEN_KEY) ? "token set ✓" : "enter token";
}

async function send(method, path, body) {
  let token = sessionStorage.getItem(TOKEN_KEY) || await askToken("A decision needs the service's token.");
  if (!token) return {ok: false, status: 0, detail: "no token entered"};
  for (let attempt = 0; attempt < 2; attempt++) {
    const r = await fetch(path, {method, headers: {"Content-Type": "application/json", "Authorization": `Bearer ${token}`},
                                 body: body === undefined ? undefined : JSON.stringify(body)});
    let data = null;
    try { data = await r.json(); } catch (_e) { data = null; }
    if (r.status === 401 && attempt === 0) {
      sessionStorage.removeItem(TOKEN_KEY);
      token = await askToken("The service refused that token; enter it again.");
      if (!token) return {ok: false, status: 401, detail: "wrong token"};
      continue;
    }
    const detail = data && data.detail ? (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail)) : "";
    return {ok: r.ok, status: r.status, data, detail};
  }
}

// ---------- geometry: local east/north metres from home, or lat/lon over tiles ----------
function homeLatLon() {
  const items = S.mission && S.mission.items;
  if (items && items.length && items[0].x && items[0].y) return [items[0].x / 1e7, items[0].y / 1e7];
  const p = S.status && S.status.position;
  if (p && num(p.lat_deg) && num(p.lon_deg) && (p.lat_deg || p.lon_deg)) return S.track.length ? S.track[0] : [p.lat_deg, p.lon_deg];
  return null;
}
function enu(lat, lon, home) {
  const k = Math.PI / 180;
  return [(lat - home[0]) * k * EARTH_R, (lon - home[1]) * k * EARTH_R * Math.cos(home[0] * k)];
}
function toMap(lat, lon) {  // Leaflet LatLng in the map's frame
  if (tilesOn()) return L.latLng(lat, lon);
  const h = homeLatLon();
  if (!h) return null;
  const [n, e] = enu(lat, lon, h);
  return L.latLng(n, e);
}
function fromScenario(home, e, n) {  // scenario east/north (about the scenario's home) -> lat/lon
  const k = Math.PI / 180;
  return [home.lat_deg + n / EARTH_R / k, home.lon_deg + e / (EARTH_R * Math.cos(home.lat_deg * k)) / k];
}
const tilesOn = () => !!(S.settings && S.settings.tile_url);
const wpKey = (lat, lon) => `${lat.toFixed(4)},${lon.toFixed(4)}`;
function navItems(items) {  // NAV_WAYPOINT (16) items in a global frame, home (seq 0) excluded
  return (items || []).filter((it) => it.seq !== 0 && it.command === 16 && (it.x || it.y))
    .map((it) => ({seq: it.seq, lat: it.x / 1e7, lon: it.y / 1e7}));
}
function numberOf(lat, lon) {
  // the catalogue number of the waypoint at this place (within ~30 m), from the plans' scenarios
  let best = null, bestD = 30;
  for (const [key, n] of Object.entries(S.waypointNames)) {
    const [a, b] = key.split(",").map(Number);
    const [dn, de] = enu(lat, lon, [a, b]);
    const d = Math.hypot(dn, de);
    if (d < bestD) { best = n; bestD = d; }
  }
  return best;
}
function learnMissionNumbers(mission) {
  // the service's waypoint numbers of the current mission's items (GET /missions/current .waypoints)
  const numbers = (mission && mission.waypoints) || {};
  for (const w of navItems(mission && mission.items)) {
    const n = numbers[w.seq];
    if (n != null) S.waypointNames[wpKey(w.lat, w.lon)] = n;
  }
}
function learnWaypoints(plan) {
  const sc = plan && plan.scenario;
  if (!sc || !sc.home || !Array.isArray(sc.waypoints)) return;
  for (const w of sc.waypoints) {
    const [lat, lon] = fromScenario(sc.home, w.east_m, w.north_m);
    S.waypointNames[wpKey(lat, lon)] = w.number;
  }
}

// ---------- map ----------
let map = null, layers = null, fitted = false, baseMode = null;
function ensureMap() {
  const mode = tilesOn() ? "tiles" : "local";
  if (map && baseMode === mode) return;
  if (map) { map.remove(); fitted = false; }
  baseMode = mode;
  if (mode === "tiles") {
    map = L.map("map", {attributionControl: true});
    L.tileLayer(S.settings.tile_url, {maxZoom: 19, attribution: esc(S.settings.tile_attribution || "")}).addTo(map);
    L.control.scale({imperial: false}).addTo(map);
  } else {
    map = L.map("map", {crs: L.CRS.Simple, minZoom: -6, maxZoom: 4, zoomSnap: 0.25, attributionControl: false});
  }
  map.setView([0, 0], mode === "tiles" ? 2 : -3);
  layers = {grid: L.layerGroup().addTo(map), mission: L.layerGroup().addTo(map), proposed: L.layerGroup().addTo(map),
            track: L.layerGroup().addTo(map), vehicle: L.layerGroup().addTo(map)};
  $("map-legend").innerHTML =
    `<span><i class="sw" style="background:#1d4ed8"></i>current mission</span>` +
    `<span><i class="sw" style="background:#ea580c"></i>proposed plan (waypoint numbers; the dashed line: its order)</span>` +
    `<span><i class="sw" style="background:#b91c1c"></i>✕ dropped waypoint</span>` +
    `<span><i class="sw" style="background:#6b7280"></i>track</span>` +
    `<span>${mode === "tiles" ? "map tiles: " + esc(S.settings.tile_url) : "local frame: metres east/north of home (no map tiles configured)"}</span>`;
}
const label = (text, cls) => L.divIcon({className: "", html: `<div class="wp-label ${cls}">${esc(text)}</div>`, iconSize: [22, 22], iconAnchor: [11, 11]});

function drawGrid(bounds) {
  layers.grid.clearLayers();
  if (tilesOn() || !bounds) return;
  const step = 500;
  const s = Math.floor(bounds.getSouth() / step - 2) * step, n = Math.ceil(bounds.getNorth() / step + 2) * step;
  const w = Math.floor(bounds.getWest() / step - 2) * step, e = Math.ceil(bounds.getEast() / step + 2) * step;
  const style = {color: "#cbd5e1", weight: 1, interactive: false};
  for (let x = w; x <= e; x += step) L.polyline([[s, x], [n, x]], style).addTo(layers.grid);
  for (let y = s; y <= n; y += step) L.polyline([[y, w], [y, e]], style).addTo(layers.grid);
  L.marker([s + step, w + step], {icon: L.divIcon({className: "", html: `<span style="color:#64748b;font-size:11px;white-space:nowrap">grid ${step} m</span>`}), interactive: false}).addTo(layers.grid);
}

function drawMission() {
  ensureMap();
  layers.mission.clearLayers();
  const h = homeLatLon();
  if (!h) return;
  const home = toMap(h[0], h[1]);
  L.marker(home, {icon: label("H", "home"), title: "home"}).addTo(layers.mission);
  learnMissionNumbers(S.mission);
  const nav = navItems(S.mission && S.mission.items);
  const pts = [home, ...nav.map((w) => toMap(w.lat, w.lon))];
  L.polyline(pts, {color: "#1d4ed8", weight: 3, className: "current-route"}).addTo(layers.mission);
  for (const w of nav) {
    const n = numberOf(w.lat, w.lon);
    if (n != null) L.marker(toMap(w.lat, w.lon), {icon: label(n, ""), title: `waypoint ${n} (mission item ${w.seq})`}).addTo(layers.mission);
    else L.circleMarker(toMap(w.lat, w.lon), {radius: 3, color: "#1d4ed8"}).bindTooltip(`mission item ${w.seq} (no objective)`).addTo(layers.mission);
  }
  if (!fitted && pts.length > 1) {
    const b = L.latLngBounds(pts);
    map.fitBounds(b.pad(0.15));
    drawGrid(b);
    fitted = true;
  }
}

function drawProposed() {
  if (!layers) return;
  layers.proposed.clearLayers();
  const plan = S.proposed[0];
  if (!plan || !homeLatLon()) return;
  learnWaypoints(plan);
  const nav = navItems(plan.items);
  const start = S.status && S.status.position && num(S.status.position.lat_deg) ? [S.status.position.lat_deg, S.status.position.lon_deg] : homeLatLon();
  const pts = [toMap(start[0], start[1]), ...nav.map((w) => toMap(w.lat, w.lon))];
  L.polyline(pts, {color: "#ea580c", weight: 4, dashArray: "8 6", className: "proposed-route"}).addTo(layers.proposed);
  const newRoute = (plan.chosen && plan.chosen.route) || [];
  nav.forEach((w) => {
    const n = numberOf(w.lat, w.lon);
    const order = n != null ? newRoute.indexOf(n) + 1 : 0;
    // waypoint numbers, as in the plans' table (the dashed line shows the order they are flown in)
    if (order > 0) L.marker(toMap(w.lat, w.lon), {icon: label(n, "proposed"), title: `proposed: waypoint ${n}, flown ${order}. of ${newRoute.length}`, zIndexOffset: 500}).addTo(layers.proposed);
  });
  const dropped = (plan.previous_route || []).filter((n) => !newRoute.includes(n));
  const sc = plan.scenario;
  for (const n of dropped) {
    // where waypoint n is: the plan's scenario, else the place the mission's numbering gave it
    const w = sc && sc.home && (sc.waypoints || []).find((x) => x.number === n);
    const known = Object.entries(S.waypointNames).find(([, m]) => m === n);
    if (!w && !known) continue;
    const [lat, lon] = w ? fromScenario(sc.home, w.east_m, w.north_m) : known[0].split(",").map(Number);
    L.marker(toMap(lat, lon), {icon: label("✕", "dropped"), title: `waypoint ${n} dropped by the proposed plan`, zIndexOffset: 600}).addTo(layers.proposed);
  }
}

function drawVehicle() {
  if (!layers) return;
  layers.track.clearLayers(); layers.vehicle.clearLayers();
  if (!homeLatLon()) return;
  const pts = S.track.map(([a, b]) => toMap(a, b)).filter(Boolean);
  if (pts.length > 1) L.polyline(pts, {color: "#6b7280", weight: 2, className: "track"}).addTo(layers.track);
  if (pts.length) L.circleMarker(pts[pts.length - 1], {radius: 7, color: "#111", fillColor: "#facc15", fillOpacity: 1, className: "vehicle"})
    .bindTooltip("vehicle").addTo(layers.vehicle);
}

// ---------- plots (canvas) ----------
function plot(canvas, points, opts) {
  // points: [t, value, sd]; draws value with a ±2σ band and horizontal limit lines
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth || 260, h = canvas.clientHeight || 64;
  canvas.width = w * dpr; canvas.height = h * dpr;
  const g = canvas.getContext("2d");
  g.scale(dpr, dpr);
  g.clearRect(0, 0, w, h);
  const pts = points.filter((p) => num(p[1]));
  g.font = "10px system-ui"; g.fillStyle = "#6e7781";
  if (pts.length < 2) { g.fillText(pts.length ? "collecting…" : "unknown: no values yet", 4, h / 2); return; }
  const t0 = pts[0][0], t1 = pts[pts.length - 1][0];
  let lo = Infinity, hi = -Infinity;
  for (const [, v, sd] of pts) { const s = num(sd) ? 2 * sd : 0; lo = Math.min(lo, v - s); hi = Math.max(hi, v + s); }
  for (const l of opts.limits || []) if (num(l.value)) { lo = Math.min(lo, l.value); hi = Math.max(hi, l.value); }
  if (opts.min != null) lo = Math.max(lo, opts.min);
  if (opts.max != null) hi = Math.min(hi, opts.max);
  if (hi - lo < 1e-9) { hi += 0.5; lo -= 0.5; }
  const pad = (hi - lo) * 0.08; lo -= pad; hi += pad;
  const X = (t) => 30 + (w - 34) * (t1 > t0 ? (t - t0) / (t1 - t0) : 1);
  const Y = (v) => h - 4 - (h - 8) * (v - lo) / (hi - lo);
  g.fillStyle = opts.band || "rgba(29,78,216,.18)";
  g.beginPath();
  pts.forEach(([t, v, sd], i) => { const y = Y(v + (num(sd) ? 2 * sd : 0)); i ? g.lineTo(X(t), y) : g.moveTo(X(t), y); });
  for (let i = pts.length - 1; i >= 0; i--) { const [t, v, sd] = pts[i]; g.lineTo(X(t), Y(v - (num(sd) ? 2 * sd : 0))); }
  g.closePath(); g.fill();
  g.strokeStyle = opts.color || "#1d4ed8"; g.lineWidth = 1.5;
  g.beginPath(); pts.forEach(([t, v], i) => i ? g.lineTo(X(t), Y(v)) : g.moveTo(X(t), Y(v))); g.stroke();
  for (const l of opts.limits || []) {
    if (!num(l.value)) continue;
    g.strokeStyle = "#b91c1c"; g.setLineDash([4, 3]); g.beginPath(); g.moveTo(30, Y(l.value)); g.lineTo(w - 4, Y(l.value)); g.stroke(); g.setLineDash([]);
    // above its line, or below it when the line runs along the top (a 10 px label would be clipped)
    const ly = Y(l.value) - 2 >= 10 ? Y(l.value) - 2 : Math.min(h - 2, Y(l.value) + 10);
    g.fillStyle = "#b91c1c"; g.fillText(l.label, w - 4 - g.measureText(l.label).width, ly);
  }
  g.fillStyle = "#6e7781";
  g.fillText(opts.fmt(hi - pad), 2, 10); g.fillText(opts.fmt(lo + pad), 2, h - 2);
}

function record(key, t, v, sd) {
  const s = S.series[key] || (S.series[key] = []);
  if (!num(t)) return;
  if (s.length && s[s.length - 1][0] >= t) return;
  s.push([t, v, sd]);
  if (s.length > SERIES_MAX) s.splice(0, s.length - SERIES_MAX);
}

// ---------- packs and motors ----------
function socWhy(st) {
  if (!st.time_s) return "no telemetry";
  return "no state estimate yet (the estimator needs this pack's battery telemetry)";
}
function cutoffText(p, st) {
  if (num(p.time_to_cutoff_s)) {
    const m = p.time_to_cutoff_s / 60, sd = num(p.time_to_cutoff_sd) ? p.time_to_cutoff_sd / 60 : null;
    return `${m.toFixed(1)} min` + (sd != null ? ` ± ${sd.toFixed(1)} min` : ` <span class="unknown">(spread unknown)</span>`);
  }
  if (!st.prediction) return unknown("no prediction yet");
  // a stale prediction (link lost) cleared the countdown: that is not "no cut-off"
  if (st.prediction.stale) return unknown(st.prediction.reason || "prediction stale");
  if (!num(p.soc)) return unknown("no state estimate");
  const hz = st.prediction.horizon_s;
  return `<span class="ok">no cut-off predicted${num(hz) ? ` within ${(hz / 60).toFixed(0)} min` : " within the prediction horizon"}</span>`;
}
// what a fault's magnitude means, per kind (gcs_pdm.diagnosis.faults.MAGNITUDE_MEANING): only a
// motor's is a power loss
const FAULT_MAGNITUDE = {
  motor_power_loss: (m) => `${(100 * m).toFixed(0)} % power lost`,
  pack_capacity_loss: (m) => `${(100 * m).toFixed(0)} % capacity lost`,
  pack_resistance_rise: (m) => `resistance ${m >= 0 ? "+" : "−"}${(100 * Math.abs(m)).toFixed(0)} %`,
  predicted_limit_violation: (m) => `${(100 * m).toFixed(0)} % probability of failing before the mission ends`,
  degradation_rate_deviation: (m) => `rate ${(100 * m).toFixed(0)} % off its prediction`,
  model_mismatch: (m) => `statistic ${m.toFixed(2)} (1 = as variable as the filter expects)`,
};
// kinds that tell the operator something but are no reason to re-plan (faults.ADVISORY_TYPES)
const ADVISORY_FAULTS = new Set(["model_mismatch"]);
// a fault in the words of its kind: "motor power loss on aft, 70 % power lost" (timeline, cards)
function faultWords(kind, target, magnitude) {
  return `${String(kind || "fault").replace(/_/g, " ")}${target != null ? " on " + target : ""}, ${faultMagnitude({kind, magnitude})}`;
}
function faultMagnitude(f) {
  if (!num(f.magnitude)) return "magnitude unknown";
  const say = FAULT_MAGNITUDE[f.kind];
  return say ? say(f.magnitude) : `magnitude ${f.magnitude.toFixed(3)}`;
}
// the estimator's model-consistency test (docs/estimation.md): matches, not judged yet, or the evidence and what to do
function modelText(m) {
  if (!m) return unknown("no model check yet");
  const f = (v, d) => fmt(v, d) ?? "?";
  if (m.state === "mismatch")
    return `<span class="bad">does not match its model</span>: statistic ${f(m.statistic, 2)} &gt; ${f(m.bound, 2)}, `
      + `mean residual ${f(m.voltage_residual_mv, 0)} mV / ${f(m.temperature_residual_k, 2)} K over ${m.window_updates} updates; `
      + `prediction spread ×${f(m.prediction_inflation, 2)}. <span class="hint">${esc(m.suggestion || "")}</span>`;
  if (m.state === "matches") return `<span class="ok">matches</span> (statistic ${f(m.statistic, 2)}, bound ${f(m.bound, 2)})`;
  return unknown(m.reason || "not judged yet");
}
// the pack against the conditions its fit was trained on (docs/service.md, "Fit envelope"); no row
// for a pack no fit learned (the paper's values: nothing to compare with)
function envelopeRow(e) {
  if (!e) return "";
  let text;
  if (e.state === "outside") text = `<span class="bad">outside</span>: ${esc(e.outside.join("; "))}; predictions extrapolate`;
  else if (e.state === "inside") text = `<span class="ok">inside</span>` + (e.not_judged.length ? ` (not judged: ${esc(e.not_judged.join(", "))})` : "");
  else text = unknown(`not judged: no ${e.not_judged.join(", ")}`);
  return `<div class="row envelope"><span>fitted conditions</span><span class="v">${text}</span></div>`;
}
function renderPacks() {
  const st = S.status; if (!st) return;
  const lim = (S.settings && S.settings.limits) || {};
  const names = Object.keys(st.packs || {});
  const host = $("packs");
  if (!names.length) { host.innerHTML = unknown("the service reports no packs"); return; }
  for (const name of names) {
    const p = st.packs[name];
    record("pack-soc-" + name, st.time_s, p.soc, p.soc_sd);
    record("pack-temp-" + name, st.time_s, p.temperature_c, p.temperature_sd);
    let card = host.querySelector(`[data-pack="${CSS.escape(name)}"]`);
    if (!card) {
      card = document.createElement("div"); card.className = "card"; card.dataset.pack = name;
      card.innerHTML = `<h3>${esc(name)} <span class="v"></span></h3><div class="body"></div>
        <canvas class="plot soc"></canvas><canvas class="plot temp"></canvas>`;
      host.appendChild(card);
    }
    card.querySelector("h3 .v").innerHTML = val(p.voltage_v, 2, " V", "no voltage received") + " · " + val(p.current_a, 1, " A", "no current received");
    card.querySelector(".body").innerHTML =
      `<div class="row"><span>state of charge</span><span class="v">${num(p.soc) ? `${(100 * p.soc).toFixed(1)} %` + (num(p.soc_sd) ? ` ± ${(100 * p.soc_sd).toFixed(1)} %` : "") : unknown(socWhy(st))}</span></div>
       <div class="row"><span>temperature</span><span class="v">${pm(p.temperature_c, p.temperature_sd, 1, " °C", num(p.temperature_raw_c) ? `estimate not ready; sensor says ${p.temperature_raw_c.toFixed(1)} °C` : "no temperature received")}</span></div>
       <div class="row"><span>time to cut-off</span><span class="v">${cutoffText(p, st)}</span></div>
       <div class="row model"><span>model</span><span class="v">${modelText(p.model_mismatch)}</span></div>
       ${envelopeRow(((st.fit_envelope || {}).packs || {})[name])}`;
    plot(card.querySelector("canvas.soc"), S.series["pack-soc-" + name], {min: 0, max: 1, fmt: (v) => `${(100 * v).toFixed(0)}%`,
      limits: [{value: lim.landing_reserve_soc || 0, label: "landing reserve"}]});
    plot(card.querySelector("canvas.temp"), S.series["pack-temp-" + name], {fmt: (v) => `${v.toFixed(0)}°`, color: "#c2410c", band: "rgba(194,65,12,.18)",
      limits: [{value: lim.pack_max_temp_c, label: "max °C"}]});
  }
  for (const card of [...host.children]) if (!names.includes(card.dataset.pack)) card.remove();
}
function renderMotors() {
  const st = S.status; if (!st) return;
  const lim = (S.settings && S.settings.limits) || {};
  const names = Object.keys(st.motors || {});
  const host = $("motors");
  if (!names.length) { host.innerHTML = unknown("the service reports no motors"); return; }
  const total = names.reduce((a, n) => a + (num(st.motors[n].current_a) ? Math.abs(st.motors[n].current_a) : 0), 0);
  const allKnown = names.every((n) => num(st.motors[n].current_a));
  for (const name of names) {
    const m = st.motors[name];
    record("motor-temp-" + name, st.time_s, m.temperature_c, m.temperature_sd);
    let card = host.querySelector(`[data-motor="${CSS.escape(name)}"]`);
    if (!card) {
      card = document.createElement("div"); card.className = "card"; card.dataset.motor = name;
      card.innerHTML = `<h3>motor ${esc(name)} <span class="v"></span></h3><div class="body"></div><canvas class="plot temp"></canvas>`;
      host.appendChild(card);
    }
    const share = allKnown && total > 0.5 ? `${(100 * Math.abs(m.current_a) / total).toFixed(0)} %` : unknown(allKnown ? "motors idle" : "a motor's current is missing");
    const health = num(m.health) ? m.health : null;
    card.querySelector("h3 .v").innerHTML = health == null ? unknown("no diagnosis") :
      `<span class="${health < 0.99 ? "bad" : "ok"}">health ${(100 * health).toFixed(0)} %</span>`;
    card.querySelector(".body").innerHTML =
      `<div class="healthbar"><div class="${health != null && health < 0.99 ? "low" : ""}" style="width:${health == null ? 0 : Math.max(0, Math.min(1, health)) * 100}%"></div></div>
       <div class="row"><span>current (share)</span><span class="v">${val(m.current_a, 1, " A", "no ESC current received")} (${share})</span></div>
       <div class="row"><span>rpm</span><span class="v">${val(m.rpm, 0, "", "no rpm received")}</span></div>
       <div class="row"><span>temperature</span><span class="v">${pm(m.temperature_c, m.temperature_sd, 1, " °C", "no estimate yet")}</span></div>
       ${m.fault ? `<div class="row bad"><span>fault</span><span class="v">${esc(faultWords(m.fault.kind, null, m.fault.magnitude))}</span></div>` : ""}`;
    plot(card.querySelector("canvas.temp"), S.series["motor-temp-" + name], {fmt: (v) => `${v.toFixed(0)}°`, color: "#c2410c", band: "rgba(194,65,12,.18)",
      limits: [{value: lim.motor_max_temp_c, label: "max °C"}]});
  }
  for (const card of [...host.children]) if (!names.includes(card.dataset.motor)) card.remove();
}

// ---------- header and banners ----------
function staleSeconds() { return (Date.now() - S.msgAdvancedAt) / 1000; }
// the wind flown in (/status.wind): speed and where it blows from, and whose estimate it is
function windText(w) {
  if (!w) return "";
  if (!num(w.speed_mps)) return `<span title="${esc(w.unknown || "")}">wind unknown</span>`;
  const src = w.source === "triangle" ? " (est.)" : "";
  return `<span id="wind" title="${w.source === "triangle" ? "estimated from ground velocity minus airspeed" : "the autopilot's estimate"}">wind ${w.speed_mps.toFixed(1)} m/s from ${w.from_deg.toFixed(0)}°${src}</span>`;
}
function renderHeader() {
  const st = S.status, conn = $("conn");
  let state, text;
  if (!S.statusOk) { state = "down"; text = "service unreachable"; }
  else if (S.sse !== "live") { state = "reconnecting"; text = "events reconnecting…"; }
  else if (st && st.link && (st.link.state === "lost" || st.link.lost === true)) { state = "stale"; text = "link lost"; }
  else if (st && st.time_s != null && staleSeconds() > STALE_AFTER_S) { state = "stale"; text = `stale ${staleSeconds().toFixed(0)} s`; }
  else { state = "live"; text = "live"; }
  conn.dataset.state = state; conn.textContent = text;
  if (!st) return;
  const pos = st.position || {};
  $("vehicle").innerHTML = [
    st.time_s != null ? `t=${st.time_s.toFixed(0)} s` : "no telemetry yet",
    `mode ${esc(st.mode ?? "unknown")}`, st.armed == null ? "armed: unknown" : (st.armed ? "armed" : "disarmed"),
    num(pos.relative_alt_m) ? `alt ${pos.relative_alt_m.toFixed(0)} m` : "",
    st.airdata && num(st.airdata.airspeed) ? `${st.airdata.airspeed.toFixed(1)} m/s` : "",
    windText(st.wind),
    `policy ${esc(st.policy ?? "?")}`, `set ${esc(st.parameter_set ?? "?")}`,
  ].filter(Boolean).join(" · ") + outlookHtml(st.outlook);
}
// the vehicle-level line, always shown (issue 31): the current mission re-evaluated from the current state
function outlookHtml(o) {
  const line = o && o.line ? o.line : "outlook unknown: not evaluated yet";
  const alarm = o && o.alarm;
  return `<div id="outlook" class="${alarm ? "bad" : ""}" data-alarm="${alarm ? esc(alarm.level) : ""}">${esc(line)}${
    o && num(o.time_s) ? ` <span class="muted">(t=${o.time_s.toFixed(0)} s)</span>` : ""}</div>`;
}

function computeBanners() {
  const out = [], st = S.status;
  if (!S.statusOk) out.push({id: "service", level: "critical", title: "Service unreachable", why: S.statusError || "no answer from /status; retrying"});
  if (st) {
    const link = st.link || {};
    const lost = link.state === "lost" || link.lost === true;
    if (lost) out.push({id: "link-lost", level: "critical", title: "Link lost", why: link.reason || link.detail || `no vehicle message for ${fmt(link.silence_s, 0) ?? "?"} s`});
    else if (st.time_s == null) out.push({id: "no-telemetry", level: "warning", title: "No telemetry yet", why: link.url ? `listening on ${link.url}` : "waiting for the vehicle"});
    else if (S.statusOk && staleSeconds() > STALE_AFTER_S)
      out.push({id: "stale", level: "critical", title: "Telemetry stale — link lost?",
                why: `the vehicle's message time has not advanced for ${staleSeconds().toFixed(0)} s (last t=${st.time_s.toFixed(0)} s); values below are old`});
    if (st.failed) out.push({id: "failed", level: "critical", title: "Vehicle failure", why: String(st.failed)});
    // the vehicle description in use, when it is not one the operator gave (docs/vehicles.md)
    const v = st.vehicle || {};
    if (v.source === "deriving" || v.provisional)
      out.push({id: "vehicle", level: "warning", title: v.provisional ? `Provisional vehicle description: ${v.name}` : "No vehicle description yet",
                why: v.provisional ? `${(v.notes || []).join("; ")}. To save and correct it: ${v.save || ""}` : (v.waiting_for || "")});
    // what the service cannot do now, and why (readiness; motor_diagnosis says how, unless it cannot)
    for (const [k, why] of Object.entries(st.readiness || {}))
      if (k !== "replan" && why !== "ready" && (k !== "motor_diagnosis" || String(why).startsWith("not diagnosable")))
        out.push({id: "readiness-" + k, level: "warning", title: `${k.replace(/_/g, " ")}: not ready`, why: String(why)});
    // an extended pack the planner still flies on its paper values (said, never silent)
    for (const [i, note] of (((st.model_variants || {}).notes) || []).entries())
      out.push({id: "variant-" + i, level: "warning", title: "Planner uses paper-variant values", why: String(note)});
    if (st.model_mismatch) out.push({id: "mismatch", level: "warning", title: "Model mismatch", why: typeof st.model_mismatch === "string" ? st.model_mismatch : (st.model_mismatch.reason || JSON.stringify(st.model_mismatch))});
    for (const [i, w] of (st.warnings || st.banners || []).entries()) {
      const o = typeof w === "string" ? {text: w} : w;
      out.push({id: "status-" + (o.kind || i), level: o.level === "critical" || o.severity === "critical" ? "critical" : "warning",
                title: o.title || o.kind || "Warning", why: o.text || o.message || o.reason || ""});
    }
  }
  for (const f of S.faults) {
    const advisory = ADVISORY_FAULTS.has(f.kind);
    out.push({id: `fault-${f.id}`, level: advisory ? "warning" : "critical",
              title: `${advisory ? "Advisory" : "Fault"}: ${f.kind.replace(/_/g, " ")} on ${f.target ?? "?"}`,
              why: `${faultMagnitude(f)}; ${f.source}${num(f.time_s) ? ", since t=" + f.time_s.toFixed(0) + " s" : ""}`});
  }
  if (S.mismatch && Date.now() / 1000 - S.mismatch.wall_time < RECENT_WARNING_S) {
    const d = S.mismatch.data;
    out.push({id: "soc-deviation", level: "warning", title: "Model mismatch: SoC off its prediction",
              why: `${num(d.magnitude) ? "deviation " + (100 * d.magnitude).toFixed(1) + " %" : ""} ${tstamp(d.time_s)}`});
  }
  const last = S.history[0];
  const infeasible = (p) => p && p.chosen && p.chosen.feasible === false;
  if (last && ((last.status === "kept" && infeasible(last)) || (last.status === "proposed" && infeasible(last))))
    out.push({id: "no-route-home", level: "critical", title: "No route gets home",
              why: `plan ${last.id}: ${last.chosen.cause || "every candidate is predicted to fail"} — operator decision needed`});
  if (S.planFailure && Date.now() / 1000 - S.planFailure.wall_time < RECENT_WARNING_S)
    out.push({id: "plan-failed", level: "warning", title: "Replanning failed", why: S.planFailure.data.error || ""});
  return out;
}
function renderBanners() {
  $("banners").innerHTML = computeBanners().map((b) =>
    `<div class="banner ${b.level}" data-banner="${esc(b.id)}"><span>${esc(b.title)}</span><span class="why">${esc(b.why)}</span></div>`).join("");
}

// ---------- decisions ----------
const landingSoc = (c) => c && Array.isArray(c.final_soc) && c.final_soc.length ? Math.min(...c.final_soc) : null;
const pct = (v) => `${(100 * v).toFixed(0)} %`;
// the Monte Carlo landing SoC (lowest pack, of the samples that land) with its 5-95 % spread
function landingCell(c) {
  const q = c.landing_soc;
  if (q && num(q.p50))
    return `${pct(q.p50)} (${pct(q.p05)}–${pct(q.p95)}, lowest pack, ${c.landing_samples} of ${c.n_samples} samples land)`;
  if (q && num(c.n_samples)) return unknown(`no sample of ${c.n_samples} lands`);
  const soc = landingSoc(c);
  return !c.feasible ? unknown("predicted to fail before landing") : soc == null ? unknown(c.risk_unknown || "not predicted")
    : `${pct(soc)} (lowest pack, planner's nominal)`;
}
function candidateCells(c) {
  if (!c) return ["unknown", "unknown", "unknown", "unknown"].map(() => unknown("not evaluated"));
  const verdict = c.feasible ? '<span class="ok">planner: gets home</span>' : `<span class="bad">planner: fails (${esc(c.cause || "?")})</span>`;
  const pf = num(c.failure_probability) ? `<span data-pfail="${c.failure_probability}">${pct(c.failure_probability)}</span> of ${c.n_samples} samples<br>${verdict}` :
    num(c.p_fail) ? `${pct(c.p_fail)}<br>${verdict}` :
    `${unknown(c.risk_unknown || "the planner reports pass/fail, not a probability")}<br>${verdict}`;
  return [esc(route(c.route)), num(c.reward) ? c.reward.toFixed(1) + (c.feasible ? "" : ` (reaches ${fmt(c.reward_reached, 1)} before failing)`) : unknown("not scored"),
          landingCell(c), pf];
}
function uploadOutcome(planId) {
  const u = S.uploads.find((x) => x.plan_id === planId);
  if (!u) return "";
  const words = {confirmed: "upload confirmed: the vehicle's mission reads back as sent", mismatch: "upload MISMATCH: the vehicle's mission differs from the plan",
                 failed: "upload FAILED", uploaded_unconfirmed: "uploaded but not confirmed (read-back failed)", sent: "sent, awaiting read-back", uploading: "uploading…"};
  return `<div class="outcome" data-upload-status="${esc(u.status)}">Plan ${planId}: ${esc(words[u.status] || u.status)}${u.error ? " — " + esc(u.error) : ""}</div>`;
}
// a proposal's gate (GET /missions/proposed): its age; Approve/Reject off with the reason when the
// link is lost or the vehicle failed or is on the ground; a stale one is re-planned when approved
function gateOff(plan) { return plan.gate && plan.gate.blocked ? ` disabled title="${esc(plan.gate.reason || "")}"` : ""; }
function gateText(plan) {
  const g = plan.gate;
  if (!g) return "";
  const age = num(g.age_s) ? `${g.age_s.toFixed(0)} s old` : "age unknown";
  // a stale proposal's reason already starts with its age ("167 s old (re-evaluated every …")
  const text = g.reason ? (g.reason.startsWith(age) ? g.reason : `${age} — ${g.reason}`) : age;
  return `<span class="gate${g.blocked ? " bad" : ""}" data-blocked="${g.blocked}" data-stale="${g.stale}">${esc(text)}</span>`;
}
function renderDecision() {
  const host = $("decision-body");
  const parts = [];
  for (const plan of S.proposed) {
    const keep = (plan.candidates || []).find((c) => c.name === "keep");
    const a = candidateCells(keep), b = candidateCells(plan.chosen);
    const dec = S.decision[plan.id];
    parts.push(`<div class="plan" data-plan="${plan.id}">
      <div><b>Plan ${plan.id} proposed</b> ${tstamp(plan.time_s)} — ${esc(plan.trigger || plan.reason || "")}</div>
      <table class="compare"><tr><th></th><th>current mission</th><th>proposed (${esc(plan.chosen && plan.chosen.name || "?")})</th></tr>
        <tr><th>route</th><td>${a[0]}</td><td>${b[0]}</td></tr>
        <tr><th>reward</th><td>${a[1]}</td><td>${b[1]}</td></tr>
        <tr><th>landing SoC</th><td>${a[2]}</td><td>${b[2]}</td></tr>
        <tr><th>probability of failure</th><td>${a[3]}</td><td>${b[3]}</td></tr></table>
      <div>${esc(plan.why || "")}</div>
      <div class="actions"><button class="approve" id="approve-${plan.id}" data-act="approve" data-id="${plan.id}"${gateOff(plan)}>Approve and upload</button>
        <button class="reject" id="reject-${plan.id}" data-act="reject" data-id="${plan.id}"${gateOff(plan)}>Reject</button>
        ${gateText(plan)}
        <span class="decision-state">${dec ? esc(dec.text) : ""}</span></div></div>`);
  }
  // the latest decided plan and what became of its upload
  const decided = S.history.find((p) => !["proposed", "planning"].includes(p.status));
  if (decided) {
    const by = (decided.history || []).slice(-1)[0];
    parts.push(`<div class="last"><b>Latest plan ${decided.id}: ${esc(decided.status)}</b> ${tstamp(decided.time_s)}
      route ${esc(route(decided.chosen && decided.chosen.route))}${by && by.note ? " — " + esc(by.note) : ""}${uploadOutcome(decided.id)}
      ${S.decision[decided.id] && !S.proposed.length && !S.uploads.some((u) => u.plan_id === decided.id) ? `<div>${esc(S.decision[decided.id].text)}</div>` : ""}</div>`);
  }
  host.innerHTML = parts.join("") || "no plan waiting for a decision";
}
$("decision-body").addEventListener("click", async (ev) => {
  const btn = ev.target.closest("button[data-act]");
  if (!btn) return;
  const id = Number(btn.dataset.id), act = btn.dataset.act;
  S.decision[id] = {text: act === "approve" ? "sending approval…" : "sending rejection…"};
  renderDecision();
  const r = await send("POST", `/missions/plans/${id}/${act}`, {note: "operator console"});
  S.decision[id] = {text: r.ok ? (act === "approve" ? "approved: uploading…" : "rejected") : `refused (${r.status}): ${r.detail}`};
  await refreshPlans();
});

// ---------- fits ----------
function renderJobs() {
  const host = $("jobs");
  const fits = S.jobs.filter((j) => j.kind === "fit");
  if (!fits.length) { host.textContent = "no fit jobs"; return; }
  host.innerHTML = fits.slice(0, 10).map((j) => {
    const res = S.jobResults[j.id];
    const running = j.status === "running" || j.status === "queued";
    let body = "";
    if (j.status === "succeeded" && res) {
      const plots = Object.keys(res.plots || {});
      body = `<div>${res.saved_as ? `saved as <b>${esc(res.saved_as)}</b>` : res.save_error ? `<span class="bad">not saved: ${esc(res.save_error)}</span>` : "not saved (no name given)"}</div>
        ${errorsTable(res)}${fitWarnings(res)}${plots.map((p) => `<img alt="${esc(p)}" src="/jobs/${encodeURIComponent(j.id)}/plots/${encodeURIComponent(p)}">`).join("")}`;
    }
    return `<div class="job" data-job="${esc(j.id)}" data-status="${esc(j.status)}">
      <div><b>${esc(j.request && j.request.component || "fit")}</b> ${esc(j.id.slice(0, 8))} — ${esc(j.status)} ${j.stage ? "· " + esc(j.stage) : ""}</div>
      ${running ? `<progress max="1" value="${num(j.progress) ? j.progress : 0}"></progress><button data-cancel="${esc(j.id)}">cancel</button>` : ""}
      ${j.error ? `<div class="bad">${esc(j.error)}</div>` : ""}${body}</div>`;
  }).join("");
}
function fitWarnings(res) {
  // each fit's own warnings (docs/fitting.md): training flights it left out or cannot draw, starts its
  // training flights do not support, flights outside their temperatures and currents, flights its equally
  // good candidates disagree on. Before activating the set, the operator reads what it cannot support.
  const items = Object.entries(res.fits || {}).flatMap(([name, fit]) =>
    ((fit && fit.warnings) || []).map((w) => `<li>${esc(name)}: ${esc(w)}</li>`));
  return items.length ? `<ul class="fit-warnings bad">${items.join("")}</ul>` : "";
}
function errorsTable(res) {
  // result.fits[name].errors[learned|reference][split].overall[quantity].rmse (docs/fitting.md)
  const unit = {voltage: " V", temperature: " °C"};
  const rows = [];
  for (const [name, fit] of Object.entries(res.fits || {})) {
    const errs = (fit && fit.errors) || {};
    for (const split of ["train", "validation", "test"]) {
      const learned = errs.learned && errs.learned[split] && errs.learned[split].overall;
      if (!learned) continue;
      for (const [q, m] of Object.entries(learned)) {
        const ref = errs.reference && errs.reference[split] && errs.reference[split].overall && errs.reference[split].overall[q];
        const show = (x) => x && num(x.rmse) ? `${x.rmse.toPrecision(3)}${unit[q] || ""}` : unknown("not computed");
        rows.push(`<tr><td>${esc(name)}</td><td>${esc(split)}</td><td>${esc(q)}</td><td>${show(m)}</td><td>${show(ref)}</td></tr>`);
      }
    }
  }
  return rows.length ? `<table class="compare"><tr><th>model</th><th>split</th><th>of</th><th>RMSE learned</th><th>RMSE reference</th></tr>${rows.join("")}</table>` : "";
}
$("jobs").addEventListener("click", async (ev) => {
  const id = ev.target.dataset.cancel;
  if (!id) return;
  const r = await send("POST", `/jobs/${encodeURIComponent(id)}/cancel`);
  if (!r.ok) alert(`cancel refused (${r.status}): ${r.detail}`);
  refreshJobs();
});
function renderParamsets() {
  $("paramsets").innerHTML = S.paramsets.map((p) => `<div class="row" data-set="${esc(p.name)}"><span><b>${esc(p.name)}</b>
    ${p.builtin ? "(built-in)" : esc((p.provenance && p.provenance.source) || "")}</span>
    <span>${p.active ? '<span class="ok">active</span>' : `<button data-activate="${esc(p.name)}">activate</button>`}</span></div>`).join("") || "none";
}
$("paramsets").addEventListener("click", async (ev) => {
  const name = ev.target.dataset.activate;
  if (!name) return;
  const r = await send("POST", `/parameter-sets/${encodeURIComponent(name)}/activate`);
  if (!r.ok) alert(`activation refused (${r.status}): ${r.detail}`);
  refreshParamsets();
});

// ---------- events timeline ----------
const CATEGORY = {fault: "faults", failure: "faults", plan: "plans", upload: "uploads", link: "link", statustext: "link",
                  mission: "mission", job: "jobs", parameter_set: "jobs", policy: "plans"};
function describe(ev) {
  const d = ev.data || {};
  switch (ev.kind) {
    case "fault":
      if (d.kind === "soc_deviation") return `Model mismatch: state of charge deviates from the plan's prediction${num(d.magnitude) ? " by " + (100 * d.magnitude).toFixed(1) + " %" : ""}`;
      if (d.cleared) return `Fault ${d.id ?? ""} cleared${d.target ? " (" + d.target + ")" : ""}`;
      return `Fault: ${faultWords(d.kind, d.target ?? "?", d.magnitude)} (${d.source || "diagnoser"})`;
    case "plan":
      if (d.status === "planning") return `Replanning: ${d.reason || ""}`;
      if (d.status === "failed") return `Replanning failed: ${d.error || d.reason || ""}`;
      if (d.status === "superseded") return `Plan ${d.id} superseded by plan ${d.by}`;
      if (d.status === "approved" && d.by === "operator") return `Plan ${d.id} approved by the operator`;
      if (d.status === "rejected") return `Plan ${d.id} rejected by the operator`;
      if (d.chosen) return `Plan ${d.id ?? ""} ${d.status}: route ${route(d.chosen.route)}, reward ${fmt(d.chosen.reward, 1)}${d.chosen.feasible ? "" : " — predicted to fail: " + (d.chosen.cause || "?")}`;
      return `Plan ${d.id ?? ""} ${d.status}`;
    case "upload":
      return `Upload of plan ${d.plan_id}: ${d.status}${d.route ? ", route " + route(d.route) : ""}${d.error ? " — " + d.error : ""}`;
    case "mission":
      if (d.waypoint != null) return `Reached waypoint ${d.waypoint} (+${d.reward}, total ${d.reward_collected})`;
      return `Mission ${d.source || ""}: ${d.count ?? "?"} items, waypoints ${route(d.route)}`;
    case "link":
      if (d.connected === false || d.state === "lost" || d.status === "lost") return `Link lost${d.reason ? ": " + d.reason : ""}`;
      if (d.status === "restored") return `Link restored: vehicle ${Array.isArray(d.vehicle) ? d.vehicle.join("/") : ""}`;
      return `Link up: vehicle ${Array.isArray(d.vehicle) ? d.vehicle.join("/") : ""}`;
    case "statustext": return `${d.sent ? "Sent to the vehicle" : "Vehicle says"}: “${d.text}”`;
    case "job": return `Fit job ${String(d.id || "").slice(0, 8)}: ${d.status}${d.stage ? " (" + d.stage + ")" : ""}${d.error ? " — " + d.error : ""}`;
    case "parameter_set": return `Parameter set ${d.name} activated${d.applies_to ? " — " + d.applies_to : ""}`;
    case "policy": return `Policy set to ${d.policy}`;
    default: return `${ev.kind}: ${Object.entries(d).map(([k, v]) => `${k} ${typeof v === "object" ? JSON.stringify(v) : v}`).join(", ")}`;
  }
}
function isProgressTick(ev) { return ev.kind === "job" && ev.data.status === "running" && num(ev.data.progress) && ev.data.progress > 0; }
function filters() { return new Set([...document.querySelectorAll("#filters input:checked")].map((i) => i.value)); }
function renderTimeline() {
  const on = filters();
  $("timeline").innerHTML = S.events.filter((e) => on.has(CATEGORY[e.kind] || "link")).slice(-TIMELINE_MAX).reverse().map((e) =>
    `<li data-cat="${CATEGORY[e.kind] || "link"}" data-kind="${esc(e.kind)}"><span class="when">${clock(e.wall_time)} ${tstamp(e.data.time_s)}</span><span class="what">${esc(describe(e))}</span></li>`).join("");
}
document.querySelectorAll("#filters input").forEach((i) => i.addEventListener("change", renderTimeline));

// ---------- live updates ----------
let timelineDirty = false;
function onEvent(ev) {
  if (ev.seq <= S.lastSeq) return;
  S.lastSeq = ev.seq;
  const d = ev.data || {};
  if (ev.kind === "job") {
    const j = S.jobs.find((x) => x.id === d.id);
    if (j) Object.assign(j, {status: d.status, progress: num(d.progress) ? d.progress : j.progress, stage: d.stage || j.stage});
    if (!j || !isProgressTick(ev)) refreshJobs();
    else renderJobs();
    if (isProgressTick(ev)) return;  // progress moves the bar, never the timeline
    if (["succeeded", "failed", "cancelled"].includes(d.status)) refreshParamsets();  // a fit may have saved a set
  }
  S.events.push(ev);
  if (S.events.length > TIMELINE_MAX * 2) S.events.splice(0, S.events.length - TIMELINE_MAX);
  timelineDirty = true;
  if (ev.kind === "fault") { if (d.kind === "soc_deviation") S.mismatch = ev; refreshFaults(); }
  if (ev.kind === "plan") { if (d.status === "failed") S.planFailure = ev; refreshPlans(); }
  if (ev.kind === "upload") refreshPlans();
  if (ev.kind === "mission" && d.source) refreshMission();
  if (ev.kind === "parameter_set") refreshParamsets();
}
const KINDS = ["fault", "plan", "upload", "mission", "job", "policy", "statustext", "link", "parameter_set", "failure", "status"];
let reconnectTimer = null;
async function connectEvents() {
  // Our own reconnect (not EventSource's): after a service restart the event numbers start again
  // at 1, so resuming from Last-Event-ID would wait for ever. /console/settings names the instance.
  clearTimeout(reconnectTimer);
  if (S.es) { S.es.close(); S.es = null; }
  try {
    const s = await getJSON("/console/settings");
    if (S.instance && s.instance !== S.instance) { S.lastSeq = 0; S.events = []; timelineDirty = true; }
    if (!S.instance) loadTrack();  // first connect: the track so far, kept by the service
    S.instance = s.instance; S.settings = s;
  } catch (e) {
    S.sse = "reconnecting"; reconnectTimer = setTimeout(connectEvents, 2000); return;
  }
  const es = new EventSource(`/events?since=${S.lastSeq}`);
  S.es = es;
  es.onopen = () => { S.sse = "live"; refreshAll(); };
  es.onerror = () => { S.sse = "reconnecting"; es.close(); if (S.es === es) { S.es = null; reconnectTimer = setTimeout(connectEvents, 1500); } renderHeader(); };
  for (const k of KINDS) es.addEventListener(k, (m) => { try { onEvent(JSON.parse(m.data)); } catch (err) { console.warn("bad event", err); } });
}

// The service keeps the vehicle's recent track (GET /status/track), so a reload still shows where
// it has been; from then on the page extends it from /status.
async function loadTrack() {
  try {
    const t = await getJSON("/status/track");
    const kept = (t.points || []).filter((p) => num(p[1]) && num(p[2])).map((p) => [p[1], p[2]]);
    if (kept.length) S.track = kept.concat(S.track);
  } catch (_e) { /* an older service without a track: the page collects its own */ }
}
async function pollStatus() {
  try {
    const st = await getJSON("/status");
    if (st.time_s !== S.msgTime) { S.msgTime = st.time_s; S.msgAdvancedAt = Date.now(); }
    S.status = st; S.statusOk = true; S.statusError = null;
    const p = st.position || {};
    if (num(p.lat_deg) && num(p.lon_deg) && (p.lat_deg || p.lon_deg) && staleSeconds() < STALE_AFTER_S) {
      const last = S.track[S.track.length - 1];
      if (!last || last[0] !== p.lat_deg || last[1] !== p.lon_deg) S.track.push([p.lat_deg, p.lon_deg]);
      if (S.track.length > 5000) S.track.splice(0, 1000);
    }
  } catch (e) {
    S.statusOk = false; S.statusError = String(e.message || e);
    S.msgAdvancedAt = Date.now();  // "stale" is about the vehicle; an unreachable service has its own banner
  }
  renderHeader(); renderBanners(); renderPacks(); renderMotors();
  if (S.mission == null && S.statusOk) refreshMission();
  // a waiting proposal's gate (age; blocked when the link is lost or the vehicle failed or landed) moves
  // with the vehicle's state, not only on plan events
  if (S.proposed.length && S.statusOk) refreshPlans();
  if (!fitted) drawMission();
  drawVehicle();
  if (timelineDirty) { timelineDirty = false; renderTimeline(); }
}

async function refreshMission() {
  try { S.mission = await getJSON("/missions/current"); } catch (_e) { return; }
  fitted = false; drawMission(); drawProposed();
}
async function refreshPlans() {
  try {
    [S.proposed, S.history, S.uploads] = await Promise.all([getJSON("/missions/proposed"), getJSON("/missions/history?limit=20"), getJSON("/missions/uploads?limit=20")]);
  } catch (_e) { return; }
  S.history.forEach(learnWaypoints);
  drawMission(); drawProposed(); renderDecision(); renderBanners();
}
async function refreshFaults() {
  try { S.faults = await getJSON("/faults?active=true"); } catch (_e) { return; }
  renderBanners();
}
async function refreshJobs() {
  try { S.jobs = await getJSON("/jobs?limit=20"); } catch (_e) { return; }
  for (const j of S.jobs) if (j.status === "succeeded" && !S.jobResults[j.id])
    try { S.jobResults[j.id] = await getJSON(`/jobs/${encodeURIComponent(j.id)}/result`); } catch (_e) { /* shown without */ }
  renderJobs();
}
async function refreshParamsets() {
  try { S.paramsets = await getJSON("/parameter-sets"); } catch (_e) { return; }
  renderParamsets();
}
function refreshAll() { refreshMission(); refreshPlans(); refreshFaults(); refreshJobs(); refreshParamsets(); }

updateTokenButton();
ensureMap();
connectEvents();
pollStatus();
setInterval(pollStatus, STATUS_PERIOD_MS);
setInterval(refreshAll, 15000);   // a safety net under the event stream
