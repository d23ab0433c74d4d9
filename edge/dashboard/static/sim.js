// edge-ips dashboard, simulator panel: shown only when the frame source is the twin's lab (GET api/sim answers).
// Scatter the rovers, cause a fault, and see what the lab's ground truth says the rovers do (moving or at rest, how
// long each took to stop after a fault) beside what the camera and the rovers' own statuses say on the left.
"use strict";

const sim = { lastEvent: 0, rovers: [] };

function simEventClass(e) {
  if (e.text.startsWith("fault")) return "fault";
  if (e.text.includes("at rest")) return "rest";
  return "";
}

function renderSim(info) {
  sim.rovers = info.rovers.map((r) => r.id);
  const select = $("fault-rover");
  if (select.options.length !== sim.rovers.length) {
    select.innerHTML = sim.rovers.map((id) => `<option value="${id}">${id}</option>`).join("");
  }
  for (const opt of $("fault-kind").options) opt.disabled = !info.offered.includes(opt.value);
  const body = document.querySelector("#sim-rovers tbody");
  body.innerHTML = info.rovers.map((r) => {
    const wifi = info.active.some((f) => f.kind === "wifi" && f.rover === r.id);
    return `<tr data-rover="${r.id}"><td><span class="swatch" style="background:${colorOf(r.id)}"></span>${r.id}</td>` +
      `<td>${wifi ? "down" : "up"}</td><td>${r.connected ? "connected" : r.switched_on ? "not connected" : "off"}</td>` +
      `<td class="${r.moving ? "moving" : "still"}" data-moving="${r.moving}">${r.moving ? `moving ${r.speed_cm_s} cm/s` : "at rest"}</td></tr>`;
  }).join("");
  const list = $("sim-events");
  for (const e of info.events) {
    if (e.n <= sim.lastEvent) continue;
    sim.lastEvent = e.n;
    const li = document.createElement("li");
    li.className = simEventClass(e);
    li.textContent = `${new Date(e.t * 1000).toLocaleTimeString()} ${e.who}: ${e.text}`;
    list.prepend(li);
  }
  while (list.children.length > 200) list.lastChild.remove();
}

async function pollSim() {
  const res = await fetch(`api/sim?after=${sim.lastEvent}`, { headers: bearer(viewToken) }).catch(() => null);
  if (res && res.ok) {
    const info = await res.json();
    $("sim-panel").hidden = false;
    for (const b of document.querySelectorAll("#sim-form button")) b.disabled = !info.controls_enabled;
    renderSim(info);
  } else if (res && res.status === 404) {
    // Not a simulated lab, or not yet: the page can load while the appliance is still starting (start prints the
    // address first), before the panel's route exists. Ask again now and then; the panel stays hidden meanwhile.
    setTimeout(pollSim, 5000);
    return;
  }
  setTimeout(pollSim, 1000);
}

async function simPost(path, body) {
  const res = await fetch(path, {
    method: "POST",
    headers: { "Content-Type": "application/json", ...bearer($("token").value.trim()) },
    body: JSON.stringify(body),
  });
  const out = await res.json().catch(() => ({ error: res.statusText }));
  $("sim-result").textContent = res.ok ? (out.done || "scattered") : `refused: ${out.error || res.status}`;
  $("sim-result").dataset.status = String(res.status);
}

$("scatter").addEventListener("click", () => simPost("api/sim/scatter", {}));
$("fault").addEventListener("click", () => {
  const kind = $("fault-kind").value;
  const body = { kind, seconds: Number($("fault-seconds").value) };
  if (kind === "wifi") body.rover = $("fault-rover").value;
  simPost("api/sim/fault", body);
});
$("fault-kind").addEventListener("change", () => {
  $("fault-rover-label").hidden = $("fault-kind").value !== "wifi";
});

pollSim();
