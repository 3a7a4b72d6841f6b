"use strict";
// The control room (no template, no inline script: every name from the office is set with
// textContent, never parsed as markup). GET /api/session says who is logged in and which commands
// this office offers; without a session every request is refused and the page goes to the login.
let RELEASE = false;  // the office has a zone controller link and this login may command
let WCC = false;  // the office has a link to the stations' WPCS and this login may command
// Everything here is built from the office's reports (GET /events, server-sent events).
const state = { count: 0, trains: new Map(), stations: new Map(), zones: new Map(), platforms: new Map(),
  stationIndex: new Map(), length: 1, stopIds: new Set(), newest: null, connected: false };
const svg = (tag, attrs) => { const e = document.createElementNS("http://www.w3.org/2000/svg", tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v); return e; };
const x = (m) => 10 + 980 * Math.max(0, Math.min(1, m / state.length));

function text(el, s) { el.textContent = s; return el; }

function drawLine() {
  const g = document.getElementById("stations"); g.replaceChildren();
  for (const [name, st] of state.stations) {
    if (st.chainage_m === undefined) continue;
    g.append(svg("rect", { x: x(st.chainage_m) - 4, y: 33, width: 8, height: 24, fill: "#8c959f" }));
    g.append(text(svg("text", { x: x(st.chainage_m), y: 80, "text-anchor": "middle" }), name));
  }
  const z = document.getElementById("zones"); z.replaceChildren();
  for (const [train, zone] of state.zones) {
    if (!zone.active) continue;
    z.append(svg("rect", { class: "zone", "data-train": train, x: x(zone.start_m), y: 38,
      width: Math.max(2, x(zone.end_m) - x(zone.start_m)), height: 14, fill: "#ff7b72", opacity: 0.6 }));
  }
  const t = document.getElementById("trains"); t.replaceChildren();
  for (const [id, tr] of state.trains) {
    const g1 = svg("g", { class: "train", "data-train": id, "data-position": tr.position_m.toFixed(1) });
    const colour = tr.radio === "dead" ? "#8c959f" : tr.emergency_brake ? "#cf222e" : "#0969da";
    g1.dataset.radio = tr.radio || "ok";
    g1.append(svg("circle", { cx: x(tr.position_m), cy: 45, r: 7, fill: colour }));
    g1.append(text(svg("text", { x: x(tr.position_m), y: 24, "text-anchor": "middle" }), `T${id}`));
    t.append(g1);
  }
}

function drawZones() {
  const body = document.querySelector("#zones-table tbody"); body.replaceChildren();
  let n = 0;
  for (const [train, z] of state.zones) {
    if (!z.active) continue;
    n += 1;
    const row = document.createElement("tr"); row.dataset.train = train;
    // SPEC §4: "lost" (the controller protects the train it no longer hears), "flagged" (it was
    // re-detected outside its zone: only the operator releases it, after seeing the train).
    const status = z.status === "flagged" ? "flagged: re-detected outside, see the train" : (z.status || "lost");
    for (const v of [`T${train}`, z.start_m.toFixed(0), z.end_m.toFixed(0), status, z.since]) {
      const td = document.createElement("td"); td.textContent = v; row.append(td);
    }
    row.children[3].className = "zone-status " + (z.status === "flagged" ? "bad" : "");
    const td = document.createElement("td");
    if (RELEASE) {
      const b = document.createElement("button"); b.textContent = "Release…"; b.className = "release";
      b.addEventListener("click", () => askRelease(train)); td.append(b);
    }
    row.append(td); body.append(row);
  }
  document.getElementById("no-zones").hidden = n > 0;
}

// Every command carries a one-time token the office issued to this session just before (a request
// captured and sent again is refused), the operator's confirmation and credential.
async function command(url, body) {
  const post = (u, b) => fetch(u, { method: "POST", credentials: "same-origin",
    headers: { "Content-Type": "application/json" }, body: JSON.stringify(b) });
  try {
    const t = await post("/api/token", {});
    if (t.status === 401) { window.location.assign("/login"); return [false, "the session has ended"]; }
    if (!t.ok) return [false, `refused (${t.status})`];
    const res = await post(url, { ...body, token: (await t.json()).token });
    let message = `refused (${res.status})`;
    try { message = (await res.json()).message || message; } catch (err) { /* not JSON */ }
    return [res.ok, message];
  } catch (err) {
    return [false, "the office is unreachable"];
  }
}

function askRelease(train) {
  const dlg = document.getElementById("release-dialog");
  document.getElementById("release-train").textContent = `T${train}`;
  document.getElementById("release-form").reset();
  dlg.dataset.train = train;
  dlg.showModal();
}

document.getElementById("release-form").addEventListener("submit", async (e) => {
  const dlg = document.getElementById("release-dialog");
  if (e.submitter && e.submitter.value === "cancel") return;
  e.preventDefault();
  const body = { train: Number(dlg.dataset.train),
    credential: document.getElementById("release-credential").value,
    confirmed: document.getElementById("release-confirm").checked };
  const out = document.getElementById("release-result");
  const [ok, message] = await command("/api/release", body);
  out.textContent = message;
  out.className = ok ? "good" : "bad";
  dlg.close();
});

// SPEC §5: each platform's WPCS as its dwell events report it; the WCC's commands (manual / auto,
// the panel's open / close buttons), each confirmed and authenticated by an operator.
const WCC_TITLES = { manual: "Switch the WPCS to manual", auto: "Switch the WPCS back to automatic",
  open: "Press the panel's open button", close: "Press the panel's close button" };
function drawPlatforms() {
  const body = document.querySelector("#platforms tbody");
  for (const [name, p] of state.platforms) {
    let row = body.querySelector(`tr[data-station="${CSS.escape(name)}"]`);
    if (!row) { row = document.createElement("tr"); row.dataset.station = name;
      for (let i = 0; i < 7; i++) row.append(document.createElement("td")); body.append(row); }
    const ev = p.event || {}, dw = p.dwell;
    const dwell = dw ? (dw.outcome === "start-enable" ? `T${dw.train} start enable ${dw.dwell_s} s`
      + (dw.corrections ? `, ${dw.corrections} correction(s)` : "") : `T${dw.train} ${dw.outcome}`) : "-";
    const cells = [name, ev.tr ?? "-", ev.psd ?? "closed_locked", ev.wcc ?? "auto", ev.ev ? `${ev.ev} at ${ev.t_s} s` : "-", dwell];
    cells.forEach((v, i) => { row.children[i].textContent = v; });
    row.children[3].className = "wpcs-mode " + (ev.wcc === "manual" ? "bad" : "");
    row.children[5].className = dw && dw.outcome !== "start-enable" ? "bad" : "";
    // Abnormal behaviour the WCC watches for (SPEC §5): a fault, the link lost, a PSD unit jammed.
    row.children[4].className = ["fault", "link-lost", "psd-jam"].includes(ev.ev) ? "bad" : "";
    const td = row.children[6]; td.replaceChildren();
    if (WCC) {
      const manual = ev.wcc === "manual";
      const cmds = manual ? [["auto", "Auto…"], ["open", "Open PSD…"], ["close", "Close PSD…"]] : [["manual", "Manual…"]];
      for (const [cmd, label] of cmds) {
        const b = document.createElement("button"); b.textContent = label; b.className = "release"; b.dataset.cmd = cmd;
        b.addEventListener("click", () => askWcc(name, cmd)); td.append(b, " ");
      }
    }
  }
}

function askWcc(name, cmd) {
  const dlg = document.getElementById("wcc-dialog");
  document.getElementById("wcc-form").reset();
  document.getElementById("wcc-title").textContent = `${WCC_TITLES[cmd]}: ${name}`;
  document.getElementById("wcc-station").textContent = name;
  dlg.dataset.station = name; dlg.dataset.cmd = cmd;
  dlg.showModal();
}

document.getElementById("wcc-form").addEventListener("submit", async (e) => {
  const dlg = document.getElementById("wcc-dialog");
  if (e.submitter && e.submitter.value === "cancel") return;
  e.preventDefault();
  const cmd = dlg.dataset.cmd;
  const body = { station: state.stationIndex.get(dlg.dataset.station), mode: cmd === "auto" ? "auto" : "manual",
    panel: cmd === "open" || cmd === "close" ? cmd : "none",
    credential: document.getElementById("wcc-credential").value,
    confirmed: document.getElementById("wcc-confirm").checked };
  const out = document.getElementById("wcc-result");
  const [ok, message] = await command("/api/wcc", body);
  out.textContent = message;
  out.className = ok ? "good" : "bad";
  dlg.close();
});

const LIMIT_M = 0.5;  // the chart's half-width
function drawAccuracy() {
  const chart = document.getElementById("accuracy");
  const names = [...state.stations.keys()];
  const rowH = 26, h = 24 + rowH * Math.max(names.length, 1);
  chart.setAttribute("viewBox", `0 0 1000 ${h}`); chart.setAttribute("height", h); chart.replaceChildren();
  const cx = (e) => 160 + 820 * (Math.max(-LIMIT_M, Math.min(LIMIT_M, e)) + LIMIT_M) / (2 * LIMIT_M);
  for (const v of [-0.5, -0.35, 0, 0.35, 0.5]) {
    chart.append(svg("line", { x1: cx(v), x2: cx(v), y1: 4, y2: h - 14, stroke: v === 0 ? "#57606a" : "#d8dce3" }));
    chart.append(text(svg("text", { x: cx(v), y: h - 2, "text-anchor": "middle" }), v.toFixed(2)));
  }
  names.forEach((name, i) => {
    const y = 16 + i * rowH;
    chart.append(text(svg("text", { x: 150, y: y + 4, "text-anchor": "end" }), name));
    for (const e of (state.stations.get(name).errors || [])) {
      const dot = svg("circle", { class: "stop-dot", cx: cx(e), cy: y, r: 4,
        fill: Math.abs(e) <= 0.35 ? "#1a7f37" : "#cf222e", opacity: 0.7 });
      chart.append(dot);
    }
  });
}

function stopRow(name, st) {
  let row = document.querySelector(`#stops tr[data-station="${CSS.escape(name)}"]`);
  if (!row) { row = document.createElement("tr"); row.dataset.station = name;
    for (let i = 0; i < 7; i++) row.append(document.createElement("td"));
    row.children[3].className = "num"; document.querySelector("#stops tbody").append(row); }
  const s = st.stop; if (!s) return;
  const cells = [name, s.train ?? "-", s.controller ?? "-", (s.error_m ?? NaN).toFixed(3), s.lamp ?? "-",
    s.doors ?? "-", st.received ?? "-"];
  cells.forEach((v, i) => { row.children[i].textContent = v; });
  row.children[3].className = "num " + (s.within ? "good" : "bad");
}

function apply(r) {
  state.count += 1;
  state.newest = r.received_utc;
  document.getElementById("count").textContent = state.count;
  document.getElementById("last").textContent = `${r.kind} #${r.id}`;
  const d = r.data;
  if (r.kind === "train-state") {
    state.trains.set(d.train, d);
  } else if (r.kind === "stop-result") {
    const st = state.stations.get(d.station) || {};
    st.stop = d; st.received = r.received_utc.slice(11, 19);
    addStop(r);
    state.stations.set(d.station, st); stopRow(d.station, st); drawAccuracy();
  } else if (r.kind === "zone-event") {
    state.zones.set(d.train, { ...d, since: r.received_utc.slice(11, 19) });
    drawZones();
  } else if (r.kind === "dwell-event") {
    const p = state.platforms.get(d.st) || {}; p.event = d; state.platforms.set(d.st, p); drawPlatforms();
  } else if (r.kind === "dwell-result") {
    const p = state.platforms.get(d.station) || {}; p.dwell = d; state.platforms.set(d.station, p); drawPlatforms();
    const st = state.stations.get(d.station);
    if (st && st.stop && st.stop.train === d.train) {
      st.stop.doors = d.outcome === "start-enable" ? `closed, start enable after ${d.dwell_s} s` : d.outcome;
      st.stop.lamp = d.corrections ? `corrected ${d.corrections}x` : "OK";
      stopRow(d.station, st);
    }
  }
  drawLine();
  if (r.kind === "train-state") return;  // the trains are on the line above, not in the log
  const log = document.getElementById("log");
  const line = document.createElement("div");
  line.dataset.kind = r.kind;
  line.textContent = `${r.received_utc.slice(11, 19)} ${sentence(r)}`;
  line.title = `#${r.id} ${r.kind} from ${r.sender_id}: ${JSON.stringify(d)}`;  // the record itself
  log.prepend(line);
  while (log.children.length > 200) log.lastChild.remove();
}

// The log in words: what each report says (the record itself on hover). Every value goes in as
// text (textContent), never as markup.
const num = (x, digits = 3) => (typeof x === "number" && isFinite(x) ? x.toFixed(digits) : "?");
const signed = (x, digits = 3) => (typeof x === "number" && x >= 0 ? "+" : "") + num(x, digits);
function sentence(r) {
  const d = r.data || {};
  switch (r.kind) {
    case "stop-result":
      return `Train ${d.train} stopped at ${d.station}, ${signed(d.error_m)} m from the stopping point ` +
        `(${d.within ? "within" : "outside"} the PSD tolerance; ${d.controller}).`;
    case "dwell-result":
      if (d.outcome === "start-enable")
        return `Train ${d.train} at ${d.station}: doors closed and locked, start enable after ${d.dwell_s} s ` +
          `(${d.psc_requests} PSC request(s), ${d.corrections} correction(s)).`;
      if (d.outcome === "fault")
        return `Train ${d.train} at ${d.station}: dwell fault (${d.fault}), emergency brake until the staff reset.`;
      return `Train ${d.train} at ${d.station}: dwell ${d.outcome}.`;
    case "dwell-event":
      return `${d.st}: ${String(d.ev).replaceAll("-", " ")}${d.tr != null ? ` (train ${d.tr})` : ""}; ` +
        `PSD ${d.psd}, WCC ${d.wcc}.`;
    case "zone-event":
      return d.active
        ? `Train ${d.train} ${d.status}: protection zone ${num(d.start_m, 1)} to ${num(d.end_m, 1)} m.`
        : `Train ${d.train}: protection zone released.`;
    case "tasc-command":
      return `${d.st}, train ${d.tr}: TASC command at detector ${d.det}, ${num(d.dist, 2)} m to go at ` +
        `${num(d.v * 3.6, 1)} km/h, ${d.eb ? "EMERGENCY BRAKE" : `${num(d.a_cmd, 3)} m/s² (notch ${d.notch})`}.`;
    case "operator-action": {
      const what = d.action === "zone-release" ? `release of train ${d.train}'s zone`
        : d.action === "wcc" ? `WCC ${d.command} at ${d.station}` : d.action;
      return `Operator ${d.operator ?? "?"}: ${what}${d.result ? `: ${d.result}` : ""}.`;
    }
    case "campaign-result":
      return `Campaign ${d.controller} at ${d.station}, ${d.runs} runs: ${num(100 * d.within, 2)} % within ` +
        `±${d.tol} m, p99 ${num(d.p99, 3)} m.`;
    default:
      return `${r.kind}: ` + Object.entries(d).map(([k, v]) => `${k} ${v}`).join(", ");
  }
}

// The stop chart covers the whole record: every stop-result the office holds (GET /api/stops),
// then each new one; a report met twice (in both) counts once.
function addStop(r) {
  if (state.stopIds.has(r.id)) return;
  state.stopIds.add(r.id);
  const st = state.stations.get(r.data.station) || {};
  st.errors = [...(st.errors || []), r.data.error_m];
  state.stations.set(r.data.station, st);
}

async function loadStops() {
  const res = await fetch("/api/stops");
  if (!res.ok) return;
  for (const r of await res.json()) addStop(r);
  drawAccuracy();
}

async function loadLine() {
  const res = await fetch("/api/line");
  if (res.status === 401) { window.location.assign("/login"); return; }
  const line = await res.json();
  state.length = line.length_m;
  line.stations.forEach((s, i) => {
    state.stations.set(s.name, { ...(state.stations.get(s.name) || {}), chainage_m: s.chainage_m });
    state.stationIndex.set(s.name, i);
    if (!state.platforms.has(s.name)) state.platforms.set(s.name, {});
  });
  drawLine(); drawAccuracy(); drawPlatforms();
}

// "live" only while reports keep coming: an office serving the record of a finished run (or a line
// that has stopped) says so, with the time of its last report.
const QUIET_S = 30;
function showLiveness() {
  const status = document.getElementById("status");
  if (!state.connected) return;
  // received_utc: ISO 8601 to the second, UTC ("2026-11-27T09:38:02+00:00")
  const age = state.newest ? (Date.now() - Date.parse(state.newest.slice(0, 19) + "Z")) / 1000 : Infinity;
  if (age <= QUIET_S) { status.textContent = "live"; status.className = "ok"; return; }
  if (!state.newest) { status.textContent = "live: no report yet"; status.className = "ok"; return; }
  status.className = "quiet";
  status.textContent = `no report for ${Math.round(age / 60)} min: a finished record ` +
    `(last report ${state.newest.slice(0, 19).replace("T", " ")} UTC)`;
}
setInterval(showLiveness, 5000);

function connect() {
  const es = new EventSource("/events");
  const status = document.getElementById("status");
  es.addEventListener("report", (e) => apply(JSON.parse(e.data)));
  es.addEventListener("ready", () => { state.connected = true; showLiveness(); });
  es.addEventListener("ended", () => { es.close(); window.location.assign("/login"); });
  es.onerror = async () => {
    state.connected = false;
    status.textContent = "office unreachable: retrying"; status.className = "down";
    // A refused stream is not retried by the browser: a session that has ended goes to the login.
    if (es.readyState === EventSource.CLOSED) {
      try {
        const res = await fetch("/api/session");
        if (res.status === 401) { window.location.assign("/login"); return; }
      } catch (err) { /* unreachable: try again below */ }
      setTimeout(connect, 3000);
    }
  };
}

async function start() {
  const res = await fetch("/api/session");
  if (res.status === 401) { window.location.assign("/login"); return; }
  const who = await res.json();
  RELEASE = who.release; WCC = who.wcc;
  document.title = who.title;
  document.getElementById("title").textContent = who.title;
  document.getElementById("user").textContent = who.user;
  document.getElementById("logout").addEventListener("click", async () => {
    await fetch("/api/logout", { method: "POST", credentials: "same-origin" });
    window.location.assign("/login");
  });
  await loadLine().then(loadStops).then(connect, connect);
}
start();
