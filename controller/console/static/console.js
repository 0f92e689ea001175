// heliocal field console: shared helpers (no framework, no CDN).
"use strict";
const HC = {};
HC.token = () => sessionStorage.getItem("heliocal-token") || "";
HC.get = async (path) => {
  const r = await fetch(path, {cache: "no-store"});
  const data = await r.json();
  if (!r.ok) throw new Error(data.error || r.statusText);
  return data;
};
// Every state change is a POST with a JSON body (and the token when the console needs one).
// With operator accounts the token is the signed-in account's session (the Sign-in page).
HC.post = async (path, body) => {
  const headers = {"Content-Type": "application/json"};
  if (HC.plant && HC.plant.accounts && !HC.token() && path !== "/api/login") {
    location.href = "/login?next=" + encodeURIComponent(location.pathname);
    throw new Error("sign in first");
  }
  if (HC.plant && HC.plant.token_required && !HC.plant.accounts && !HC.token()) {
    sessionStorage.setItem("heliocal-token", prompt("Console token (X-Heliocal-Token):") || "");
  }
  if (HC.token()) headers["X-Heliocal-Token"] = HC.token();
  const r = await fetch(path, {method: "POST", headers, body: JSON.stringify(body || {})});
  const data = await r.json();
  if (r.status === 401) sessionStorage.removeItem("heliocal-token");
  if (!r.ok) { const e = new Error(data.error || r.statusText); e.data = data; throw e; }
  return data;
};
HC.fmt = (v, nd = 2) => (v === null || v === undefined) ? "–" : (typeof v === "number" ? v.toFixed(nd) : String(v));
HC.esc = (s) => String(s).replace(/[&<>"]/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;"}[c]));
HC.msg = (el, text, ok) => { el.textContent = text; el.className = "msg " + (ok ? "ok" : "err"); };
HC.driveText = (st) => !st ? "no reading" :
  `az ${st.az_steps} el ${st.el_steps} steps` + (st.moving ? " (moving)" : st.in_position ? " (in position)" : "");
HC.faultPill = (st, link) => {
  if (link && !link.ok) return `<span class="pill bad">link: ${HC.esc(link.last_error || "no reading")}</span>`;
  if (st && st.faults && st.faults.length) return `<span class="pill bad">${HC.esc(st.faults.join(", "))}</span>`;
  return st ? (st.moving ? '<span class="pill busy">moving</span>' : '<span class="pill good">ok</span>') : "";
};
// Header with navigation, the plant's name and the live-connection indicator.
HC.init = async (here) => {
  HC.plant = await HC.get("/api/plant");
  const nav = [["field", "/field", "Field"], ["commission", "/commission/" + HC.plant.heliostats[0].id, "Commission"],
               ["campaign", "/campaign", "Campaign"], ["reports", "/reports", "Reports"],
               ["alarms", "/alarms", "Alarms"], ["audit", "/audit", "Audit"]];
  document.querySelector("header").innerHTML = `<b>heliocal console</b><nav>` +
    nav.map(([k, href, t]) => `<a href="${href}" class="${k === here ? "here" : ""}">${t}</a>`).join("") +
    `</nav><span class="plant">${HC.esc(HC.plant.site)} · ${HC.esc(HC.plant.plant)}</span>` +
    `<span id="who"></span><span id="live">offline</span>`;
  document.querySelector("header").insertAdjacentHTML("afterend", '<div id="alarm-banner" style="display:none"></div>');
  HC.whoami();
  HC.banner();
  return HC.plant;
};
// Who is signed in (with accounts), and a way out.
HC.whoami = async () => {
  const headers = HC.token() ? {"X-Heliocal-Token": HC.token()} : {};
  const r = await fetch("/api/whoami", {cache: "no-store", headers});
  const w = await r.json();
  const el = document.getElementById("who");
  if (!w.accounts) return;
  el.innerHTML = w.user ? `${HC.esc(w.user)} (${HC.esc(w.role)}) <a href="#" id="sign-out">sign out</a>`
    : `<a href="/login?next=${encodeURIComponent(location.pathname)}">sign in</a>`;
  const out = document.getElementById("sign-out");
  if (out) out.onclick = async (ev) => { ev.preventDefault(); await HC.post("/api/logout").catch(() => null);
    sessionStorage.removeItem("heliocal-token"); location.reload(); };
};
// The alarm banner on every page: the alarms not acknowledged and not shelved, most urgent first.
HC.banner = async () => {
  const el = document.getElementById("alarm-banner");
  if (!el) return;
  const data = await HC.get("/api/alarms");
  const open = data.alarms.filter((a) => a.state === "unack_active" || a.state === "unack_rtn");
  el.style.display = open.length ? "" : "none";
  el.className = open.some((a) => a.priority === "high") ? "high" : "";
  el.innerHTML = open.length ? `<b>${open.length} alarm${open.length > 1 ? "s" : ""} to acknowledge</b>: ` +
    open.slice(0, 3).map((a) => `${HC.esc(a.priority)} ${HC.esc(a.condition)} ${HC.esc(a.source)}`).join("; ") +
    (open.length > 3 ? " …" : "") + ` <a href="/alarms">alarm list</a>` : "";
};
// Server-sent events: handlers by event name; the indicator shows whether the stream is up.
HC.listen = (handlers) => {
  const es = new EventSource("/api/events");
  const live = () => document.getElementById("live");
  es.onopen = () => { const l = live(); if (l) { l.textContent = "live"; l.className = "on"; } if (handlers.open) handlers.open(); };
  es.onerror = () => { const l = live(); if (l) { l.textContent = "reconnecting"; l.className = ""; } };
  for (const [name, fn] of Object.entries(handlers)) {
    if (name !== "open") es.addEventListener(name, (ev) => fn(JSON.parse(ev.data)));
  }
  if (!handlers.alarms) es.addEventListener("alarms", () => HC.banner());
  return es;
};
// Coalesce bursts of events into one refresh per animation frame.
HC.throttle = (fn) => { let queued = false; return () => { if (!queued) { queued = true; requestAnimationFrame(() => { queued = false; fn(); }); } }; };
// The heliostat id in /heliostat/H or /commission/H.
HC.hid = () => decodeURIComponent(location.pathname.split("/").pop());
// Drive status as key/value rows (steps, targets, limits, faults, link health).
HC.driveKV = (d) => {
  const st = d.status, l = d.link;
  const row = (k, v) => `<span>${k}</span><span>${v}</span>`;
  return row("azimuth", st ? `<b id="az-steps">${st.az_steps}</b> steps (target ${st.az_target})` : "–") +
    row("elevation", st ? `<b id="el-steps">${st.el_steps}</b> steps (target ${st.el_target})` : "–") +
    row("motion", st ? (st.moving ? "moving" : st.in_position ? "in position" : "stopped") : "–") +
    row("limit switches", st ? `az ${st.limit_az ? "HIT" : "clear"}, el ${st.limit_el ? "HIT" : "clear"}` : "–") +
    row("faults", st ? (st.faults.length ? `<span class="pill bad">${HC.esc(st.faults.join(", "))}</span>` : "none") : "–") +
    row("link", l.ok ? `<span class="pill good">ok</span> ${l.polls} readings, last ${HC.fmt(l.age_s, 1)} s ago`
      : `<span class="pill bad">${HC.esc(l.last_error || "no reading yet")}</span> (${l.failures_in_a_row} failures in a row)`) +
    (d.limits ? row("soft limits", `az ${d.limits.az[0]} … ${d.limits.az[1]}, el ${d.limits.el[0]} … ${d.limits.el[1]}`) : "");
};
// One step on a heliostat; shows the outcome (a refusal in red) in msgEl.
HC.step = async (hid, step, body, msgEl) => {
  HC.msg(msgEl, `${step} …`, true);
  try {
    const r = await HC.post(`/api/heliostats/${encodeURIComponent(hid)}/${step}`, body);
    HC.msg(msgEl, `${step}: done`, true);
    return r.result;
  } catch (e) {
    const d = e.data || {};
    const why = d.kind === "soft_limits" ? "refused by the controller (soft limits), nothing sent"
      : d.kind === "firmware_refused" ? "refused by the firmware" : d.kind || "error";
    HC.msg(msgEl, `${step}: ${why}: ${e.message}`, false);
    return null;
  }
};
// Jog / move / park / stow / stop controls into el.
HC.controls = (el, hid, msgEl, after) => {
  el.innerHTML = `<div>jog by <input type="number" id="jog-n" value="200" min="1"> steps:
    <button data-j="1,0">az +</button> <button data-j="-1,0">az −</button>
    <button data-j="0,1">el +</button> <button data-j="0,-1">el −</button></div>
    <div style="margin-top:6px">move to az <input type="number" id="move-az"> el <input type="number" id="move-el">
    <button id="move-go" class="go">move</button></div>
    <div style="margin-top:6px"><button id="park">park (standby)</button> <button id="stow">stow</button>
    <button id="stop" class="warn">stop</button> <button id="clear">clear fault</button></div>`;
  const run = async (step, body) => { el.querySelectorAll("button").forEach((b) => b.disabled = true);
    const r = await HC.step(hid, step, body, msgEl); el.querySelectorAll("button").forEach((b) => b.disabled = false);
    if (after) after(step, r); };
  el.querySelectorAll("button[data-j]").forEach((b) => b.onclick = () => {
    const n = parseInt(document.getElementById("jog-n").value, 10) || 0;
    const [a, e] = b.dataset.j.split(",").map(Number);
    run("jog", {az_steps: a * n, el_steps: e * n});
  });
  document.getElementById("move-go").onclick = () => run("move", {
    az_steps: parseInt(document.getElementById("move-az").value, 10),
    el_steps: parseInt(document.getElementById("move-el").value, 10)});
  document.getElementById("park").onclick = () => run("park", {});
  document.getElementById("stow").onclick = () => run("stow", {});
  document.getElementById("stop").onclick = () => run("stop", {});
  document.getElementById("clear").onclick = () => run("clear_fault", {});
};
HC.reloadImage = (img, hid) => {
  const probe = new Image();
  probe.onload = () => { img.src = probe.src; img.style.display = ""; img.nextElementSibling.textContent = ""; };
  probe.onerror = () => { img.style.display = "none"; img.nextElementSibling.textContent = "no beam image yet (capture one, or run a campaign)"; };
  probe.src = `/api/heliostats/${encodeURIComponent(hid)}/image.png?t=${Date.now()}`;
};
