// btrun console: the runs list and one inventory (rack faces, map, table, place detail, live).
"use strict";

const app = document.getElementById("app");
const PAGE = app.dataset.page;
const RUN = app.dataset.run;

function mount(...nodes) {
  app.replaceChildren(...nodes.flat().filter((n) => n !== null && n !== undefined && n !== false));
}

// ---- the runs list -------------------------------------------------------------------------
async function indexPage() {
  const data = await getJSON("/api/runs");
  const rows = data.runs.map((r) => {
    const disc = Object.entries(r.discrepancies || {}).map(([k, n]) => `${k} ${n}`).join(", ");
    const fromStore = r.source === "store";
    // a run known only from the store: its folder (crops, track) is on another machine
    return el("tr", { "data-run": r.name, "data-source": r.source, class: fromStore ? "from-store" : "" },
      el("td", {}, fromStore ? r.name : el("a", { href: `/runs/${encodeURIComponent(r.name)}` }, r.name)),
      el("td", {}, r.kind + (r.drones.length > 1 ? ` (${r.drones.length} drones)` : ""),
        fromStore ? el("span", { class: "note" }, ` from the store${r.host ? " (" + r.host + ")" : ""}`) : null),
      el("td", {}, r.mission),
      el("td", {}, el("span", { class: `status status-${r.status}` }, r.status),
        r.error ? el("span", { class: "error problem", title: r.error }, " damaged files") : null),
      r.places_known === false
        ? el("td", { class: "num", title: "the site store records the places a run answered, not those it planned" }, `${r.answered}/?`)
        : el("td", { class: "num" }, `${r.answered}/${r.places}`),
      el("td", { class: "num", title: r.accuracy_over === "answered" ? "over the places answered" : "" }, pct(r.accuracy) + (typeof r.accuracy === "number" && r.accuracy_over === "answered" && r.answered < r.places ? ` of ${r.answered}` : "")),
      el("td", {}, disc || (r.exceptions ? "" : "")),
      el("td", { class: "num" }, r.exceptions ? `${r.exceptions - Math.min(r.reviewed, r.exceptions)} of ${r.exceptions}` : "0"),
      el("td", {}, fmtTime(r.started)));
  });
  mount(
    el("h1", {}, "Runs and fleets"),
    data.store ? el("p", { class: "note" }, `site store: ${data.store}`) : null,
    data.store_note ? el("p", { class: "error", id: "store-note" }, data.store_note) : null,
    rows.length === 0 ? el("p", {}, "No runs yet: fly one (btrun fleet fleets/aisle_2.yaml).") :
      el("div", { class: "scroll" }, el("table", { id: "runs", class: "grid" },
        el("thead", {}, el("tr", {}, ["run", "kind", "mission", "status", "places", "accuracy (sim)",
          "discrepancies", "to review", "started"].map((h) => el("th", {}, h)))),
        el("tbody", {}, rows))),
    data.skipped ? el("p", { class: "note", id: "skipped" }, `not listed: ${data.skipped}`) : null);
  if (data.runs.some((r) => r.status === "RUNNING")) setTimeout(indexAgain, 3000);
}

// Again while a run is RUNNING; a hidden tab waits until it is shown
function indexAgain() {
  if (!document.hidden) { indexPage(); return; }
  document.addEventListener("visibilitychange", indexAgain, { once: true });
}

// ---- one inventory -------------------------------------------------------------------------
const state = { info: null, colourBy: "status", filter: "", statusFilter: "", sortKey: null, sortUp: true, selected: null, source: null, poll: null, live: null };

function rowOf(place) {
  return state.info.rows.find((r) => r.place === place) || null;
}

function reviewOf(place) {
  let last = null;
  for (const d of state.info.review || []) if (d.place === place) last = d;
  return last;
}

function categoryOf(row) {
  if (!row) return "pending";
  const d = row.reviewed_discrepancy || row.discrepancy || row.category;
  if (d) return d;
  if (row.status === "mismatch" || row.status === "unverified") return row.status;
  if (state.info.queue.includes(row.place)) return "exception";
  return "none";
}

function colourKey(place) {
  const row = rowOf(place);
  if (state.colourBy === "grade") return state.info.grades[place] || "pending";
  if (state.colourBy === "discrepancy") return categoryOf(row);
  if (!row) return "pending";
  const d = reviewOf(place);
  if (d && d.answer !== "unknown") return "reviewed";
  return row.status;
}

function colour(place) {
  return COLOURS[state.colourBy][colourKey(place)] || "#eeeeee";
}

function rackFaces() {
  const racks = {};
  for (const [place, [rack, bay, level]] of Object.entries(state.info.layout)) {
    (racks[rack] = racks[rack] || []).push({ place, bay, level });
  }
  const CW = 74, CH = 44;
  return Object.keys(racks).sort().map((rack) => {
    const cells = racks[rack];
    const bays = Math.max(...cells.map((c) => c.bay));
    const levels = Math.max(...cells.map((c) => c.level));
    const w = bays * CW + 40, h = levels * CH + 36;
    const g = svg("svg", { class: "rack", "data-rack": rack, viewBox: `0 0 ${w} ${h}`, width: w, height: h,
      role: "group", "aria-label": `rack ${rack}: ${cells.length} places, bays 1 to ${bays} left to right, level 1 at the bottom; Enter on a place opens it` });
    g.append(svg("text", { x: 4, y: 14, class: "rack-name" }, `rack ${rack}`));
    for (let b = 1; b <= bays; b++) {
      g.append(svg("text", { x: 30 + (b - 0.5) * CW, y: h - 4, class: "axis" }, String(b).padStart(2, "0")));
    }
    for (const c of cells) {
      const row = rowOf(c.place);
      const d = reviewOf(c.place);
      const answer = d ? d.answer : row ? (row.answer || "-") : "";
      const x = 30 + (c.bay - 1) * CW, y = 18 + (levels - c.level) * CH;
      const ink = inkFor(colour(c.place));
      const cell = svg("g", {
        class: "place" + (state.selected === c.place ? " selected" : ""), "data-place": c.place,
        "data-answer": row ? (row.answer || "") : "", "data-status": row ? row.status : "pending",
        "data-colour": colourKey(c.place), onclick: () => select(c.place),
        "aria-label": `${c.place}: ${answer || "not answered"} (${colourKey(c.place).replace("_", " ")})`,
      },
      svg("rect", { x: x + 2, y: y + 2, width: CW - 4, height: CH - 4, rx: 3, fill: colour(c.place), stroke: "#555" }),
      svg("text", { x: x + CW / 2, y: y + 17, class: `cell-place ${ink}` }, c.place),
      svg("text", { x: x + CW / 2, y: y + 33, class: `cell-answer ${ink}` }, answer));
      g.append(cell);
    }
    return g;
  });
}

// The top view: places (from the world), pads, every drone's track and where it is now.
function mapView() {
  const pts = [];
  for (const p of Object.values(state.info.positions)) pts.push([p[0], p[1]]);
  for (const pad of state.info.pads) pts.push(pad.xy);
  for (const tr of Object.values(state.info.tracks)) for (const p of tr) pts.push([p[1], p[2]]);
  if (pts.length === 0) return el("p", { class: "note" }, "no positions yet");
  const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
  const minX = Math.min(...xs) - 0.5, maxX = Math.max(...xs) + 0.5;
  const minY = Math.min(...ys) - 0.5, maxY = Math.max(...ys) + 0.5;
  // the long side across: an aisle along y is drawn as seen from it (bay 01 on the left)
  const turned = maxY - minY > maxX - minX;
  const across = turned ? maxY - minY : maxX - minX, down = turned ? maxX - minX : maxY - minY;
  const S = Math.min(860 / across, 360 / down);
  // room in pixels around the world's extent for the names written beside pads and drones
  const PX = 44, PY = 16;
  const W = across * S + 2 * PX, H = down * S + 2 * PY;
  state.toMap = turned
    ? (x, y) => [PX + (maxY - y) * S, PY + (maxX - x) * S]
    : (x, y) => [PX + (x - minX) * S, PY + (maxY - y) * S];
  const m = svg("svg", { id: "map", viewBox: `0 0 ${W} ${H}`, width: W, height: H, role: "img",
    "aria-label": `map, top view: ${Object.keys(state.info.positions).length} places, ${state.info.pads.length} pads and the tracks of ${Object.keys(state.info.tracks).length} drones` });
  // the levels of a bay stand one above the other: drawn side by side, the lowest first
  const spots = {};
  for (const [place, p] of Object.entries(state.info.positions)) {
    const [x, y] = state.toMap(p[0], p[1]);
    const key = `${Math.round(x)},${Math.round(y)}`;
    (spots[key] = spots[key] || []).push({ place, x, y, z: p[2] });
  }
  for (const spot of Object.values(spots)) {
    spot.sort((a, b) => a.z - b.z);
    const w = Math.max(3, 12 / spot.length), x0 = spot[0].x - (w * spot.length) / 2;
    spot.forEach((s, k) => m.append(svg("rect", { class: "map-place", "data-place": s.place, x: x0 + k * w, y: s.y - 4, width: w, height: 8, fill: colour(s.place), stroke: "#555", "stroke-width": 0.5 },
      svg("title", {}, s.place))));
  }
  for (const pad of state.info.pads) {
    const [x, y] = state.toMap(pad.xy[0], pad.xy[1]);
    m.append(svg("circle", { class: "pad", cx: x, cy: y, r: 7 }), svg("text", { x: x + 9, y: y + 4, class: "axis" }, pad.name));
  }
  const palette = ["#1f77b4", "#d62728", "#9467bd", "#17becf"];
  Object.entries(state.info.tracks).forEach(([drone, tr], i) => {
    const line = svg("polyline", { class: "track", "data-drone": drone, stroke: palette[i % 4], points: tr.map((p) => state.toMap(p[1], p[2]).join(",")).join(" ") });
    m.append(line);
    const last = tr[tr.length - 1];
    const [x, y] = last ? state.toMap(last[1], last[2]) : [-20, -20];
    m.append(svg("g", { class: "drone", "data-drone": drone, "data-x": last ? last[1] : "", "data-y": last ? last[2] : "" },
      svg("circle", { cx: x, cy: y, r: 6, fill: palette[i % 4] }),
      svg("text", { x: x - 8, y: y - 8, class: "drone-name" }, drone)));
  });
  return m;
}

function moveDrone(drone, at, points) {
  const g = document.querySelector(`#map g.drone[data-drone="${CSS.escape(drone)}"]`);
  const line = document.querySelector(`#map polyline.track[data-drone="${CSS.escape(drone)}"]`);
  if (!g || !state.toMap) { renderRun(); return; }
  const [x, y] = state.toMap(at[1], at[2]);
  g.setAttribute("data-x", at[1]);
  g.setAttribute("data-y", at[2]);
  g.querySelector("circle").setAttribute("cx", x);
  g.querySelector("circle").setAttribute("cy", y);
  g.querySelector("text").setAttribute("x", x - 8);
  g.querySelector("text").setAttribute("y", y - 8);
  if (line) {
    const more = points.map((p) => state.toMap(p[1], p[2]).join(",")).join(" ");
    line.setAttribute("points", (line.getAttribute("points") + " " + more).trim());
  }
}

const COLUMNS = [
  ["place", "place"], ["answer", "answer"], ["status", "status"], ["best_id", "closest"],
  ["distance", "distance"], ["margin", "margin"], ["blocks_seen", "blocks"], ["drone", "drone"],
  ["mission_time_s", "time (s)"], ["grade", "grade (sim)"], ["review", "review"],
];

function cellValue(row, key) {
  if (key === "grade") return state.info.grades[row.place] || "";
  if (key === "review") { const d = reviewOf(row.place); return d ? `${d.answer} (${d.reviewer})` : ""; }
  return row[key];
}

function placesTable() {
  let rows = state.info.rows.slice();
  const f = state.filter.toLowerCase();
  if (f) rows = rows.filter((r) => COLUMNS.some(([k]) => String(cellValue(r, k) ?? "").toLowerCase().includes(f)));
  if (state.statusFilter) rows = rows.filter((r) => r.status === state.statusFilter);
  if (state.sortKey) {
    const k = state.sortKey, s = state.sortUp ? 1 : -1;
    rows.sort((a, b) => {
      const x = cellValue(a, k), y = cellValue(b, k);
      if (typeof x === "number" && typeof y === "number") return s * (x - y);
      return s * String(x ?? "").localeCompare(String(y ?? ""));
    });
  }
  const head = el("tr", {}, COLUMNS.map(([k, label]) => el("th", {
    "data-key": k, class: "sortable" + (state.sortKey === k ? (state.sortUp ? " up" : " down") : ""),
    onclick: () => { state.sortUp = state.sortKey === k ? !state.sortUp : true; state.sortKey = k; renderTable(); },
  }, label)));
  const body = rows.map((r) => el("tr", { "data-place": r.place, class: state.selected === r.place ? "selected" : "", onclick: () => select(r.place) },
    COLUMNS.map(([k]) => {
      const v = cellValue(r, k);
      const text = typeof v === "number" ? (k === "mission_time_s" ? fmtNumber(v, 1) : Number.isInteger(v) ? String(v) : fmtNumber(v, 3)) : (v ?? "");
      return el("td", { "data-key": k, class: typeof v === "number" ? "num" : "" }, text);
    })));
  return el("div", { class: "scroll", id: "places" }, el("table", { class: "grid" }, el("thead", {}, head), el("tbody", {}, body)));
}

function renderTable() {
  keepFocus(() => {
    const old = document.getElementById("places");
    if (old) old.replaceWith(placesTable());
  });
}

// Redraw without losing the keyboard focus (and the caret of a text field): live updates
// and clicks redraw the page, and the operator typing in the filter keeps typing there
function keepFocus(draw) {
  const a = document.activeElement;
  const was = a && a !== document.body && app.contains(a) ? {
    id: a.id, place: a.getAttribute("data-place"), key: a.getAttribute("data-key"),
    where: a.closest("#racks") ? "#racks g.place" : a.closest("#places tbody") ? "#places tbody tr" : a.closest("#places thead") ? "#places th" : null,
    start: typeof a.selectionStart === "number" ? a.selectionStart : null, end: a.selectionEnd,
  } : null;
  draw();
  if (!was) return;
  let next = null;
  if (was.id) next = document.getElementById(was.id);
  else if (was.where && was.place) next = app.querySelector(`${was.where}[data-place="${CSS.escape(was.place)}"]`);
  else if (was.where && was.key) next = app.querySelector(`${was.where}[data-key="${CSS.escape(was.key)}"]`);
  if (!next || next === document.activeElement) return;
  next.focus({ preventScroll: true });
  if (was.start !== null && typeof next.setSelectionRange === "function") {
    try { next.setSelectionRange(was.start, was.end); } catch (e) { /* not a text field */ }
  }
}

function placeDetail() {
  const place = state.selected;
  if (!place) return el("div", { id: "place-detail", class: "detail" }, el("p", { class: "note" }, "Click a place for its crops and candidates."));
  const row = rowOf(place) || {};
  const ev = state.info.evidence[place];
  const d = reviewOf(place);
  return el("div", { id: "place-detail", class: "detail", "data-place": place },
    el("h3", {}, place),
    el("p", {}, `answer ${row.answer || "-"} (${row.status || "not answered yet"})`,
      row.reason ? ` - ${row.reason}` : "", state.info.truth[place] !== undefined ? ` - in the simulator: ${state.info.truth[place] || "empty"}` : ""),
    d ? el("p", { class: "reviewed" }, `reviewed: ${d.answer} by ${d.reviewer} at ${d.time}${d.reason ? " - " + d.reason : ""}`) : null,
    ev && ev.crops.length ? el("div", { class: "crops" }, ev.crops.map((c) => el("img", { src: fileUrl(RUN, c), alt: c, class: "crop" }))) : el("p", { class: "note" }, "no block crops for this place"),
    ev && ev.candidates.length ? el("table", { class: "grid candidates" },
      el("thead", {}, el("tr", {}, el("th", {}, "candidate"), el("th", {}, "distance"))),
      el("tbody", {}, ev.candidates.map(([id, dist]) => el("tr", {}, el("td", {}, id), el("td", { class: "num" }, fmtNumber(dist, 3)))))) : null,
    state.info.queue.includes(place) ? el("p", {}, el("a", { href: `/runs/${encodeURIComponent(RUN)}/review#${encodeURIComponent(place)}` }, "review this place")) : null,
    state.info.store ? el("p", {}, el("a", { href: `/places/${encodeURIComponent(place)}`, id: "place-history-link" }, "history across runs (site store)")) : null);
}

function select(place) {
  state.selected = place;
  renderRun();
}

function summaryLine() {
  const i = state.info;
  const counts = {};
  for (const r of i.rows) counts[r.status] = (counts[r.status] || 0) + 1;
  const parts = Object.entries(counts).map(([k, n]) => `${n} ${k.replace("_", " ")}`);
  // a place not scanned (an interrupted run) has a row, but no answer
  const notScanned = i.places - i.answered;
  const shown = typeof i.accuracy !== "number" ? "" : i.accuracy_over === "answered"
    ? ` - accuracy in simulation ${i.status === "RUNNING" ? "so far " : ""}${pct(i.accuracy)} of the places answered` +
      (i.status !== "RUNNING" && notScanned > 0 ? ` (${notScanned} not scanned)` : "")
    : ` - accuracy in simulation ${pct(i.accuracy)}`;
  return `${i.answered} of ${i.places} places answered` + (parts.length ? `: ${parts.join(", ")}` : "") + shown;
}

function renderRun() {
  keepFocus(drawRun);
}

function drawRun() {
  const i = state.info;
  const exp = (kind, fmt) => el("a", { href: `/export/${encodeURIComponent(RUN)}/${kind}.${fmt}`, class: "button", "data-export": `${kind}.${fmt}`, download: "" }, `${kind} ${fmt.toUpperCase()}`);
  const pending = i.queue.filter((p) => !reviewOf(p)).length;
  const colourBy = el("select", { id: "colour-by", "aria-label": "colour the racks by", onchange: (e) => { state.colourBy = e.target.value; renderRun(); } },
    ["status", "grade", "discrepancy"].map((k) => el("option", { value: k, selected: state.colourBy === k }, `colour by ${k}`)));
  const filter = el("input", { id: "filter", type: "search", placeholder: "filter places", "aria-label": "filter places", value: state.filter,
    oninput: (e) => { state.filter = e.target.value; renderTable(); } });
  const statuses = [...new Set(i.rows.map((r) => r.status))].sort();
  const statusSel = el("select", { id: "status-filter", "aria-label": "show only places of status", onchange: (e) => { state.statusFilter = e.target.value; renderTable(); } },
    el("option", { value: "" }, "every status"), statuses.map((s) => el("option", { value: s, selected: state.statusFilter === s }, s)));
  mount(
    el("h1", {}, i.name, " ", el("span", { id: "run-status", class: `status status-${i.status}` }, i.status)),
    el("p", { id: "run-summary" }, `${i.mission} - ${i.kind}${i.drones.length ? " of " + i.drones.join(", ") : ""} - `, summaryLine()),
    i.error ? el("p", { class: "error" }, i.error) : null,
    state.live ? el("p", { id: "live-state", class: state.live.cls, role: "status" }, state.live.text) : null,
    el("p", { class: "actions" },
      el("a", { href: `/runs/${encodeURIComponent(RUN)}/review`, class: "button", id: "review-link" }, `review queue (${pending} to review)`),
      i.rows_error ? el("span", { class: "note" }, "no export: the run's rows cannot be read")
        : i.no_inventory ? el("span", { class: "note", id: "no-export" }, "no export: the run has no inventory.json (no place answered yet, or not an inventory)") : [exp("inventory", "csv"), exp("inventory", "xlsx"), exp("discrepancies", "csv"), exp("discrepancies", "xlsx")],
      i.report ? el("a", { href: fileUrl(RUN, "report.html"), class: "button" }, "flight report") : null),
    el("section", {}, el("h2", {}, "Rack faces ", colourBy), legend(state.colourBy), el("div", { id: "racks" }, rackFaces())),
    el("div", { class: "two" },
      el("section", {}, el("h2", {}, "Map (top view)"), mapView()),
      el("section", {}, el("h2", {}, "Place"), placeDetail())),
    el("section", {}, el("h2", {}, "Places ", filter, statusSel), placesTable()));
}

// Live updates: one event stream while the tab is shown. A hidden tab closes it (a browser
// has 6 connections per host: six tabs left open on running runs locked the console out),
// and opens it again when shown; a stream the console refuses (too many live views) or
// loses is said on the page, which then checks every POLL_MS instead.
const POLL_MS = 10000;

function setLive(text, cls) {
  state.live = text ? { text, cls: cls || "note" } : null;
  const old = document.getElementById("live-state");
  if (old && state.live) { old.textContent = text; old.className = state.live.cls; }
  else if (old) old.remove();
  else if (state.live) {
    const after = document.getElementById("run-summary");
    if (after) after.after(el("p", { id: "live-state", class: state.live.cls, role: "status" }, text));
  }
}

function isLive() {
  return state.info && ["RUNNING", "INCOMPLETE"].includes(state.info.status);
}

function stopFollowing() {
  if (state.source) { state.source.close(); state.source = null; }
  if (state.poll) { clearTimeout(state.poll); state.poll = null; }
}

function pollLater() {
  if (state.poll) clearTimeout(state.poll);
  state.poll = setTimeout(async () => {
    state.poll = null;
    if (document.hidden) return;
    try { await refresh(); } catch (e) { setLive(`live updates stopped: the console did not answer (${e.message}); trying again`, "error"); pollLater(); return; }
    if (!isLive()) { setLive(null); return; }
    follow(true);
  }, POLL_MS);
}

function follow(retry) {
  if (state.source) return;
  if (!isLive()) { if (state.live) setLive(null); return; }
  if (document.hidden) { setLive("live updates paused while this tab is hidden"); return; }
  const src = new EventSource(`/api/runs/${encodeURIComponent(RUN)}/events`);
  state.source = src;
  if (!retry) setLive("live: updating as the run writes its files");
  src.addEventListener("open", () => setLive("live: updating as the run writes its files"));
  src.addEventListener("error", () => {
    if (state.source !== src) return;
    if (src.readyState === EventSource.CLOSED) {  // refused (503), or not an event stream
      state.source = null;
      setLive(`live view refused by the console (too many live views open, or it stopped): this page checks for changes every ${POLL_MS / 1000} s instead`, "error");
      pollLater();
    } else {
      setLive("live updates interrupted: reconnecting...", "error");
    }
  });
  src.addEventListener("drones", (e) => {
    for (const [drone, d] of Object.entries(JSON.parse(e.data))) {
      const tr = state.info.tracks[drone] || (state.info.tracks[drone] = []);
      tr.push(...d.track);
      moveDrone(drone, d.at, d.track);
    }
  });
  src.addEventListener("rows", async (e) => {
    const data = JSON.parse(e.data);
    const known = new Set(Object.keys(state.info.evidence));
    state.info.rows = data.rows;
    state.info.planned = data.planned;
    state.info.answered = data.rows.filter((r) => r.status !== "not_scanned").length;
    for (const r of data.rows) if (!(r.place in state.info.layout)) { await refresh(); return; }
    if (data.rows.some((r) => !known.has(r.place))) { await refresh(); return; }
    renderRun();
  });
  src.addEventListener("review", (e) => { state.info.review = JSON.parse(e.data); renderRun(); });
  src.addEventListener("status", async () => { await refresh(); });
  src.addEventListener("end", () => { src.close(); state.source = null; setLive(null); });
}

document.addEventListener("visibilitychange", async () => {
  if (PAGE !== "run" || !state.info) return;
  if (document.hidden) {
    if (state.source || state.poll) {
      stopFollowing();
      setLive("live updates paused while this tab is hidden");
    }
    return;
  }
  if (!isLive()) return;
  await refresh();  // what changed while hidden
  follow();
});

// Everything again (new places' evidence, grades at the end), keeping the view's choices.
async function refresh() {
  state.info = await getJSON(`/api/runs/${encodeURIComponent(RUN)}`);
  renderRun();
}

async function runPage() {
  await refresh();
  follow();
}

// ---- a place's history across runs (the site store) -------------------------------------
async function placePage() {
  const place = RUN;
  const data = await getJSON(`/api/places/${encodeURIComponent(place)}`);
  const rows = data.history.map((h) => el("tr", { "data-run": h.run },
    el("td", {}, h.here ? el("a", { href: `/runs/${encodeURIComponent(h.run)}` }, h.run) : h.run),
    el("td", {}, fmtTime(h.started)), el("td", {}, h.answer ?? ""), el("td", {}, h.status ?? ""),
    el("td", {}, h.drone ?? ""), el("td", { class: "num" }, fmtNumber(h.distance, 3)),
    el("td", { class: "num" }, fmtNumber(h.margin, 3)), el("td", {}, h.run_status ?? ""),
    el("td", {}, h.fleet ? `${h.fleet} (fleet)` : (h.rig ?? ""))));
  // runs of several rigs or fleets (one store may hold several sites): said above the table
  const flownBy = new Set(data.history.map((h) => h.fleet ? `fleet ${h.fleet}` : (h.rig ? `rig ${h.rig}` : "")));
  flownBy.delete("");
  mount(
    el("h1", {}, `Place ${place}`),
    el("p", { class: "note" }, `${data.history.length} runs, oldest first, from the site store ${data.store}`),
    flownBy.size > 1 ? el("p", { class: "note", id: "history-rigs" },
      `flown by ${[...flownBy].join(", ")}: compare answers of one rig or fleet with care`) : null,
    el("table", { id: "history", class: "grid" },
      el("thead", {}, el("tr", {}, ["run", "started", "answer", "status", "drone", "distance", "margin",
        "run status", "rig or fleet"].map((h) => el("th", {}, h)))),
      el("tbody", {}, rows)));
}

if (PAGE === "place") placePage().catch((e) => mount(el("p", { class: "error" }, String(e))));
if (PAGE === "index") indexPage().catch((e) => mount(el("p", { class: "error" }, String(e))));
if (PAGE === "run") runPage().catch((e) => mount(el("p", { class: "error" }, String(e))));
