// bodyhealth dashboard: plain JS polling the REST API (no build step).
// Robots with their monitoring answer (healthy / damaged / undetermined, as the API's status gives it),
// their learned trees (baseline vs current, SVG), their geometry (joint axes, IMU lever arms, drift),
// active and pending alerts (confirmed by the sensor networks or not), what the worker waits on for
// each robot and its retrains in the training queue, simulated damage.
"use strict";

const API = "/api/v1";
const POLL_MS = 2000;
const KINDS = ["imu_moved", "imu_detached", "imu_dead", "joint_locked", "encoder_fault",
  "joint_reparented", "link_lost", "imu_rotated", "imu_shifted", "axis_changed", "backlash"];
// The geometry drifts take a magnitude: the body field, the unit shown, its default, the factor to SI.
const MAGNITUDE = {
  imu_rotated: { field: "angle_deg", unit: "deg", value: 2, scale: 1 },
  axis_changed: { field: "angle_deg", unit: "deg", value: 2, scale: 1 },
  imu_shifted: { field: "meters", unit: "mm", value: 5, scale: 1e-3 },
  backlash: { field: "deg", unit: "deg", value: 1, scale: 1 },
};
const SVGNS = "http://www.w3.org/2000/svg";
const cards = new Map();  // robot name -> {root, trees, meta, ...}
const TOKEN_KEY = "bodyhealth-token";  // sessionStorage: the token lives as long as the tab

// ------------------------------------------------------------------------------------ API token
// A service with BODYHEALTH_API_TOKEN set answers 401 without it: the page then asks for the token
// once (kept in this tab's sessionStorage) and sends it on every request. Every request that changes
// something says it is JSON from this page (Content-Type and X-Requested-With), which a cross-site form
// cannot send: the API refuses writes without them.
function apiToken() {
  try { return window.sessionStorage.getItem(TOKEN_KEY) || ""; } catch (e) { return ""; }
}

function apiFetch(url, opts = {}) {
  const token = apiToken();
  const headers = new Headers(opts.headers || {});
  if (token) headers.set("Authorization", `Bearer ${token}`);
  const method = (opts.method || "GET").toUpperCase();
  if (method !== "GET" && method !== "HEAD") {
    if (!headers.has("Content-Type")) headers.set("Content-Type", "application/json");
    headers.set("X-Requested-With", "bodyhealth");
  }
  return fetch(url, { ...opts, headers });
}

function askForToken(message) {
  const box = document.getElementById("auth");
  if (!box) return;
  document.getElementById("auth-message").textContent = message;
  box.hidden = false;
}

function setupTokenForm() {
  const form = document.getElementById("auth");
  if (!form) return;
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    const input = document.getElementById("auth-token");
    const token = input.value.trim();
    if (!token) return;
    try { window.sessionStorage.setItem(TOKEN_KEY, token); } catch (e) { /* storage off: not kept */ }
    input.value = "";
    form.hidden = true;
    refresh();
  });
}

async function getJSON(url, opts) {
  const r = await apiFetch(url, opts);
  const body = await r.json().catch(() => ({}));
  if (r.status === 401) {
    askForToken(apiToken() ? "The API refused this token: enter the right one."
      : "This service needs an API token (BODYHEALTH_API_TOKEN).");
  }
  if (!r.ok) {
    const d = body && body.detail;
    throw new Error(typeof d === "string" ? d : JSON.stringify(d || r.statusText));
  }
  return body;
}

function el(tag, attrs = {}, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function svg(tag, attrs = {}, text) {
  const e = document.createElementNS(SVGNS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function fmtTime(s) {
  if (s === null || s === undefined) return "–";
  return new Date(s * 1000).toLocaleTimeString();
}

// ------------------------------------------------------------------------------------ tree drawing
// Tidy layout: leaves get consecutive columns, a parent sits above the middle of its children.
function layout(topo) {
  const joints = Object.keys(topo.joints);
  const kids = new Map([["", []]]);
  joints.forEach((j) => kids.set(j, []));
  joints.forEach((j) => kids.get(topo.joints[j].parent || "").push(j));
  kids.forEach((v) => v.sort());
  const pos = new Map();
  let col = 0;
  let depthMax = 0;
  (function place(node, depth) {
    depthMax = Math.max(depthMax, depth);
    const ch = kids.get(node) || [];
    if (!ch.length) { pos.set(node, { x: col++, y: depth }); return; }
    ch.forEach((c) => place(c, depth + 1));
    const xs = ch.map((c) => pos.get(c).x);
    pos.set(node, { x: (Math.min(...xs) + Math.max(...xs)) / 2, y: depth });
  })("", 0);
  return { pos, cols: Math.max(col, 1), depth: depthMax };
}

function drawTree(topo, changed, cls) {
  const { pos, cols, depth } = layout(topo);
  const dx = 74, dy = 62, pad = 30;
  const w = Math.max(cols * dx + pad + 60, 260), h = (depth + 1) * dy + pad + 14;
  const X = (p) => pad / 2 + p.x * dx + dx / 2 - 4, Y = (p) => pad / 2 + p.y * dy + 10;
  const root = svg("svg", { class: `tree ${cls}`, viewBox: `0 0 ${w} ${h}`, "data-tree": cls });
  const undetermined = new Set(topo.insufficient_excitation || []);
  for (const [j, info] of Object.entries(topo.joints)) {
    const a = pos.get(info.parent || ""), b = pos.get(j);
    const c = changed.joints.has(j) ? " changed" : "";
    root.appendChild(svg("line", { class: "edge" + c, x1: X(a), y1: Y(a), x2: X(b), y2: Y(b) }));
  }
  const base = pos.get("");
  root.appendChild(svg("rect", { class: "base-node", x: X(base) - 14, y: Y(base) - 7, width: 28, height: 14, rx: 3 }));
  root.appendChild(svg("text", { x: X(base) + 18, y: Y(base) + 4 }, "base"));
  const imusOf = new Map();
  for (const [imu, j] of Object.entries(topo.imus)) {
    const k = j || "";
    if (!imusOf.has(k)) imusOf.set(k, []);
    imusOf.get(k).push(imu);
  }
  for (const j of Object.keys(topo.joints)) {
    const p = pos.get(j);
    let c = changed.joints.has(j) ? " changed" : "";
    if (!c && undetermined.has(j)) c = " undetermined";
    const node = svg("circle", { class: "joint-node" + c, cx: X(p), cy: Y(p), r: 8, "data-joint": j });
    node.appendChild(svg("title", {}, j + (undetermined.has(j) ? " (not enough excitation)" : "")));
    root.appendChild(node);
    root.appendChild(svg("text", { x: X(p) + 11, y: Y(p) - 6 }, j));
  }
  for (const [k, imus] of imusOf) {
    const p = pos.get(k);
    if (!p) continue;
    imus.sort((a, b) => (changed.imus.has(b) - changed.imus.has(a)) || a.localeCompare(b));
    const shown = imus.slice(0, 6);
    shown.forEach((imu, i) => {
      const c = changed.imus.has(imu) ? " changed" : "";
      const sq = svg("rect", { class: "imu-node" + c, x: X(p) - 21 + i * 7, y: Y(p) + 13, width: 6, height: 6,
        "data-imu": imu });
      sq.appendChild(svg("title", {}, `${imu} on ${k || "base"}`));
      root.appendChild(sq);
    });
    if (imus.length > shown.length) {
      root.appendChild(svg("text", { class: "imu-more", x: X(p) - 21 + 6 * 7 + 2, y: Y(p) + 19 },
        `+${imus.length - shown.length}`));
    }
  }
  return root;
}

function changedParts(baseline, current, alerts) {
  const joints = new Set(), imus = new Set();
  if (baseline && current) {
    for (const [j, info] of Object.entries(baseline.joints)) {
      const cur = current.joints[j];
      if (!cur || (cur.parent || null) !== (info.parent || null)) joints.add(j);
    }
    for (const [imu, j] of Object.entries(baseline.imus)) {
      if (!(imu in current.imus) || (current.imus[imu] || null) !== (j || null)) imus.add(imu);
    }
  }
  for (const a of alerts) {
    if (a.imu) imus.add(a.imu);
    if (a.joint) joints.add(a.joint);
  }
  return { joints, imus };
}

// ----------------------------------------------------------------------------------- robot cards
function makeCard(robot) {
  const root = el("article", { class: "robot", "data-robot": robot.name });
  const head = el("div", { class: "head" });
  const h = el("h3", {}, robot.name);
  const verdict = el("span", { class: "verdict" });
  head.append(h, verdict);
  const meta = el("div", { class: "meta" });
  const detail = el("div", { class: "verdict-detail" });
  const trees = el("div", { class: "trees" });
  const geometry = el("div", { class: "geometry" });
  root.append(head, meta, detail, trees, geometry);
  const card = { root, meta, verdict, detail, trees, geometry, damage: null };
  const ops = el("div", { class: "damage ops" });
  const approve = el("button", { type: "button", class: "approve" }, "Approve current as baseline");
  const opsResult = el("span", { class: "result" });
  approve.addEventListener("click", async () => {
    if (!window.confirm(`Make the latest learned body of ${robot.name} its baseline? Open alerts are resolved.`)) return;
    opsResult.textContent = "…";
    try {
      const r = await getJSON(`${API}/robots/${encodeURIComponent(robot.name)}/baseline`, { method: "POST" });
      opsResult.textContent = `baseline set (${r.source})`;
      refresh();
    } catch (err) {
      opsResult.textContent = `failed: ${err.message}`;
    }
  });
  ops.append(approve, opsResult);
  root.appendChild(ops);
  if (robot.simulated) {
    const form = el("form", { class: "damage" });
    const kind = el("select", { name: "kind" });
    KINDS.forEach((k) => kind.appendChild(el("option", { value: k }, k)));
    const part = el("input", { name: "part", placeholder: "part (optional): imu or joint name", size: 26 });
    const size = el("input", { name: "magnitude", type: "number", min: "0", step: "any", size: 5 });
    const unit = el("span", { class: "unit" });
    const showSize = () => {
      const m = MAGNITUDE[kind.value];
      size.hidden = unit.hidden = !m;
      if (m) { size.value = String(m.value); unit.textContent = m.unit; }
    };
    kind.addEventListener("change", showSize);
    showSize();
    const btn = el("button", { type: "submit" }, "Inject damage");
    const result = el("span", { class: "result" });
    form.append(el("span", {}, "simulate:"), kind, part, size, unit, btn, result);
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      const body = { kind: kind.value };
      const p = part.value.trim();
      if (p) {
        if (kind.value.startsWith("imu_")) body.imu = p; else body.joint = p;
      }
      const m = MAGNITUDE[kind.value];
      if (m && size.value !== "") body[m.field] = Number(size.value) * m.scale;
      result.textContent = "…";
      try {
        const r = await getJSON(`${API}/robots/${encodeURIComponent(robot.name)}/simulate/damage`, {
          method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(body),
        });
        const f = (r.truth.findings || [])[0] || {};
        result.textContent = `injected ${r.kind} on ${f.imu || f.joint || "?"}`;
      } catch (err) {
        result.textContent = `failed: ${err.message}`;
      }
    });
    root.appendChild(form);
    card.damage = form;
  }
  return card;
}

async function renderRobot(robot, alerts) {
  let card = cards.get(robot.name);
  if (!card) {
    card = makeCard(robot);
    cards.set(robot.name, card);
    document.getElementById("robots").appendChild(card.root);
  }
  const mine = alerts.filter((a) => a.robot === robot.name);
  renderStatus(card, robot.status);
  const exc = Object.values(robot.excitation || {});
  const excTxt = exc.length ? `excitation ${Math.min(...exc).toFixed(2)}–${Math.max(...exc).toFixed(2)} rad/s` : "";
  card.meta.textContent = [
    robot.catalog ? `${robot.catalog} (simulated)` : (robot.simulated ? "simulated" : "real"),
    `${robot.joints.length} joints, ${robot.imus.length} IMUs`,
    robot.silent_imus.length ? `silent: ${robot.silent_imus.join(", ")}` : null,
    `last frame t=${robot.last_frame_t === null ? "–" : robot.last_frame_t.toFixed(1)} s`,
    robot.has_baseline ? "baseline set" : "learning baseline…",
    excTxt,
  ].filter(Boolean).join(" · ");
  let topo;
  try {
    topo = await getJSON(`${API}/robots/${encodeURIComponent(robot.name)}/topology`);
  } catch (err) {
    return;
  }
  // An ambiguous estimate (several trees fit) is drawn, but its placements are not called changes.
  const ambiguous = topo.current && (topo.current.unique === false || (topo.current.candidates || []).length > 0);
  const nTrees = topo.current && topo.current.candidates ? topo.current.candidates.length + 1 : null;
  const changed = changedParts(topo.baseline, ambiguous ? null : topo.current, mine);
  const figs = [];
  for (const [which, t] of [["baseline", topo.baseline], ["current", topo.current]]) {
    const fig = el("figure", {});
    if (t) fig.appendChild(drawTree(t, changed, which));
    else fig.appendChild(el("div", { class: "empty" }, which === "baseline" ? "no baseline yet" : "nothing learned yet"));
    const meta = which === "baseline" ? topo.baseline_meta : topo.current_meta;
    const note = which === "current" && ambiguous
      ? `, one of ${nTrees === null ? "several" : nTrees} trees that fit` : "";
    fig.appendChild(el("figcaption", {}, meta ? `${which} (${meta.method}${meta.source ? ", " + meta.source : ""}, ${fmtTime(meta.wall_time)}${note})` : which));
    figs.push(fig);
  }
  card.trees.replaceChildren(...figs);
  if (robot.has_baseline) await renderGeometry(card, robot);
}

// ------------------------------------------------------------------------------------ geometry
// Joint axes and lever arms as the worker estimated them under the baseline, and what drifted since:
// the API's comparison, beyond both estimates' own uncertainty (docs/kinematics.md).
function fmtVec(v, scale = 1, digits = 3) {
  return v ? `(${v.map((x) => (x * scale).toFixed(digits)).join(", ")})` : "–";
}

async function renderGeometry(card, robot) {
  let g;
  try {
    g = await getJSON(`${API}/robots/${encodeURIComponent(robot.name)}/kinematics`);
  } catch (err) {
    return;
  }
  const now = g.latest || g.baseline;
  if (!now) {
    card.geometry.replaceChildren(el("div", { class: "muted" }, "geometry: not learned yet"));
    return;
  }
  const imus = Object.entries(now.kinematics.imus || {});
  const drift = g.drift || [];
  const drifted = new Set(drift.map((f) => f.imu || f.joint));
  const converged = imus.filter(([, k]) => k.converged).length;
  const head = el("summary", {}, `geometry: ${converged}/${imus.length} IMUs converged · `);
  const verdict = drift.length
    ? el("span", { class: "drift bad" }, `drift: ${drift.map((f) => `${f.kind} ${f.imu || f.joint}`).join(", ")}`)
    : el("span", { class: "drift" }, g.latest && g.baseline && g.latest.id !== g.baseline.id
      ? "no drift beyond the estimates' uncertainty" : "learned; nothing to compare yet");
  head.appendChild(verdict);
  const table = el("table", { class: "kinematics" });
  const hr = el("tr", {});
  ["IMU", "joint", "axis (IMU frame)", "± deg", "lever arm, mm", "± mm", ""].forEach((h) => hr.appendChild(el("th", {}, h)));
  table.appendChild(hr);
  for (const [name, k] of imus) {
    const tr = el("tr", { "data-imu": name, class: drifted.has(name) || drifted.has(k.joint) ? "drifted" : "" });
    tr.append(el("td", {}, name), el("td", {}, k.joint ?? "base"), el("td", {}, fmtVec(k.axis)),
      el("td", {}, k.axis_std_deg === null ? "–" : k.axis_std_deg.toFixed(2)),
      el("td", {}, fmtVec(k.lever_arm, 1e3, 1)),
      el("td", {}, k.lever_arm_std_m === null ? "–" : (k.lever_arm_std_m * 1e3).toFixed(1)),
      el("td", { class: "muted" }, k.converged ? "" : (k.reason || "not converged")));
    table.appendChild(tr);
  }
  const details = el("details", { class: "geometry-table" });
  const open = card.geometry.querySelector("details");
  if (open && open.open) details.open = true;
  // fetched with the API token (a plain link would not send it), then saved from a blob
  const urdf = el("a", { href: "#", class: "urdf" }, "download URDF");
  urdf.addEventListener("click", async (ev) => {
    ev.preventDefault();
    const r = await apiFetch(`${API}/robots/${encodeURIComponent(robot.name)}/kinematics/urdf`);
    if (!r.ok) { urdf.textContent = `URDF: ${r.status}`; return; }
    const a = el("a", { href: URL.createObjectURL(await r.blob()), download: `${robot.name}.urdf` });
    a.click();
    URL.revokeObjectURL(a.href);
  });
  // slides are judged on lever arms pooled over many estimates, once both pools are full (kinematics.md)
  const pooled = g.baseline
    ? `slides judged on pooled lever arms: ${g.baseline.pooled_estimates} estimates under the baseline, `
      + `${g.latest && g.latest.id !== g.baseline.id ? g.latest.pooled_estimates : 0} newest · `
    : "";
  const note = el("div", { class: "muted pooled" },
    `axis along positive q; lever arm from the axis to the IMU, across it · ${pooled}`);
  note.appendChild(urdf);
  details.append(head, table, note);
  card.geometry.dataset.drift = String(drift.length);
  card.geometry.replaceChildren(details);
}

// ------------------------------------------------------------------------------------ status
// The answer is the API's, never recomputed here: "healthy" is shown only when the API says so, so an
// undetermined robot can never come out green.
function plural(n, one, many) { return `${n} ${n === 1 ? one : many}`; }

function renderStatus(card, st) {
  const value = st ? st.status : "undetermined";
  card.root.classList.remove("healthy", "damaged", "undetermined");
  card.root.classList.add(value);
  card.root.dataset.status = value;
  card.verdict.className = "verdict " + value;
  card.verdict.dataset.status = value;
  card.verdict.textContent = value;
  const lines = [];
  if (!st) {
    lines.push(el("div", { class: "why" }, "no status from the API"));
  } else {
    if (value === "undetermined") {
      const trees = st.trees_fit === null ? null
        : st.trees_fit === 1 ? "one tree fits" : `${st.trees_fit} trees fit the data`;
      if (trees) lines.push(el("div", { class: "trees-fit", "data-trees": String(st.trees_fit) }, trees));
      if (st.decide_by.length) {
        lines.push(el("div", { class: "decide" },
          `to decide, move each on its own with the others still: ${st.decide_by.join(", ")}`));
        lines.push(planLink(card.root.dataset.robot));
      }
    }
    // the joints to move are on their own line above; the reasons say the rest
    const shown = lines.some((l) => l.classList.contains("decide"));
    const ul = el("ul", { class: "reasons" });
    st.reasons.filter((r) => !(shown && r.startsWith("to decide,")))
      .forEach((r) => ul.appendChild(el("li", {}, r)));
    lines.push(ul);
    const extra = [];
    if (st.timing && st.timing.skew_ms !== null && st.timing.skew_ms !== undefined) {
      const lag = st.timing.lag_ms === null || st.timing.lag_ms === undefined ? ""
        : ` (IMU lag ${st.timing.lag_ms.toFixed(1)} ms)`;
      // the skew of a drifting clock pair grows with time: say when it holds, and the drift
      const at = st.timing.at_s === null || st.timing.at_s === undefined ? ""
        : ` at device time ${st.timing.at_s.toFixed(0)} s`;
      const drift = st.timing.drift_ppm === null || st.timing.drift_ppm === undefined ? ""
        : `, drift ${st.timing.drift_ppm.toFixed(0)} ppm`;
      const unc = st.timing.lag_unc_ms === null || st.timing.lag_unc_ms === undefined ? ""
        : ` ± ${st.timing.lag_unc_ms.toFixed(1)}`;
      extra.push(el("span", { class: "skew" },
        `IMU-to-encoder skew ${st.timing.skew_ms.toFixed(1)}${unc} ms${at}${lag}${drift}`));
    }
    if (st.training) {
      const t = st.training;
      const parts = [t.epochs === null ? null : plural(t.epochs, "epoch", "epochs"),
        t.converged === null ? null : (t.converged ? "converged" : "stopped at its epoch bound"),
        t.loss === null ? "loss not finite" : `loss ${t.loss.toPrecision(3)}`].filter(Boolean);
      extra.push(el("span", { class: "training" }, `${st.method} training: ${parts.join(", ")}`));
    }
    if (st.network) {
      const n = st.network, t = n.training || {};
      const when = new Date(n.wall_time * 1000).toLocaleTimeString();
      const parts = [t.warm === null || t.warm === undefined ? null : (t.warm ? "warm start" : "cold start"),
        t.epochs === null || t.epochs === undefined ? null : plural(t.epochs, "epoch", "epochs"),
        t.converged === null || t.converged === undefined ? null : (t.converged ? "converged" : "not converged"),
        `${n.cpu_seconds.toFixed(1)} CPU s`,
        n.same_as_judged === null ? null : (n.same_as_judged ? "same body as the screen" : "a body other than the screen's")]
        .filter(Boolean);
      extra.push(el("span", { class: "network", "data-topology": String(n.topology_id) },
        `${n.method} retrain ${when}: ${parts.join(", ")}`));
    }
    if (extra.length) {
      const row = el("div", { class: "timing" });
      extra.forEach((e, i) => { if (i) row.append(" · "); row.append(e); });
      lines.push(row);
    }
    const waits = renderWaits(st);
    if (waits) lines.push(waits);
  }
  card.detail.replaceChildren(...lines);
}

// The motion that decides what the data left open (GET .../excitation, docs/excitation.md), as CSV:
// a time column and one column of positions (rad) per joint. Fetched with the API token (a plain link
// would not send it), then saved from a blob; the href names the route for a reader of the page.
function planLink(robot) {
  const route = `${API}/robots/${encodeURIComponent(robot)}/excitation?format=csv`;
  const file = `${robot}-excitation.csv`;
  const a = el("a", { href: route, class: "excitation-plan", download: file },
    "download the excitation plan (CSV)");
  a.addEventListener("click", async (ev) => {
    ev.preventDefault();
    const r = await apiFetch(route);
    if (!r.ok) { a.textContent = `excitation plan: ${r.status}`; return; }
    const blob = URL.createObjectURL(await r.blob());
    el("a", { href: blob, download: file }).click();
    setTimeout(() => URL.revokeObjectURL(blob), 60_000);  // once the browser has read it
  });
  const row = el("div", { class: "plan" });
  row.appendChild(a);
  return row;
}

function ago(t) {
  const s = Math.max(0, Date.now() / 1000 - t);
  return s < 120 ? `${s.toFixed(0)} s` : `${(s / 60).toFixed(1)} min`;
}

// What the worker waits on for this robot (since when, until when at most) and its retrains in the
// training queue (position, CPU spent, expected finish), as the status gives them.
function renderWaits(st) {
  const waits = st.waiting || [], queue = st.training_queue || [];
  const baseline = st.baseline_source === "fast-unconfirmed"
    ? `baseline from the fast screen, not confirmed by the sensor networks (${st.baseline_networks || "unconfirmed"})` : null;
  if (!waits.length && !queue.length && !baseline) return null;
  const box = el("div", { class: "waiting" });
  if (baseline) {
    box.appendChild(el("div", { class: "baseline-source " + (st.baseline_networks || ""),
      "data-baseline": st.baseline_networks || "unconfirmed" }, baseline));
  }
  waits.forEach((w) => {
    const until = w.until === null || w.until === undefined ? "" : `, at most until ${fmtTime(w.until)}`;
    box.appendChild(el("div", { class: "wait", "data-what": w.what },
      `waiting on ${w.what} for ${ago(w.since)} (since ${fmtTime(w.since)}${until})`));
  });
  queue.forEach((q) => {
    const cpu = q.cpu_seconds === null || q.cpu_seconds === undefined ? "CPU not reported yet"
      : `${q.cpu_seconds.toFixed(1)} CPU s`;
    const finish = q.expected_finish === null || q.expected_finish === undefined ? "finish not known yet"
      : `expected to finish ${fmtTime(q.expected_finish)}`;
    box.appendChild(el("div", { class: "queue", "data-state": q.state },
      `${q.method} retrain ${q.state}, position ${q.position + 1} in the queue for ${ago(q.since)}: ${cpu}, ${finish}`));
  });
  return box;
}

function renderSummary(robots) {
  const counts = { damaged: 0, undetermined: 0, healthy: 0 };
  robots.forEach((r) => { counts[r.status ? r.status.status : "undetermined"] += 1; });
  const s = document.getElementById("summary");
  s.replaceChildren(...Object.entries(counts).filter(([, n]) => n > 0)
    .map(([k, n]) => el("span", { class: "verdict small " + k, "data-status": k }, `${n} ${k}`)));
}

function renderAlerts(alerts) {
  const body = document.querySelector("#alerts tbody");
  const rows = alerts.map((a) => {
    const tr = el("tr", { class: "alert", "data-alert": String(a.id), "data-kind": a.kind, "data-part": a.part,
      "data-state": a.state });
    const f = a.finding || {};
    const moved = a.kind === "imu_moved" || a.kind === "joint_reparented";
    const detail = moved ? `${f.from ?? "base"} → ${f.to ?? "base"}`
      : [f.detail, f.from ? `(on ${f.from})` : null].filter(Boolean).join(" ");
    const state = a.state === "pending" ? "pending"
      : a.confirmed === false ? "active, unconfirmed" : a.confirmed === true ? "active, confirmed" : "active";
    tr.classList.add(a.state);
    if (a.confirmed === false) tr.classList.add("unconfirmed");
    tr.append(el("td", {}, a.robot), el("td", {}, a.kind), el("td", {}, a.part), el("td", {}, detail),
      el("td", { class: "state", title: a.note || "" }, state + (a.note ? ` (${a.note})` : "")),
      el("td", {}, fmtTime(a.raised_at)));
    const td = el("td", {});
    if (a.acked) td.textContent = "acked";
    else {
      const b = el("button", {}, "ack");
      b.addEventListener("click", async () => {
        b.disabled = true;
        await getJSON(`${API}/alerts/${a.id}/ack`, { method: "POST" }).catch(() => null);
        refresh();
      });
      td.appendChild(b);
    }
    tr.appendChild(td);
    return tr;
  });
  body.replaceChildren(...rows);
  document.getElementById("no-alerts").hidden = alerts.length > 0;
  const active = alerts.filter((a) => a.state === "active").length;
  const c = document.getElementById("alert-count");
  c.textContent = String(active);
  c.classList.toggle("bad", active > 0);
  const p = document.getElementById("pending-count");
  if (p) p.textContent = String(alerts.length - active);
}

let busy = false;
async function refresh() {
  if (busy) return;
  busy = true;
  const status = document.getElementById("status");
  try {
    const ready = await apiFetch("/readyz").then((r) => r.json()).catch(() => null);
    const degraded = ready && ready.degraded && ready.degraded.length ? ready.degraded : null;
    status.textContent = !ready ? "unreachable"
      : ready.status === "ready" && degraded ? `ready, degraded: ${degraded.join("; ")}`
        : ready.status === "ready" ? "ready" : `not ready: ${ready.reason}`;
    status.className = "status " + (ready && ready.status === "ready" ? (degraded ? "degraded" : "ready") : "down");
    const [robots, alerts, pending] = await Promise.all([getJSON(`${API}/robots`),
      getJSON(`${API}/alerts?active=true`), getJSON(`${API}/alerts?state=pending`)]);
    renderAlerts([...alerts, ...pending]);
    renderSummary(robots);
    await Promise.all(robots.map((r) => renderRobot(r, alerts)));
    document.body.dataset.loaded = "1";
  } catch (err) {
    status.textContent = "API error: " + err.message;
    status.className = "status down";
  } finally {
    busy = false;
  }
}

setupTokenForm();
refresh();
setInterval(refresh, POLL_MS);
