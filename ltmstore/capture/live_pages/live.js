// ltm capture: what both pages share (the session token, the server's API, small helpers).
"use strict";

const ltm = (() => {
  const token = new URLSearchParams(location.search).get("token") || "";

  /** fetch with the session token; JSON answer, or an Error carrying the server's line. */
  async function api(path, options = {}) {
    const headers = Object.assign({"X-Ltm-Token": token}, options.headers || {});
    const response = await fetch(path, Object.assign({}, options, {headers, cache: "no-store"}));
    let body = null;
    try { body = await response.json(); } catch (e) { body = null; }
    if (!response.ok) {
      const error = new Error((body && body.error) || `${path}: HTTP ${response.status}`);
      error.status = response.status;
      error.body = body;
      throw error;
    }
    return body;
  }

  const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

  /** Show ``text`` in element ``id`` with a banner class (ok, warn, error, info, enough), or
   * hide it when ``text`` is empty. */
  function banner(id, text, kind = "info") {
    const el = document.getElementById(id);
    el.hidden = !text;
    el.textContent = text || "";
    el.className = `banner ${kind}`;
  }

  function setText(id, text) { document.getElementById(id).textContent = text; }

  /** Keep the screen on while capturing, where the browser allows it. */
  async function keepAwake() {
    try { return await navigator.wakeLock.request("screen"); } catch (e) { return null; }
  }

  /** The camera, at the best resolution (and frame rate) it offers: ideal constraints, so a
   * camera that offers less still opens. */
  async function openCamera(extra = {}) {
    if (!navigator.mediaDevices || !navigator.mediaDevices.getUserMedia) {
      throw new Error("this browser gives no camera access here (the page needs HTTPS or " +
                      "127.0.0.1, and a recent browser)");
    }
    const video = Object.assign({width: {ideal: 3840}, height: {ideal: 2160}}, extra);
    return navigator.mediaDevices.getUserMedia({video, audio: false});
  }

  // Labels of a phone's ultra-wide back lens: iOS "Back Ultra Wide Camera", others "0.5x"
  const ULTRA_WIDE = /ultra[\s-]?wide|\b0[.,]5\s*x/i;

  /** The camera to open among ``devices`` (enumerateDevices' video inputs): ``saved`` (a
   * deviceId) where it is still there, else a back ultra-wide lens (its wide view keeps the
   * painting in sight close up), else null: the browser's own back camera. */
  function preferredCamera(devices, saved) {
    if (saved && devices.some((d) => d.deviceId === saved)) return saved;
    const wide = devices.find((d) => ULTRA_WIDE.test(d.label) && !/front/i.test(d.label));
    return wide ? wide.deviceId : null;
  }

  /** Fill ``select`` with the cameras the browser names (it names them once one was open),
   * ``current`` (a deviceId) selected; a choice is saved under ``key`` for the next Start. */
  async function listCameras(select, key, current = null) {
    const devices = (await navigator.mediaDevices.enumerateDevices())
      .filter((d) => d.kind === "videoinput" && d.label);
    select.replaceChildren(...devices.map((d) => new Option(d.label, d.deviceId, false,
                                                             d.deviceId === current)));
    select.hidden = !devices.length;
    select.onchange = () => localStorage.setItem(key, select.value);
    return devices;
  }

  /** Open the back camera, then switch to the preferred one (``preferredCamera``: the one
   * saved under ``key``, else an ultra-wide lens); ``select`` lists them all. */
  async function openPreferredCamera(select, key, extra = {}) {
    let stream = await openCamera(Object.assign({facingMode: {ideal: "environment"}}, extra));
    const opened = stream.getVideoTracks()[0].getSettings().deviceId;
    const wanted = preferredCamera(await listCameras(select, key, opened),
                                   localStorage.getItem(key));
    if (wanted && wanted !== opened) {
      stream.getTracks().forEach((t) => t.stop());
      stream = await openCamera(Object.assign({deviceId: {exact: wanted}}, extra));
      select.value = wanted;
    }
    return stream;
  }

  function formatTime(seconds) {
    const s = Math.max(0, Math.floor(seconds));
    return `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
  }

  /** After this page's own finish: end the whole capture (POST /api/finish succeeds once both
   * phones finished), else wait for the other page to end it. The server closes right after
   * the capture is finished, so a server that stops answering then means it is done (or was
   * stopped on the laptop). Resolves {state: "finished" | "closed", text}. */
  async function finishCapture() {
    let unreachable = 0;
    for (;;) {
      try {
        const done = await api("/api/finish", {method: "POST"});
        return {state: "finished", text: `Capture complete in ${done.folder}. Next on the ` +
                "laptop: ltm sync, ltm ingest, ltm reconstruct (as it printed)."};
      } catch (error) {
        if (error.status && error.status !== 409) throw error;
        unreachable = error.status ? 0 : unreachable + 1;
      }
      if (unreachable >= 3) {
        return {state: "closed", text: "The laptop's server has closed: the capture is " +
                "complete if its terminal says `ltm capture: finished`."};
      }
      await sleep(1000);
    }
  }

  const MIME_TYPES = ["video/webm;codecs=vp8", "video/webm;codecs=vp9", "video/webm", "video/mp4"];
  const TIMESLICE_MS = 1000;  // one piece of video per second

  /** Record ``stream`` (MediaRecorder, the first MIME type offered of MIME_TYPES) in one-second
   * pieces handed to ``upload.add``. Returns the recorder. */
  function startRecorder(stream, upload, bitsPerSecond) {
    const mime = MIME_TYPES.find((m) => MediaRecorder.isTypeSupported(m));
    const options = mime ? {mimeType: mime, videoBitsPerSecond: bitsPerSecond}
                         : {videoBitsPerSecond: bitsPerSecond};
    const recorder = new MediaRecorder(stream, options);
    upload.stats.mime = recorder.mimeType || mime || "video/webm";
    recorder.addEventListener("dataavailable", (event) => {
      if (event.data && event.data.size) upload.add(event.data);
    });
    recorder.start(TIMESLICE_MS);
    return recorder;
  }

  /** Stop ``recorder``; resolves once its last piece has been handed over. */
  function stopRecorder(recorder) {
    if (!recorder || recorder.state === "inactive") return Promise.resolve();
    return new Promise((resolve) => {
      recorder.addEventListener("stop", resolve, {once: true});
      recorder.stop();
    });
  }

  /** A phone's recording (``who``: "a" or "b") sent piece by piece to
   * POST /api/{who}/chunk?index=N, in order, each retried until the server has it (a dropped
   * connection loses nothing already recorded), then joined by POST /api/{who}/finish?chunks=N.
   * ``onChange(stats, problem)`` after every step (``problem``: a line while the laptop does not
   * answer, else null); ``onFail(error)`` when the server refuses a piece. */
  function recordingUpload(who, onChange, onFail) {
    const stats = {mime: null, recorded: 0, acked: 0, bytes: 0, bytesAcked: 0, retries: 0,
                   queued: 0};
    const pieces = [];  // every recorded piece (a Blob) by index, kept until the video is whole
    const queue = [];   // indices waiting to be sent, oldest first
    let pumping = null; // the running upload loop (a promise), if any
    let failed = null;

    function add(blob) {
      pieces.push(blob);
      stats.recorded = pieces.length;
      stats.bytes += blob.size;
      queue.push(pieces.length - 1);
      pump();
    }

    async function send(index) {
      const blob = pieces[index];
      await api(`/api/${who}/chunk?index=${index}`, {
        method: "POST", body: blob,
        headers: {"Content-Type": "application/octet-stream", "X-Mime-Type": stats.mime}});
      stats.acked += 1;
      stats.bytesAcked += blob.size;
    }

    /** Send the queued pieces in order, retrying each until the server has it. */
    function pump() {
      stats.queued = queue.length;
      if (!pumping) {
        pumping = (async () => {
          let wait = 250;
          while (queue.length) {
            let problem = null;
            try {
              await send(queue[0]);
              queue.shift();
              wait = 250;
            } catch (error) {
              if (error.status && error.status < 500) throw error;
              stats.retries += 1;
              problem = `The laptop does not answer: ${queue.length} piece(s) wait here and ` +
                "go as soon as it is back.";
              await sleep(wait);
              wait = Math.min(5000, 2 * wait);
            }
            stats.queued = queue.length;
            onChange(stats, problem);
          }
        })().catch((error) => { failed = error; onFail(error); })
          .finally(() => { pumping = null; });
      }
      return pumping;
    }

    /** Wait for the queue, then have the server join the pieces; re-send any it lacks. */
    async function finish() {
      for (let attempt = 0; ; attempt++) {
        while (queue.length || pumping) {
          if (failed) throw failed;
          await (pumping || pump());
        }
        if (failed) throw failed;
        try {
          return await api(`/api/${who}/finish?chunks=${pieces.length}`, {method: "POST"});
        } catch (error) {
          const missing = error.status === 409 && /chunks? ([\d, ]+) missing/.exec(error.message);
          const busy = error.status === 409 && /finishing already/.test(error.message);
          if (!error.status || busy) { await sleep(1000); continue; }
          if (!missing || attempt >= 3) throw error;
          for (const i of missing[1].split(",").map(Number)) queue.push(i);
          pump();
        }
      }
    }

    return {stats, add, finish};
  }

  return {token, api, sleep, banner, setText, keepAwake, openCamera, preferredCamera, listCameras,
          openPreferredCamera, formatTime, finishCapture, startRecorder, stopRecorder,
          recordingUpload};
})();
