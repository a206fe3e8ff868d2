// The replay page's script: draws the run embedded as JSON in #replay-data (see
// fleet/view/replay.py for its keys) and plays it. It loads nothing; fleet.view.replay inlines it.
(function () {
"use strict";
const D = JSON.parse(document.getElementById("replay-data").textContent);
const F = D.floor, C = F.colours;
const stage = document.getElementById("stage");
const canvas = document.getElementById("floor");
const ctx = canvas.getContext("2d");
const slider = document.getElementById("slider");
const playButton = document.getElementById("play");
const speedSelect = document.getElementById("speed");
const timeLabel = document.getElementById("time");
// Label fonts and height: set by layout(), a size larger on a large canvas.
let LABEL_FONT = "11px sans-serif", STATION_FONT = "10px sans-serif", LABEL_H = 14;
const LABEL_PAD = 2;
// Robots whose disks come closer than this (px, rim to rim) share one label, in groups at most
// MAX_GROUP_PX across.
const CLUSTER_GAP = 14, MAX_GROUP_PX = 72;

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  for (const k in attrs || {}) e.setAttribute(k, attrs[k]);
  if (text !== undefined) e.textContent = text;
  return e;
}

// -- the world-to-pixel map --------------------------------------------------------------------
// Mirrors fleet.view.replay.view_transform (same arithmetic, so the same numbers): the floor at
// one scale for both axes, `margin` px free on every side, the canvas shrunk to the floor.
function viewTransform(b, width, height, margin) {
  const w = b[2] - b[0], h = b[3] - b[1];
  const scale = Math.min((width - 2 * margin) / w, (height - 2 * margin) / h);
  return {
    scale, x0: margin - scale * b[0], y0: margin + scale * b[3],
    width: Math.min(width, Math.ceil(scale * w + 2 * margin)),
    height: Math.min(height, Math.ceil(scale * h + 2 * margin)),
  };
}

let V = null;  // the map in use; set by layout()
const px = (x) => V.x0 + V.scale * x;
const py = (y) => V.y0 - V.scale * y;

// -- labels that never overlap -----------------------------------------------------------------
const hits = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;

function labelWidth(g, text) { return Math.ceil(g.measureText(text).width) + 2 * LABEL_PAD; }

// Places around an anchor box `gap` px away, best first: above right (where a reader looks
// first), right, above left, left, above, below, below right, below left.
function spots(box, w, h, gap) {
  const cx = (box.x0 + box.x1) / 2, cy = (box.y0 + box.y1) / 2, up = h - 4;
  return [
    [box.x1 + gap, box.y0 - up], [box.x1 + gap, cy - h / 2],
    [box.x0 - gap - w, box.y0 - up], [box.x0 - gap - w, cy - h / 2],
    [cx - w / 2, box.y0 - gap - h], [cx - w / 2, box.y1 + gap],
    [box.x1 + gap, box.y1 - 4], [box.x0 - gap - w, box.y1 - 4],
  ];
}

// The first of `texts` (longest first) that fits at one of the spots: clear of every label in
// `taken` and inside the canvas, and preferably (first at any distance, then close by) clear of
// `soft` boxes too (disks, markers). Null when nothing fits: the label is left out rather than
// drawn over another.
function placeLabel(g, texts, box, taken, soft) {
  const tries = [[3, true], [14, true], [28, true], [3, false]];
  for (const text of texts) {
    const w = labelWidth(g, text), h = LABEL_H;
    for (const [gap, strict] of tries) {
      for (const [x, y] of spots(box, w, h, gap)) {
        const r = { x: Math.round(x), y: Math.round(y), w, h };
        if (r.x < 0 || r.y < 0 || r.x + w > V.width || r.y + h > V.height) continue;
        if (taken.some((o) => hits(r, o))) continue;
        if (strict && soft.some((o) => hits(r, o))) continue;
        return Object.assign(r, { text });
      }
    }
  }
  return null;
}

function drawLabel(g, r, colour) {
  g.fillStyle = "rgba(255,255,255,0.82)";
  g.fillRect(r.x, r.y, r.w, r.h);
  g.fillStyle = colour;
  g.fillText(r.text, r.x + LABEL_PAD, r.y + r.h / 2 + 0.5);
}

function boxRect(b) { return { x: b.x0, y: b.y0, w: b.x1 - b.x0, h: b.y1 - b.y0 }; }

// -- the floor, drawn once per size ------------------------------------------------------------
function tracePolys(g, polys) {
  g.beginPath();
  for (const rings of polys) {
    for (const ring of rings) {
      for (let i = 0; i < ring.length; i += 2) {
        if (i === 0) g.moveTo(px(ring[i]), py(ring[i + 1]));
        else g.lineTo(px(ring[i]), py(ring[i + 1]));
      }
      g.closePath();
    }
  }
}

function hatch() {
  const p = document.createElement("canvas");
  p.width = p.height = 8;
  const g = p.getContext("2d");
  g.strokeStyle = "rgba(80,80,80,0.7)";
  g.lineWidth = 1;
  g.beginPath(); g.moveTo(0, 8); g.lineTo(8, 0); g.moveTo(-2, 2); g.lineTo(2, -2);
  g.moveTo(6, 10); g.lineTo(10, 6); g.stroke();
  return p;
}

const MARKERS = { depot: "square", delivery: "triangle", charger: "plus" };

function marker(g, kind, x, y, r) {
  g.beginPath();
  const shape = MARKERS[kind] || "diamond";
  if (shape === "square") g.rect(x - r, y - r, 2 * r, 2 * r);
  else if (shape === "triangle") { g.moveTo(x, y - r * 1.2); g.lineTo(x + r * 1.1, y + r * 0.8);
    g.lineTo(x - r * 1.1, y + r * 0.8); g.closePath(); }
  else if (shape === "plus") { const a = r * 0.4; g.moveTo(x - a, y - r); g.lineTo(x + a, y - r);
    g.lineTo(x + a, y - a); g.lineTo(x + r, y - a); g.lineTo(x + r, y + a); g.lineTo(x + a, y + a);
    g.lineTo(x + a, y + r); g.lineTo(x - a, y + r); g.lineTo(x - a, y + a); g.lineTo(x - r, y + a);
    g.lineTo(x - r, y - a); g.lineTo(x - a, y - a); g.closePath(); }
  else { g.moveTo(x, y - r); g.lineTo(x + r, y); g.lineTo(x, y + r); g.lineTo(x - r, y);
    g.closePath(); }
}

// The longest of 1, 2, 5 x 10^k metres that is at most `most` px long on the canvas.
function niceLength(scale, most) {
  let k = Math.floor(Math.log10(most / scale));
  for (;;) {
    for (const m of [5, 2, 1]) {
      const metres = m * Math.pow(10, k);
      if (metres * scale <= most) return { metres, text: k >= 0 ? metres + " m"
        : k >= -2 ? Math.round(metres * 100) + " cm" : Math.round(metres * 1000) + " mm" };
    }
    k -= 1;
  }
}

let scaleBar = null, stationMarks = [];

function drawScaleBar(g) {
  const most = Math.max(30, Math.min(160, V.width / 6));
  const { metres, text } = niceLength(V.scale, most);
  const len = metres * V.scale, pad = 6;
  g.font = LABEL_FONT;
  const w = Math.ceil(pad + len + 6 + g.measureText(text).width + pad), h = 20;
  const x = D.margin + 4, y = V.height - D.margin - 4 - h;
  g.fillStyle = "rgba(255,255,255,0.85)"; g.fillRect(x, y, w, h);
  g.strokeStyle = "#111"; g.lineWidth = 2; g.beginPath();
  const bx = x + pad, by = y + h / 2 + 3;
  g.moveTo(bx, by - 5); g.lineTo(bx, by); g.lineTo(bx + len, by); g.lineTo(bx + len, by - 5);
  g.stroke();
  g.fillStyle = "#111"; g.textBaseline = "middle"; g.fillText(text, bx + len + 6, y + h / 2);
  scaleBar = { metres, text, px: len, x, y, w, h };
}

function drawFloor(g) {
  g.fillStyle = "#ffffff";
  g.fillRect(0, 0, V.width, V.height);
  // Grey under white free space: what shows grey is the band the robot's centre may not enter.
  tracePolys(g, F.boundary); g.fillStyle = C.clearance; g.fill("evenodd");
  tracePolys(g, F.free); g.fillStyle = "#ffffff"; g.fill("evenodd");
  for (const z of F.zones) { tracePolys(g, z.polys); g.fillStyle = z.colour; g.fill("evenodd"); }
  if (F.rough.length) {
    tracePolys(g, F.rough); g.fillStyle = g.createPattern(hatch(), "repeat"); g.fill("evenodd");
  }
  tracePolys(g, F.obstacles); g.fillStyle = C.obstacle; g.fill("evenodd");
  tracePolys(g, F.boundary); g.strokeStyle = "#000"; g.lineWidth = 1.2; g.stroke();
  drawScaleBar(g);
  stationMarks = F.stations.map((s) => {
    const x = px(s.x), y = py(s.y);
    marker(g, s.kind, x, y, 4); g.fillStyle = C.station; g.fill();
    g.strokeStyle = "#fff"; g.lineWidth = 0.8; g.stroke();
    return { x0: x - 5, y0: y - 5, x1: x + 5, y1: y + 5 };
  });
}

const background = document.createElement("canvas");

// Fit the floor into the space the window leaves it; again on every resize.
function layout() {
  const margin = D.margin;
  const areaW = Math.max(stage.clientWidth, 2 * margin + 10);
  const areaH = Math.max(stage.clientHeight, 2 * margin + 10);
  V = viewTransform(D.bounds, areaW, areaH, margin);
  V.left = Math.floor((stage.clientWidth - V.width) / 2);
  V.top = Math.floor((stage.clientHeight - V.height) / 2);
  V.area = [areaW, areaH];
  const large = V.width >= 1200;
  LABEL_FONT = (large ? 13 : 11) + "px sans-serif";
  STATION_FONT = (large ? 12 : 10) + "px sans-serif";
  LABEL_H = large ? 17 : 14;
  const dpr = window.devicePixelRatio || 1;
  for (const c of [canvas, background]) {
    c.width = Math.round(V.width * dpr); c.height = Math.round(V.height * dpr);
  }
  Object.assign(canvas.style, { left: V.left + "px", top: V.top + "px",
    width: V.width + "px", height: V.height + "px" });
  canvas.dataset.view = JSON.stringify(V);
  const g = background.getContext("2d");
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  drawFloor(g);
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
}

// -- where things are at time t ----------------------------------------------------------------
function bisect(a, t) {  // last i with a[i] <= t (-1 if none)
  let lo = 0, hi = a.length;
  while (lo < hi) { const mid = (lo + hi) >> 1; if (a[mid] <= t) lo = mid + 1; else hi = mid; }
  return lo - 1;
}

function positionAt(r, t) {
  const n = r.t.length;
  if (n === 0) return null;
  const i = bisect(r.t, t);
  if (i < 0) return { x: r.x[0], y: r.y[0], vx: 0, vy: 0 };
  if (i >= n - 1) return { x: r.x[n - 1], y: r.y[n - 1], vx: 0, vy: 0 };
  const dt = r.t[i + 1] - r.t[i];
  const f = dt > 0 ? (t - r.t[i]) / dt : 1;
  const vx = dt > 0 ? (r.x[i + 1] - r.x[i]) / dt : 0, vy = dt > 0 ? (r.y[i + 1] - r.y[i]) / dt : 0;
  return { x: r.x[i] + f * (r.x[i + 1] - r.x[i]), y: r.y[i] + f * (r.y[i + 1] - r.y[i]), vx, vy };
}

// Every robot's try at a job (attempts.csv): a job handed back has one per robot that held it.
// A run written without attempts has one per job, from its story.
const ATTEMPTS = D.attempts || [];
const HANDBACK_MARK_S = D.handback_mark_s || 10;
const jobById = new Map(D.jobs.map((j) => [j.id, j]));
for (const j of D.jobs) j.attempts = [];
for (const a of ATTEMPTS) { const j = jobById.get(a.job); if (j) j.attempts.push(a); }
const HANDBACKS = ATTEMPTS.filter((a) => a.scrapped && a.ended !== null);

for (const r of D.robots) {
  if (ATTEMPTS.length) {
    // Each spell the robot held a job; the job's arrival and print end are the attempt's own
    // only when it is the one that delivered (or was still under way).
    r.jobs = ATTEMPTS.filter((a) => a.robot === r.id).map((a) => {
      const j = jobById.get(a.job) || {};
      const own = !a.scrapped;
      const ends = r.tasks.filter((k) => k[3] === a.job && (k[4] || 1) === a.attempt)
        .map((k) => k[1]);
      return { id: a.job, station: j.station || null, assigned: a.assigned,
        delivered: a.ended, arrived: own ? (j.arrived ?? null) : null,
        print_end: ends.length ? Math.max(...ends) : (own ? (j.print_end ?? null) : null),
        attempt: a.attempt, scrapped: a.scrapped, result: a.result, reason: a.reason };
    });
  } else {
    r.jobs = D.jobs.filter((j) => j.robot === r.id && j.assigned !== null);
  }
  r.handbacks = HANDBACKS.filter((a) => a.robot === r.id);
}

const BROKEN = "#7b3294";  // purple: red marks hand-backs

function stateAt(r, t) {
  const down = (r.broken || []).find((b) => b[0] <= t && (b[1] === null || t < b[1]));
  if (down) {
    const until = down[1] === null ? "" : " (repaired at " + down[1].toFixed(0) + " s)";
    return { key: "broken", text: "broken down" + until, ring: BROKEN };
  }
  const job = r.jobs.find((j) => j.assigned <= t && (j.delivered === null || t < j.delivered));
  if (!job) {
    const hb = r.handbacks.find((a) => a.ended <= t && t < a.ended + HANDBACK_MARK_S);
    if (hb) return { key: "handed_back", ring: null, mark: hb.ended,
      text: "handed back " + hb.job + " (" + (hb.reason || hb.result) + ")" };
    return { key: "idle", text: "idle", ring: null };
  }
  const to = job.station || "station";
  const task = r.tasks.find((k) => k[0] <= t && t < k[1]);
  const kind = task ? task[2] : null;
  const kindColour = kind ? (D.kinds[kind] || D.kinds.other) : null;
  // A print its robot will hand back: the part is scrapped (dashed ring).
  const scrap = job.scrapped ? ", scrapped at " + job.delivered.toFixed(1) + " s" : "";
  if (job.arrived !== null && job.arrived <= t) {
    if (job.print_end !== null && t < job.print_end) {
      const what = kind ? " (" + kind + ")" : "";
      return { key: "waiting", text: "at " + to + ", waiting for print" + what + scrap,
        ring: kindColour || "#b8860b", dashed: !!job.scrapped };
    }
    return { key: "arrived", text: "at " + to, ring: "#555555" };
  }
  if (task) return { key: "printing", text: "printing " + kind + ", to " + to + scrap,
    ring: kindColour, dashed: !!job.scrapped };
  return { key: "to", text: "to " + to, ring: C.station };
}

// [battery] runs: the charge (interpolated between battery.csv samples) and what it is doing.
function batteryAt(r, t) {
  const b = r.battery, i = b ? bisect(b.t, t) : -1;
  if (i < 0) return "";
  const j = Math.min(i + 1, b.t.length - 1), span = b.t[j] - b.t[i];
  const share = span > 0 ? b.charge[i] + (b.charge[j] - b.charge[i]) * (t - b.t[i]) / span : b.charge[i];
  const st = b.state[i] === "working" ? "" : ", " + b.state[i].replace("_", " ");
  return " [battery " + Math.round(100 * share) + " %" + st + "]";
}

function planAt(r, t) {
  const i = bisect(r.plans.sent, t);
  return i < 0 ? null : r.plans.pts[i];
}

// -- drawing a frame ---------------------------------------------------------------------------
let labels = [];  // what drawLabels drew last
let marks = [];  // the hand-back crosses drawFrame drew last

function radiusPx(r) { return Math.max(r.radius * V.scale, 4); }

// Robots close together, as groups (in robot order) that share one label. The closest pairs
// join first, and a group stops growing at MAX_GROUP_PX across, so a label names robots that
// are really together (a depot's crowd), not a chain of them across the floor.
function clusters(now) {
  const at = now.map(({ p }) => (p ? [px(p.x), py(p.y)] : null));
  const pairs = [];
  for (let i = 0; i < now.length; i++) {
    for (let j = i + 1; j < now.length; j++) {
      if (!at[i] || !at[j]) continue;
      const d = Math.hypot(at[i][0] - at[j][0], at[i][1] - at[j][1]);
      if (d < radiusPx(now[i].r) + radiusPx(now[j].r) + CLUSTER_GAP) pairs.push([d, i, j]);
    }
  }
  pairs.sort((a, b) => a[0] - b[0] || a[1] - b[1] || a[2] - b[2]);
  const group = now.map((_, i) => (at[i] ? { members: [i], x0: at[i][0], y0: at[i][1],
    x1: at[i][0], y1: at[i][1] } : null));
  for (const [, i, j] of pairs) {
    const a = group[i], b = group[j];
    if (a === b) continue;
    const x0 = Math.min(a.x0, b.x0), y0 = Math.min(a.y0, b.y0);
    const x1 = Math.max(a.x1, b.x1), y1 = Math.max(a.y1, b.y1);
    if (x1 - x0 > MAX_GROUP_PX || y1 - y0 > MAX_GROUP_PX) continue;
    Object.assign(a, { x0, y0, x1, y1 });
    for (const m of b.members) { a.members.push(m); group[m] = a; }
  }
  const groups = [...new Set(group.filter((g) => g))];
  for (const g of groups) g.members.sort((a, b) => a - b);
  groups.sort((a, b) => a.members[0] - b.members[0]);
  return groups.map((g) => g.members.map((i) => now[i]));
}

function names(ids) {
  return ids.length <= 4 ? ids.join(", ") : ids.slice(0, 3).join(", ") + " and " +
    (ids.length - 3) + " more";
}

// What a group's label may say, longest first.
function labelTexts(group) {
  const ids = group.map((n) => n.r.id);
  if (group.length === 1) return [ids[0] + ": " + group[0].s.text, ids[0]];
  const byState = new Map();
  for (const n of group) {
    if (!byState.has(n.s.text)) byState.set(n.s.text, []);
    byState.get(n.s.text).push(n.r.id);
  }
  const parts = [...byState].map(([text, who]) => names(who) + ": " + text);
  return [parts.join("; "), names(ids), group.length + " robots"];
}

// Station labels first (they move aside for robots parked at the station), then one label per
// group of robots; each is clear of all labels placed before it.
function drawLabels(now) {
  ctx.textBaseline = "middle";
  const sb = scaleBar;
  const taken = [{ x: sb.x, y: sb.y, w: sb.w, h: sb.h }];
  const soft = stationMarks.map(boxRect);
  const boxes = now.map(({ r, p }) => {
    if (!p) return null;
    const x = px(p.x), y = py(p.y), e = radiusPx(r) + 4;  // the ring and a little air
    const b = { x0: x - e, y0: y - e, x1: x + e, y1: y + e };
    soft.push(boxRect(b));
    return b;
  });
  labels = [];
  ctx.font = STATION_FONT;
  F.stations.forEach((s, i) => {
    const r = placeLabel(ctx, [s.name], stationMarks[i], taken, soft);
    if (!r) return;
    taken.push(r);
    labels.push(Object.assign(r, { kind: "station", station: s.name }));
    drawLabel(ctx, r, C.station);
  });
  ctx.font = LABEL_FONT;
  for (const group of clusters(now)) {
    const bs = group.map((n) => boxes[now.indexOf(n)]);
    const box = { x0: Math.min(...bs.map((b) => b.x0)), y0: Math.min(...bs.map((b) => b.y0)),
      x1: Math.max(...bs.map((b) => b.x1)), y1: Math.max(...bs.map((b) => b.y1)) };
    const r = placeLabel(ctx, labelTexts(group), box, taken, soft);
    if (!r) continue;
    taken.push(r);
    labels.push(Object.assign(r, { kind: "robot", robots: group.map((n) => n.r.id) }));
    drawLabel(ctx, r, "#111111");
  }
}

function drawFrame(t) {
  ctx.clearRect(0, 0, V.width, V.height);
  ctx.drawImage(background, 0, 0, V.width, V.height);
  const now = D.robots.map((r) => ({ r, p: positionAt(r, t), s: stateAt(r, t) }));
  // Planned horizons first: robots are drawn over them.
  ctx.lineWidth = 1.5;
  ctx.setLineDash([5, 3]);
  for (const { r, p } of now) {
    const pts = p && planAt(r, t);
    if (!pts) continue;
    ctx.beginPath();
    ctx.moveTo(px(p.x), py(p.y));
    let ahead = 0;
    for (let i = 0; i < pts.length; i += 3) {
      if (pts[i] <= t) continue;  // the part of the plan already lived through
      ctx.lineTo(px(pts[i + 1]), py(pts[i + 2]));
      ahead++;
    }
    if (ahead) { ctx.strokeStyle = r.colour; ctx.stroke(); }
  }
  ctx.setLineDash([]);
  for (const { r, p, s } of now) {
    if (!p) continue;
    const x = px(p.x), y = py(p.y), rad = radiusPx(r);
    ctx.beginPath(); ctx.arc(x, y, rad, 0, 2 * Math.PI);
    ctx.fillStyle = r.colour; ctx.fill();
    ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 1; ctx.stroke();
    if (s.ring) {
      ctx.beginPath(); ctx.arc(x, y, rad + 2.5, 0, 2 * Math.PI);
      ctx.setLineDash(s.dashed ? [3, 3] : []);
      ctx.strokeStyle = s.ring; ctx.lineWidth = 2; ctx.stroke();
      ctx.setLineDash([]);
    }
    if (s.key === "broken") {  // a purple cross over a broken-down robot
      const d = rad * 0.7;
      ctx.beginPath(); ctx.moveTo(x - d, y - d); ctx.lineTo(x + d, y + d);
      ctx.moveTo(x + d, y - d); ctx.lineTo(x - d, y + d);
      ctx.strokeStyle = BROKEN; ctx.lineWidth = 2.5; ctx.stroke();
    }
    const speed = Math.hypot(p.vx, p.vy);
    if (speed > 1e-3) {  // the velocity tick starts at the rim so the disk keeps its colour
      const ux = p.vx / speed, uy = -p.vy / speed, len = 5 + 12 * Math.min(1, speed / D.v_max);
      ctx.beginPath();
      ctx.moveTo(x + ux * (rad + 3.5), y + uy * (rad + 3.5));
      ctx.lineTo(x + ux * (rad + 3.5 + len), y + uy * (rad + 3.5 + len));
      ctx.strokeStyle = "#111111"; ctx.lineWidth = 2; ctx.stroke();
    }
  }
  // A red cross where each robot handed a job back, for HANDBACK_MARK_S after.
  marks = [];
  for (const { r } of now) {
    for (const a of r.handbacks) {
      if (!(a.ended <= t && t < a.ended + HANDBACK_MARK_S)) continue;
      const p = positionAt(r, a.ended);
      if (!p) continue;
      const x = px(p.x), y = py(p.y), e = Math.max(5, radiusPx(r) * 0.8);
      ctx.beginPath(); ctx.moveTo(x - e, y - e); ctx.lineTo(x + e, y + e);
      ctx.moveTo(x + e, y - e); ctx.lineTo(x - e, y + e);
      ctx.strokeStyle = "#b00000"; ctx.lineWidth = 3; ctx.stroke();
      marks.push({ robot: r.id, job: a.job, attempt: a.attempt, t: a.ended, x, y });
    }
  }
  drawLabels(now);
  return now;
}

// -- the side panel ----------------------------------------------------------------------------
document.getElementById("title").textContent = D.title;
document.title = "replay: " + D.title;
const legend = document.getElementById("legend");
function legendItem(colour, label, ring) {
  const li = el("li", { title: label });
  const sw = el("span", { class: "sw" + (ring ? " ring" : "") });
  if (ring) sw.style.borderColor = colour; else sw.style.background = colour;
  li.append(sw, document.createTextNode(label));
  legend.append(li);
}
for (const z of F.zones) legendItem(z.colour, "zone " + z.label);
if (F.obstacles.length) legendItem(C.obstacle, "obstacle");
if (F.clearance > 0) legendItem(C.clearance, "clearance (" + F.clearance + " m)");
if (F.rough.length) legendItem("repeating-linear-gradient(135deg,#fff 0 3px,#777 3px 4px)",
  "rough floor");
if (F.stations.length) legendItem(C.station, "station");
for (const k in D.kinds) legendItem(D.kinds[k], "printing " + k, true);
legendItem(C.station, "to a station", true);
legendItem("#b8860b", "waiting for print", true);
if (HANDBACKS.length) {
  legendItem("#777777", "print to be scrapped (dashed ring)", true);
  legendItem("#b00000", "handed back (red cross)");
}
if (D.robots.some((r) => r.broken && r.broken.length)) legendItem(BROKEN, "broken down", true);

const robotList = document.getElementById("robots");
const robotText = D.robots.map((r) => {
  const li = el("li");
  const sw = el("span", { class: "sw dot" });
  sw.style.background = r.colour;
  const text = el("span", {}, "");
  li.append(sw, document.createTextNode(r.id + ": "), text);
  robotList.append(li);
  return text;
});

const jobBody = document.getElementById("jobs");
const jobCount = document.getElementById("job-count");
const jobRows = D.jobs.map((j) => {
  const tr = el("tr");
  const state = el("td");
  const cell = (text) => el("td", { title: text }, text);
  tr.append(cell(j.id), cell(j.part || "-"), cell(j.station || "-"), cell(j.robot || "-"), state);
  jobBody.append(tr);
  return { j, tr, state, last: null };
});

function jobState(j, t) {
  if (j.released !== null && t < j.released) return null;
  if (j.attempts.length) {
    let last = null;
    for (const a of j.attempts) if (a.assigned <= t) last = a;
    if (!last) return ["open", "st-open"];
    if (last.ended === null || t < last.ended) {
      return [last.attempt > 1 ? "assigned (attempt " + last.attempt + ")" : "assigned",
        "st-assigned"];
    }
    const why = " (" + (last.reason || last.result) + ")";
    if (last.result === "failed") return ["failed" + why, "st-bad"];
    if (last.result === "handed_back") return ["handed back" + why, "st-open"];
  } else {
    if (j.assigned === null || t < j.assigned) return ["open", "st-open"];
    if (j.delivered === null || t < j.delivered) return ["assigned", "st-assigned"];
  }
  const late = j.due !== null && j.delivered > j.due ? ", late" : "";
  const bad = (j.outcome && j.outcome !== "good") || late;
  return ["delivered" + (j.outcome ? " (" + j.outcome + late + ")" : late ? " (late)" : ""),
    bad ? "st-bad" : "st-delivered"];
}

let states = {};  // what updatePanel showed last: robot and job states

function updatePanel(t, now) {
  states = { robots: {}, jobs: {} };
  now.forEach(({ r, s }) => { states.robots[r.id] = { key: s.key, text: s.text }; });
  now.forEach(({ r, s }, i) => {
    const text = s.text + batteryAt(r, t);
    if (robotText[i].textContent !== text) {
      robotText[i].textContent = text;
      robotText[i].className = s.key === "idle" ? "st-idle" : "st-assigned";
    }
  });
  let shown = 0, open = 0, done = 0;
  for (const row of jobRows) {
    const st = jobState(row.j, t);
    if (st) { shown++; if (st[1] === "st-open") open++; else if (st[0].startsWith("deliv")) done++; }
    if (st) states.jobs[row.j.id] = st[0];
    const key = st ? st.join("|") : "hidden";
    if (key === row.last) continue;  // touch the DOM only when a job changes state
    row.last = key;
    row.tr.style.display = st ? "" : "none";
    if (st) { row.state.textContent = row.state.title = st[0]; row.state.className = st[1]; }
  }
  jobCount.textContent = "(" + shown + " released, " + open + " open, " + done + " delivered)";
}

// -- time --------------------------------------------------------------------------------------
const FRAME_MS = 33;
let current = D.t0, playing = false, lastStamp = 0, timer = null;
slider.min = D.t0; slider.max = D.t1;

function hms(t) {
  const s = Math.floor(t), h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60);
  const pad = (v) => String(v).padStart(2, "0");
  return h + ":" + pad(m) + ":" + pad(s % 60);
}
function clock(t) { return "t = " + t.toFixed(2) + " s (" + hms(t) + ")"; }
document.getElementById("length").textContent = "of " + hms(D.t1);

function seek(t) {
  t = Number(t);
  if (!isFinite(t)) return current;
  current = Math.min(D.t1, Math.max(D.t0, t));
  slider.value = current;
  timeLabel.textContent = clock(current);
  updatePanel(current, drawFrame(current));
  return current;
}

function setPlaying(on) {
  if (on && current >= D.t1) seek(D.t0);  // Play at the end starts over
  playing = on;
  playButton.textContent = playing ? "Pause" : "Play";
  clearTimeout(timer);
  lastStamp = performance.now();
  if (playing) timer = setTimeout(step, FRAME_MS);
}

// A timer rather than requestAnimationFrame: it also runs under a headless browser's virtual
// time, where animation frames may never come.
function step() {
  if (!playing) return;
  const now = performance.now();
  seek(current + (now - lastStamp) / 1000 * Number(speedSelect.value));
  lastStamp = now;
  if (current >= D.t1) { setPlaying(false); return; }
  timer = setTimeout(step, FRAME_MS);
}

function hashTime() {
  const m = /(?:^#|&)t=([-+0-9.eE]+)/.exec(location.hash);
  return m ? Number(m[1]) : null;
}

slider.addEventListener("input", () => seek(slider.value));
playButton.addEventListener("click", () => setPlaying(!playing));
window.addEventListener("hashchange", () => { const t = hashTime(); if (t !== null) seek(t); });
window.addEventListener("resize", () => { layout(); seek(current); });
document.addEventListener("keydown", (e) => {
  if (e.key === " " && e.target === document.body) { e.preventDefault(); setPlaying(!playing); }
});

// For scripts and tests: copies, so a caller cannot change what the page draws.
const copy = (v) => JSON.parse(JSON.stringify(v));
window.replaySeek = seek;
window.replayTime = () => current;
window.replayView = () => copy(V);
window.replayLabels = () => copy(labels);
window.replayScaleBar = () => copy(scaleBar);
window.replayStates = () => copy(states);
window.replayHandbacks = () => copy(marks);
layout();
const start = hashTime();
seek(start === null ? D.t0 : start);
})();
