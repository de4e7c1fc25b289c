// One run's map as tiles: its index by level, the tiles the camera needs under a point budget
// (nearest first, coarser further away), loading and decoding them, and letting go of those
// that left the view.
import * as THREE from 'three';
import { api } from './api.js';
import { tilePoints } from './points.js';
import { framePoints, tileMatrix } from './registration.js';

const MAX_IN_FLIGHT = 4;
const keyOf = (level, ix, iy) => `${level}/${ix}/${iy}`;

export class TileLayer {
  constructor({ run, runIndex, view, grid, decoder, material, onChange }) {
    this.run = run;
    this.runIndex = runIndex;
    this.view = view;
    this.grid = grid; // {tile_m, voxel_m, levels}
    this.decoder = decoder;
    this.material = material;
    this.onChange = onChange;
    this.index = []; // per level: Map key -> tile info
    this.loaded = new Map(); // key -> {info, points, version, used}
    this.inFlight = new Map(); // key -> AbortController
    this.group = new THREE.Group();
    this.group.name = `run ${run}`;
    this.visible = new Set();
    this.wanted = [];
    this.stats = { requested: 0, loaded: 0, failed: 0, points: 0 };
    this.lastError = null;
    this.firstDrawnAt = null;
    this.announced = new Map(); // key@version -> server's sent_ns of a live tiles message
    this.liveLatencyMs = []; // from the server announcing a tile to drawing it
    // The same from the later of the announcement and the view first wanting that version: a
    // tile out of view (or at a level of detail not drawn) waits for the camera, not the viewer.
    this.liveViewLatencyMs = [];
    this.waiting = new Map(); // key@version -> when a frame first wanted it fetched
  }

  side(level) {
    return this.grid.tile_m * 2 ** level;
  }

  async loadIndex() {
    const levels = await Promise.all(
      Array.from({ length: this.grid.levels }, (_, level) => api.tiles(this.run, level)),
    );
    this.index = levels.map((l) => new Map(l.tiles.map((t) => [keyOf(t.level, t.ix, t.iy), t])));
    return this.tileCount();
  }

  tileCount() {
    return this.index.reduce((n, m) => n + m.size, 0);
  }

  /** The first tile's origin (to place the scene frame), or null for a run without tiles. */
  anyOrigin() {
    for (const m of this.index) for (const t of m.values()) return t.origin;
    return null;
  }

  /** Tiles written while the run streams: their index entries again, in the box they span. */
  async refresh(updates, sentNs) {
    const byLevel = new Map();
    for (const u of updates) {
      if (sentNs) this.announced.set(`${keyOf(u.level, u.ix, u.iy)}@${u.version}`, sentNs);
      if (!byLevel.has(u.level)) byLevel.set(u.level, []);
      byLevel.get(u.level).push(u);
    }
    await Promise.all(
      [...byLevel].map(async ([level, list]) => {
        const s = this.side(level);
        const xs = list.map((u) => u.ix), ys = list.map((u) => u.iy);
        const bbox = [
          Math.min(...xs) * s + 0.01, Math.min(...ys) * s + 0.01,
          (Math.max(...xs) + 1) * s - 0.01, (Math.max(...ys) + 1) * s - 0.01,
        ];
        const answer = await api.tiles(this.run, level, bbox);
        while (this.index.length <= level) this.index.push(new Map());
        for (const t of answer.tiles) this.index[level].set(keyOf(t.level, t.ix, t.iy), t);
      }),
    );
  }

  box(t) {
    const s = this.side(t.level);
    const o = this.view.origin;
    const x = t.ix * s - o[0], y = t.iy * s - o[1], z = t.origin[2] - o[2];
    return new THREE.Box3(new THREE.Vector3(x, y, z - s / 2), new THREE.Vector3(x + s, y + s, z + s));
  }

  /**
   * The tiles to draw: from the coarsest level down, a tile is refined while its voxel covers
   * more than `pixels` on screen; `pixels` grows until the points fit the budget.
   */
  select(budget) {
    const cam = this.view.camera;
    cam.updateMatrixWorld();
    const frustum = new THREE.Frustum().setFromProjectionMatrix(
      new THREE.Matrix4().multiplyMatrices(cam.projectionMatrix, cam.matrixWorldInverse),
    );
    const top = this.index.length - 1;
    if (top < 0) return [];
    const candidates = [];
    for (const t of this.index[top].values()) {
      const box = this.box(t);
      if (frustum.intersectsBox(box)) candidates.push({ t, box });
    }
    for (let pixels = 1.5; pixels < 200; pixels *= 2) {
      const chosen = [];
      let points = 0;
      const visit = ({ t, box }) => {
        const d = box.distanceToPoint(cam.position);
        const voxel = this.grid.voxel_m * 2 ** t.level;
        if (t.level > 0 && voxel * this.view.pixelsPerMetre(d) > pixels) {
          const children = this.children(t)
            .map((c) => ({ t: c, box: this.box(c) }))
            .filter((c) => frustum.intersectsBox(c.box));
          if (children.length) return children.forEach(visit);
        }
        chosen.push({ t, d });
        points += t.points;
      };
      candidates.forEach(visit);
      if (points <= budget || pixels * 2 >= 200) {
        chosen.sort((a, b) => a.d - b.d);
        let sum = 0;
        return chosen.filter((c) => (sum += c.t.points) <= budget).map((c) => c.t);
      }
    }
    return [];
  }

  children(t) {
    const level = this.index[t.level - 1];
    if (!level) return [];
    const out = [];
    for (const dx of [0, 1]) {
      for (const dy of [0, 1]) {
        const c = level.get(keyOf(t.level - 1, 2 * t.ix + dx, 2 * t.iy + dy));
        if (c) out.push(c);
      }
    }
    return out;
  }

  /** Draws what is wanted and loaded (a loaded coarser tile stands in for one on its way). */
  update(budget) {
    if (!this.view.origin) return;
    this.wanted = this.select(budget);
    // The coarse ancestors of what is wanted: a few small tiles put the whole view on screen
    // at once, and stand in while the finer ones load.
    const top = this.index.length - 1;
    const ancestors = new Map();
    for (const t of this.wanted) {
      const a = this.ancestor(t, top);
      if (a) ancestors.set(keyOf(a.level, a.ix, a.iy), a);
    }
    const wantedKeys = new Set([...this.wanted.map((t) => keyOf(t.level, t.ix, t.iy)), ...ancestors.keys()]);
    for (const [key, controller] of this.inFlight) {
      if (!wantedKeys.has(key)) {
        controller.abort();
        this.inFlight.delete(key);
      }
    }
    for (const [key, a] of ancestors) if (!this.loaded.has(key)) this.fetchTile(a, key);
    const show = new Set();
    const fetches = [];
    for (const t of this.wanted) {
      const key = keyOf(t.level, t.ix, t.iy);
      const have = this.loaded.get(key);
      if (have) show.add(key);
      if (!have || have.version !== t.version) {
        fetches.push({ t, key });
        if (!have) {
          const stand = this.loadedAncestor(t);
          if (stand) show.add(stand);
        }
      }
    }
    this.fetchInTurn(fetches);
    this.setVisible(show);
    this.evict(budget);
  }

  /**
   * Fetches in the order the tiles were first wanted, nearest first among those wanted in the
   * same frame: while a train streams, the near tiles change with every submap, and taken
   * nearest first every frame they could keep the few fetches in flight to themselves while a
   * new version of a farther, coarser tile waits.
   */
  fetchInTurn(fetches) {
    const now = performance.now();
    const waiting = new Map();
    for (const f of fetches) {
      const id = `${f.key}@${f.t.version}`;
      f.since = this.waiting.get(id) ?? now;
      waiting.set(id, f.since);
    }
    this.waiting = waiting;
    fetches.sort((a, b) => a.since - b.since); // stable: nearest first within a frame
    for (const { t, key, since } of fetches) this.fetchTile(t, key, since);
  }

  ancestor(t, level) {
    if (level <= t.level) return null;
    const f = 2 ** (level - t.level);
    return this.index[level]?.get(keyOf(level, Math.floor(t.ix / f), Math.floor(t.iy / f))) ?? null;
  }

  loadedAncestor(t) {
    for (let level = t.level + 1; level < this.index.length; level++) {
      const f = 2 ** (level - t.level);
      const key = keyOf(level, Math.floor(t.ix / f), Math.floor(t.iy / f));
      if (this.loaded.has(key)) return key;
    }
    return null;
  }

  setVisible(show) {
    let points = 0;
    const now = performance.now();
    for (const key of this.visible) {
      if (!show.has(key)) this.group.remove(this.loaded.get(key)?.points);
    }
    for (const key of show) {
      const tile = this.loaded.get(key);
      tile.used = now;
      points += tile.info.points;
      if (!this.visible.has(key)) this.group.add(tile.points);
      const sent = this.announced.get(`${key}@${tile.version}`);
      if (sent) {
        const drawn = Date.now();
        this.liveLatencyMs.push(drawn - sent / 1e6);
        this.liveViewLatencyMs.push(drawn - Math.max(sent / 1e6, performance.timeOrigin + tile.wantedAt));
        this.announced.delete(`${key}@${tile.version}`);
      }
    }
    if (show.size && this.firstDrawnAt === null) {
      this.firstDrawnAt = now;
      performance.mark('raillomer:first-drawn');
    }
    this.visible = show;
    this.stats.points = points;
  }

  fetchTile(t, key, wantedAt = performance.now()) {
    if (this.inFlight.has(key) || this.inFlight.size >= MAX_IN_FLIGHT) return;
    const controller = new AbortController();
    this.inFlight.set(key, controller);
    this.stats.requested += 1;
    // The worker fetches with no-cache: the browser revalidates with the tile's ETag, a 304
    // costs no bytes.
    this.decoder
      .load(this.url(key), controller.signal)
      .then((decoded) => this.store(t, key, decoded, wantedAt))
      .catch((e) => {
        if (e.name === 'AbortError') return;
        this.stats.failed += 1;
        this.lastError = `tile ${key} of run ${this.run}: ${e.message}`;
      })
      .finally(() => {
        if (this.inFlight.get(key) === controller) this.inFlight.delete(key);
        this.onChange();
      });
  }

  /** Draws the run registered onto its reference (null: as it was recorded). */
  setRegistration(registration, track) {
    this.registration = registration;
    this.track = track;
    for (const tile of this.loaded.values()) this.place(tile.points, tile.info);
  }

  /** A tile's matrix: at its origin, through its stretch's registration if there is one. */
  place(points, t) {
    let stretch = null;
    if (this.registration && !this.registration.empty) {
      const half = this.side(t.level) / 2;
      const located = this.track?.locate([t.origin[0] + half, t.origin[1] + half, t.origin[2]]);
      if (located) stretch = this.registration.at(located.chainage);
    }
    points.matrix.copy(tileMatrix(stretch, t.origin, this.view.origin));
    points.matrixWorldNeedsUpdate = true;
  }

  store(t, key, decoded, wantedAt) {
    const old = this.loaded.get(key);
    const points = tilePoints(decoded, this.material);
    this.place(points, t);
    points.userData = { run: this.run, key, level: t.level, runIndex: this.runIndex };
    if (old) {
      this.group.remove(old.points);
      old.points.geometry.dispose();
      this.visible.delete(key);
    }
    this.loaded.set(key, { info: t, points, version: t.version, used: performance.now(), wantedAt });
    this.stats.loaded += 1;
  }

  url(key) {
    return `/api/v1/runs/${this.run}/tiles/${key}`;
  }

  /** Lets go of tiles out of view once those held pass twice the budget. */
  evict(budget) {
    let held = 0;
    for (const tile of this.loaded.values()) held += tile.info.points;
    if (held <= 2 * budget) return;
    const idle = [...this.loaded].filter(([key]) => !this.visible.has(key));
    idle.sort((a, b) => a[1].used - b[1].used);
    for (const [key, tile] of idle) {
      if (held <= budget) break;
      tile.points.geometry.dispose();
      this.loaded.delete(key);
      held -= tile.info.points;
    }
  }

  /**
   * The full-detail (level 0) tiles within `radius` of a scene point, loaded if they are not:
   * sections and measurements need every point, whatever the view draws.
   */
  async detailNear(center, radius) {
    const o = this.view.origin;
    const s = this.side(0);
    const x0 = Math.floor((center.x + o[0] - radius) / s), x1 = Math.floor((center.x + o[0] + radius) / s);
    const y0 = Math.floor((center.y + o[1] - radius) / s), y1 = Math.floor((center.y + o[1] + radius) / s);
    const keys = [];
    for (let ix = x0; ix <= x1; ix++) {
      for (let iy = y0; iy <= y1; iy++) {
        const t = this.index[0]?.get(keyOf(0, ix, iy));
        if (!t) continue;
        const key = keyOf(0, ix, iy);
        keys.push(key);
        if (this.loaded.get(key)?.version === t.version) continue;
        this.store(t, key, await this.decoder.load(this.url(key)));
      }
    }
    return keys;
  }

  /** The points of loaded tiles (by key) near a scene point. */
  *pointsNear(center, radius, keys = this.visible) {
    for (const key of keys) {
      const tile = this.loaded.get(key);
      if (!tile) continue;
      const p = tile.points;
      const sphere = p.geometry.boundingSphere.clone().applyMatrix4(p.matrix);
      if (sphere.center.distanceTo(center) > sphere.radius + radius) continue;
      const intensity = p.geometry.attributes.intensity.array;
      for (const [x, y, z, i] of framePoints(p)) {
        if (Math.abs(x - center.x) > radius || Math.abs(y - center.y) > radius) continue;
        yield [x, y, z, intensity[i], tile.info.level];
      }
    }
  }

  dispose() {
    for (const c of this.inFlight.values()) c.abort();
    for (const tile of this.loaded.values()) tile.points.geometry.dispose();
    this.loaded.clear();
    this.group.removeFromParent();
  }
}
