// edge-ips dashboard: no build step, no dependencies. Poses and status arrive by server-sent events; camera frames
// are fetched one at a time as JPEG (the server caps the rate), overlays are drawn here, not on the camera board.
"use strict";

const TRAIL = 90;                 // points kept per rover trail (6 s at the default 15 pose events/s)
const state = { info: null, rovers: new Map(), formation: null, frameSize: [1280, 720], lastPose: null,
  reports: new Map(), lastStatus: null };
const $ = (id) => document.getElementById(id);

// The dashboard token: taken from the address (?token=..., then removed from it) and kept for this tab's session.
// fetch sends it as a bearer token; EventSource and <img> cannot send headers, so they carry ?token=.
const TOKEN_KEY = "edge-ips-token";
let viewToken = initialToken();

function initialToken() {
  const url = new URL(location.href);
  const given = url.searchParams.get("token");
  if (given !== null) {
    sessionStorage.setItem(TOKEN_KEY, given);
    url.searchParams.delete("token");
    history.replaceState(null, "", url.pathname + url.search + url.hash);
  }
  return sessionStorage.getItem(TOKEN_KEY) || "";
}

function withToken(path) {
  if (!viewToken) return path;
  return `${path}${path.includes("?") ? "&" : "?"}token=${encodeURIComponent(viewToken)}`;
}

function bearer(token) {
  return token ? { Authorization: `Bearer ${token}` } : {};
}

function colorOf(id) {
  const r = state.info && state.info.rovers.find((x) => x.id === id);
  return r ? r.color : "#cccccc";
}

async function loadState() {
  const res = await fetch("api/state", { headers: bearer(viewToken) });
  if (!res.ok) {
    const out = await res.json().catch(() => ({ error: res.statusText }));
    $("formation-result").textContent = `${out.error || res.status}: enter the dashboard token`;
    $("formation-result").dataset.status = String(res.status);
    return false;
  }
  state.info = await res.json();
  state.frameSize = [state.info.image.width, state.info.image.height];
  state.formation = state.info.formation;
  $("edge-id").textContent = state.info.edge_id;
  $("formation-rovers").value = state.info.rovers.map((r) => r.id).join(",");
  const enabled = state.info.formation_enabled;
  for (const b of document.querySelectorAll("#formation-form button")) b.disabled = !enabled;
  $("formation-result").textContent = enabled ? "" : "formation controls are disabled: no dashboard token is configured";
  const c = state.info.calibration;
  if (c && c.exact) {
    $("calibration-info").textContent = `(${c.note})`;
  } else if (c && c.mean_cm != null) {
    $("calibration-info").textContent = `${c.method}: predicted 95% error mean ${c.mean_cm.toFixed(2)} cm, max ${c.max_cm.toFixed(2)} cm`;
  } else {
    $("calibration-info").textContent = c ? `(${c.note || c.method})` : "(no calibration known)";
  }
  $("errormap").src = withToken("api/errormap.png");
  showFormation();
  return true;
}

// -- camera ----------------------------------------------------------------------------------------------------------
let frameCount = 0;
function nextFrame() {
  const img = $("camera");
  const url = withToken(`api/frame.jpg?n=${frameCount++}`);
  img.onload = () => { drawCameraOverlay(); setTimeout(nextFrame, 0); };
  img.onerror = () => setTimeout(nextFrame, 1000);
  img.src = url;
}

function drawCameraOverlay() {
  const img = $("camera"), cv = $("camera-overlay");
  const w = img.clientWidth, h = img.clientHeight;
  if (!w || !h) return;
  cv.width = w; cv.height = h;
  const ctx = cv.getContext("2d");
  const sx = w / state.frameSize[0], sy = h / state.frameSize[1];
  ctx.clearRect(0, 0, w, h);
  if (state.info && state.info.area_px) {
    ctx.strokeStyle = "rgba(255,255,0,0.7)"; ctx.lineWidth = 1.5; ctx.beginPath();
    state.info.area_px.forEach(([u, v], i) => (i ? ctx.lineTo(u * sx, v * sy) : ctx.moveTo(u * sx, v * sy)));
    ctx.closePath(); ctx.stroke();
  }
  for (const [id, r] of state.rovers) {
    if (!r.last || r.missing) continue;
    const col = colorOf(id);
    ctx.strokeStyle = col; ctx.fillStyle = col; ctx.lineWidth = 2;
    ctx.beginPath();
    r.trailPx.forEach(([u, v], i) => (i ? ctx.lineTo(u * sx, v * sy) : ctx.moveTo(u * sx, v * sy)));
    ctx.stroke();
    const p = r.last;
    if (p.outline && p.outline.length > 2) {
      ctx.beginPath();
      p.outline.forEach(([u, v], i) => (i ? ctx.lineTo(u * sx, v * sy) : ctx.moveTo(u * sx, v * sy)));
      ctx.closePath(); ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 1.5; ctx.stroke();
      ctx.strokeStyle = col; ctx.lineWidth = 2;
    } else {
      ctx.beginPath(); ctx.arc(p.u * sx, p.v * sy, 12, 0, 2 * Math.PI); ctx.stroke();
    }
    if (p.head_u != null) {
      arrow(ctx, p.u * sx, p.v * sy, p.head_u * sx, p.head_v * sy);
    }
    ctx.font = "bold 13px sans-serif"; ctx.fillStyle = "#ffffff";
    ctx.fillText(id, p.u * sx + 14, p.v * sy - 10);
  }
}

function arrow(ctx, x0, y0, x1, y1) {
  const a = Math.atan2(y1 - y0, x1 - x0), l = 7;
  ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x1, y1);
  ctx.lineTo(x1 - l * Math.cos(a - 0.4), y1 - l * Math.sin(a - 0.4));
  ctx.moveTo(x1, y1); ctx.lineTo(x1 - l * Math.cos(a + 0.4), y1 - l * Math.sin(a + 0.4));
  ctx.stroke();
}

// -- map -------------------------------------------------------------------------------------------------------------
function drawMap() {
  const cv = $("map");
  if (!state.info) return;
  const W = state.info.area.width_cm, L = state.info.area.length_cm, m = 30;
  const x0 = state.info.area.x0_cm || 0, y0 = state.info.area.y0_cm || 0;
  const w = cv.clientWidth || 400;
  const scale = (w - 2 * m) / W;
  const h = Math.round(L * scale + 2 * m);
  if (cv.width !== w || cv.height !== h) { cv.width = w; cv.height = h; }
  const ctx = cv.getContext("2d");
  const X = (x) => m + (x - x0) * scale, Y = (y) => h - m - (y - y0) * scale;
  ctx.clearRect(0, 0, w, h);
  ctx.strokeStyle = "#223038"; ctx.lineWidth = 1;
  const x1 = x0 + W, y1 = y0 + L;
  for (let x = x0; x <= x1; x += 50) { ctx.beginPath(); ctx.moveTo(X(x), Y(y0)); ctx.lineTo(X(x), Y(y1)); ctx.stroke(); }
  for (let y = y0; y <= y1; y += 50) { ctx.beginPath(); ctx.moveTo(X(x0), Y(y)); ctx.lineTo(X(x1), Y(y)); ctx.stroke(); }
  ctx.strokeStyle = "#e0c341"; ctx.lineWidth = 2; ctx.strokeRect(X(x0), Y(y1), W * scale, L * scale);
  ctx.fillStyle = "#8a96a3"; ctx.font = "11px sans-serif";
  ctx.fillText(`(${x0}, ${y0})`, X(x0) - 10, Y(y0) + 14); ctx.fillText(`(${x1}, ${y1})`, X(x1) - 60, Y(y1) - 6);
  drawFormationTarget(ctx, X, Y, scale);
  for (const [id, r] of state.rovers) {
    const col = colorOf(id);
    ctx.strokeStyle = col; ctx.globalAlpha = 0.6; ctx.lineWidth = 1.5; ctx.beginPath();
    r.trail.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    ctx.stroke(); ctx.globalAlpha = 1;
    if (!r.last) continue;
    const p = r.last;
    ctx.fillStyle = r.missing ? "#555" : col;
    ctx.beginPath(); ctx.arc(X(p.x), Y(p.y), Math.max(4, 9 * scale), 0, 2 * Math.PI); ctx.fill();
    if (p.theta != null) {
      ctx.strokeStyle = "#ffffff"; ctx.lineWidth = 2;
      arrow(ctx, X(p.x), Y(p.y), X(p.x + 25 * Math.cos(p.theta)), Y(p.y + 25 * Math.sin(p.theta)));
    }
    ctx.fillStyle = "#ffffff"; ctx.font = "bold 12px sans-serif";
    ctx.fillText(id, X(p.x) + 10, Y(p.y) - 8);
  }
}

function drawFormationTarget(ctx, X, Y, scale) {
  // The targets come with each pose event, computed on the board by the firmware's own formation code from where
  // the rovers are: the shape is drawn turned and mirrored as the rovers will form it.
  const f = state.formation, t = state.lastPose && state.lastPose.targets;
  if (!f || f.kind === "stop" || !t || !t.length) return;
  ctx.strokeStyle = "rgba(255, 215, 0, 0.8)"; ctx.fillStyle = "rgba(255, 215, 0, 0.15)"; ctx.lineWidth = 2;
  ctx.setLineDash([6, 4]);
  ctx.beginPath();
  t.forEach((p, k) => (k ? ctx.lineTo(X(p.x), Y(p.y)) : ctx.moveTo(X(p.x), Y(p.y))));
  if (f.kind !== "line" && t.length > 2) { ctx.closePath(); ctx.fill(); }
  ctx.stroke();
  ctx.setLineDash([]);
  for (const p of t) {
    ctx.strokeStyle = colorOf(p.id);
    ctx.beginPath(); ctx.arc(X(p.x), Y(p.y), Math.max(5, 7 * scale), 0, 2 * Math.PI); ctx.stroke();
  }
}

// -- rovers table ----------------------------------------------------------------------------------------------------
// The last two columns are what each rover itself reports (its retained status): its halt reason and the formation it
// applies, flagged when that is not the broker's retained command.
function reportCells(id) {
  const r = state.reports.get(id);
  if (!r || !r.reported) return `<td class="halt" data-halt="">no status</td><td class="applies">–</td>`;
  const halt = r.state === "offline" ? "offline" : r.halt;
  const applies = r.formation ? `${r.formation} (seq ${r.seq})` : "none";
  const off = r.formation && !r.on_retained ? " off-retained" : "";
  const title = off ? ` title="not the broker's retained command"` : "";
  return `<td class="halt" data-halt="${halt}">${halt}</td><td class="applies${off}"${title}>${applies}</td>`;
}

function renderTable(status) {
  const body = document.querySelector("#rovers tbody");
  const ids = state.info ? state.info.rovers.map((r) => r.id) : [...state.rovers.keys()];
  const rows = ids.map((id) => {
    const r = state.rovers.get(id), p = r && r.last, s = status && status.rovers ? status.rovers[id] : null;
    const fmt = (v, d) => (v == null ? "–" : v.toFixed(d));
    const speed = p && p.vx != null ? Math.hypot(p.vx, p.vy) : null;
    const heading = p && p.theta != null ? `${((p.theta * 180) / Math.PI).toFixed(0)}°` : "–";
    const missing = !r || r.missing;
    return `<tr data-rover="${id}" class="${missing ? "missing" : ""}"><td><span class="swatch" style="background:${colorOf(id)}"></span>${id}</td>` +
      `<td>${fmt(p && p.x, 1)}</td><td>${fmt(p && p.y, 1)}</td><td>${heading}</td><td>${fmt(speed, 1)}</td>` +
      `<td>${fmt(p && p.q, 2)}</td><td>${s ? s.rate_hz.toFixed(1) + " Hz" : "–"}</td>` +
      `<td>${s && s.last_seen_s != null ? s.last_seen_s.toFixed(1) + " s ago" : missing ? "missing" : "–"}</td>` +
      `${reportCells(id)}</tr>`;
  });
  body.innerHTML = rows.join("");
}

// -- events ----------------------------------------------------------------------------------------------------------
function onPose(msg) {
  state.lastPose = msg;
  $("frame-info").textContent = `frame ${msg.frame}`;
  for (const p of msg.rovers) {
    let r = state.rovers.get(p.id);
    if (!r) { r = { trail: [], trailPx: [], last: null, missing: false }; state.rovers.set(p.id, r); }
    r.last = p; r.missing = false;
    r.trail.push([p.x, p.y]); if (r.trail.length > TRAIL) r.trail.shift();
    r.trailPx.push([p.u, p.v]); if (r.trailPx.length > TRAIL) r.trailPx.shift();
  }
  for (const id of msg.missing) {
    const r = state.rovers.get(id);
    if (r) r.missing = true; else state.rovers.set(id, { trail: [], trailPx: [], last: null, missing: true });
  }
  drawMap();
  drawCameraOverlay();
}

function pill(el, text, cls) { el.textContent = text; el.className = `pill ${cls}`; }

function onStatus(s) {
  pill($("pill-state"), s.state, s.state === "online" ? "ok" : s.state === "degraded" ? "warn" : "bad");
  pill($("pill-camera"), `camera ${s.camera}`, s.camera === "ok" ? "ok" : "warn");
  pill($("pill-broker"), `broker ${s.broker}`, s.broker === "connected" ? "ok" : "bad");
  $("fps").textContent = s.fps.toFixed(1);
  $("lat-p50").textContent = s.latency_ms && s.latency_ms.p50 != null ? s.latency_ms.p50.toFixed(1) : "–";
  $("lat-p99").textContent = s.latency_ms && s.latency_ms.p99 != null ? s.latency_ms.p99.toFixed(1) : "–";
  state.lastStatus = s;
  renderTable(s);
}

function showFormation() {
  const f = state.formation;
  $("formation-current").textContent = f ? `${f.kind} (${f.ids.join(", ")}), seq ${f.seq}` : "none";
  drawMap();
}

function connectEvents() {
  const es = new EventSource(withToken("api/events"));
  es.addEventListener("pose", (e) => onPose(JSON.parse(e.data)));
  es.addEventListener("status", (e) => onStatus(JSON.parse(e.data)));
  es.addEventListener("formation", (e) => { state.formation = JSON.parse(e.data); showFormation(); });
  es.addEventListener("rovers", (e) => {
    state.reports = new Map(JSON.parse(e.data).rovers.map((r) => [r.id, r]));
    renderTable(state.lastStatus);
  });
  es.onerror = () => pill($("pill-state"), "disconnected", "bad");
}

// -- formation controls ----------------------------------------------------------------------------------------------
async function sendFormation(kind) {
  const ids = $("formation-rovers").value.split(",").map((s) => s.trim()).filter(Boolean);
  const body = { kind, ids, spacing: Number($("spacing").value), side: Number($("side").value) };
  // The STOP has its own route: with the right token it goes through even from an address locked out for wrong
  // tokens (a tab left open with an old token would otherwise keep this machine's STOP refused).
  const res = await fetch(kind === "stop" ? "api/stop" : "api/formation", {
    method: "POST",
    headers: { "Content-Type": "application/json", ...bearer($("token").value.trim()) },
    body: JSON.stringify(body),
  });
  const out = await res.json().catch(() => ({ error: res.statusText }));
  $("formation-result").textContent = res.ok ? `published ${kind} (seq ${out.seq})` : `refused: ${out.error || res.status}`;
  $("formation-result").dataset.status = String(res.status);
}

for (const b of document.querySelectorAll("#formation-form button")) {
  b.addEventListener("click", () => sendFormation(b.dataset.kind));
}
window.addEventListener("resize", () => { drawMap(); drawCameraOverlay(); });

async function start() {
  $("token").value = viewToken;
  if (await loadState()) {
    connectEvents(); nextFrame(); drawMap();
    return;
  }
  $("token").addEventListener("change", () => {  // a token typed in: try again with it
    viewToken = $("token").value.trim();
    sessionStorage.setItem(TOKEN_KEY, viewToken);
    start();
  }, { once: true });
}

start();
