// A stick figure on a canvas: orbit camera, floor grid, trails, joints coloured by reliability.

export const BONES = [
  ["root", "waist"], ["waist", "chest"], ["chest", "neck"],
  ["neck", "l_shoulder"], ["l_shoulder", "l_elbow"], ["l_elbow", "l_wrist"],
  ["neck", "r_shoulder"], ["r_shoulder", "r_elbow"], ["r_elbow", "r_wrist"],
  ["root", "l_hip"], ["l_hip", "l_knee"], ["l_knee", "l_ankle"],
  ["root", "r_hip"], ["r_hip", "r_knee"], ["r_knee", "r_ankle"],
];

export const RELIABILITY_COLOURS = {
  data: "#3ccf6e", "prior-assisted": "#f0b429", prior: "#ef5350", unknown: "#9aa5b1",
};

/** A rotation taking `up` to +Y (Rodrigues), as a function on [x, y, z]. */
export function uprighter(up = [0, 1, 0]) {
  const n = Math.hypot(...up) || 1;
  const u = up.map((c) => c / n);
  const axis = [-u[2], 0, u[0]]; // u × y
  const s = Math.hypot(...axis);
  const c = u[1];
  if (s < 1e-9) return c > 0 ? (p) => p : (p) => [p[0], -p[1], -p[2]];
  const k = axis.map((a) => a / s);
  return (p) => {
    const dot = k[0] * p[0] + k[1] * p[1] + k[2] * p[2];
    const cross = [k[1] * p[2] - k[2] * p[1], k[2] * p[0] - k[0] * p[2], k[0] * p[1] - k[1] * p[0]];
    return [0, 1, 2].map((i) => p[i] * c + cross[i] * s + k[i] * dot * (1 - c));
  };
}

/** Frames of every joint turned upright, and the take's bounds. */
export function prepare(doc, up) {
  const turn = uprighter(up);
  const joints = {};
  const lo = [Infinity, Infinity, Infinity];
  const hi = [-Infinity, -Infinity, -Infinity];
  for (const [name, rows] of Object.entries(doc.joints)) {
    joints[name] = rows.map((p) => {
      const q = turn(p);
      for (let i = 0; i < 3; i += 1) { lo[i] = Math.min(lo[i], q[i]); hi[i] = Math.max(hi[i], q[i]); }
      return q;
    });
  }
  const center = lo.map((l, i) => (l + hi[i]) / 2);
  const radius = Math.max(0.5, Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2);
  return { joints, frames: doc.frames, fps: doc.fps, center, radius, floor: lo[1] };
}

/** Screen position [x, y, depth] of a world point for a camera. */
export function project(p, camera, width, height) {
  const [cx, cy, cz] = camera.center;
  const x = p[0] - cx; const y = p[1] - cy; const z = p[2] - cz;
  const x1 = Math.cos(camera.yaw) * x - Math.sin(camera.yaw) * z;
  const z1 = Math.sin(camera.yaw) * x + Math.cos(camera.yaw) * z;
  const y2 = Math.cos(camera.pitch) * y - Math.sin(camera.pitch) * z1;
  const z2 = Math.sin(camera.pitch) * y + Math.cos(camera.pitch) * z1;
  const distance = camera.radius * 6;
  const scale = (Math.min(width, height) / (2.4 * camera.radius)) * camera.zoom
    * (distance / Math.max(distance + z2, 1e-3));
  return [width / 2 + x1 * scale, height / 2 - y2 * scale, z2];
}

function drawGrid(ctx, scene, camera, w, h) {
  const step = 0.5;
  const span = Math.ceil((scene.radius * 1.5) / step) * step;
  const [cx, , cz] = scene.center;
  ctx.strokeStyle = "rgba(255,255,255,0.15)";
  ctx.lineWidth = 1;
  for (let d = -span; d <= span + 1e-9; d += step) {
    for (const [a, b] of [[[cx + d, scene.floor, cz - span], [cx + d, scene.floor, cz + span]],
      [[cx - span, scene.floor, cz + d], [cx + span, scene.floor, cz + d]]]) {
      const p = project(a, camera, w, h); const q = project(b, camera, w, h);
      ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
    }
  }
}

function drawTrails(ctx, scene, camera, frame, w, h) {
  const length = Math.round(scene.fps || 60);
  ctx.strokeStyle = "rgba(120,170,255,0.5)";
  for (const name of ["l_wrist", "r_wrist", "l_ankle", "r_ankle", "root"]) {
    const rows = scene.joints[name];
    if (!rows) continue;
    ctx.beginPath();
    for (let i = Math.max(0, frame - length); i <= frame; i += 1) {
      const p = project(rows[i], camera, w, h);
      if (i === Math.max(0, frame - length)) ctx.moveTo(p[0], p[1]); else ctx.lineTo(p[0], p[1]);
    }
    ctx.stroke();
  }
}

/** Draw frame `frame` of `scene` on `canvas`; `colours[joint]` fills each joint. */
export function draw(canvas, scene, camera, frame, { trails = false, colours = {} } = {}) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width; const h = canvas.height;
  ctx.fillStyle = "#10131b";
  ctx.fillRect(0, 0, w, h);
  drawGrid(ctx, scene, camera, w, h);
  if (trails) drawTrails(ctx, scene, camera, frame, w, h);
  const at = (name) => scene.joints[name] && project(scene.joints[name][frame], camera, w, h);
  ctx.strokeStyle = "#e8ecf4";
  ctx.lineWidth = 3;
  for (const [a, b] of BONES) {
    const p = at(a); const q = at(b);
    if (!p || !q) continue;
    ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(q[0], q[1]); ctx.stroke();
  }
  for (const name of Object.keys(scene.joints)) {
    const p = at(name);
    ctx.fillStyle = colours[name] || RELIABILITY_COLOURS.unknown;
    ctx.beginPath(); ctx.arc(p[0], p[1], 5, 0, 2 * Math.PI); ctx.fill();
  }
}
