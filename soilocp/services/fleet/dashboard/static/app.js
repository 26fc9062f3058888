// soilocp fleet dashboard: renders server-sent fleet updates (GET /events) as a table and, per
// vehicle, three SVG plots. No libraries, no build step; works offline.
"use strict";

const WINDOW_S = 180;           // time span of the time plots
const MAX_POINTS = 900;         // history points kept per vehicle (as the server)
const vehicles = new Map();     // vid -> {row, history, curve, wheels}
let soils = {};
let serverTime = Date.now() / 1000;

const esc = (s) => String(s).replace(/[&<>"']/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}[c]));
const fmt = (x, d = 3) => (x === null || x === undefined ? "–" : Number(x).toFixed(d));
const utc = (t) => new Date(t * 1000).toISOString().slice(11, 19) + " UTC";

function badge(text, colour) { return `<span class="badge ${colour}">${esc(text)}</span>`; }

function stateBadge(r) {
  if (r.state === "offline") return badge(r.offline_since ? `offline since ${utc(r.offline_since)}` : "offline", "red");
  if (r.state === "degraded") return badge("missing: " + r.services_missing.join(", "), "amber");
  return badge("online", "green");
}

function statusBadge(r) {
  if (r.status === "fresh") return badge("fresh" + (r.estimate_status ? " · " + r.estimate_status : ""), "green");
  if (r.status === "stale") return badge("stale", "amber");
  return badge("no estimate", "grey");
}

function age(x) { return x === null ? "–" : x < 120 ? x.toFixed(1) + " s" : (x / 60).toFixed(0) + " min"; }

function renderTable() {
  const body = document.getElementById("rows");
  if (vehicles.size === 0) { body.innerHTML = '<tr><td colspan="11" class="muted">no vehicle seen yet</td></tr>'; return; }
  const html = [];
  for (const [vid, v] of [...vehicles].sort()) {
    const r = v.row, n = r.services_alive.length, total = n + r.services_missing.length;
    const k = r.K === null ? "–" : `${r.K.toFixed(1)} ± ${fmt(r.K_std, 1)}`;
    const cls = r.soil_class ? r.soil_class + (r.soil_class_confidence !== null ? ` (${r.soil_class_confidence.toFixed(2)})` : "") : "–";
    html.push(`<tr class="${r.state}" data-vehicle="${esc(vid)}" data-status="${esc(r.status)}" data-state="${esc(r.state)}">` +
      `<td><b>${esc(vid)}</b></td><td>${stateBadge(r)}</td><td>${n}/${total}${r.source_alive ? "" : ' <span class="muted">(no source)</span>'}</td>` +
      `<td class="num k-value">${k}</td><td>${esc(cls)}</td><td class="num">${fmt(r.mu_T)}</td><td class="num">${fmt(r.S_T)}</td>` +
      `<td class="num">${fmt(r.S_E)}</td><td>${statusBadge(r)}</td><td class="num">${age(r.age_s)}</td><td class="num">${r.rejections}</td></tr>`);
  }
  body.innerHTML = html.join("");
}

// --- tiny SVG plotting -------------------------------------------------------------------------
const W = 460, H = 210, M = {l: 46, r: 58, t: 10, b: 28};
const lin = (d0, d1, r0, r1) => (x) => r0 + (x - d0) / (d1 - d0) * (r1 - r0);
const logs = (d0, d1, r0, r1) => { const f = lin(Math.log10(d0), Math.log10(d1), r0, r1); return (x) => f(Math.log10(x)); };

function path(xs, ys, cls) {   // a polyline broken at nulls
  let d = "", pen = false;
  for (let i = 0; i < xs.length; i++) {
    if (ys[i] === null || !isFinite(ys[i])) { pen = false; continue; }
    d += (pen ? "L" : "M") + xs[i].toFixed(1) + "," + ys[i].toFixed(1);
    pen = true;
  }
  return d ? `<path class="${cls}" d="${d}"/>` : "";
}

function band(xs, lo, hi) {   // filled polygon between lo and hi, one per unbroken run
  let out = "", run = [];
  const flush = () => {
    if (run.length > 1) {
      const pts = run.map((i) => `${xs[i].toFixed(1)},${hi[i].toFixed(1)}`).concat(
        run.slice().reverse().map((i) => `${xs[i].toFixed(1)},${lo[i].toFixed(1)}`));
      out += `<polygon class="band" points="${pts.join(" ")}"/>`;
    }
    run = [];
  };
  for (let i = 0; i < xs.length; i++) { if (lo[i] === null || hi[i] === null) flush(); else run.push(i); }
  flush();
  return out;
}

function frame(x, y, xticks, yticks, xlabel, ylabel, xfmt, yfmt) {
  let s = "";
  for (const t of yticks) { const py = y(t); s += `<line class="grid" x1="${M.l}" x2="${W - M.r}" y1="${py}" y2="${py}"/><text x="${M.l - 5}" y="${py + 4}" text-anchor="end">${yfmt(t)}</text>`; }
  for (const t of xticks) { const px = x(t); s += `<line class="grid" x1="${px}" x2="${px}" y1="${M.t}" y2="${H - M.b}"/><text x="${px}" y="${H - M.b + 14}" text-anchor="middle">${xfmt(t)}</text>`; }
  s += `<line class="axis" x1="${M.l}" x2="${W - M.r}" y1="${H - M.b}" y2="${H - M.b}"/><line class="axis" x1="${M.l}" x2="${M.l}" y1="${M.t}" y2="${H - M.b}"/>`;
  s += `<text x="${(M.l + W - M.r) / 2}" y="${H - 2}" text-anchor="middle">${xlabel}</text>`;
  s += `<text transform="translate(11,${(M.t + H - M.b) / 2}) rotate(-90)" text-anchor="middle">${ylabel}</text>`;
  return s;
}

const svg = (inner) => `<svg viewBox="0 0 ${W} ${H}" xmlns="http://www.w3.org/2000/svg">${inner}</svg>`;
const noData = (msg) => `<text class="none" x="${(M.l + W - M.r) / 2}" y="${H / 2}" text-anchor="middle">${msg}</text>`;

function timeAxis(hist) {
  const span = hist.length ? Math.min(WINDOW_S, Math.max(30, Math.ceil((serverTime - hist[0].t) / 10) * 10)) : 60;
  const x = lin(-span, 0, M.l, W - M.r);
  const step = span > 90 ? 30 : 10, ticks = [];
  for (let t = -span; t <= 0; t += step) ticks.push(t);
  return {x, ticks, span, rel: hist.map((p) => p.t - serverTime)};
}

function kPlot(v) {
  const hist = v.history, ta = timeAxis(hist);
  const ks = hist.map((p) => p.K).filter((k) => k !== null);
  const soilKs = Object.values(soils);
  // decades around the reference soils and the current K; a transient spike is clipped to the
  // axis rather than squeezing the whole plot
  const now = v.row.K;
  let lo = Math.min(20, ...soilKs.map((k) => k / 1.5), now ? now / 1.5 : 20);
  let hi = Math.max(1000, ...soilKs.map((k) => k * 1.5), now ? now * 1.5 : 1000);
  lo = Math.pow(10, Math.floor(Math.log10(lo))); hi = Math.pow(10, Math.ceil(Math.log10(hi)));
  const y = logs(lo, hi, H - M.b, M.t);
  const yt = []; for (let d = lo; d <= hi; d *= 10) yt.push(d);
  let s = frame(ta.x, y, ta.ticks, yt, "time, s (0 = now)", "K (log)", (t) => t, (k) => k);
  for (const [name, k] of Object.entries(soils)) {
    const py = y(k).toFixed(1);
    s += `<line class="soil" x1="${M.l}" x2="${W - M.r}" y1="${py}" y2="${py}"/><text class="soil-label" x="${W - M.r + 4}" y="${Number(py) + 3}">${esc(name)} ${k}</text>`;
  }
  const xs = ta.rel.map(ta.x), inWin = ta.rel.map((t) => t >= -ta.span);
  const clip = (k) => Math.min(hi, Math.max(lo, k));
  const kv = hist.map((p, i) => (inWin[i] && p.K !== null ? y(clip(p.K)) : null));
  const bl = hist.map((p, i) => (inWin[i] && p.K !== null && p.K_std !== null ? y(clip(p.K - p.K_std > 0 ? p.K - p.K_std : lo)) : null));
  const bh = hist.map((p, i) => (inWin[i] && p.K !== null && p.K_std !== null ? y(clip(p.K + p.K_std)) : null));
  s += band(xs, bl, bh) + path(xs, kv, "k");
  if (!ks.length) s += noData("no K estimate yet");
  return svg(s);
}

function ocpPlot(v) {
  const hist = v.history, ta = timeAxis(hist);
  const top = Math.max(1.4, ...hist.map((p) => (p.mu_T === null ? 0 : p.mu_T * 1.1)));
  const y = lin(0, top, H - M.b, M.t);
  const yt = []; for (let t = 0; t <= top + 1e-9; t += 0.2) yt.push(t);
  let s = frame(ta.x, y, ta.ticks, yt, "time, s (0 = now)", "mu_T, S_T, S_E", (t) => t, (t) => t.toFixed(1));
  const xs = ta.rel.map(ta.x), inWin = ta.rel.map((t) => t >= -ta.span);
  const series = {muT: "mu_T", ST: "S_T", SE: "S_E"};
  let ly = M.t + 10;
  for (const [cls, key] of Object.entries(series)) {
    s += path(xs, hist.map((p, i) => (inWin[i] && p[key] !== null ? y(Math.min(top, Math.max(0, p[key]))) : null)), cls);
    s += `<line class="${cls}" x1="${W - M.r + 4}" x2="${W - M.r + 16}" y1="${ly}" y2="${ly}"/><text x="${W - M.r + 19}" y="${ly + 4}">${key}</text>`;
    ly += 16;
  }
  if (!hist.some((p) => p.mu_T !== null)) s += noData("no OCP yet");
  return svg(s);
}

function curvePlot(v) {
  const c = v.curve, r = v.row;
  if (!c) return svg(frame(lin(0, 1, M.l, W - M.r), lin(0, 1, H - M.b, M.t), [], [], "slip S", "net traction mu", String, String) + noData("no K: no curve"));
  const s0 = c.slip[0], s1 = c.slip[c.slip.length - 1];
  const all = c.mu_lo.concat(c.mu_hi, (v.wheels || []).map((w) => w.mu).filter((m) => m !== null));
  const ymin = Math.min(-0.2, ...all) - 0.05, ymax = Math.max(1.2, ...all) + 0.05;
  const x = lin(s0, s1, M.l, W - M.r), y = lin(ymin, ymax, H - M.b, M.t);
  const xt = [], yt = [];
  for (let t = Math.ceil(s0 * 5) / 5; t <= s1 + 1e-9; t += 0.2) xt.push(t);
  for (let t = Math.ceil(ymin * 2.5) / 2.5; t <= ymax + 1e-9; t += 0.4) yt.push(t);
  let s = frame(x, y, xt, yt, "slip S", "net traction mu", (t) => t.toFixed(1), (t) => t.toFixed(1));
  const xs = c.slip.map(x);
  s += band(xs, c.mu_lo.map(y), c.mu_hi.map(y)) + path(xs, c.mu.map(y), "k");
  if (r.S_T !== null) s += `<line class="vST" x1="${x(r.S_T)}" x2="${x(r.S_T)}" y1="${M.t}" y2="${H - M.b}"/><text x="${x(r.S_T) + 3}" y="${H - M.b - 4}">S_T</text>`;
  if (r.S_E !== null && r.S_E >= s0 && r.S_E <= s1) s += `<line class="vSE" x1="${x(r.S_E)}" x2="${x(r.S_E)}" y1="${M.t}" y2="${H - M.b}"/><text x="${x(r.S_E) + 3}" y="${M.t + 10}">S_E</text>`;
  (v.wheels || []).forEach((w, i) => {
    if (w.slip === null || w.mu === null) return;
    const px = x(Math.min(s1, Math.max(s0, w.slip))), py = y(w.mu);
    // each label in its wheel's corner (LR below-left, LF above-left, RF above-right, RR below-right),
    // so that wheels at nearly the same operating point stay readable
    const [dx, dy, anchor] = [[-6, 13, "end"], [-6, -5, "end"], [6, -5, "start"], [6, 13, "start"]][i];
    s += `<circle class="wheel" cx="${px.toFixed(1)}" cy="${py.toFixed(1)}" r="4"/>` +
      `<text class="wheel-label" x="${(px + dx).toFixed(1)}" y="${(py + dy).toFixed(1)}" text-anchor="${anchor}">${w.wheel}</text>`;
  });
  s += `<text x="${W - M.r + 4}" y="${M.t + 10}">K=${c.K.toFixed(0)}</text>`;
  return svg(s);
}

function renderCards() {
  const root = document.getElementById("cards");
  for (const [vid, v] of [...vehicles].sort()) {
    let card = document.getElementById("card-" + vid);
    if (!card) {
      card = document.createElement("section");
      card.id = "card-" + vid;
      card.className = "card";
      card.innerHTML = `<h2><span>${esc(vid)}</span><span class="badges"></span><span class="muted info"></span></h2>
        <div class="plots"><div class="plot"><h3>Soil strength K ± std vs soil classes</h3><div class="p-k"></div></div>
        <div class="plot"><h3>Optimal control parameters</h3><div class="p-ocp"></div></div>
        <div class="plot"><h3>Traction–slip curve at current K, wheel operating points</h3><div class="p-curve"></div></div></div>`;
      root.appendChild(card);
    }
    const r = v.row;
    card.className = "card " + r.state;
    card.querySelector(".badges").innerHTML = stateBadge(r) + " " + statusBadge(r);
    card.querySelector(".info").textContent = (r.seq !== null ? `seq ${r.seq}, stamp ${fmt(r.stamp, 2)} s` : "") +
      (r.reason ? " — " + r.reason : "");
    card.querySelector(".p-k").innerHTML = kPlot(v);
    card.querySelector(".p-ocp").innerHTML = ocpPlot(v);
    card.querySelector(".p-curve").innerHTML = curvePlot(v);
  }
  for (const card of [...root.children]) if (!vehicles.has(card.id.slice(5))) card.remove();
}

function apply(msg) {
  serverTime = msg.time;
  soils = msg.soils || soils;
  const seen = new Set();
  for (const d of msg.vehicles) {
    seen.add(d.vehicle_id);
    let v = vehicles.get(d.vehicle_id);
    if (!v) { v = {history: []}; vehicles.set(d.vehicle_id, v); }
    v.history = d.history_full ? d.history : v.history.concat(d.history);
    if (v.history.length > MAX_POINTS) v.history = v.history.slice(-MAX_POINTS);
    const {history, curve, wheels, ...row} = d;
    v.row = row; v.curve = curve; v.wheels = wheels;
  }
  for (const vid of [...vehicles.keys()]) if (!seen.has(vid)) vehicles.delete(vid);
  const conn = document.getElementById("conn");
  if (msg.router.connected) { conn.className = "badge green"; conn.textContent = "router " + msg.router.endpoints.join(", "); }
  else { conn.className = "badge amber"; conn.textContent = "connecting to " + msg.router.endpoints.join(", ") + "…"; }
  document.getElementById("clock").textContent = `${vehicles.size} vehicle(s) · ${utc(serverTime)}`;
  renderTable();
  renderCards();
}

function connect() {
  const es = new EventSource("/events");
  es.addEventListener("fleet", (e) => apply(JSON.parse(e.data)));
  es.onerror = () => {
    const conn = document.getElementById("conn");
    conn.className = "badge red"; conn.textContent = "dashboard server unreachable — retrying";
  };
}

connect();
