// marionette studio: a perspective view of the skeleton on a 2D canvas, draggable IK handles,
// and the panels; everything the server knows arrives over the WebSocket at /ws.
"use strict";

const $ = (id) => document.getElementById(id);
const canvas = $("view");
const ctx = canvas.getContext("2d");

// ---- vectors ---------------------------------------------------------------------------------
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

// ---- state -----------------------------------------------------------------------------------
const studio = {
  hello: null,       // skeleton, servos, methods
  state: null,       // the newest state from the server
  selected: null,    // effector name
  drag: null,        // {effector, plane point, position}
  fps: 0,
  framesWhileDragging: 0,
  errors: window.studioErrors,
  sent: 0,
};
window.studio = studio;

const camera = { target: [0, 15, 0], distance: 80, yaw: 0.6, pitch: 0.25, fov: 45 * Math.PI / 180, framed: false };
let floorY = 0;

function basis() {
  const cp = Math.cos(camera.pitch);
  const eye = add(camera.target, mul([cp * Math.sin(camera.yaw), Math.sin(camera.pitch), cp * Math.cos(camera.yaw)], camera.distance));
  const f = norm(sub(camera.target, eye));
  const r = norm(cross(f, [0, 1, 0]));
  const u = cross(r, f);
  const h = canvas.clientHeight;
  const F = (h / 2) / Math.tan(camera.fov / 2);
  return { eye, f, r, u, F, w: canvas.clientWidth, h };
}

// World → CSS pixels of the canvas, with depth; null behind the eye.
function project(b, p) {
  const d = sub(p, b.eye);
  const z = dot(d, b.f);
  if (z < 1e-3) return null;
  return { x: b.w / 2 + b.F * dot(d, b.r) / z, y: b.h / 2 - b.F * dot(d, b.u) / z, z };
}

// The ray through a pixel.
function ray(b, sx, sy) {
  return norm(add(b.f, add(mul(b.r, (sx - b.w / 2) / b.F), mul(b.u, (b.h / 2 - sy) / b.F))));
}

// Where the ray through a pixel meets the plane through `point` facing the camera.
function onViewPlane(b, sx, sy, point) {
  const d = ray(b, sx, sy);
  const t = dot(sub(point, b.eye), b.f) / dot(d, b.f);
  return add(b.eye, mul(d, t));
}

// ---- connection ------------------------------------------------------------------------------
let socket = null;
function send(msg) {
  if (socket && socket.readyState === WebSocket.OPEN) {
    socket.send(JSON.stringify(msg));
    studio.sent += 1;
  }
}

function connect() {
  socket = new WebSocket(`ws://${location.host}/ws`);
  socket.onopen = () => { $("connection").textContent = "connected"; $("connection").className = "good"; };
  socket.onclose = () => {
    $("connection").textContent = "disconnected: retrying";
    $("connection").className = "bad";
    setTimeout(connect, 1000);
  };
  socket.onmessage = (ev) => {
    const msg = JSON.parse(ev.data);
    if (msg.type === "hello") setup(msg);
    else if (msg.type === "state") update(msg);
    else if (msg.type === "error") showError(msg.message);
  };
}

let errorShown = null;
function showError(text) {
  $("connection").textContent = text;
  $("connection").className = "bad";
  clearTimeout(errorShown);
  errorShown = setTimeout(() => {
    if (socket && socket.readyState === WebSocket.OPEN) {
      $("connection").textContent = "connected";
      $("connection").className = "good";
    }
  }, 3000);
}

// ---- panels ----------------------------------------------------------------------------------
function setup(hello) {
  studio.hello = hello;
  const method = $("method"), compare = $("compare");
  method.innerHTML = "";
  compare.innerHTML = '<option value="">none</option>';
  for (const m of hello.methods) {
    method.add(new Option(m, m));
    compare.add(new Option(m, m));
  }
  const body = $("servos").tBodies[0];
  body.innerHTML = "";
  for (const s of hello.servos) {
    const row = body.insertRow();
    row.insertCell().textContent = s.name;
    row.cells[0].title = s.bone ? `moves ${s.bone}` : "a robot joint";
    row.insertCell(); row.insertCell();
    const bar = row.insertCell(); bar.className = "bar";
    bar.innerHTML = '<div class="err" style="width:0"></div>';
  }
  $("timeline").hidden = !hello.has_clip;
}

const fmt = (x, d = 2) => (x === null || x === undefined || !Number.isFinite(x)) ? "–" : x.toFixed(d);

function update(state) {
  const first = !studio.state;
  studio.state = state;
  if (first || !camera.framed) frame(state);
  if (state.selected && !studio.drag) studio.selected = state.selected;
  const r = state.report;
  $("method").value = r.solver;
  $("primary-name").textContent = r.solver;
  $("primary-iterations").textContent = r.iterations;
  $("primary-residual").textContent = r.residual.toExponential(2);
  $("primary-micros").textContent = fmt(r.micros, 0);
  $("ghost-row").hidden = !state.ghost;
  $("compare").value = state.ghost ? state.ghost.solver : "";
  if (state.ghost) {
    const g = state.ghost.report;
    $("ghost-name").textContent = g.solver;
    $("ghost-iterations").textContent = g.iterations;
    $("ghost-residual").textContent = g.residual.toExponential(2);
    $("ghost-micros").textContent = fmt(g.micros, 0);
  }
  $("selected").textContent = studio.selected || "none selected";
  $("swivels").textContent = r.swivels.map(([n, d]) => `${n} swivel ${d.toFixed(1)}°`).join(" · ");
  const fixed = state.swivel.fixed_deg;
  $("swivel-auto").checked = fixed === null;
  $("swivel").disabled = fixed === null;
  $("swivel-value").textContent = fixed === null ? "auto" : `${fixed.toFixed(0)}°`;
  if (state.timeline && !scrubbing) {
    const t = state.timeline;
    $("scrub").max = t.duration;
    $("scrub").value = t.time;
    $("time").textContent = `${t.time.toFixed(2)} / ${t.duration.toFixed(2)} s`;
    $("play").textContent = t.playing ? "pause" : "play";
    $("looping").checked = t.looping;
  }
  const lp = state.loop;
  const compute = lp.simulated_time
    ? "compute not timed (the loop runs on the simulator's time)"
    : `compute p50 ${fmt(lp.compute_p50_us, 0)} µs, p99 ${fmt(lp.compute_p99_us, 0)} µs`;
  $("loop").textContent = `loop ${fmt(lp.measured_hz, 1)} of ${lp.rate_hz} Hz on ${lp.bus} · ${lp.ticks} ticks, ${lp.misses} misses · ${compute}`;
  const l = state.latency;
  $("latency").textContent = l.n ? `drag → Sync Write: p50 ${fmt(l.p50 / 1000)} ms, p99 ${fmt(l.p99 / 1000)} ms (${l.n} drags)` : "drag → Sync Write: no drag yet";
  const rows = $("servos").tBodies[0].rows;
  state.servos.forEach((s, k) => {
    const row = rows[k];
    if (!row) return;
    row.cells[1].textContent = fmt(s.goal_deg, 1);
    row.cells[2].textContent = fmt(s.present_deg, 1);
    const e = (s.goal_deg === null || s.present_deg === null) ? 0 : Math.min(60, Math.abs(s.goal_deg - s.present_deg) * 6);
    row.cells[3].firstChild.style.width = `${e}px`;
  });
}

// Frames the camera on the skeleton once its first pose is known.
function frame(state) {
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (const s of state.bones) for (let i = 0; i < 6; i++) { lo[i % 3] = Math.min(lo[i % 3], s[i]); hi[i % 3] = Math.max(hi[i % 3], s[i]); }
  // The robot beside the human is framed too (its floor is the human's).
  if (state.robot) for (const [p, q] of state.robot.links) for (const v of [p, q]) for (let i = 0; i < 3; i++) {
    if (i !== 1) { lo[i] = Math.min(lo[i], v[i]); hi[i] = Math.max(hi[i], v[i]); }
  }
  if (!Number.isFinite(lo[0])) return;
  camera.target = mul(add(lo, hi), 0.5);
  camera.distance = 1.6 * Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / Math.tan(camera.fov / 2) / 2 + 1;
  floorY = lo[1];
  camera.framed = true;
}

$("method").onchange = $("compare").onchange = () => {
  send({ type: "solver", method: $("method").value, compare: $("compare").value || null });
};
$("swivel-auto").onchange = () => send({ type: "swivel", deg: $("swivel-auto").checked ? null : Number($("swivel").value) });
$("swivel").oninput = () => send({ type: "swivel", deg: Number($("swivel").value) });
$("pin").onclick = () => studio.selected && send({ type: "pin", effector: studio.selected });
$("release").onclick = () => studio.selected && send({ type: "release", effector: studio.selected });
$("reset").onclick = () => send({ type: "reset" });
let scrubbing = false;
$("scrub").oninput = () => { scrubbing = true; send({ type: "timeline", time: Number($("scrub").value) }); };
$("scrub").onchange = () => { scrubbing = false; };
$("play").onclick = () => studio.state && studio.state.timeline && send({ type: "timeline", playing: !studio.state.timeline.playing });
$("speed").onchange = () => send({ type: "timeline", speed: Number($("speed").value) });
$("looping").onchange = () => send({ type: "timeline", looping: $("looping").checked });

// ---- drawing ---------------------------------------------------------------------------------
function resize() {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
}

function line(b, p, q, style, width) {
  const a = project(b, p), c = project(b, q);
  if (!a || !c) return;
  ctx.strokeStyle = style;
  ctx.lineWidth = width;
  ctx.beginPath(); ctx.moveTo(a.x, a.y); ctx.lineTo(c.x, c.y); ctx.stroke();
}

function dotAt(b, p, radius, fill, stroke) {
  const a = project(b, p);
  if (!a) return null;
  const r = Math.max(2, radius * b.F / a.z);
  ctx.beginPath(); ctx.arc(a.x, a.y, r, 0, 2 * Math.PI);
  if (fill) { ctx.fillStyle = fill; ctx.fill(); }
  if (stroke) { ctx.strokeStyle = stroke; ctx.lineWidth = 1.5; ctx.stroke(); }
  return a;
}

function grid(b) {
  const mpu = (studio.hello && studio.hello.metres_per_unit) || 0.05;
  const step = 0.25 / mpu, n = 12;
  const c = camera.target;
  const x0 = Math.round(c[0] / step) * step, z0 = Math.round(c[2] / step) * step;
  for (let i = -n; i <= n; i++) {
    const style = i === 0 ? "#3a4250" : "#262b33";
    line(b, [x0 + i * step, floorY, z0 - n * step], [x0 + i * step, floorY, z0 + n * step], style, 1);
    line(b, [x0 - n * step, floorY, z0 + i * step], [x0 + n * step, floorY, z0 + i * step], style, 1);
  }
}

function skeleton(b, bones, color, width, joints) {
  for (const s of bones) line(b, s.slice(0, 3), s.slice(3), color, width);
  if (!joints) return;
  const servoBones = new Set((studio.hello ? studio.hello.servos : []).map((s) => s.bone).filter(Boolean));
  const names = studio.hello ? studio.hello.bones : [];
  bones.forEach((s, k) => {
    const name = names[k] && names[k].name;
    if (servoBones.has(name)) {
      const a = project(b, s.slice(0, 3));
      if (a) { ctx.fillStyle = "#e0a040"; ctx.fillRect(a.x - 3.5, a.y - 3.5, 7, 7); }
    } else {
      dotAt(b, s.slice(0, 3), 0.25, "#c8d0da");
    }
  });
}

// The robot beside the human: the support polygon of its planted soles (filled), its soles
// (solid when planted), its links at the servos' present angles, the centre of mass (red) and
// the ZMP (blue) on the floor.
function robot(b, r) {
  const poly = r.support.map((p) => project(b, p)).filter(Boolean);
  if (poly.length >= 3) {
    ctx.beginPath(); ctx.moveTo(poly[0].x, poly[0].y);
    for (const a of poly.slice(1)) ctx.lineTo(a.x, a.y);
    ctx.closePath(); ctx.fillStyle = "rgba(96,208,128,0.25)"; ctx.fill();
  }
  for (const sole of r.soles) {
    ctx.setLineDash(sole.planted ? [] : [4, 4]);
    const c = sole.corners;
    for (let i = 0; i < 4; i++) line(b, c[i], c[(i + 1) % 4], "#f0a040", 1.5);
  }
  ctx.setLineDash([]);
  for (const [p, q] of r.links) line(b, p, q, r.present ? "#f08030" : "rgba(240,128,48,0.55)", 3);
  dotAt(b, r.com, 0.3, "#e05050");
  dotAt(b, r.zmp, 0.3, "#5080f0");
  studio.robotDrawn = r.links.length;
}

// Where each handle is drawn: the target when it has one (or is being dragged), else the tip.
function handles() {
  const st = studio.state;
  if (!st) return [];
  return st.effectors.map((e) => {
    let at = e.target || e.tip;
    if (studio.drag && studio.drag.effector === e.name) at = studio.drag.position;
    return { name: e.name, at, tip: e.tip, target: e.target, bone: e.bone };
  });
}

function draw() {
  resize();
  const b = basis();
  ctx.clearRect(0, 0, b.w, b.h);
  const st = studio.state;
  grid(b);
  if (!st) return;
  for (const p of st.swivel.region) dotAt(b, p, 0.08, "rgba(128,144,255,0.35)");
  const circle = st.swivel.circle;
  for (let i = 0; i < circle.length; i++) {
    const p = circle[i], q = circle[(i + 1) % circle.length];
    line(b, p.elbow, q.elbow, p.legal && q.legal ? "#60d080" : "#e06060", 2);
  }
  if (st.ghost) skeleton(b, st.ghost.bones, "rgba(120,200,255,0.55)", 3, false);
  skeleton(b, st.bones, "#e8ecf0", 3, true);
  if (st.robot) robot(b, st.robot);
  for (const h of handles()) {
    const selected = h.name === studio.selected;
    if (h.target) line(b, h.tip, h.target, "rgba(255,208,96,0.6)", 1);
    const a = project(b, h.at);
    if (!a) continue;
    ctx.beginPath(); ctx.arc(a.x, a.y, selected ? 8 : 6.5, 0, 2 * Math.PI);
    ctx.fillStyle = selected ? "rgba(255,208,96,0.9)" : "rgba(255,208,96,0.4)"; ctx.fill();
    ctx.strokeStyle = "#ffd060"; ctx.lineWidth = 1.5; ctx.stroke();
    if (selected) { ctx.fillStyle = "#ffd060"; ctx.fillText(h.name, a.x + 10, a.y - 8); }
  }
  if (st.ghost) {
    ctx.fillStyle = "rgba(120,200,255,0.9)";
    ctx.fillText(`ghost: ${st.ghost.solver}`, 8, 16);
    ctx.fillStyle = "#e8ecf0";
    ctx.fillText(`solid: ${st.report.solver}`, 8, 30);
  }
}

// Screen position of an effector's handle (CSS pixels in the canvas), for tests and scripts.
studio.handleScreen = (name) => {
  const h = handles().find((x) => x.name === name);
  if (!h) return null;
  const p = project(basis(), h.at);
  return p && { x: p.x, y: p.y };
};

// ---- the frame loop, with frames per second ---------------------------------------------------
let frames = 0, since = performance.now();
function loop(now) {
  draw();
  frames += 1;
  if (studio.drag) studio.framesWhileDragging += 1;
  if (now - since >= 1000) {
    studio.fps = frames * 1000 / (now - since);
    frames = 0; since = now;
    $("fps").textContent = `page ${studio.fps.toFixed(0)} frames/s`;
  }
  requestAnimationFrame(loop);
}

// ---- mouse: drag a handle, pick a bone tip, orbit, pan, zoom ----------------------------------
let pointer = null;

function nearest(points, x, y, within) {
  let best = null, bd = within;
  for (const p of points) {
    const d = Math.hypot(p.x - x, p.y - y);
    if (d < bd) { bd = d; best = p; }
  }
  return best;
}

canvas.addEventListener("pointerdown", (ev) => {
  const rect = canvas.getBoundingClientRect();
  const x = ev.clientX - rect.left, y = ev.clientY - rect.top;
  const b = basis();
  canvas.setPointerCapture(ev.pointerId);
  const hs = handles().map((h) => ({ ...project(b, h.at), h })).filter((p) => Number.isFinite(p.x));
  const hit = ev.button === 0 && !ev.shiftKey && nearest(hs, x, y, 14);
  if (hit) {
    studio.selected = hit.h.name;
    studio.drag = { effector: hit.h.name, plane: hit.h.at, position: hit.h.at };
    send({ type: "select", effector: hit.h.name });
    canvas.classList.add("dragging");
    pointer = { mode: "drag", x, y };
    return;
  }
  pointer = { mode: ev.button === 2 || ev.shiftKey ? "pan" : "orbit", x, y, moved: false };
});

canvas.addEventListener("pointermove", (ev) => {
  if (!pointer) return;
  const rect = canvas.getBoundingClientRect();
  const x = ev.clientX - rect.left, y = ev.clientY - rect.top;
  const dx = x - pointer.x, dy = y - pointer.y;
  if (Math.abs(dx) + Math.abs(dy) > 2) pointer.moved = true;
  const b = basis();
  if (pointer.mode === "drag" && studio.drag) {
    const p = onViewPlane(b, x, y, studio.drag.plane);
    studio.drag.position = p;
    send({ type: "drag", effector: studio.drag.effector, position: p, t: performance.timeOrigin + performance.now() });
    return;
  }
  pointer.x = x; pointer.y = y;
  if (pointer.mode === "orbit") {
    camera.yaw -= dx * 0.008;
    camera.pitch = Math.max(-1.45, Math.min(1.45, camera.pitch + dy * 0.008));
  } else {
    const s = camera.distance / b.F;
    camera.target = add(camera.target, add(mul(b.r, -dx * s), mul(b.u, dy * s)));
  }
});

function endPointer(ev) {
  if (!pointer) return;
  if (pointer.mode === "orbit" && !pointer.moved && studio.state) {
    // A click: pick the nearest bone tip as a new handle.
    const rect = canvas.getBoundingClientRect();
    const x = ev.clientX - rect.left, y = ev.clientY - rect.top;
    const b = basis();
    const names = studio.hello.bones;
    const tips = studio.state.bones
      .map((s, k) => ({ ...project(b, s.slice(3)), name: names[k].name }))
      .filter((p) => Number.isFinite(p.x));
    const hit = nearest(tips, x, y, 10);
    if (hit) {
      studio.selected = hit.name;
      send({ type: "pick", bone: hit.name });
    }
  }
  studio.drag = null;
  pointer = null;
  canvas.classList.remove("dragging");
}
canvas.addEventListener("pointerup", endPointer);
canvas.addEventListener("pointercancel", endPointer);
canvas.addEventListener("contextmenu", (ev) => ev.preventDefault());
canvas.addEventListener("wheel", (ev) => {
  ev.preventDefault();
  camera.distance = Math.max(1, camera.distance * Math.exp(ev.deltaY * 0.001));
}, { passive: false });

connect();
requestAnimationFrame(loop);
