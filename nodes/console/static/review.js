// btrun console: the review queue (every unknown, unverified and mismatch place).
"use strict";

const reviewApp = document.getElementById("app");

function lastDecision(info, place) {
  let last = null;
  (info.review || []).forEach((d, i) => {
    if (d.place === place) last = { ...d, seq: Number.isInteger(d.seq) ? d.seq : i + 1 };
  });
  return last;
}

function reviewItem(info, place) {
  const row = info.rows.find((r) => r.place === place) || {};
  const ev = info.evidence[place] || { crops: [], candidates: [] };
  let done = lastDecision(info, place);  // the decision a new one replaces (null: none)
  const name = `decision-${place}`;
  const ids = [...new Set([...ev.candidates.map((c) => c[0]), ...info.gallery.identities])];
  const listId = `ids-${place}`;
  const result = el("p", { class: "result", "aria-live": "polite" }, done ? `decided: ${done.answer} (${done.decision}) by ${done.reviewer} at ${done.time}` : "");
  // the engine's closest candidate is only a suggestion where it identified the place: an
  // unknown place's candidate was refused, and two clicks would teach the gallery a wrong one
  const suggested = ev.candidates.length && row.status !== "unknown" && row.status !== "not_identified" ? ev.candidates[0][0] : "";
  const form = el("form", { class: "decide", "data-place": place },
    el("label", {}, el("input", { type: "radio", name, value: "identity", disabled: ev.crops.length !== 3 }), " this pallet: ",
      el("input", { type: "text", name: "identity", list: listId, placeholder: "identity", "aria-label": `identity of ${place}`, value: suggested, size: 10 })),
    el("datalist", { id: listId }, ids.map((id) => el("option", { value: id }))),
    el("label", {}, el("input", { type: "radio", name, value: "new_pallet", disabled: ev.crops.length !== 3 }), " new pallet, enrol as ",
      el("input", { type: "text", name: "new_name", placeholder: "new identity", "aria-label": `new identity for ${place}`, size: 10 })),
    el("label", {}, el("input", { type: "radio", name, value: "leave_unknown" }), " leave unknown"),
    el("label", {}, "why ", el("input", { type: "text", name: "reason", placeholder: "reason (audit)", size: 28 })),
    el("button", { type: "submit" }, "Decide"));
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    const fd = new FormData(form);
    const reviewer = document.getElementById("reviewer").value.trim();
    localStorage.setItem("console-reviewer", reviewer);
    const body = {
      place, decision: fd.get(name), identity: fd.get("identity"), new_name: fd.get("new_name"),
      reason: fd.get("reason"), reviewer, replaces: done ? done.seq : null,
    };
    if (!fd.get(name)) {
      result.textContent = "choose one first: this pallet, new pallet or leave unknown";
      result.className = "result error";
      return;
    }
    result.textContent = "recording...";
    result.className = "result";
    const r = await fetch(`/api/runs/${encodeURIComponent(RUN_NAME)}/review`, {
      method: "POST",
      headers: { "Content-Type": "application/json", "X-Console-Token": consoleToken() },
      body: JSON.stringify(body),
    });
    const data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
    if (!r.ok) {
      result.textContent = `refused: ${data.error}`;
      result.className = "result error";
      return;
    }
    const d = data.decision;
    done = d;  // a change of mind from this page replaces this decision
    result.textContent = `recorded: ${d.answer} (${d.decision}) by ${d.reviewer}` + (d.gallery_event ? ` - gallery event #${d.gallery_event}` : "");
    result.className = "result ok";
    item.classList.add("decided");
  });
  const item = el("div", { class: "review-item" + (done ? " decided" : ""), id: place, "data-place": place },
    el("h3", {}, place, " ", el("span", { class: "was" }, `${row.answer || "-"} (${row.status})`), row.drone ? ` - ${row.drone}` : ""),
    row.discrepancy ? el("p", { class: "expected" }, `expected ${row.expected || "empty"}: ${row.discrepancy}` + (row.moved_from ? `, moved from ${row.moved_from}` : "")) : null,
    row.reason ? el("p", { class: "note" }, row.reason) : null,
    el("div", { class: "crops" }, ev.crops.length ? ev.crops.map((c, i) => el("img", { src: fileUrl(RUN_NAME, c), alt: `block ${i + 1} of ${place}`, class: "crop" })) : el("span", { class: "note" }, "no crops")),
    ev.candidates.length ? el("table", { class: "grid candidates" },
      el("thead", {}, el("tr", {}, el("th", {}, "candidate"), el("th", {}, "distance"))),
      el("tbody", {}, ev.candidates.slice(0, 5).map(([id, d]) => el("tr", {}, el("td", {}, id), el("td", { class: "num" }, fmtNumber(d, 3)))))) : null,
    form, result);
  return item;
}

const RUN_NAME = reviewApp.dataset.run;

async function reviewPage() {
  const info = await getJSON(`/api/runs/${encodeURIComponent(RUN_NAME)}`);
  const reviewer = el("input", { id: "reviewer", type: "text", placeholder: "your name", value: localStorage.getItem("console-reviewer") || "", size: 16 });
  const tokenInput = el("input", { id: "token", type: "password", placeholder: "console token", size: 24,
    onchange: (e) => { sessionStorage.setItem("console-token", e.target.value.trim()); tokenState(); } });
  reviewApp.replaceChildren(...[
    el("h1", {}, "Review ", el("a", { href: `/runs/${encodeURIComponent(RUN_NAME)}` }, RUN_NAME)),
    el("p", {}, `${info.queue.length} exceptions (unknown, unverified, mismatch). Decisions go to review.json beside the run's rows and update the gallery `,
      el("code", { id: "gallery-path" }, info.gallery.path),
      "; fly the next inventory with ", el("code", {}, `--set gallery=${info.gallery.path}`), "."),
    el("p", { class: "who" }, el("label", {}, "reviewer ", reviewer), " ", consoleToken() ? null : el("label", {}, "token ", tokenInput)),
    info.queue.length === 0 ? el("p", {}, "Nothing to review.") : el("div", { id: "queue" }, info.queue.map((p) => reviewItem(info, p)))].filter((n) => n));
  if (location.hash) {
    const target = document.getElementById(decodeURIComponent(location.hash.slice(1)));
    if (target) target.scrollIntoView();
  }
}

if (reviewApp.dataset.page === "review") reviewPage().catch((e) => reviewApp.replaceChildren(el("p", { class: "error" }, String(e))));
