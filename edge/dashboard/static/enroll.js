// edge-ips dashboard: enroll the rovers in view (their marker colours as this camera sees them). Loaded after app.js,
// whose $, bearer, withToken and viewToken it uses; commands carry the token typed into the formation form.
// The board measures (edge/dashboard/enrolment.py); this file only asks and shows.
"use strict";

const enrolling = { status: null, result: null, pending: null };

function enrollSay(text, status, kind) {
  const el = $("enroll-message");
  el.textContent = text;
  el.dataset.status = String(status);
  el.className = kind || "muted";
}

async function enrollCall(method, path, body) {
  const headers = { "Content-Type": "application/json", ...bearer($("token").value.trim()) };
  const res = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const out = await res.json().catch(() => ({ error: res.statusText }));
  return { status: res.status, ok: res.ok, out };
}

async function refreshEnroll() {
  clearTimeout(enrolling.pending);
  const res = await fetch("api/enroll", { headers: bearer(viewToken) });
  if (!res.ok) return;  // no viewing token yet: the page asks for it
  enrolling.status = await res.json();
  showEnrollStatus();
}

function showEnrollStatus() {
  const s = enrolling.status;
  for (const b of document.querySelectorAll("#enroll-form button")) b.disabled = !s.enabled;
  const img = $("enroll-floor-image");
  if (s.floor) {
    const when = new Date(s.floor.t * 1000).toLocaleTimeString();
    $("enroll-floor").textContent = `captured at ${when} (frame ${s.floor.frame})`;
    img.src = withToken(`api/enroll/floor.jpg?frame=${s.floor.frame}`);
    img.hidden = false;
  } else {
    img.hidden = true;
    const m = s.tracker_model;
    const ready = m && m.ready;  // the server's own test: the share it sends is rounded
    $("enroll-floor").textContent = !m ? "not captured"
      : `not captured: the tracker's background model is used for the rovers it tracks (${(100 * m.known).toFixed(1)} % of the floor seen${ready ? "" : ", not ready"})`;
    $("enroll-floor").dataset.ready = String(Boolean(ready));
    if (m && !ready) enrolling.pending = setTimeout(refreshEnroll, 2000);  // it learns the floor as the rovers move
  }
  $("enroll-forget").disabled = !s.enabled || !s.floor;
  const save = $("enroll-save");
  save.hidden = !s.rovers_file;
  save.textContent = `save to ${s.rovers_file}`;
  save.disabled = !s.enabled || !enrolling.result;
  if (!s.enabled) enrollSay(s.reason, 403, "muted");
}

async function captureFloor() {
  enrollSay("capturing the empty floor...", 0);
  const r = await enrollCall("POST", "api/enroll/floor", {});
  if (!r.ok) { enrollSay(`refused: ${r.out.error}`, r.status, "bad"); return; }
  const warned = r.out.warnings.length ? ` WARNING: ${r.out.warnings.join("; ")}` : "";
  enrollSay(`empty floor captured (frame ${r.out.floor.frame}); now place the rovers and enroll.${warned}`, r.status, warned ? "bad" : "ok");
  await refreshEnroll();
}

async function forgetFloor() {
  const r = await enrollCall("DELETE", "api/enroll/floor");
  enrollSay(r.ok ? "captured floor forgotten" : `refused: ${r.out.error}`, r.status, r.ok ? "muted" : "bad");
  await refreshEnroll();
}

async function enrollNow() {
  const ids = $("enroll-ids").value.split(",").map((s) => s.trim()).filter(Boolean);
  enrollSay("enrolling the rovers in view...", 0);
  const r = await enrollCall("POST", "api/enroll", ids.length ? { ids } : {});
  if (!r.ok) {
    enrollSay(`not enrolled: ${r.out.error}`, r.status, "bad");
    return;
  }
  enrolling.result = r.out;
  showEnrolment(r.out);
  const against = r.out.background.kind === "floor" ? "the captured floor" : "the tracker's background model";
  enrollSay(`enrolled ${r.out.markers.length} rovers from frame ${r.out.frame} against ${against}`, r.status, "ok");
  showEnrollStatus();
}

function swatch(color) {
  return `<span class="swatch" style="background:${color}"></span>`;
}

function escapeText(text) {
  const d = document.createElement("div");
  d.textContent = text;
  return d.innerHTML;
}

function showEnrolment(res) {
  const rows = res.markers.map((m) =>
    `<tr data-rover="${m.id}"><td>${swatch(m.color)}${m.id}</td><td>${m.color_bgr.join(", ")}</td>` +
    `<td>${m.hue_deg.toFixed(0)}° ±${m.spread_deg.toFixed(0)}</td>` +
    `<td>${m.length_cm.toFixed(1)} x ${m.width_cm.toFixed(1)}</td>` +
    `<td>${m.front ? `${swatch(m.front.color)}${m.front.fraction}` : "–"}</td>` +
    `<td>${m.x_cm.toFixed(0)}, ${m.y_cm.toFixed(0)}</td><td>${m.tracked_as || "–"}</td></tr>`);
  document.querySelector("#enroll-table tbody").innerHTML = rows.join("");
  $("enroll-warnings").innerHTML = res.warnings.map((w) => `<li>${escapeText(w)}</li>`).join("");
  $("enroll-ignored").innerHTML = res.ignored.map((w) => `<li>ignored: ${escapeText(w)}</li>`).join("");
  $("enroll-toml").textContent = res.toml;
  const link = $("enroll-download");
  if (link.href.startsWith("blob:")) URL.revokeObjectURL(link.href);
  link.href = URL.createObjectURL(new Blob([res.toml], { type: "application/toml" }));
  $("enroll-result").hidden = false;
  drawEnrolled();
}

// The enrolled markers on the camera view, where they were in the enrolled frame: which rover got which id.
function drawEnrolled() {
  const img = $("camera"), cv = $("enroll-overlay"), res = enrolling.result;
  const w = img.clientWidth, h = img.clientHeight;
  if (!res || !w || !h) return;
  cv.width = w; cv.height = h;
  const ctx = cv.getContext("2d");
  const sx = w / res.image.width, sy = h / res.image.height;
  ctx.font = "bold 13px sans-serif"; ctx.lineWidth = 2; ctx.setLineDash([4, 3]);
  for (const m of res.markers) {
    ctx.strokeStyle = "#ffffff";
    ctx.beginPath(); ctx.arc(m.u_px * sx, m.v_px * sy, 18, 0, 2 * Math.PI); ctx.stroke();
    ctx.fillStyle = m.color;
    ctx.fillText(`${m.id} (enrolled)`, m.u_px * sx + 20, m.v_px * sy + 18);
  }
}

async function saveEnrolment(replace) {
  const r = await enrollCall("POST", "api/enroll/save", { enrolment: enrolling.result.enrolment, replace });
  if (r.status === 409 && r.out.exists && !replace) {
    if (confirm(`${r.out.error} It holds the rovers enrolled before.`)) return saveEnrolment(true);
    enrollSay("not saved: the existing file was kept", r.status, "muted");
    return;
  }
  if (!r.ok) { enrollSay(`not saved: ${r.out.error}`, r.status, "bad"); return; }
  const how = r.out.replaced ? "replaced" : "written";
  enrollSay(`${r.out.saved} ${how} (${r.out.rovers.join(", ")}): it takes effect at the next start`, r.status, "ok");
  await refreshEnroll();
}

$("enroll-capture").addEventListener("click", captureFloor);
$("enroll-forget").addEventListener("click", forgetFloor);
$("enroll-run").addEventListener("click", enrollNow);
$("enroll-save").addEventListener("click", () => saveEnrolment(false));
$("token").addEventListener("change", () => setTimeout(refreshEnroll, 0));  // after app.js has taken the token
window.addEventListener("resize", drawEnrolled);
refreshEnroll();
