// The run's path with its chainage: where a kilometre lies, the direction of the track there,
// km marks along it, and the train's marker.
import * as THREE from 'three';

/** "12.345", "12,345" or "K12+345" (km and metres) to kilometres; NaN when neither. */
export function parseKm(text) {
  const s = String(text).trim().toUpperCase().replace(/\s+/g, '');
  const k = /^K?(\d+)\+(\d{1,3}(?:\.\d+)?)$/.exec(s);
  if (k) return Number(k[1]) + Number(k[2]) / 1000;
  const d = /^K?(-?\d+(?:[.,]\d+)?)$/.exec(s);
  return d ? Number(d[1].replace(',', '.')) : NaN;
}

/** Kilometres as railway engineers write them: K12+345. */
export function formatKm(km) {
  if (!Number.isFinite(km)) return '–';
  const m = Math.round(km * 1000);
  const sign = m < 0 ? '-' : '';
  const a = Math.abs(m);
  return `${sign}K${Math.floor(a / 1000)}+${String(a % 1000).padStart(3, '0')}`;
}

/** Poses of a TUM text (UTM) zipped with the GeoJSON trajectory's chainage. */
export function parseTrajectory(tum, geo) {
  const poses = [];
  for (const line of tum.split('\n')) {
    if (!line.trim() || line.startsWith('#')) continue;
    const v = line.trim().split(/\s+/).map(Number);
    poses.push({ t: v[0], p: [v[1], v[2], v[3]], q: [v[4], v[5], v[6], v[7]] });
  }
  const feature = geo?.features ? geo.features[0] : geo;
  const chainage = feature?.properties?.chainage_m ?? [];
  if (chainage.length === poses.length) poses.forEach((p, i) => (p.chainage = chainage[i]));
  return poses;
}

export class Track {
  constructor(poses) {
    this.poses = poses;
    // Progressing samples by chainage, for km lookups.
    this.byKm = poses.filter((p) => Number.isFinite(p.chainage)).sort((a, b) => a.chainage - b.chainage);
  }

  get hasChainage() {
    return this.byKm.length > 1;
  }

  range() {
    if (!this.hasChainage) return null;
    return [this.byKm[0].chainage, this.byKm[this.byKm.length - 1].chainage];
  }

  /** UTM position and horizontal unit direction (of increasing chainage) at a chainage. */
  at(chainage) {
    const s = this.byKm;
    if (s.length < 2) return null;
    let lo = 0, hi = s.length - 1;
    if (chainage <= s[0].chainage) hi = 1;
    else if (chainage >= s[hi].chainage) lo = hi - 1;
    else {
      while (hi - lo > 1) {
        const mid = (lo + hi) >> 1;
        if (s[mid].chainage <= chainage) lo = mid;
        else hi = mid;
      }
    }
    const a = s[lo], b = s[hi];
    const span = b.chainage - a.chainage || 1;
    const f = (chainage - a.chainage) / span;
    const p = a.p.map((v, i) => v + f * (b.p[i] - v));
    // The direction over about 10 m, steadier than one pose step.
    const back = this.nearestIndex(chainage - 5), ahead = this.nearestIndex(chainage + 5);
    let dx = s[ahead].p[0] - s[back].p[0], dy = s[ahead].p[1] - s[back].p[1];
    const n = Math.hypot(dx, dy) || 1;
    dx /= n;
    dy /= n;
    return { p, dir: [dx, dy], chainage };
  }

  nearestIndex(chainage) {
    const s = this.byKm;
    let lo = 0, hi = s.length - 1;
    while (hi - lo > 1) {
      const mid = (lo + hi) >> 1;
      if (s[mid].chainage <= chainage) lo = mid;
      else hi = mid;
    }
    return Math.abs(s[lo].chainage - chainage) <= Math.abs(s[hi].chainage - chainage) ? lo : hi;
  }

  /** The chainage nearest a UTM point (horizontal), with its signed offset (left positive). */
  locate(utm) {
    let best = null;
    for (const p of this.byKm) {
      const d = Math.hypot(p.p[0] - utm[0], p.p[1] - utm[1]);
      if (!best || d < best.d) best = { d, p };
    }
    if (!best) return null;
    const here = this.at(best.p.chainage);
    const ex = utm[0] - here.p[0], ey = utm[1] - here.p[1];
    const along = ex * here.dir[0] + ey * here.dir[1];
    const offset = -ex * here.dir[1] + ey * here.dir[0];
    return { chainage: best.p.chainage + along, offset, body: here };
  }
}

/** The path as a line, a tick and label every `stepM` of chainage, in the view's frame. */
export function trackObjects(track, view, stepM = 100) {
  const group = new THREE.Group();
  group.name = 'track';
  const points = track.poses.map((p) => view.toScene(p.p));
  const line = new THREE.Line(
    new THREE.BufferGeometry().setFromPoints(points),
    new THREE.LineBasicMaterial({ color: 0xffd23f }),
  );
  group.add(line);
  const range = track.range();
  if (!range) return group;
  for (let c = Math.ceil(range[0] / stepM) * stepM; c <= range[1]; c += stepM) {
    const at = track.at(c);
    const base = view.toScene(at.p);
    const nx = -at.dir[1], ny = at.dir[0];
    const tick = new THREE.Line(
      new THREE.BufferGeometry().setFromPoints([
        base.clone().add(new THREE.Vector3(-4 * nx, -4 * ny, 0)),
        base.clone().add(new THREE.Vector3(4 * nx, 4 * ny, 0)),
      ]),
      new THREE.LineBasicMaterial({ color: 0xffd23f }),
    );
    group.add(tick);
    const label = textSprite(formatKm(c / 1000), c % 1000 === 0 ? 1.6 : 1.0);
    label.position.copy(base).add(new THREE.Vector3(5 * nx, 5 * ny, 3));
    group.add(label);
  }
  return group;
}

/** A label that faces the camera. */
export function textSprite(text, scale = 1, color = '#ffd23f') {
  const canvas = document.createElement('canvas');
  canvas.width = 256;
  canvas.height = 64;
  const ctx = canvas.getContext('2d');
  ctx.font = 'bold 40px sans-serif';
  ctx.fillStyle = 'rgba(16,20,26,0.7)';
  const w = Math.min(256, ctx.measureText(text).width + 20);
  ctx.fillRect(0, 8, w, 50);
  ctx.fillStyle = color;
  ctx.fillText(text, 10, 46);
  const texture = new THREE.CanvasTexture(canvas);
  // A fixed size on screen, whatever the distance.
  const sprite = new THREE.Sprite(
    new THREE.SpriteMaterial({ map: texture, depthTest: false, transparent: true, sizeAttenuation: false }),
  );
  sprite.center.set(0, 0.5);
  sprite.scale.set(0.12 * scale, 0.03 * scale, 1);
  sprite.renderOrder = 10;
  return sprite;
}

/** The train: a box 20 m long pointing along its heading. */
export function trainMarker() {
  const mesh = new THREE.Mesh(
    new THREE.BoxGeometry(20, 3, 4),
    new THREE.MeshBasicMaterial({ color: 0xff3b6b, transparent: true, opacity: 0.85 }),
  );
  mesh.name = 'train';
  mesh.visible = false;
  return mesh;
}
