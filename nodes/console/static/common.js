// btrun console: helpers shared by the pages (no framework, no CDN: served by btrun console).
"use strict";

const SVGNS = "http://www.w3.org/2000/svg";

// The token for review decisions: given once as ?token=... (the URL btrun console prints),
// kept for this browser tab only, and taken out of the address bar.
(function keepToken() {
  const url = new URL(window.location.href);
  const token = url.searchParams.get("token");
  if (token) {
    sessionStorage.setItem("console-token", token);
    sessionStorage.removeItem("console-token-state");
    url.searchParams.delete("token");
    history.replaceState(null, "", url.pathname + url.search + url.hash);
  }
})();

function consoleToken() {
  return sessionStorage.getItem("console-token") || "";
}

// An element with attributes and children (text children become text nodes: data from a
// run folder never becomes HTML).
function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  setAttrs(node, attrs);
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

function svg(tag, attrs, ...children) {
  const node = document.createElementNS(SVGNS, tag);
  setAttrs(node, attrs);
  for (const c of children.flat()) {
    if (c === null || c === undefined) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

// Elements that act on a click without being a link or a button (a rack cell, a table row,
// a sortable header) are reachable by keyboard too: Tab to them, Enter or Space acts.
const NATIVE = new Set(["a", "button", "input", "select", "textarea", "summary", "label"]);

function setAttrs(node, attrs) {
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v === true ? "" : String(v));
  }
  const click = attrs && attrs.onclick;
  if (typeof click === "function" && !NATIVE.has(node.localName)) {
    if (!node.hasAttribute("tabindex")) node.setAttribute("tabindex", "0");
    if (!node.hasAttribute("role") && !["th", "tr", "td"].includes(node.localName)) node.setAttribute("role", "button");
    node.addEventListener("keydown", (e) => {
      if (e.key === "Enter" || e.key === " ") { e.preventDefault(); click(e); }
    });
  }
}

async function getJSON(url) {
  const r = await fetch(url, { headers: { Accept: "application/json" } });
  if (!r.ok) throw new Error(`${url}: ${r.status} ${await r.text()}`);
  return r.json();
}

function fmtNumber(v, digits) {
  return typeof v === "number" && isFinite(v) ? v.toFixed(digits) : "";
}

function fmtTime(epochS) {
  // local time, with its offset from UTC: the exports are in UTC ("...Z")
  if (typeof epochS !== "number" || !epochS) return "";
  const d = new Date(epochS * 1000);
  const p = (n) => String(n).padStart(2, "0");
  const off = -d.getTimezoneOffset();
  const zone = off === 0 ? "UTC" : `UTC${off > 0 ? "+" : "-"}${p(Math.floor(Math.abs(off) / 60))}${Math.abs(off) % 60 ? ":" + p(Math.abs(off) % 60) : ""}`;
  return `${d.getFullYear()}-${p(d.getMonth() + 1)}-${p(d.getDate())} ${p(d.getHours())}:${p(d.getMinutes())} ${zone}`;
}

function pct(share) {
  // 0.9965 -> "99.7 %": one decimal, and "100 %" only when every place was right (a
  // whole-number percentage showed 287 of 288 as 100 %)
  if (typeof share !== "number") return "";
  if (share >= 1) return "100 %";
  return `${Math.min(99.9, Math.round(1000 * share) / 10).toFixed(1)} %`;
}

function fileUrl(run, rel) {
  return `/files/${encodeURIComponent(run)}/${rel.split("/").map(encodeURIComponent).join("/")}`;
}

// Colours of a place: by answer (status), by grade in simulation, by discrepancy category.
const COLOURS = {
  status: {
    identified: "#2e9d4f", unknown: "#e0a100", not_identified: "#f07f0a", empty: "#c9ccd1",
    not_scanned: "#ffffff", unverified: "#8e5cc9", mismatch: "#d2342c", reviewed: "#2a7bd0",
    pending: "#f4f5f7",
  },
  grade: {
    right: "#2e9d4f", wrong: "#d2342c", unknown: "#e0a100", missed: "#f07f0a",
    not_scanned: "#ffffff", pending: "#f4f5f7",
  },
  discrepancy: {
    confirmed: "#2e9d4f", mismatch: "#d2342c", missing: "#f07f0a", unexpected: "#c2185b",
    unverified: "#8e5cc9", not_scanned: "#ffffff", unlisted: "#9aa4b2", exception: "#e0a100",
    none: "#c9ccd1", pending: "#f4f5f7",
  },
};

// The text colour (class ink-dark / ink-light) readable on a fill: black or white, whichever
// contrasts more (every fill above gives at least 4.5:1, WCAG AA)
function luminance(hex) {
  const c = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16) / 255)
    .map((x) => (x <= 0.04045 ? x / 12.92 : ((x + 0.055) / 1.055) ** 2.4));
  return 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2];
}

function inkFor(fill) {
  if (!/^#[0-9a-fA-F]{6}$/.test(fill)) return "ink-dark";
  const l = luminance(fill);
  return (l + 0.05) / 0.05 >= 1.05 / (l + 0.05) ? "ink-dark" : "ink-light";
}

function swatch(colour) {
  return svg("svg", { class: "swatch", width: 12, height: 12, viewBox: "0 0 12 12" },
    svg("rect", { x: 0.5, y: 0.5, width: 11, height: 11, fill: colour, stroke: "#666" }));
}

function legend(scheme) {
  return el("div", { class: "legend" },
    Object.entries(COLOURS[scheme]).map(([k, c]) =>
      el("span", { class: "key" }, swatch(c), k.replace("_", " "))));
}

function tokenState() {
  const span = document.getElementById("token-state");
  if (!span) return;
  const checked = sessionStorage.getItem("console-token-state");
  if (consoleToken()) {
    span.textContent = checked === "accepted" ? "review token accepted" : "review token set (checked at the first decision)";
    span.className = "token ok";
  } else if (checked === "refused") {
    span.textContent = "review token refused: type the token btrun console printed";
    span.className = "token refused";
  } else {
    span.textContent = "read only (open the URL btrun console printed to review)";
    span.className = "token none";
  }
}

document.addEventListener("DOMContentLoaded", tokenState);
