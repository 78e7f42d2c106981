/*
 * player.js - 3-D stick-figure player of the mocapflow report (no dependencies).
 * Copyright (c) 2026 mocapflow developers. BSD-3-Clause licence (the licence of mocapflow):
 * redistribution and use in source and binary forms, with or without modification, are
 * permitted provided that the copyright notice, this condition and the disclaimer are kept.
 * THIS SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND.
 *
 * A scene is a set of tracks (canonical joint positions in metres, y up) sampled along one
 * timeline of steps: step s shows frame track.frames[s] of every track, so two takes play
 * in sync along a warping path. Canvas 2-D with a perspective camera: drag to orbit, wheel
 * to zoom, double-click to reset; play/pause, scrub, speed.
 */
"use strict";

class MocapPlayer {
  constructor(container, bones) {
    this.bones = bones;
    this.tracks = [];
    this.steps = 1;
    this.step = 0;
    this.playing = false;
    this.speed = 1;
    this.fps = 30;
    this.frameCount = 0;   // frames drawn since creation (tests read it)
    this.resetView();
    const el = (tag, cls, parent) => { const e = document.createElement(tag); if (cls) e.className = cls; (parent || container).appendChild(e); return e; };
    this.canvas = el("canvas", "player-canvas");
    this.canvas.width = 720; this.canvas.height = 400;
    const bar = el("div", "player-bar");
    this.button = el("button", "player-play", bar);
    this.button.type = "button";
    this.button.textContent = "\u25B6 play";
    this.slider = el("input", "player-scrub", bar);
    this.slider.type = "range"; this.slider.min = 0; this.slider.value = 0;
    this.slider.setAttribute("aria-label", "time step");
    this.speedSel = el("select", "player-speed", bar);
    this.speedSel.setAttribute("aria-label", "speed");
    for (const s of [0.1, 0.25, 0.5, 1, 2, 4]) {
      const o = el("option", null, this.speedSel); o.value = s; o.textContent = s + "\u00D7"; if (s === 1) o.selected = true;
    }
    this.readout = el("span", "player-readout", bar);
    this.caption = el("div", "player-caption");
    this.button.addEventListener("click", () => (this.playing ? this.pause() : this.play()));
    this.slider.addEventListener("input", () => { this.pause(); this.seek(+this.slider.value); });
    this.speedSel.addEventListener("change", () => { this.speed = +this.speedSel.value; });
    this.bindCamera();
    this.tick = this.tick.bind(this);
  }

  resetView() { this.yaw = 0.6; this.pitch = 0.25; this.dist = 3.8; }

  bindCamera() {
    const c = this.canvas;
    let drag = null;
    c.addEventListener("pointerdown", (e) => {
      drag = [e.clientX, e.clientY];
      try { c.setPointerCapture(e.pointerId); } catch (_) { /* synthetic events have no active pointer */ }
    });
    c.addEventListener("pointermove", (e) => {
      if (!drag) return;
      this.yaw -= (e.clientX - drag[0]) * 0.01;
      this.pitch = Math.max(-1.2, Math.min(1.45, this.pitch + (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      this.draw();
    });
    c.addEventListener("pointerup", () => { drag = null; });
    c.addEventListener("wheel", (e) => {
      e.preventDefault();
      this.dist = Math.max(0.8, Math.min(40, this.dist * Math.exp(e.deltaY * 0.001)));
      this.draw();
    }, { passive: false });
    c.addEventListener("dblclick", () => { this.resetView(); this.draw(); });
  }

  /* scene: {tracks: [{label, color, pos: Float32Array(T*J*3), nJ, frames: Int32Array(steps),
   *          offset: [x, y, z], highlight: joint or -1, bones (optional: [] for markers),
   *          points (optional: point radius)}], fps, steps, caption(step) -> str} */
  setScene(scene) {
    this.pause();
    this.tracks = scene.tracks;
    this.steps = Math.max(1, scene.steps);
    this.fps = scene.fps || 30;
    this.captionFn = scene.caption || (() => "");
    this.slider.max = this.steps - 1;
    this.floor = Infinity;
    for (const t of this.tracks) {
      for (let s = 0; s < this.steps; s += Math.max(1, (this.steps / 200) | 0)) {
        const base = t.frames[s] * t.nJ * 3;
        for (let j = 0; j < t.nJ; j++) { const y = t.pos[base + 3 * j + 1]; if (y < this.floor) this.floor = y; }
      }
    }
    if (!isFinite(this.floor)) this.floor = 0;
    this.seek(0);
  }

  play() {
    if (this.playing || !this.tracks.length) return;
    this.playing = true;
    this.button.textContent = "\u275A\u275A pause";
    this.last = null;
    this.acc = 0;
    requestAnimationFrame(this.tick);
  }

  pause() {
    this.playing = false;
    if (this.button) this.button.textContent = "\u25B6 play";
  }

  tick(now) {
    if (!this.playing) return;
    if (this.last !== null) {
      this.acc += ((now - this.last) / 1000) * this.fps * this.speed;
      const n = Math.floor(this.acc);
      if (n > 0) { this.acc -= n; this.seek((this.step + n) % this.steps); }
    }
    this.last = now;
    requestAnimationFrame(this.tick);
  }

  seek(step) {
    this.step = Math.max(0, Math.min(this.steps - 1, step | 0));
    this.slider.value = this.step;
    this.readout.textContent = `step ${this.step + 1}/${this.steps}`;
    this.caption.textContent = this.captionFn(this.step);
    this.draw();
  }

  joint(t, s, j) {
    const b = (t.frames[s] * t.nJ + j) * 3, o = t.offset || [0, 0, 0];
    return [t.pos[b] + o[0], t.pos[b + 1] + o[1], t.pos[b + 2] + o[2]];
  }

  camera() {
    let cx = 0, cz = 0, n = 0;
    for (const t of this.tracks) {
      // the root (joint 0); a marker track: its first marker seen at this step
      for (let j = 0; j < (t.bones && !t.bones.length ? t.nJ : 1); j++) {
        const r = this.joint(t, this.step, j); if (isFinite(r[0])) { cx += r[0]; cz += r[2]; n++; break; }
      }
    }
    const target = n ? [cx / n, this.floor + 0.9, cz / n] : [0, 0.9, 0];
    const cp = Math.cos(this.pitch);
    const eye = [target[0] + this.dist * cp * Math.sin(this.yaw), target[1] + this.dist * Math.sin(this.pitch),
                 target[2] + this.dist * cp * Math.cos(this.yaw)];
    const norm = (v) => { const l = Math.hypot(v[0], v[1], v[2]) || 1; return [v[0] / l, v[1] / l, v[2] / l]; };
    const f = norm([target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]]);
    const r = norm([-f[2], 0, f[0]]);   // f x up
    const u = [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]];
    const W = this.canvas.width, H = this.canvas.height, focal = H / (2 * Math.tan(0.45));
    return { target, project: (p) => {
      const v = [p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]];
      const z = v[0] * f[0] + v[1] * f[1] + v[2] * f[2];
      if (!(z > 0.05)) return null;
      return [W / 2 + focal * (v[0] * r[0] + v[1] * r[1] + v[2] * r[2]) / z,
              H / 2 - focal * (v[0] * u[0] + v[1] * u[1] + v[2] * u[2]) / z];
    } };
  }

  draw() {
    const ctx = this.canvas.getContext("2d"), W = this.canvas.width, H = this.canvas.height;
    ctx.fillStyle = "#f7f7f4"; ctx.fillRect(0, 0, W, H);
    if (!this.tracks.length) return;
    const cam = this.camera(), P = cam.project;
    // floor grid, 0.5 m squares around the target
    ctx.strokeStyle = "#d6d6cf"; ctx.lineWidth = 1;
    const gx = Math.round(cam.target[0] / 0.5) * 0.5, gz = Math.round(cam.target[2] / 0.5) * 0.5, y = this.floor;
    ctx.beginPath();
    for (let i = -8; i <= 8; i++) {
      for (const [a, b] of [[[gx + i * 0.5, y, gz - 4], [gx + i * 0.5, y, gz + 4]], [[gx - 4, y, gz + i * 0.5], [gx + 4, y, gz + i * 0.5]]]) {
        const pa = P(a), pb = P(b); if (pa && pb) { ctx.moveTo(pa[0], pa[1]); ctx.lineTo(pb[0], pb[1]); }
      }
    }
    ctx.stroke();
    this.tracks.forEach((t, k) => {
      const pts = [];
      for (let j = 0; j < t.nJ; j++) { const q = this.joint(t, this.step, j); pts.push(isFinite(q[0]) ? P(q) : null); }
      ctx.strokeStyle = t.color; ctx.lineWidth = t.width || 3; ctx.lineCap = "round";
      ctx.beginPath();
      for (const [a, b] of (t.bones || this.bones)) if (pts[a] && pts[b]) { ctx.moveTo(pts[a][0], pts[a][1]); ctx.lineTo(pts[b][0], pts[b][1]); }
      ctx.stroke();
      ctx.fillStyle = t.color;
      const radius = t.points || 2.5;   // markers: bigger points, no bones
      for (const p of pts) if (p) { ctx.beginPath(); ctx.arc(p[0], p[1], radius, 0, 2 * Math.PI); ctx.fill(); }
      if (t.highlight >= 0 && pts[t.highlight]) {
        const p = pts[t.highlight];
        ctx.strokeStyle = "#e8590c"; ctx.lineWidth = 2; ctx.beginPath(); ctx.arc(p[0], p[1], 9, 0, 2 * Math.PI); ctx.stroke();
      }
      // legend: one line per track
      ctx.fillStyle = t.color; ctx.fillRect(10, 12 + 18 * k, 14, 4);
      ctx.fillStyle = "#222"; ctx.font = "13px sans-serif"; ctx.fillText(t.label + `  (frame ${t.frames[this.step]})`, 30, 18 + 18 * k);
    });
    this.frameCount++;
    this.canvas.dataset.step = this.step;
  }

  /* A static front view of one pose (flat positions J*3) into a small canvas. */
  static drawPose(canvas, flat, bones, color) {
    const ctx = canvas.getContext("2d"), W = canvas.width, H = canvas.height;
    ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, W, H);
    const xs = [], ys = [];
    for (let j = 0; j < flat.length / 3; j++) if (flat[3 * j] !== null) { xs.push(flat[3 * j]); ys.push(flat[3 * j + 1]); }
    if (!xs.length) return;
    const minX = Math.min(...xs), maxX = Math.max(...xs), minY = Math.min(...ys), maxY = Math.max(...ys);
    const s = 0.85 * Math.min(W / Math.max(maxX - minX, 0.5), H / Math.max(maxY - minY, 0.5));
    const px = (j) => [W / 2 + s * (flat[3 * j] - (minX + maxX) / 2), H / 2 - s * (flat[3 * j + 1] - (minY + maxY) / 2)];
    ctx.strokeStyle = color || "#1c4e80"; ctx.lineWidth = 2; ctx.lineCap = "round"; ctx.beginPath();
    for (const [a, b] of bones) if (flat[3 * a] !== null && flat[3 * b] !== null) { const p = px(a), q = px(b); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); }
    ctx.stroke();
  }
}

window.MocapPlayer = MocapPlayer;
