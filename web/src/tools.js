// The tools panel: the cross-section with the gauge, measuring, the clip box, point size,
// the divide between two runs and colouring by change.
import * as THREE from 'three';
import { api } from './api.js';
import { RUN_COLORS } from './points.js';
import { RAIL_HALF_GAUGE_M, cutSection, drawSection, widenedGauge } from './section.js';
import { formatKm, parseKm } from './track.js';
import { drawProfile } from './profile.js';
import { fmt } from './util.js';
import { changeDistances } from './compare.js';

const $ = (id) => document.getElementById(id);

const neighbours = (t) =>
  [-1, 0, 1].flatMap((dx) => [-1, 0, 1].map((dy) => `${t.level}/${t.ix + dx}/${t.iy + dy}`));

/** Section points on the rail plane at each rail's offset: [left, right]. */
const railPoints = (points) =>
  [1, -1].map((side) => points.filter(([u, h]) => Math.abs(h) < 0.08 && Math.abs(u - side * RAIL_HALF_GAUGE_M) < 0.1).length);

export class Tools {
  constructor(app) {
    this.app = app;
    this.picks = [];
    this.lastPick = null;
    this.measureGroup = new THREE.Group();
    app.view.scene.add(this.measureGroup);
    this.coloured = new WeakMap();
    this.bind();
  }

  bind() {
    $('section-form').onsubmit = (e) => {
      e.preventDefault();
      this.cut(parseKm($('section-km').value));
    };
    $('section-close').onclick = () => ($('section-panel').hidden = true);
    $('measure-clear').onclick = () => this.clearMeasure();
    $('point-size').oninput = () => {
      this.app.uniforms.pointSize.value = Number($('point-size').value);
      this.app.view.requestRender();
    };
    $('attenuate').onchange = () => {
      this.app.uniforms.attenuate.value = $('attenuate').checked ? 1 : 0;
      this.app.view.requestRender();
    };
    $('clip-enable').onchange = () => this.updateClip();
    $('clip-half').onchange = () => this.updateClip();
    $('split').oninput = () => this.updateClip();
    $('profile-form').onsubmit = (e) => {
      e.preventDefault();
      this.profile();
    };
    this.app.view.renderer.domElement.addEventListener('pointerdown', (e) => {
      if (e.shiftKey) this.pick(e);
    });
  }

  onRunOpened() {
    document.querySelector('.split-control').hidden = this.app.layers.length < 2;
    this.updateClip();
    this.clearMeasure();
  }

  onFrame() {
    if ($('clip-enable').checked) this.updateClip(false);
  }

  /** The section at a kilometre, drawn over the structure gauge. */
  async cut(km) {
    const app = this.app;
    if (Number.isNaN(km)) return app.fail(`"${$('section-km').value}" is not a kilometre`);
    if (!app.jumpToKm(km)) return;
    const at = app.track.at(km * 1000);
    const curvature = await this.curvatureAt(km);
    const section = await cutSection(app.layers, app.view, at, Number($('section-thickness').value) || 0.3);
    const gauge = widenedGauge(app.info.clearance, curvature);
    $('section-panel').hidden = false;
    const colors = app.layers.length === 2 ? RUN_COLORS.map((c) => c.getStyle()) : [RUN_COLORS[1].getStyle(), RUN_COLORS[1].getStyle()];
    const nearest = drawSection($('section-canvas'), section, gauge, { chainage: km * 1000, colors });
    this.section = { ...nearest, points: section.points.length, km, rails: railPoints(section.points) };
    return this.section;
  }

  async curvatureAt(km) {
    try {
      const seg = await api.segment(this.app.run.line, km - 0.01, km + 0.01);
      const c = seg.features[0].properties.profile.curvature_per_m;
      return c.length ? c[Math.floor(c.length / 2)] : 0;
    } catch {
      return 0;
    }
  }

  /** Shift+click: the nearest point under the cursor. */
  pick(event) {
    const app = this.app;
    const rect = app.view.renderer.domElement.getBoundingClientRect();
    const mouse = new THREE.Vector2(
      ((event.clientX - rect.left) / rect.width) * 2 - 1,
      -((event.clientY - rect.top) / rect.height) * 2 + 1,
    );
    const ray = new THREE.Raycaster();
    ray.params.Points.threshold = 0.15;
    ray.setFromCamera(mouse, app.view.camera);
    const hits = ray.intersectObjects(app.layers.map((l) => l.group), true);
    if (!hits.length) return;
    const utm = app.view.toUtm(hits[0].point);
    return this.addPick(utm);
  }

  async addPick(utm) {
    this.lastPick = utm;
    if (this.picks.length === 2) this.clearMeasure();
    this.picks.push(utm);
    await this.drawMeasure();
  }

  /** Height above the rail and offset from the track centre of a picked point. */
  async describe(utm) {
    const app = this.app;
    const located = app.track?.locate(utm);
    if (!located) return { text: 'off the track' };
    const at = app.track.at(located.chainage);
    const section = await cutSection(app.layers, app.view, at, 1.0, 3);
    const above = utm[2] - section.railZ;
    return {
      chainage: located.chainage,
      offset: located.offset,
      above,
      text: `${formatKm(located.chainage / 1000)}, offset ${fmt(located.offset)} m, ${fmt(above)} m above rail`,
    };
  }

  async drawMeasure() {
    const app = this.app;
    for (const c of [...this.measureGroup.children]) c.removeFromParent();
    const pts = this.picks.map((p) => app.view.toScene(p));
    for (const p of pts) {
      const dot = new THREE.Mesh(new THREE.SphereGeometry(0.12), new THREE.MeshBasicMaterial({ color: 0xffffff }));
      dot.position.copy(p);
      this.measureGroup.add(dot);
    }
    const described = await Promise.all(this.picks.map((p) => this.describe(p)));
    const lines = described.map((d, i) => `point ${i + 1}: ${d.text}`);
    this.described = described;
    if (pts.length === 2) {
      this.measureGroup.add(new THREE.Line(
        new THREE.BufferGeometry().setFromPoints(pts),
        new THREE.LineBasicMaterial({ color: 0xffffff }),
      ));
      const [a, b] = this.picks;
      const d = Math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
      const h = Math.hypot(b[0] - a[0], b[1] - a[1]);
      lines.push(`distance ${fmt(d)} m (horizontal ${fmt(h)} m, height ${fmt(b[2] - a[2])} m)`);
      this.measurement = { distance: d, horizontal: h, dz: b[2] - a[2] };
    }
    $('measure-out').innerHTML = lines.map((l) => `<div>${l}</div>`).join('');
    app.view.requestRender();
  }

  clearMeasure() {
    this.picks = [];
    this.measurement = null;
    for (const c of [...this.measureGroup.children]) c.removeFromParent();
    $('measure-out').textContent = '';
    this.app.view.requestRender();
  }

  /** Clip box around the view's centre and the divide between two runs, as clipping planes. */
  updateClip(render = true) {
    const app = this.app;
    const planes = [];
    if ($('clip-enable').checked) {
      const c = app.view.controls.target;
      const half = Number($('clip-half').value) || 15;
      planes.push(
        new THREE.Plane(new THREE.Vector3(1, 0, 0), -(c.x - half)),
        new THREE.Plane(new THREE.Vector3(-1, 0, 0), c.x + half),
        new THREE.Plane(new THREE.Vector3(0, 1, 0), -(c.y - half)),
        new THREE.Plane(new THREE.Vector3(0, -1, 0), c.y + half),
      );
    }
    app.layers.forEach((layer) => {
      const own = [...planes];
      const divide = this.dividePlane(layer);
      if (divide) own.push(divide);
      layer.material.clippingPlanes = own;
    });
    if (render) app.view.requestRender();
  }

  /** With two runs: the reference before the divide, the later run after it. */
  dividePlane(layer) {
    const app = this.app;
    if (app.layers.length < 2 || !app.track?.hasChainage) return null;
    const [lo, hi] = app.track.range();
    const s = lo + (Number($('split').value) / 1000) * (hi - lo);
    const at = app.track.at(s);
    const p = app.view.toScene(at.p);
    const n = new THREE.Vector3(at.dir[0], at.dir[1], 0);
    if (layer === app.layers[0]) n.negate();
    return new THREE.Plane().setFromNormalAndCoplanarPoint(n, p);
  }

  /**
   * Colour by change: each drawn point's distance to the other run's points of the same level
   * in its tile and the eight around it (the runs' registration moves points across tile
   * borders), less half the level's voxel (coarse tiles differ by their resolution).
   */
  updateChangeColours() {
    const layers = this.app.layers;
    if (layers.length < 2) return;
    layers.forEach((layer, i) => {
      const other = layers[1 - i];
      for (const key of layer.visible) {
        const tile = layer.loaded.get(key);
        const around = neighbours(tile.info).map((k) => other.loaded.get(k)).filter(Boolean);
        const stamp = around.map((t) => t.points.id).join(',');
        if (!around.length || this.coloured.get(tile.points) === stamp) continue;
        const voxel = this.app.info.tiles.voxel_m * 2 ** tile.info.level;
        changeDistances(tile.points, around.map((t) => t.points), voxel / 2);
        this.coloured.set(tile.points, stamp);
      }
    });
  }

  async profile() {
    const from = parseKm($('profile-from').value), to = parseKm($('profile-to').value);
    if (Number.isNaN(from) || Number.isNaN(to) || to <= from) {
      return this.app.fail('the profile needs a km range (from below to)');
    }
    try {
      const seg = await api.segment(this.app.run.line, from, to);
      drawProfile($('profile-canvas'), seg.features[0].properties.profile);
    } catch (e) {
      this.app.fail(e);
    }
  }
}
