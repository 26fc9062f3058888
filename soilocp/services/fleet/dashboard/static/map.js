// The fleet soil map view: cells coloured by K (log scale) with their uncertainty, and vehicle
// tracks, drawn as SVG from GET /api/map (no library, works offline).
"use strict";
const params = new URLSearchParams(location.search);
const api = "/api/map?" + ["map", "frame", "bbox"].filter(k => params.get(k)).map(k => k + "=" + encodeURIComponent(params.get(k))).join("&");
const NS = "http://www.w3.org/2000/svg";
const W = 900, H = 600, PAD = 40;
const K_MIN = 30, K_MAX = 400;  // colour scale ends (log)
const SOILS = {sand: 50, gravel: 80, EST: 120, grass: 200, firm: 300};
const TRACK_COLOURS = ["#111827", "#be185d", "#0369a1", "#4d7c0f", "#7c2d12", "#6d28d9"];

function el(tag, attrs, parent) {
  const e = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (parent) parent.appendChild(e);
  return e;
}
// soft (sand, orange-brown) -> firm (green-blue): hue along log K
function colour(k, logStd) {
  const u = Math.min(1, Math.max(0, Math.log(k / K_MIN) / Math.log(K_MAX / K_MIN)));
  const hue = 25 + u * 160;
  const sat = Math.max(15, 75 - 100 * Math.min(1, logStd / 0.6));  // pale where little is known
  return `hsl(${hue.toFixed(0)},${sat.toFixed(0)}%,${(55 - 10 * u).toFixed(0)}%)`;
}

function draw(view) {
  const svg = document.getElementById("map");
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  const defs = el("defs", {}, svg);
  const pat = el("pattern", {id: "wide", width: 6, height: 6, patternUnits: "userSpaceOnUse", patternTransform: "rotate(45)"}, defs);
  el("line", {x1: 0, y1: 0, x2: 0, y2: 6, stroke: "#ffffff", "stroke-width": 2, opacity: 0.8}, pat);
  const pts = [];
  view.cells.forEach(c => c.polygon.forEach(p => pts.push(p)));
  Object.values(view.tracks).forEach(t => t.forEach(p => pts.push(p)));
  if (!pts.length) {
    el("text", {x: W / 2, y: H / 2, "text-anchor": "middle", class: "none"}, svg).textContent =
      view.error ? view.error : "no mapped cell yet";
    return;
  }
  let [x0, y0, x1, y1] = [Infinity, Infinity, -Infinity, -Infinity];
  pts.forEach(([x, y]) => { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); });
  const geo = view.frame === "wgs84";
  const kx = geo ? Math.cos((y0 + y1) / 2 * Math.PI / 180) : 1;  // equal metres both ways
  const s = Math.min((W - 2 * PAD) / Math.max((x1 - x0) * kx, 1e-9), (H - 2 * PAD) / Math.max(y1 - y0, 1e-9));
  const X = x => PAD + (x - x0) * kx * s, Y = y => H - PAD - (y - y0) * s;
  const g = el("g", {id: "cells"}, svg);
  view.cells.forEach(c => {
    const d = c.polygon.map(([x, y], i) => (i ? "L" : "M") + X(x).toFixed(1) + "," + Y(y).toFixed(1)).join("") + "Z";
    const p = el("path", {d, fill: colour(c.K, c.log_k_std), stroke: "#ffffff", "stroke-width": 1, class: "cell",
                          "data-k": c.K.toFixed(1)}, g);
    el("title", {}, p).textContent = `${c.cell}\nK ${c.K.toFixed(1)} (95 %: ${c.K_lo.toFixed(0)}–${c.K_hi.toFixed(0)})\n` +
      `${c.count} estimates, ${c.vehicles.join(", ")}\nlast ${c.age_s.toFixed(0)} s ago`;
    if (c.log_k_std > 0.25) el("path", {d, fill: "url(#wide)", "pointer-events": "none"}, g);
    const cx = c.polygon.slice(0, -1).reduce((a, q) => a + q[0], 0) / (c.polygon.length - 1);
    const cy = c.polygon.slice(0, -1).reduce((a, q) => a + q[1], 0) / (c.polygon.length - 1);
    const size = Math.abs(X(c.polygon[1][0]) - X(c.polygon[0][0])) + Math.abs(Y(c.polygon[1][1]) - Y(c.polygon[0][1]));
    if (size > 28) {
      const t = el("text", {x: X(cx), y: Y(cy) + 4, "text-anchor": "middle", class: "cell-k"}, g);
      t.textContent = c.K.toFixed(0);
    }
  });
  const tg = el("g", {id: "tracks"}, svg);
  Object.entries(view.tracks).sort().forEach(([vid, t], i) => {
    if (t.length < 2) return;
    const col = TRACK_COLOURS[i % TRACK_COLOURS.length];
    el("polyline", {points: t.map(([x, y]) => X(x).toFixed(1) + "," + Y(y).toFixed(1)).join(" "), fill: "none",
                    stroke: col, "stroke-width": 2, "stroke-dasharray": "6 3", class: "track", "data-vehicle": vid}, tg);
    const [lx, ly] = t[t.length - 1];
    el("circle", {cx: X(lx), cy: Y(ly), r: 4, fill: col}, tg);
    el("text", {x: X(lx) + 6, y: Y(ly) - 6, class: "track-label"}, tg).textContent = vid;
  });
  // scale bar (local frames) / degrees note
  if (!geo) {
    const len = Math.pow(10, Math.floor(Math.log10((x1 - x0) / 3 || 1)));
    el("line", {x1: PAD, y1: H - 12, x2: PAD + len * s, y2: H - 12, stroke: "#374151", "stroke-width": 2}, svg);
    el("text", {x: PAD + len * s + 6, y: H - 8}, svg).textContent = `${len} m`;
  }
}

function legend() {
  const box = document.getElementById("legend");
  const svg = el("svg", {viewBox: "0 0 900 46"});
  for (let i = 0; i < 100; i++) {
    const k = K_MIN * Math.pow(K_MAX / K_MIN, i / 99);
    el("rect", {x: 40 + i * 7, y: 6, width: 7.5, height: 14, fill: colour(k, 0)}, svg);
  }
  Object.entries(SOILS).forEach(([name, k]) => {
    const x = 40 + 700 * Math.log(k / K_MIN) / Math.log(K_MAX / K_MIN);
    el("line", {x1: x, y1: 4, x2: x, y2: 24, stroke: "#111827"}, svg);
    el("text", {x, y: 38, "text-anchor": "middle"}, svg).textContent = `${name} ${k}`;
  });
  el("text", {x: 760, y: 18}, svg).textContent = "K (log)";
  box.appendChild(svg);
}

async function refresh() {
  try {
    const r = await fetch(api);
    const view = await r.json();
    if (!r.ok) throw new Error(view.error || r.status);
    draw(view);
    const conn = document.getElementById("conn");
    conn.textContent = view.error ? "map: " + view.error : "map " + view.map_id;
    conn.className = "badge " + (view.error ? "amber" : "green");
    document.getElementById("sub").textContent =
      `${view.cells.length} cells · frame ${view.frame} · ${Object.keys(view.tracks).length} vehicle track(s)`;
    document.getElementById("info").textContent = new Date(view.time * 1000).toISOString().slice(11, 19) + " UTC";
  } catch (e) {
    document.getElementById("conn").textContent = "error: " + e.message;
    document.getElementById("conn").className = "badge red";
  }
}
legend();
refresh();
setInterval(refresh, 2000);
