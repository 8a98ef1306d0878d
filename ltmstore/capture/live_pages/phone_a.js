// Phone A's page: the back camera with its LED on, every frame it can send tracked by the
// server, the answer drawn: the path over the plane, covered cells, K/M, the expected SNR.
// The camera is also recorded (MediaRecorder) and uploaded in pieces as camera B's is: at Stop
// the server tracks that whole video for the poses; the frames sent live are the feedback.
"use strict";

// Frames go to the tracker at most this wide (scaled, same aspect: the server scales the
// intrinsics): 1280 x 720 is what the tracker is measured at, and a 4K JPEG per frame would
// cut the update rate several times over for no gain in the drawn path.
const MAX_SEND_WIDTH = 1280;
const FRAME_WAIT_MS = 2000;  // a frame's callback awaited this long before trying again
const POLL_MS = 250;  // without that callback: the current frame drawn this often
// Where the page keeps the camera picked (a deviceId): the lens the intrinsics were calibrated on.
const CAMERA_KEY = "ltm.capture.phoneA.camera";

const capture = {
  state: "idle",      // idle -> starting -> running -> stopping -> stopped -> finished | error
  config: null,       // GET /api/config
  path: [],           // [[t, r, s, z], ...]: the placed frames the page drew, in order
  coveredCells: [],   // [[i, j], ...] from GET /api/state
  last: null,         // the last answer of POST /api/a/frame
  sent: 0,            // frames sent
  answered: 0,        // answers received
  placed: 0,          // answers with the light placed
  overtaken: 0,       // frames not sent: the next frame replaced it before it was drawn
  camera: null,       // the open camera's label
  torch: "unknown",   // "on" (the page switched the LED on) | "manual" (the user must)
  resolution: null,   // [width, height] of the frames sent
  latencyMs: null,    // mean time from sending a frame to its answer (last 20)
  rateHz: null,       // answers per second (last 20)
  finish: null,       // answer of POST /api/a/finish
  recording: null,    // the upload's counts (ltm.recordingUpload's stats)
  liveCoverage: null, // the coverage of the live frames, before phone A's video replaced it
  error: null,
};
window.ltmCapture = capture;

const el = (id) => document.getElementById(id);
let stream = null;
let track = null;
let stateRefresh = null;  // the pending GET /api/state, if any
let looping = null;       // the running frame loop (a promise), if any
const recent = [];        // [answer time ms, latency ms] of the last answers
let recorder = null;
let uploadProblem = false;  // the message banner shows the upload's problem
const upload = ltm.recordingUpload("a", (stats, problem) => {
  if (problem) ltm.banner("message", problem, "error");
  else if (uploadProblem) ltm.banner("message", "");
  uploadProblem = Boolean(problem);
}, fail);
capture.recording = upload.stats;

async function start() {
  el("start").disabled = true;
  capture.state = "starting";
  if (stream) stream.getTracks().forEach((t) => t.stop());  // a restart after an error
  try {
    capture.config = await ltm.api("/api/config");
    el("camera").disabled = true;
    stream = await ltm.openPreferredCamera(el("camera"), CAMERA_KEY, wantedSize(capture.config));
    track = stream.getVideoTracks()[0];
    capture.camera = track.label;
    const video = el("video");
    video.srcObject = stream;
    await video.play();
    await switchTorchOn();
    await refreshState();
    ltm.keepAwake();
    const settings = track.getSettings();
    const pixels = (settings.width || 1280) * (settings.height || 720);
    recorder = ltm.startRecorder(stream, upload,
                                 Math.min(40e6, Math.max(2.5e6, 0.25 * pixels * 30)));
    capture.state = "running";
    el("stop").disabled = false;
    draw();
    looping = frameLoop(video);
  } catch (error) {
    fail(error);
  }
}

/** The frame size the tracker's intrinsics were calibrated for, where the server says it. */
function wantedSize(config) {
  const size = config && config.image_size;
  return size ? {width: {ideal: size[0]}, height: {ideal: size[1]}} : {};
}

async function switchTorchOn() {
  const caps = track.getCapabilities ? track.getCapabilities() : {};
  if (caps.torch) {
    try {
      await track.applyConstraints({advanced: [{torch: true}]});
      capture.torch = "on";
      ltm.banner("torch", "LED on.", "ok");
      return;
    } catch (error) { /* fall through: the user switches it on */ }
  }
  capture.torch = "manual";
  ltm.banner("torch", "This browser cannot switch the LED on: switch the flashlight on " +
             "yourself now (quick settings), and keep it on until you press Stop.", "warn");
}

/**
 * Draw the next frame into ``canvas`` and return the time (s, on this page's performance.now()
 * clock) at which it was captured, or null where the video has no size yet or no frame came
 * within FRAME_WAIT_MS. The frame is drawn in its own callback: drawn later, a frame that
 * arrived in between (a loaded machine) was sent with its predecessor's time, one frame
 * interval early. The camera's own capture time is taken where the browser gives one: the
 * callback's ``now`` is the compositor's frame time, which a loaded machine delays by up to a
 * frame interval, and which precedes the capture time of half the frames of Chromium's camera
 * (so ``now`` cannot bound it). Where the browser has that callback, a frame is never sent
 * with a guessed time: without it, the time the page gave up waiting would place a frame that
 * arrived late (a loaded machine) where the LED was a few hundred ms later. Without the
 * callback, the current frame is drawn every POLL_MS and timed on arrival. The callback does
 * not guarantee that the video still shows its frame when it runs (a suite run paired one
 * frame in 35 with its neighbour's time): where the browser has VideoFrame, the frame is taken
 * as a VideoFrame, drawn only if its timestamp is the callback's, and skipped otherwise.
 */
function nextFrame(video, canvas) {
  const callback = Boolean(video.requestVideoFrameCallback);
  return new Promise((resolve) => {
    const timer = setTimeout(() => resolve(
      !callback && drawFrame(video, canvas) ? performance.now() / 1000 : null),
    callback ? FRAME_WAIT_MS : POLL_MS);
    if (callback) {
      video.requestVideoFrameCallback((now, meta) => {
        clearTimeout(timer);
        const arrived = performance.now();
        const t = meta && Number.isFinite(meta.captureTime) && meta.captureTime <= arrived &&
          meta.captureTime > arrived - 1000 ? meta.captureTime : now;
        resolve(drawFrame(video, canvas, meta) ? t / 1000 : null);
      });
    }
  });
}

/**
 * Draw the video's current frame into ``canvas``: false where the video has no size yet, or
 * where ``meta`` (a video-frame callback's) describes another frame than the one shown now.
 */
function drawFrame(video, canvas, meta) {
  if (!video.videoWidth) return false;
  const frame = meta ? currentFrame(video) : null;
  if (frame && Math.abs(frame.timestamp - meta.mediaTime * 1e6) > 1) {
    frame.close();
    capture.overtaken += 1;
    return false;
  }
  const scale = Math.min(1, MAX_SEND_WIDTH / video.videoWidth);
  canvas.width = Math.round(video.videoWidth * scale);
  canvas.height = Math.round(video.videoHeight * scale);
  canvas.getContext("2d").drawImage(frame || video, 0, 0, canvas.width, canvas.height);
  if (frame) frame.close();
  capture.resolution = [canvas.width, canvas.height];
  return true;
}

/** The frame the video shows now, with its own timestamp (null without VideoFrame). */
function currentFrame(video) {
  if (typeof VideoFrame !== "function") return null;
  try {
    return new VideoFrame(video);
  } catch (error) {
    return null;
  }
}

function encode(canvas) {
  return new Promise((resolve) => canvas.toBlob(resolve, "image/jpeg", 0.92));
}

/** Grab, send, wait for the answer, draw; the next frame only once the answer is in. */
async function frameLoop(video) {
  const canvas = document.createElement("canvas");
  let previous = -Infinity;
  while (capture.state === "running") {
    const t = await nextFrame(video, canvas);
    if (capture.state !== "running" || t === null || t <= previous) continue;
    previous = t;  // the server wants increasing times
    const jpeg = await encode(canvas);
    const sentAt = performance.now();
    try {
      capture.sent += 1;
      const answer = await ltm.api("/api/a/frame", {
        method: "POST", body: jpeg,
        headers: {"Content-Type": "image/jpeg", "X-Frame-Time": t.toFixed(4)}});
      onAnswer(answer, performance.now() - sentAt);
      ltm.banner("message", "");
    } catch (error) {
      if (capture.state !== "running") break;
      if (error.status) return fail(error);  // the server refused: retrying would not help
      ltm.banner("message", "The laptop does not answer: check the Wi-Fi; retrying…", "error");
      await ltm.sleep(1000);
    }
  }
}

function onAnswer(answer, latency) {
  capture.last = answer;
  capture.answered += 1;
  if (answer.placed && answer.led) {
    capture.placed += 1;
    const end = capture.path[capture.path.length - 1];
    if (!end || answer.t > end[0]) {  // a state refresh may have brought this frame already
      capture.path.push([answer.t, answer.led[0], answer.led[1], answer.led[2]]);
    }
  }
  recent.push([performance.now(), latency]);
  if (recent.length > 20) recent.shift();
  capture.latencyMs = recent.reduce((sum, r) => sum + r[1], 0) / recent.length;
  const span = (recent[recent.length - 1][0] - recent[0][0]) / 1000;
  capture.rateHz = span > 0 ? (recent.length - 1) / span : null;
  if (answer.coverage && answer.coverage.covered !== capture.coveredCells.length) {
    refreshState();
  }
  show(answer);
  draw();
}

/** The covered cells (and the path, when the page starts late) from GET /api/state. */
function refreshState() {
  if (!stateRefresh) {
    stateRefresh = ltm.api("/api/state").then((state) => {
      capture.coveredCells = state.covered_cells || [];
      if (state.path && state.path.length > capture.path.length) capture.path = state.path;
      draw();
      return state;
    }).catch(() => null).finally(() => { stateRefresh = null; });
  }
  return stateRefresh;
}

/** The coverage of phone A's whole video (GET /api/state once it is finished): what
 * `ltm reconstruct` will count. */
function showFinal(state) {
  if (!state) return;
  capture.liveCoverage = capture.last && capture.last.coverage;
  const keep = ["coverage", "expected_snr_db", "expected_snr_spread_db", "expected_snr_measured",
                "enough", "frames", "placed_frames"];
  capture.last = Object.assign({}, capture.last, {warning: null},
                               Object.fromEntries(keep.map((k) => [k, state[k]])));
  show(capture.last);
  draw();
}

function show(answer) {
  const c = answer.coverage;
  const target = capture.config.target_km;
  ltm.setText("km", `K/M ${c.k_over_m.toFixed(3)} of ${target.toFixed(2)}`);
  ltm.setText("cells", `${c.covered} of ${c.cells} covered`);
  ltm.setText("snr", `${answer.expected_snr_db.toFixed(1)} dB ± ` +
              `${answer.expected_snr_spread_db.toFixed(1)}`);
  const measured = (capture.config.expected_snr_source || {}).k_over_m;
  el("snr-note").hidden = answer.expected_snr_measured !== false || !measured;
  if (measured) {
    el("snr-note").textContent = `measured for K/M ${measured[0].toFixed(2)}–` +
      `${measured[measured.length - 1].toFixed(2)}: the nearest shown`;
  }
  ltm.setText("frames", `${answer.placed_frames} placed of ${answer.frames}`);
  ltm.setText("rate", capture.rateHz === null ? "–" :
              `${capture.rateHz.toFixed(1)} per s, ${Math.round(capture.latencyMs)} ms each`);
  ltm.banner("enough", answer.enough ? "ENOUGH: the plane is covered. You can stop." : "",
             "enough");
  const what = capture.config.tracker === "painting" ? "the painting" : "the board";
  const h = capture.config.plane.height;
  const tol = capture.config.height_tolerance;
  const warnings = {
    lost: `Light lost: keep ${what} in phone A's view.`,
    height: `Off the plane's height: hold the light at ${(100 * h).toFixed(0)} cm ` +
            `(± ${(100 * tol).toFixed(0)} cm) above the painting.`,
  };
  ltm.banner("warning", warnings[answer.warning] || "", "warn");
}

/** The plane (r right, s up), its lattice, the covered cells, the path and the light. */
function draw() {
  const config = capture.config;
  if (!config) return;
  const canvas = el("plane");
  const [r0, r1] = config.plane.r;
  const [s0, s1] = config.plane.s;
  const [nr, ns] = config.lattice;
  const cssWidth = canvas.clientWidth || 388;
  const ratio = window.devicePixelRatio || 1;
  const pad = 18;
  const scale = (cssWidth - 2 * pad) / (r1 - r0);
  const cssHeight = Math.round((s1 - s0) * scale + 2 * pad);
  canvas.width = Math.round(cssWidth * ratio);
  canvas.height = Math.round(cssHeight * ratio);
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  const x = (r) => pad + (r - r0) * scale;
  const y = (s) => pad + (s1 - s) * scale;
  const cw = (r1 - r0) / nr;
  const ch = (s1 - s0) / ns;
  g.fillStyle = "#1b1b1b";
  g.fillRect(x(r0), y(s1), (r1 - r0) * scale, (s1 - s0) * scale);
  g.fillStyle = "rgba(46, 164, 79, 0.55)";
  for (const [i, j] of capture.coveredCells) {
    g.fillRect(x(r0 + i * cw), y(s0 + (j + 1) * ch), cw * scale, ch * scale);
  }
  g.strokeStyle = "#3a3a3a";
  g.lineWidth = 0.5;
  g.beginPath();
  for (let i = 0; i <= nr; i++) { g.moveTo(x(r0 + i * cw), y(s0)); g.lineTo(x(r0 + i * cw), y(s1)); }
  for (let j = 0; j <= ns; j++) { g.moveTo(x(r0), y(s0 + j * ch)); g.lineTo(x(r1), y(s0 + j * ch)); }
  g.stroke();
  g.strokeStyle = "#888";
  g.lineWidth = 1;
  g.strokeRect(x(r0), y(s1), (r1 - r0) * scale, (s1 - s0) * scale);
  g.strokeStyle = "#ffcc33";
  g.lineWidth = 1.5;
  g.beginPath();
  capture.path.forEach(([, r, s], k) => (k ? g.lineTo(x(r), y(s)) : g.moveTo(x(r), y(s))));
  g.stroke();
  const last = capture.path[capture.path.length - 1];
  if (last) {
    const lost = capture.last && !capture.last.placed;
    g.fillStyle = lost ? "#777" : "#fff";
    g.strokeStyle = lost ? "#444" : "#ff8800";
    g.lineWidth = 3;
    g.beginPath();
    g.arc(x(last[1]), y(last[2]), 7, 0, 2 * Math.PI);
    g.fill();
    g.stroke();
  }
  g.fillStyle = "#999";
  g.font = "12px system-ui, sans-serif";
  g.fillText(`r → ${(100 * (r1 - r0)).toFixed(0)} cm`, x(r0), cssHeight - 4);
  g.fillText(`s ↑ ${(100 * (s1 - s0)).toFixed(0)} cm · ${nr} × ${ns} cells`, x(r0), 13);
}

async function stop() {
  el("stop").disabled = true;
  capture.state = "stopping";
  try {
    await looping;  // the frame in flight is answered (and counted) first
    await ltm.stopRecorder(recorder);
    if (track && capture.torch === "on") {
      try { await track.applyConstraints({advanced: [{torch: false}]}); } catch (e) { /* off */ }
    }
    if (stream) stream.getTracks().forEach((t) => t.stop());
    capture.torch = capture.torch === "on" ? "off" : capture.torch;
    ltm.banner("torch", capture.torch === "off" ? "" : "You can switch the flashlight off.");
    ltm.banner("message", "Sending the rest of phone A's video; the laptop then tracks all of " +
               "it (a few seconds per second of video)…", "info");
    capture.finish = await upload.finish();
    capture.state = "stopped";
    await refreshState();  // one begun before the finish, if any
    showFinal(await refreshState());
    await finishCapture();
  } catch (error) {
    fail(error);
  }
}

/** The whole capture ends once both phones stopped: the second page to stop ends it (and the
 * server closes after answering it); the first waits for the other. */
async function finishCapture() {
  ltm.banner("message", "Phone A stopped. Waiting for camera B to stop…", "info");
  const outcome = await ltm.finishCapture();
  capture.state = outcome.state;
  ltm.banner("message", outcome.text, "ok");
}

function fail(error) {
  capture.state = "error";
  capture.error = String(error.message || error);
  const text = error.status === 403
    ? "The server refused this page: open the exact address `ltm capture` printed (with its token)."
    : `Stopped: ${capture.error}`;
  ltm.banner("message", text, "error");
  el("start").disabled = false;
  el("stop").disabled = true;
  el("camera").disabled = false;
}

ltm.listCameras(el("camera"), CAMERA_KEY, localStorage.getItem(CAMERA_KEY)).catch(() => null);
el("start").addEventListener("click", start);
el("stop").addEventListener("click", stop);
window.addEventListener("resize", draw);
