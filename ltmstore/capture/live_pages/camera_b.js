// Camera B's page: the camera at the best resolution and frame rate it offers, exposure and
// white balance locked where the browser allows it, recorded in one-second pieces uploaded as
// they come (a queue with retries: a dropped connection loses nothing already recorded).
"use strict";

const METER_MS = 1500;      // automatic exposure this long before it is locked

const capture = {
  state: "idle",    // idle -> starting -> recording -> stopping -> stopped -> finished | error
  mime: null,       // the recorder's MIME type
  resolution: null, // [width, height]
  frameRate: null,
  locks: {},        // exposure / whiteBalance / focus: "locked" | "auto" (cannot lock) | "failed"
  recorded: 0,      // pieces recorded (indices 0..recorded-1)
  acked: 0,         // pieces the server acknowledged
  bytes: 0,         // bytes recorded
  bytesAcked: 0,    // bytes acknowledged
  retries: 0,       // failed uploads retried
  queued: 0,        // pieces waiting to be sent
  seconds: 0,       // recording time
  finish: null,     // answer of POST /api/b/finish
  error: null,
};
window.ltmCapture = capture;

const el = (id) => document.getElementById(id);
const upload = ltm.recordingUpload("b", (stats, problem) => {
  Object.assign(capture, stats);
  ltm.banner("message", problem || (capture.state === "recording" ? "Recording." : ""),
             problem ? "error" : "ok");
  render();
}, fail);
let recorder = null;
let stream = null;
let startedAt = 0;

async function start() {
  el("start").disabled = true;
  capture.state = "starting";
  if (stream) stream.getTracks().forEach((t) => t.stop());  // a restart after an error
  try {
    stream = await ltm.openCamera({facingMode: {ideal: "environment"}, frameRate: {ideal: 60}});
    const track = stream.getVideoTracks()[0];
    el("video").srcObject = stream;
    // the preview is for the user; the recording does not wait on it being drawn
    el("video").play().catch(() => {});
    const settings = track.getSettings();
    capture.resolution = [settings.width, settings.height];
    capture.frameRate = settings.frameRate;
    ltm.banner("message", "Metering the light…", "info");
    await ltm.sleep(METER_MS);
    capture.locks = await lockCamera(track);
    showLocks();
    record();
    ltm.keepAwake();
  } catch (error) {
    fail(error);
  }
}

/** Exposure, white balance and focus to "manual" at their current values, where offered. */
async function lockCamera(track) {
  const caps = track.getCapabilities ? track.getCapabilities() : {};
  const now = track.getSettings();
  const locks = {};
  const what = [["exposure", "exposureMode", ["exposureTime", "iso"]],
                ["whiteBalance", "whiteBalanceMode", ["colorTemperature"]],
                ["focus", "focusMode", ["focusDistance"]]];
  for (const [name, mode, values] of what) {
    if (!(caps[mode] || []).includes("manual")) {
      locks[name] = "auto";
      continue;
    }
    const constraint = {[mode]: "manual"};
    for (const key of values) if (now[key] !== undefined && caps[key]) constraint[key] = now[key];
    try {
      await track.applyConstraints({advanced: [constraint]});
      locks[name] = track.getSettings()[mode] === "manual" ? "locked" : "failed";
    } catch (error) {
      locks[name] = "failed";
    }
  }
  return locks;
}

function showLocks() {
  const locked = capture.locks.exposure === "locked" && capture.locks.whiteBalance === "locked";
  if (locked) {
    ltm.banner("exposure", "Exposure and white balance locked.", "ok");
  } else {
    const open = [capture.locks.exposure !== "locked" ? "exposure" : null,
                  capture.locks.whiteBalance !== "locked" ? "white balance" : null]
      .filter(Boolean).join(" and ");
    ltm.banner("exposure", `This browser cannot lock the ${open}: the camera adjusts ` +
               "itself as the light moves (ltm ingest corrects that where it can).", "warn");
  }
}

function record() {
  const [w, h] = capture.resolution;
  const fps = capture.frameRate || 30;
  const bits = Math.min(40e6, Math.max(2.5e6, 0.25 * w * h * fps));
  recorder = ltm.startRecorder(stream, upload, bits);
  capture.mime = upload.stats.mime;
  ltm.setText("format", `${w} × ${h}, ${Math.round(fps)} fps, ${capture.mime.split(";")[0]}`);
  startedAt = performance.now();
  capture.state = "recording";
  ltm.banner("message", "Recording. Now start phone A's light.", "ok");
  el("stop").disabled = false;
  tick();
}

function tick() {
  if (capture.state === "recording") {
    capture.seconds = (performance.now() - startedAt) / 1000;
    setTimeout(tick, 250);
  }
  render();
}

/** The recording's time and the upload's counts. */
function render() {
  Object.assign(capture, upload.stats);
  ltm.setText("time", ltm.formatTime(capture.seconds));
  ltm.setText("chunks", `${capture.acked} of ${capture.recorded} sent` +
              (capture.queued ? `, ${capture.queued} waiting` : ""));
  ltm.setText("bytes", `${size(capture.bytesAcked)} of ${size(capture.bytes)}`);
}

function size(bytes) {
  return bytes < 1e6 ? `${(bytes / 1e3).toFixed(0)} kB` : `${(bytes / 1e6).toFixed(1)} MB`;
}

async function stop() {
  el("stop").disabled = true;
  capture.state = "stopping";
  try {
    await ltm.stopRecorder(recorder);
    stream.getTracks().forEach((t) => t.stop());
    ltm.banner("message", "Sending the last pieces…", "info");
    capture.finish = await upload.finish();
    capture.state = "stopped";
    render();
    await finishCapture();
  } catch (error) {
    fail(error);
  }
}

/** The whole capture ends once both phones stopped: the second page to stop ends it (and the
 * server closes after answering it); the first waits for the other. */
async function finishCapture() {
  ltm.banner("message", "Camera B stopped. Waiting for phone A to stop…", "info");
  const outcome = await ltm.finishCapture();
  capture.state = outcome.state;
  ltm.banner("message", `${outcome.text} Camera B: ${capture.finish.frames} frames in ` +
             `${capture.finish.video}.`, "ok");
}

function fail(error) {
  capture.state = "error";
  capture.error = String(error.message || error);
  const text = error.status === 403
    ? "The server refused this page: open the exact address `ltm capture` printed (with its token)."
    : `Stopped: ${capture.error}`;
  ltm.banner("message", text, "error");
  el("stop").disabled = !recorder || recorder.state === "inactive";
}

el("start").addEventListener("click", start);
el("stop").addEventListener("click", stop);
