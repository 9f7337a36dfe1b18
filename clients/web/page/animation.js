// animation.js — the "animation" member of POST …/renders (protocol/API.md, Animation jobs)
// from the page's presets: a still camera (a run of frames to watch converge), an orbit around
// the point the camera looks at, or keyframes typed as JSON.

function sub(a, b) {
  return a.map((v, i) => v - b[i]);
}

function add(a, b) {
  return a.map((v, i) => v + b[i]);
}

function dot(a, b) {
  return a.reduce((s, v, i) => s + v * b[i], 0);
}

function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

function scale(a, s) {
  return a.map((v) => v * s);
}

// Rodrigues' rotation of v by `angle` radians about the unit axis k.
function rotate(v, k, angle) {
  const c = Math.cos(angle);
  const s = Math.sin(angle);
  return add(add(scale(v, c), scale(cross(k, v), s)), scale(k, dot(k, v) * (1 - c)));
}

// Camera keys for an orbit of `degrees` about the camera's up axis through look_at: one key per
// 45 degrees (at least two) with Catmull-Rom between them, so the path is round rather than a
// polygon, the last key at the last frame's time (frame i is rendered at i / fps).
export function orbitAnimation(camera, { frames, fps, degrees }) {
  const duration = Math.max(frames - 1, 1) / fps;
  const len = Math.hypot(...camera.up);
  const axis = scale(camera.up, 1 / len);
  const arm = sub(camera.position, camera.look_at);
  const steps = Math.max(2, Math.ceil(Math.abs(degrees) / 45));
  const keys = [];
  for (let i = 0; i <= steps; i++) {
    const angle = ((degrees * Math.PI) / 180) * (i / steps);
    keys.push({ t: (duration * i) / steps, position: add(camera.look_at, rotate(arm, axis, angle)), look_at: camera.look_at });
  }
  return { fps, frames, interpolation: 'catmull_rom', camera_keys: keys };
}

export function stillAnimation({ frames, fps }) {
  return { fps, frames };
}
