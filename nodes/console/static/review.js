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
  // a gallery change needs the place's 3 crops and a gallery of the run's world
  const noLearning = ev.crops.length !== 3 || !!info.gallery.problem;
  const reviewBroken = !!info.review_error;  // review.json cannot be read: nothing is recorded
  const button = el("button", { type: "submit", disabled: reviewBroken }, "Decide");
  const form = el("form", { class: "decide", "data-place": place },
    el("label", {}, el("input", { type: "radio", name, value: "identity", disabled: noLearning }), " this pallet: ",
      el("input", { type: "text", name: "identity", list: listId, placeholder: "identity", "aria-label": `identity of ${place}`, value: suggested, size: 10 })),
    el("datalist", { id: listId }, ids.map((id) => el("option", { value: id }))),
    el("label", {}, el("input", { type: "radio", name, value: "new_pallet", disabled: noLearning }), " new pallet, enrol as ",
      el("input", { type: "text", name: "new_name", placeholder: "new identity", "aria-label": `new identity for ${place}`, size: 10 })),
    el("label", {}, el("input", { type: "radio", name, value: "leave_unknown" }), " leave unknown"),
    el("label", {}, "why ", el("input", { type: "text", name: "reason", placeholder: "reason (audit)", size: 28 })),
    button);
  let busy = false;  // one request at a time: a double click records one decision
  form.addEventListener("submit", async (e) => {
    e.preventDefault();
    if (busy || reviewBroken) return;
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
    busy = true;
    button.disabled = true;
    form.setAttribute("aria-busy", "true");
    let r, data;
    try {
      r = await fetch(`/api/runs/${encodeURIComponent(RUN_NAME)}/review`, {
        method: "POST",
        headers: { "Content-Type": "application/json", "X-Console-Token": consoleToken() },
        body: JSON.stringify(body),
      });
      data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
    } catch (err) {
      r = { ok: false };
      data = { error: `the console did not answer (${err.message}): try again` };
    } finally {
      busy = false;
      button.disabled = false;
      form.removeAttribute("aria-busy");
    }
    if (!r.ok) {
      if (data.token_refused) tokenRefused();
      result.textContent = data.token_refused
        ? "refused: the console refused the review token (a typo, or the console was restarted with another one): type the token btrun console printed, above, and decide again"
        : `refused: ${data.error}`;
      result.className = "result error";
      return;
    }
    tokenAccepted();
    const d = data.decision;
    done = d;  // a change of mind from this page replaces this decision
    result.textContent = `recorded: ${d.answer} (${d.decision}) by ${d.reviewer}` + (d.gallery_event ? ` - gallery event #${d.gallery_event}` : "") + (d.already_recorded ? " (already recorded: not recorded twice)" : "");
    result.className = "result ok";
    item.classList.add("decided");
  });
  const item = el("div", { class: "review-item" + (done ? " decided" : ""), id: place, "data-place": place },
    el("h3", {}, place, " ", el("span", { class: "was" }, `${row.answer || "-"} (${row.status})`), row.drone ? ` - ${row.drone}` : ""),
    row.discrepancy ? el("p", { class: "expected" }, expectedText(row)) : null,
    row.reason ? el("p", { class: "note" }, row.reason) : null,
    el("div", { class: "crops" }, ev.crops.length ? ev.crops.map((c, i) => el("img", { src: fileUrl(RUN_NAME, c), alt: `block ${i + 1} of ${place}`, class: "crop" })) : el("span", { class: "note" }, "no crops")),
    ev.candidates.length ? el("table", { class: "grid candidates" },
      el("thead", {}, el("tr", {}, el("th", {}, "candidate"), el("th", {}, "distance"))),
      el("tbody", {}, ev.candidates.slice(0, 5).map(([id, d]) => el("tr", {}, el("td", {}, id), el("td", { class: "num" }, fmtNumber(d, 3)))))) : null,
    form, result);
  return item;
}

const RUN_NAME = reviewApp.dataset.run;

// What the expected stock said of a place: "not listed" is not "expected empty"
function expectedText(row) {
  const what = row.discrepancy === "unlisted" ? "not in the expected stock"
    : row.expected ? `expected ${row.expected}` : "expected empty";
  return `${what} (${row.discrepancy})` + (row.moved_from ? `, moved from ${row.moved_from}` : "");
}

// The token was refused: forget it and ask for it again (a typo, a restarted console)
function tokenRefused() {
  sessionStorage.removeItem("console-token");
  sessionStorage.setItem("console-token-state", "refused");
  tokenState();
  const field = document.getElementById("token-field");
  if (field) {
    field.hidden = false;
    const input = document.getElementById("token");
    input.value = "";
    input.focus();
  }
}

function tokenAccepted() {
  sessionStorage.setItem("console-token-state", "accepted");
  tokenState();
}

// Which gallery a decision teaches, said before any decision is taken
function galleryText(g) {
  if (!g.path) return el("p", { class: "error", id: "gallery-problem" }, `No gallery can be taught from this page: ${g.problem} Leaving a place unknown is still recorded.`);
  const whose = g.source === "option" ? "the console's --gallery file"
    : g.source === "run" ? "the gallery file this run flew with"
    : `the review gallery of this run's world ${g.world} (one per world in the runs folder${g.exists ? "" : "; made on the first decision as a copy of that world's demo gallery"})`;
  return el("div", {},
    el("p", { id: "gallery-note" }, "Decisions go to review.json beside the run's rows; \"this pallet\" and \"new pallet\" also teach ", whose, ": ",
      el("code", { id: "gallery-path" }, g.path),
      "; fly the next inventory with ", el("code", {}, `--set gallery=${g.path}`), "."),
    g.problem ? el("p", { class: "error", id: "gallery-problem" }, `${g.problem}. Leaving a place unknown is still recorded.`) : null);
}

async function reviewPage() {
  const info = await getJSON(`/api/runs/${encodeURIComponent(RUN_NAME)}`);
  const reviewer = el("input", { id: "reviewer", type: "text", placeholder: "your name", value: localStorage.getItem("console-reviewer") || "", size: 16 });
  const tokenInput = el("input", { id: "token", type: "password", placeholder: "console token", size: 24,
    onchange: (e) => {
      sessionStorage.setItem("console-token", e.target.value.trim());
      sessionStorage.removeItem("console-token-state");  // not checked yet
      tokenState();
    } });
  const tokenField = el("label", { id: "token-field" }, "token ", tokenInput);
  tokenField.hidden = !!consoleToken();
  reviewApp.replaceChildren(...[
    el("h1", {}, "Review ", el("a", { href: `/runs/${encodeURIComponent(RUN_NAME)}` }, RUN_NAME)),
    el("p", {}, `${info.queue.length} exceptions (unknown, unverified, mismatch).`),
    info.review_error ? el("p", { class: "error", id: "review-error" }, `Decisions cannot be recorded: ${info.review_error}`) : null,
    galleryText(info.gallery),
    el("p", { class: "who" }, el("label", {}, "reviewer ", reviewer), " ", tokenField),
    info.queue.length === 0 ? el("p", {}, "Nothing to review.") : el("div", { id: "queue" }, info.queue.map((p) => reviewItem(info, p)))].filter((n) => n));
  if (location.hash) {
    const target = document.getElementById(decodeURIComponent(location.hash.slice(1)));
    if (target) target.scrollIntoView();
  }
}

if (reviewApp.dataset.page === "review") reviewPage().catch((e) => reviewApp.replaceChildren(el("p", { class: "error" }, String(e))));
