// ltm view: the light follows the pointer. One /relight request in flight at a time; when it
// returns, the latest pointer position (if it moved) is sent next. Each request asks for the
// part of the image on the screen at the screen's resolution (never more than the image's),
// first as a preview (the server relights every n-th pixel where the screen shows fewer), then,
// if nothing newer is wanted, whole.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { info: null, u: 0, v: 0, inflight: false, sent: null, wanted: null, url: null,
  k: 1, tx: 0, ty: 0, drag: null };
// Read by tests and benchmarks: the last image's light and round trip, every latency (ms).
window.ltmView = { ready: false, requests: 0, previews: 0, last: null, latencies: [],
  inflight: false };

const mode = () => document.querySelector("input[name=mode]:checked").value;
const fmt = (x) => Number(x).toFixed(3);

function viewValue(axis) {
  const [lo, hi] = state.info.views[axis];
  return lo + Number($("view-" + axis).value) * (hi - lo);
}

function query() {
  const p = new URLSearchParams({ u: state.u.toFixed(5), v: state.v.toFixed(5) });
  if (mode() === "area") p.set("radius", $("radius").value);
  if (state.info.views) p.set("view", `${viewValue("p")},${viewValue("q")}`);
  p.set("ev", $("auto").checked ? "auto" : $("ev").value);
  const shown = onScreen();
  p.set("region", shown.region.join(","));
  p.set("size", shown.size.join(","));
  return p.toString();
}

// The image's pixels in the viewport, whole pixels from the top left, and the size that fills
// the screen's pixels there (the region's own when zoomed in further).
function onScreen() {
  const vp = $("viewport").getBoundingClientRect();
  const { width, height } = state.info;
  const x0 = Math.max(0, Math.floor(-state.tx / state.k));
  const y0 = Math.max(0, Math.floor(-state.ty / state.k));
  const x1 = Math.min(width, Math.max(x0 + 1, Math.ceil((vp.width - state.tx) / state.k)));
  const y1 = Math.min(height, Math.max(y0 + 1, Math.ceil((vp.height - state.ty) / state.k)));
  const x = Math.min(x0, width - 1), y = Math.min(y0, height - 1);
  const w = Math.max(1, x1 - x), h = Math.max(1, y1 - y);
  const screen = state.k * (window.devicePixelRatio || 1);
  return { region: [x, y, w, h],
           size: [Math.min(w, Math.max(1, Math.ceil(w * screen))),
                  Math.min(h, Math.max(1, Math.ceil(h * screen)))] };
}

function request() {
  if (!state.info) return;
  state.wanted = query();
  if (!state.inflight && state.wanted !== state.sent) send(state.wanted, true);
}

async function send(q, preview) {
  state.inflight = window.ltmView.inflight = true;
  state.sent = q;
  let previewed = false;
  const t0 = performance.now();
  try {
    const resp = await fetch(`relight?${q}&${preview ? "preview" : "yield"}=1`,
                             { cache: "no-store" });
    if (resp.status === 409) return;  // given up for a newer light: it is sent next
    if (!resp.ok) throw new Error(await resp.text());
    const url = URL.createObjectURL(await resp.blob());
    const decoded = new Image();
    decoded.src = url;
    await decoded.decode();  // then shown and placed at once: no frame of it in the old place
    const img = $("image");
    img.src = url;
    const region = new URLSearchParams(q).get("region").split(",").map(Number);
    Object.assign(img.style, { left: `${region[0]}px`, top: `${region[1]}px`,
                               width: `${region[2]}px`, height: `${region[3]}px` });
    if (state.url) URL.revokeObjectURL(state.url);
    state.url = url;
    const ms = performance.now() - t0;
    const light = JSON.parse(resp.headers.get("X-Ltm-Light"));
    showLight(light, ms);
    $("warning").textContent = resp.headers.get("X-Ltm-Warning") || "";
    previewed = resp.headers.get("X-Ltm-Preview") === "1";
    Object.assign(window.ltmView, { last: { query: q, light, ms, region, preview: previewed,
      render_ms: Number(resp.headers.get("X-Ltm-Render-Ms")) }, ready: true });
    window.ltmView.latencies.push(ms);
    window.ltmView.requests += 1;
    window.ltmView.previews += previewed;
  } catch (err) {
    $("warning").textContent = String(err.message || err);
  } finally {
    state.inflight = window.ltmView.inflight = false;
    if (state.wanted !== state.sent) send(state.wanted, true);
    else if (previewed) send(q, false);  // nothing newer: the whole picture of the same view
  }
}

function showLight(light, ms) {
  const info = state.info;
  let text = info.far
    ? `lx ${fmt(light.r)}, ly ${fmt(light.s)}, lz ${fmt(Math.sqrt(Math.max(0,
        1 - light.r * light.r - light.s * light.s)))}`
    : `r ${fmt(light.r)}, s ${fmt(light.s)} ${info.unit}`;
  if (light.radius > 0) text += `, radius ${fmt(light.radius)}`;
  if (light.view) text += `; view p ${fmt(light.view[0])}, q ${fmt(light.view[1])}`;
  $("light-out").textContent = text;
  $("ms-out").textContent = `${ms.toFixed(0)} ms`;
}

// -- zoom and pan -------------------------------------------------------------------------

function apply() {
  $("stage").style.transform = `translate(${state.tx}px, ${state.ty}px) scale(${state.k})`;
  $("viewport").style.imageRendering = state.k > 2 ? "pixelated" : "auto";
  request();  // what is on the screen changed
}

function fit() {
  const vp = $("viewport").getBoundingClientRect();
  const { width, height } = state.info;
  state.k = 0.96 * Math.min(vp.width / width, vp.height / height);
  state.tx = (vp.width - width * state.k) / 2;
  state.ty = (vp.height - height * state.k) / 2;
  apply();
}

function zoom(e) {
  e.preventDefault();
  const vp = $("viewport").getBoundingClientRect();
  const x = e.clientX - vp.left, y = e.clientY - vp.top;
  const k = Math.min(Math.max(state.k * Math.exp(-e.deltaY * 0.0015), 0.05), 200);
  state.tx = x - (x - state.tx) * (k / state.k);
  state.ty = y - (y - state.ty) * (k / state.k);
  state.k = k;
  apply();
}

function pointerLight(e) {
  const rect = $("stage").getBoundingClientRect();
  const clip = (x) => Math.min(Math.max(x, -1), 1);
  state.u = clip(2 * (e.clientX - rect.left) / rect.width - 1);
  state.v = clip(1 - 2 * (e.clientY - rect.top) / rect.height);
  request();
}

function bind() {
  const vp = $("viewport");
  vp.addEventListener("wheel", zoom, { passive: false });
  vp.addEventListener("dblclick", fit);
  vp.addEventListener("pointerdown", (e) => {
    state.drag = { x: e.clientX, y: e.clientY, tx: state.tx, ty: state.ty };
    vp.setPointerCapture(e.pointerId);
    vp.classList.add("panning");
  });
  vp.addEventListener("pointermove", (e) => {
    if (state.drag) {
      state.tx = state.drag.tx + e.clientX - state.drag.x;
      state.ty = state.drag.ty + e.clientY - state.drag.y;
      apply();
    } else if (!$("hold").checked) {
      pointerLight(e);
    }
  });
  const stop = () => { state.drag = null; vp.classList.remove("panning"); };
  vp.addEventListener("pointerup", stop);
  vp.addEventListener("pointercancel", stop);
  document.addEventListener("keydown", (e) => {
    if (e.key === "h" || e.key === "H") $("hold").checked = !$("hold").checked;
  });
  for (const el of document.querySelectorAll("input[name=mode]")) {
    el.addEventListener("change", () => { $("radius-row").hidden = mode() !== "area";
      request(); });
  }
  $("radius").addEventListener("input", () => { showRadius(); request(); });
  $("auto").addEventListener("change", () => { $("ev").disabled = $("auto").checked;
    request(); });
  $("ev").addEventListener("input", () => { $("ev-out").textContent = $("ev").value;
    request(); });
  for (const axis of ["p", "q"]) {
    $("view-" + axis).addEventListener("input", () => { showViews(); request(); });
  }
  $("error").addEventListener("change", showError);
  $("opacity").addEventListener("input", showError);
  window.addEventListener("resize", fit);
}

function showRadius() {
  const info = state.info;
  const half = info.far ? 1 : (info.plane.r[1] - info.plane.r[0]) / 2;
  $("radius-out").textContent = `${fmt($("radius").value * half)}${info.far ? "" : " " + info.unit}`;
}

function showViews() {
  for (const axis of ["p", "q"]) $(`view-${axis}-out`).textContent = fmt(viewValue(axis));
}

async function showError() {
  const overlay = $("overlay");
  overlay.hidden = !$("error").checked;
  overlay.style.opacity = $("opacity").value;
  if (!overlay.hidden && !overlay.src) {
    const resp = await fetch("expected_error.png");
    $("error-max").textContent = resp.headers.get("X-Ltm-Error-Max");
    overlay.src = URL.createObjectURL(await resp.blob());
  }
}

async function start() {
  const info = state.info = await (await fetch("info")).json();
  document.title = `ltm view: ${info.store}`;
  $("title").textContent = info.store;
  $("stage").style.width = `${info.width}px`;
  $("stage").style.height = `${info.height}px`;
  $("view-set").hidden = !info.views;
  $("error-set").hidden = !info.expected_error;
  if (info.views) showViews();
  showRadius();
  bind();
  fit();
}

start();
