/*
 * report.js - the mocapflow workspace report page (no dependencies).
 * Copyright (c) 2026 mocapflow developers. BSD-3-Clause licence (the licence of mocapflow):
 * redistribution and use in source and binary forms, with or without modification, are
 * permitted provided that the copyright notice, this condition and the disclaimer are kept.
 * THIS SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND.
 *
 * Reads the model inlined in index.html (<script id="model">), builds the sections, and
 * loads motion data scripts (data/*.js, see blobs.py) on demand: a data script calls
 * MocapReport.blob(key, meta, base64) and the page decodes the little-endian parts.
 */
"use strict";

const MocapReport = (() => {
  const model = JSON.parse(document.getElementById("model").textContent);
  const cache = new Map(), waiting = new Map();
  const R = { model, players: [], timings: {}, errors: [] };
  const NAN_CODE = -32768;
  const TYPES = { float32: Float32Array, int16: Int16Array, uint8: Uint8Array, int32: Int32Array, uint16: Uint16Array };

  /* --- data ------------------------------------------------------------------------------ */
  R.blob = (key, meta, b64) => {
    const t0 = performance.now();
    const bin = atob(b64), bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    const parts = {};
    for (const p of meta.parts) {
      const n = p.shape.reduce((a, b) => a * b, 1);
      parts[p.name] = new TYPES[p.dtype](bytes.buffer, p.offset, n);
    }
    const out = { meta, parts };
    if (parts.root && parts.rel) out.pos = positions(parts.root, parts.rel, meta.scale, meta.n_frames);
    out.decodeMs = performance.now() - t0;
    cache.set(key, out);
    const w = waiting.get(key);
    if (w) { waiting.delete(key); w.resolve(out); }
  };

  function positions(root, rel, scale, T) {
    const nJ = rel.length / (3 * T), out = new Float32Array(rel.length);
    for (let t = 0; t < T; t++) {
      const rx = root[3 * t], ry = root[3 * t + 1], rz = root[3 * t + 2];
      for (let j = 0; j < nJ; j++) {
        const i = (t * nJ + j) * 3;
        if (rel[i] === NAN_CODE) { out[i] = out[i + 1] = out[i + 2] = NaN; continue; }
        out[i] = rx + rel[i] * scale; out[i + 1] = ry + rel[i + 1] * scale; out[i + 2] = rz + rel[i + 2] * scale;
      }
    }
    return out;
  }

  R.load = (key) => {
    if (cache.has(key)) return Promise.resolve(cache.get(key));
    if (waiting.has(key)) return waiting.get(key).promise;
    const info = model.data_files[key];
    if (!info) return Promise.reject(new Error("no data file for " + key));
    let resolve, reject;
    const promise = new Promise((a, b) => { resolve = a; reject = b; });
    waiting.set(key, { promise, resolve, reject });
    const t0 = performance.now(), s = document.createElement("script");
    s.src = info.file;
    s.onerror = () => { waiting.delete(key); reject(new Error("cannot load " + info.file)); };
    document.head.appendChild(s);
    return promise.then((d) => { R.timings[key] = { ms: performance.now() - t0, bytes: info.bytes, frames: d.meta.n_frames }; return d; });
  };

  /* --- DOM helpers ----------------------------------------------------------------------- */
  function h(tag, attrs, ...kids) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (k === "on") for (const [ev, fn] of Object.entries(v)) e.addEventListener(ev, fn);
      else if (v !== undefined && v !== null) e.setAttribute(k, v);
    }
    for (const k of kids.flat()) if (k !== null && k !== undefined) e.appendChild(typeof k === "object" ? k : document.createTextNode(String(k)));
    return e;
  }
  const fmt = (v) => (typeof v === "number" ? (Number.isInteger(v) ? String(v) : v.toPrecision(4)) : v === null ? "\u2014" : String(v));
  function table(t, opts) {
    opts = opts || {};
    const head = h("tr", null, t.columns.map((c) => h("th", null, c)), opts.extraHead ? h("th", null, opts.extraHead) : null);
    const rows = t.rows.map((r, i) => h("tr", null, r.map((v) => h("td", null, fmt(v))), opts.extra ? h("td", null, opts.extra(i)) : null));
    const more = t.n_rows > t.rows.length ? h("p", { class: "note" }, `${t.rows.length} of ${t.n_rows} rows shown`) : null;
    return h("div", { class: "table-wrap" }, h("table", null, h("thead", null, head), h("tbody", null, rows)), more);
  }
  function newPlayer(parent) { const p = new MocapPlayer(parent, model.bones); R.players.push(p); return p; }
  const nJ = model.joints.length;
  const secs = (f, fps) => (f / fps).toFixed(2) + " s";

  /* --- sections -------------------------------------------------------------------------- */
  function clipsSection() {
    const rej = model.rejects.n_rows ? table(model.rejects) : h("p", null, "No file was rejected.");
    return h("section", { id: "clips" }, h("h2", null, "Clips"),
      h("p", null, `${model.clips.n_rows} clips (duration in seconds, frame rate in frames per second; source = the file and its own rate).`),
      table(model.clips), h("h3", null, "Rejects"), rej);
  }

  function provenance(step) {
    const ins = Object.entries(step.inputs).map(([k, v]) => h("li", null, `${k}: `, h("a", { href: "#step-" + v }, v),
      h("span", { class: "note" }, ` (fingerprint ${step.input_fingerprints[k]})`)));
    const rows = [["component", `${step.component} (version ${step.version})`], ["computed", `${step.created} in ${step.seconds} s`],
      ["pipeline", step.pipeline], ["fingerprint", step.fingerprint],
      ["tables", Object.entries(step.tables).map(([k, v]) => `${k}: ${v} rows`).join(", ")]];
    return h("details", { class: "provenance" }, h("summary", null, "Provenance"),
      h("table", null, h("tbody", null, rows.map(([k, v]) => h("tr", null, h("th", null, k), h("td", null, v))),
        h("tr", null, h("th", null, "inputs"), h("td", null, ins.length ? h("ul", null, ins) : "none")))),
      h("h4", null, "Parameters"), h("pre", null, JSON.stringify(step.params, null, 2)),
      h("h4", null, "Summary"), h("pre", null, JSON.stringify(step.summary, null, 2)));
  }

  function stepSection(step) {
    const sec = h("section", { id: "step-" + step.id, class: "step" },
      h("h2", null, `${step.id} `, h("span", { class: "component" }, step.component)), provenance(step));
    if (step.view_error) sec.appendChild(h("p", { class: "error" }, "This step's results could not be shown: " + step.view_error));
    for (const v of step.views) {
      const fn = { retrieval: retrievalView, cleaning: cleaningView, base_poses: basePosesView, derived: derivedView, markers: markersView }[v.type];
      if (fn) sec.appendChild(fn(v, step));
    }
    if (step.images.length) {
      sec.appendChild(h("h3", null, "Plots"));
      sec.appendChild(h("div", { class: "images" }, step.images.map((im) =>
        h("figure", null, h("a", { href: `img/${step.id}/${im}` }, h("img", { src: `img/${step.id}/${im}`, alt: im, loading: "lazy" })), h("figcaption", null, im)))));
    }
    const small = Object.entries(step.small_tables);
    if (small.length) {
      const d = h("details", { class: "tables" }, h("summary", null, "Tables"));
      for (const [name, t] of small) d.append(h("h4", null, name), table(t));
      sec.appendChild(d);
    }
    return sec;
  }

  function retrievalView(v) {
    const box = h("div", { class: "view retrieval" });
    const stage = h("div", { class: "player" }, h("p", { class: "note" }, "Click \u25B6 on a hit to play the query and the hit side by side, in sync along the warping path."));
    let player = null;
    const queries = new Map(v.queries.map((q) => [q.id, q]));
    async function play(hit) {
      const q = queries.get(hit.query_id);
      if (!player) { stage.textContent = ""; player = newPlayer(stage); }
      const keys = [hit.motion].concat(q && q.motion ? [q.motion] : []);
      const data = await Promise.all(keys.map(R.load));
      const hitLen = hit.end - hit.start, qLen = q && q.motion ? q.end - q.start : hitLen;
      let path = hit.path;
      if (!path || !path.length) { path = []; const n = Math.max(qLen, hitLen); for (let i = 0; i < n; i++) path.push([Math.round(i * (qLen - 1) / Math.max(1, n - 1)), hit.start + Math.round(i * (hitLen - 1) / Math.max(1, n - 1))]); }
      let steps = path.length, hFrames, qFrames;
      if (v.poses) {  // nearest poses: one second around both frames, frame by frame
        const half = Math.round(data[0].meta.fps / 2), hd = data[0].meta.n_frames, qd = data[1] ? data[1].meta.n_frames : hd;
        steps = 2 * half + 1;
        hFrames = Int32Array.from({ length: steps }, (_, i) => Math.max(0, Math.min(hd - 1, hit.start - half + i)));
        qFrames = Int32Array.from({ length: steps }, (_, i) => Math.max(0, Math.min(qd - 1, q.start - half + i)));
      } else {
        hFrames = Int32Array.from(path, (p) => Math.min(data[0].meta.n_frames - 1, p[1]));
        qFrames = Int32Array.from(path, (p) => Math.min((data[1] || data[0]).meta.n_frames - 1, q ? q.start + p[0] : p[0]));
      }
      const anchor = (d, f, dx) => [dx - d.pos[f * nJ * 3], 0, -d.pos[f * nJ * 3 + 2]];
      const tracks = [{ label: `hit ${hit.rank}: ${hit.clip} ${hit.frames || `[${hit.start}, ${hit.end})`}`, color: "#c92a2a", pos: data[0].pos, nJ, frames: hFrames, offset: anchor(data[0], hFrames[0], 0.6), highlight: -1 }];
      if (data[1]) tracks.unshift({ label: `query: ${q.name}`, color: "#1c4e80", pos: data[1].pos, nJ, frames: qFrames, offset: anchor(data[1], qFrames[0], -0.6), highlight: -1 });
      player.setScene({ tracks, steps, fps: data[0].meta.fps, caption: (s) => `${v.cost_label} ${fmt(hit.cost)}` + (v.poses ? (hFrames[s] === hit.start ? " \u2014 the compared poses" : "") : ` \u2014 path step ${s + 1}: query frame ${qFrames[s]}, hit frame ${hFrames[s]}`) });
      player.play();
    }
    box.appendChild(stage);
    if (v.export) {  // a static page runs nothing: the button copies the command that writes the clips
      const cmd = h("code", null, v.export);
      box.appendChild(h("p", { class: "export" }, "Export these hits as clips in each take's own format, rate and rig (one folder per query, index.csv): ", cmd, " ",
        h("button", { type: "button", class: "export-hits", on: { click: () => navigator.clipboard && navigator.clipboard.writeText(v.export).catch(() => {}) } }, "copy")));
    }
    for (const q of v.queries) {
      const hits = v.hits.filter((x) => x.query_id === q.id);
      box.appendChild(h("h3", null, `Query ${q.id}: ${q.name}`, q.clip ? h("span", { class: "note" }, ` \u2014 ${q.clip}, frames ${q.frames || `[${q.start}, ${q.end})`}`) : null));
      const t = { columns: ["rank", "clip", "frames", "start (s)", "duration (s)", v.cost_label].concat(v.extra), n_rows: hits.length,
        rows: hits.map((x) => [x.rank, x.clip, x.frames || `[${x.start}, ${x.end})`, x.start_s, x.seconds, x.cost].concat(v.extra.map((c) => x.extra[c]))) };
      box.appendChild(table(t, { extraHead: "play", extra: (i) => h("button", { type: "button", class: "play-hit", on: { click: () => play(hits[i]).catch(report) } }, "\u25B6") }));
    }
    return box;
  }

  const JET = (v) => { const c = (x) => Math.round(255 * Math.max(0, Math.min(1, x))); return [c(1.5 - Math.abs(4 * v - 3)), c(1.5 - Math.abs(4 * v - 2)), c(1.5 - Math.abs(4 * v - 1))]; };

  function cleaningView(v) {
    const box = h("div", { class: "view cleaning" });
    const legend = h("div", { class: "legend" }, h("span", { class: "bar" }), h("span", null,
      "MDM value 0 \u2192 1 (dimensionless: 1 \u2212 exp(\u2212M\u00B2), M = the joint's rotation difference from its nearest neighbours over its row scale). ",
      h("b", null, "White outline"), ` = cell flagged as erroneous (MDM > ${v.threshold}, or the cue named in the tooltip)` +
      (v.has_cue_column ? "." : "; this cleaner's table has no cue column, so the cue is the threshold.")));
    const picker = h("div", { class: "clip-picker" });
    const heat = h("div", { class: "heatmap" }), stage = h("div", { class: "player" });
    let player = null;
    box.append(h("p", null, "Pick a take, hover the digression map for joint, time, value and cue; click a cell to play the original and the cleaned take overlaid around it."), picker, legend, heat, stage);
    v.clips.forEach((c, i) => picker.appendChild(h("button", { type: "button", class: "pick-clip", on: { click: () => show(c).catch(report) } },
      `${c.clip} (${c.n_flagged} flagged, ${c.n_edits} edits)`)));
    async function show(c) {
      const [d, orig] = await Promise.all([R.load(c.data), R.load(c.motion)]);
      const T = d.meta.n_frames, m = d.meta.joints.length, mdm = d.parts.mdm, cue = d.parts.cue, ms = d.meta.mdm_scale;
      heat.textContent = "";
      heat.appendChild(h("h3", null, `${c.clip}: movement digression map (${T} frames, ${secs(T, c.fps)})`));
      const cv = h("canvas", { class: "heat-canvas" }), tip = document.getElementById("tooltip");
      const labelW = 90, cellH = 12, W = Math.max(200, Math.min(1400, heat.clientWidth || 1000)), plotW = W - labelW;
      cv.width = W; cv.height = m * cellH + 24;
      heat.appendChild(cv);
      // one column per frame, or per bin of frames (its largest value) when the take is longer than the plot is wide
      const B = Math.min(T, Math.floor(plotW)), lo = (b) => Math.floor((b * T) / B), cw = plotW / B;
      const ctx = cv.getContext("2d"), img = ctx.createImageData(B, m), peak = new Int32Array(B * m), hit = new Uint8Array(B * m);
      for (let b = 0; b < B; b++) for (let j = 0; j < m; j++) {
        let best = lo(b);  // the largest value, a flagged frame first
        for (let t = lo(b); t < lo(b + 1); t++) {
          const f = cue[t * m + j] ? 1 : 0, fb = cue[best * m + j] ? 1 : 0;
          if (f > fb || (f === fb && mdm[t * m + j] > mdm[best * m + j])) best = t;
          if (f) hit[b * m + j] = 1;
        }
        peak[b * m + j] = best;
        const [r, g, bl] = JET(Math.min(1, mdm[best * m + j] * ms)), o = (j * B + b) * 4;
        img.data[o] = r; img.data[o + 1] = g; img.data[o + 2] = bl; img.data[o + 3] = 255;
      }
      const off = document.createElement("canvas"); off.width = B; off.height = m; off.getContext("2d").putImageData(img, 0, 0);
      ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, W, cv.height);
      ctx.imageSmoothingEnabled = false; ctx.drawImage(off, labelW, 0, plotW, m * cellH);
      ctx.strokeStyle = "#fff"; ctx.fillStyle = "#fff"; ctx.lineWidth = 1;
      for (let b = 0; b < B; b++) for (let j = 0; j < m; j++) if (hit[b * m + j]) {
        if (cw >= 3) ctx.strokeRect(labelW + b * cw + 0.5, j * cellH + 0.5, cw - 1, cellH - 1);
        else ctx.fillRect(labelW + b * cw, j * cellH + 1, Math.max(1, cw), 3);  // too narrow to outline: a white tick
      }
      ctx.fillStyle = "#222"; ctx.font = "10px sans-serif"; ctx.textAlign = "right";
      d.meta.joints.forEach((name, j) => ctx.fillText(name, labelW - 4, j * cellH + 9));
      ctx.textAlign = "center";
      for (let s = 0; s <= T / c.fps; s += Math.max(0.5, Math.ceil(T / c.fps / 12))) ctx.fillText(s + " s", labelW + (s * c.fps * plotW) / T, m * cellH + 14);
      const cell = (e) => {  // [frame, joint]: in a bin, its frame of largest value
        const r = cv.getBoundingClientRect(), x = (e.clientX - r.left) * (cv.width / r.width) - labelW, y = (e.clientY - r.top) * (cv.height / r.height);
        const b = Math.floor(x / cw), j = Math.floor(y / cellH);
        return b >= 0 && b < B && j >= 0 && j < m ? [peak[b * m + j], j, b] : null;
      };
      cv.addEventListener("mousemove", (e) => {
        const at = cell(e); if (!at) { tip.hidden = true; return; }
        const [t, j, b] = at, k = cue[t * m + j];
        const where = B < T ? `frames ${lo(b)}\u2013${lo(b + 1) - 1}, largest at ${t} (${secs(t, c.fps)})` : `frame ${t} (${secs(t, c.fps)})`;
        tip.textContent = `joint ${d.meta.joints[j]} \u00B7 ${where} \u00B7 MDM ${(mdm[t * m + j] * ms).toFixed(3)} \u00B7 ` + (k ? `flagged by: ${d.meta.cues[k - 1]}` : "not flagged");
        tip.hidden = false; tip.style.left = e.pageX + 12 + "px"; tip.style.top = e.pageY + 12 + "px";
      });
      cv.addEventListener("mouseleave", () => { tip.hidden = true; });
      cv.addEventListener("click", (e) => { const at = cell(e); if (at) playAround(c, d, orig, at[0], at[1]); });
      playAround(c, d, orig, 0, -1, true);
    }
    function playAround(c, d, orig, t, j, whole) {
      if (!player) { player = newPlayer(stage); }
      const T = d.meta.n_frames, half = Math.round(2 * c.fps);
      const a = whole ? 0 : Math.max(0, t - half), b = whole ? T : Math.min(T, t + half + 1);
      const frames = Int32Array.from({ length: b - a }, (_, i) => a + i);
      const hl = j >= 0 ? d.meta.canonical[j] : -1;
      player.setScene({ steps: b - a, fps: c.fps, tracks: [
        { label: `original ${c.clip}`, color: "#c92a2a", pos: orig.pos, nJ, frames, offset: [0, 0, 0], highlight: hl, width: 4 },
        { label: "cleaned", color: "#1c7ed6", pos: d.pos, nJ, frames, offset: [0, 0, 0], highlight: -1, width: 2 }],
        caption: (s) => `frame ${frames[s]} (${secs(frames[s], c.fps)})` + (j >= 0 ? ` \u2014 around the cell at frame ${t}, joint ${d.meta.joints[j]}` : " \u2014 whole take") });
      player.seek(whole ? 0 : t - a);
      if (!whole) player.play();
    }
    return box;
  }

  function basePosesView(v) {
    const box = h("div", { class: "view base-poses" }, h("h3", null, `${v.n_base_poses} base poses`),
      h("p", null, "Each base pose in its root frame (facing the viewer), labelled with its source clip, frame and the number of frames it covers (members). Click one to play a second of its clip around it."));
    const stage = h("div", { class: "player" }), grid = h("div", { class: "pose-grid" });
    let player = null;
    v.poses.forEach((p) => {
      const cv = h("canvas", { width: 110, height: 150 });
      const fig = h("figure", { class: "pose", on: { click: () => playPose(p).catch(report) } }, cv,
        h("figcaption", null, `#${p.cluster} ${p.clip} frame ${p.frame}`, h("br"), `${p.n_members} member${p.n_members === 1 ? "" : "s"}`));
      grid.appendChild(fig);
      if (p.positions) MocapPlayer.drawPose(cv, p.positions, model.bones);
    });
    async function playPose(p) {
      const d = await R.load(p.motion);
      if (!player) player = newPlayer(stage);
      const T = d.meta.n_frames, half = Math.round(d.meta.fps / 2), a = Math.max(0, p.frame - half), b = Math.min(T, p.frame + half + 1);
      const frames = Int32Array.from({ length: b - a }, (_, i) => a + i);
      player.setScene({ steps: b - a, fps: d.meta.fps, tracks: [{ label: `${p.clip} around frame ${p.frame}`, color: "#1c4e80", pos: d.pos, nJ, frames, offset: [0, 0, 0], highlight: -1 }],
        caption: (s) => (frames[s] === p.frame ? "the base pose" : "") });
      player.seek(p.frame - a);
    }
    box.append(stage, grid);
    return box;
  }

  function derivedView(v, step) {
    const box = h("div", { class: "view derived" }, h("h3", null, "Results over their input"),
      h("p", null, `Each take of ${step.id} (blue) played over the take it was computed from (red).`));
    const stage = h("div", { class: "player" });
    let player = null;
    for (const p of v.pairs) {
      box.appendChild(h("button", { type: "button", class: "play-derived", on: { click: () => play(p).catch(report) } }, `\u25B6 ${p.clip} over ${p.source_clip} (${p.source_step})`));
    }
    async function play(p) {
      // a reconstruction from markers: the input markers (red points) beside the skeleton
      const [a, b] = await Promise.all([R.load(p.motion), R.load(p.markers || p.source_motion)]);
      if (!player) player = newPlayer(stage);
      const T = Math.min(a.meta.n_frames, b.meta.n_frames), frames = Int32Array.from({ length: T }, (_, i) => i);
      const input = p.markers
        ? { label: `input markers ${p.source_clip}`, color: "#c92a2a", pos: b.pos, nJ: b.pos.length / (3 * b.meta.n_frames), frames, offset: [0, 0, 0], highlight: -1, bones: [], points: 3.5 }
        : { label: `input ${p.source_clip}`, color: "#c92a2a", pos: b.pos, nJ, frames, offset: [0, 0, 0], highlight: -1, width: 4 };
      player.setScene({ steps: T, fps: a.meta.fps, tracks: [input,
        { label: `${step.id} ${p.clip}`, color: "#1c7ed6", pos: a.pos, nJ, frames, offset: [0, 0, 0], highlight: -1, width: 2 }],
        caption: (s) => `frame ${s}` });
      player.play();
    }
    box.appendChild(stage);
    return box;
  }

  function markersView(v, step) {
    const box = h("div", { class: "view markers" }, h("h3", null, "Marker takes"),
      h("p", null, `Each take's markers as points (y up; a marker in a gap is not drawn)` +
        (v.n_clips > v.clips.length ? `; the first ${v.clips.length} of ${v.n_clips} takes.` : ".")));
    const stage = h("div", { class: "player" });
    let player = null;
    for (const c of v.clips) {
      box.appendChild(h("button", { type: "button", class: "play-markers", on: { click: () => play(c).catch(report) } },
        `\u25B6 ${c.clip} (${c.n_markers} markers, ${c.n_frames} frames at ${c.fps} fps)`));
    }
    async function play(c) {
      const d = await R.load(c.markers);
      if (!player) player = newPlayer(stage);
      const T = d.meta.n_frames, frames = Int32Array.from({ length: T }, (_, i) => i);
      player.setScene({ steps: T, fps: d.meta.fps, tracks: [
        { label: `${c.clip}: ${c.n_markers} markers`, color: "#1c4e80", pos: d.pos, nJ: c.n_markers, frames, offset: [0, 0, 0], highlight: -1, bones: [], points: 3.5 }],
        caption: (s) => `frame ${s} of ${c.clip}` });
      player.play();
    }
    box.appendChild(stage);
    return box;
  }

  function report(err) {
    R.errors.push(String(err));
    console.error(err);
    const e = document.getElementById("status"); if (e) e.textContent = "Error: " + err.message;
  }

  /* --- page ------------------------------------------------------------------------------ */
  function build() {
    const main = document.getElementById("main"), nav = document.getElementById("nav");
    document.getElementById("generated").textContent = `workspace ${model.workspace}, report written ${model.generated}`;
    nav.appendChild(h("a", { href: "#clips" }, "clips"));
    for (const s of model.steps) nav.appendChild(h("a", { href: "#step-" + s.id }, s.id));
    main.appendChild(clipsSection());
    for (const s of model.steps) main.appendChild(stepSection(s));
    R.ready = true;
  }
  build();
  return R;
})();
window.MocapReport = MocapReport;
