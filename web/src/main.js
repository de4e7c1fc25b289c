// The viewer: picks a line and run (from the URL, or the most recent run, a live one first),
// streams its tiles into the 3D view, and wires the panels: changes, tools, POIs, profile.
import './style.css';
import * as THREE from 'three';
import { api, ApiError, saveToken, savedToken } from './api.js';
import { DecoderPool } from './decoder.js';
import { Live } from './live.js';
import { ChangesPanel } from './changes.js';
import { PoiPanel } from './pois.js';
import { Tools } from './tools.js';
import { COLOR_MODES, RUN_COLORS, pointMaterial, sharedUniforms, tilePoints } from './points.js';
import { TileLayer } from './tiles.js';
import { Track, formatKm, parseKm, parseTrajectory, trackObjects, trainMarker } from './track.js';
import { View } from './view.js';
import { readUrl, writeUrl } from './url.js';
import { drawLegend } from './legend.js';
import { cutSection } from './section.js';
import { Registration } from './registration.js';
import { escapeHtml } from './util.js';

const $ = (id) => document.getElementById(id);

export class App {
  constructor() {
    this.view = new View($('viewport'));
    this.decoder = new DecoderPool(2);
    this.uniforms = sharedUniforms();
    this.layers = [];
    this.runs = [];
    this.track = null;
    this.trackGroup = null;
    this.train = trainMarker();
    this.view.scene.add(this.train);
    this.budget = 2_000_000;
    this.errors = [];
    this.live = new Live((m) => this.onLive(m), (s) => this.setLiveState(s));
    this.changes = new ChangesPanel(this);
    this.pois = new PoiPanel(this);
    this.tools = new Tools(this);
    this.view.onFrame(() => this.frame());
    this.view.onRendered(() => {
      // Milliseconds from navigation to the first frame with points (performance.now() counts
      // from the navigation's start).
      if (this.firstPointsMs === undefined && this.layers.some((l) => l.visible.size)) {
        this.firstPointsMs = performance.now();
      }
      // The first frame has sent for the first tiles: compile while they come.
      if (!this.shadersWarm && this.view.origin) {
        this.shadersWarm = true;
        setTimeout(() => this.warmShaders(), 0);
      }
    });
    this.extras(false);
  }

  get token() {
    return $('token-input').value.trim();
  }

  /** Shows a problem in the status line and, when it stops the view, in the middle. */
  fail(error, blocking = false) {
    const text = error instanceof ApiError || error instanceof Error ? error.message : String(error);
    this.errors.push(text);
    $('status').textContent = text;
    $('status').classList.add('error');
    if (blocking) this.message(text);
  }

  message(text, kind = 'error') {
    const box = $('message');
    box.hidden = !text;
    box.textContent = text || '';
    box.className = kind;
  }

  async start() {
    performance.mark('raillomer:start');
    $('token-input').value = savedToken();
    this.bindControls();
    try {
      [this.info, this.runs] = await Promise.all([api.info(), api.runs()]);
    } catch (e) {
      this.fail(e, true);
      return;
    }
    this.live.connect(this.info);
    if (!this.runs.length) {
      this.message('No runs on this server yet: stream one with raillomer-estimator --server.', 'info');
      $('status').textContent = 'no runs';
      return;
    }
    const url = readUrl();
    if (COLOR_MODES.includes(url.color)) $('color-select').value = url.color;
    const run = this.pickRun(url);
    this.fillSelects(run, url.compare);
    await this.open(run.id, url.compare, url);
  }

  /** The run the URL names, else the most recent live run, else the most recent run. */
  pickRun(url) {
    const byId = (id) => this.runs.find((r) => r.id === id);
    if (url.run && byId(url.run)) return byId(url.run);
    const ofLine = url.line ? this.runs.filter((r) => r.line === url.line) : this.runs;
    const pool = ofLine.length ? ofLine : this.runs;
    const newest = (list) => list.reduce((a, b) => (b.start_ns > a.start_ns ? b : a));
    const live = pool.filter((r) => r.status === 'live');
    return newest(live.length ? live : pool);
  }

  fillSelects(run, compare) {
    const lines = [...new Set(this.runs.map((r) => r.line))];
    $('line-select').innerHTML = lines.map((l) => `<option>${escapeHtml(l)}</option>`).join('');
    $('line-select').value = run.line;
    this.fillRuns(run.line, run.id, compare);
  }

  fillRuns(line, runId, compare) {
    const runs = this.runs.filter((r) => r.line === line);
    const label = (r) =>
      `#${r.id} ${r.vehicle} ${new Date(r.start_ns / 1e6).toISOString().slice(0, 16).replace('T', ' ')}` +
      (r.status === 'live' ? ' (live)' : '');
    $('run-select').innerHTML = runs
      .map((r) => `<option value="${r.id}">${escapeHtml(label(r))}</option>`)
      .join('');
    $('run-select').value = String(runId);
    $('compare-select').innerHTML =
      '<option value="">none</option>' +
      runs
        .filter((r) => r.id !== runId)
        .map((r) => `<option value="${r.id}">${escapeHtml(label(r))}</option>`)
        .join('');
    $('compare-select').value = compare ? String(compare) : '';
  }

  /** Opens a run (and a second one to compare) and places the camera. */
  async open(runId, compareId, url = {}) {
    this.closeLayers();
    this.run = this.runs.find((r) => r.id === runId);
    this.compare = compareId ? this.runs.find((r) => r.id === compareId) : null;
    $('status').classList.remove('error');
    $('status').textContent = `loading run ${runId}…`;
    this.message('');
    const ids = this.compare ? [this.compare.id, runId] : [runId];
    try {
      [this.layers, , this.registrations] = await Promise.all([
        Promise.all(ids.map((id, i) => this.openLayer(id, ids.length === 2 ? i : 1))),
        this.loadTrack(runId),
        this.loadRegistrations(ids),
      ]);
    } catch (e) {
      this.fail(e, true);
      return;
    }
    performance.mark('raillomer:run-loaded');
    await this.applyRegistration(this.registrations);
    this.placeOrExplain(url);
    this.live.subscribe(ids);
    // A train still on the line: follow it, so the map is seen growing.
    if (this.run.status === 'live' && !url.cam && !Number.isFinite(url.km)) $('follow').checked = true;
    this.changes.load(this.run);
    this.pois.load(this.run.line);
    this.tools.onRunOpened();
    this.applyColorMode();
    this.view.requestRender();
  }

  /** Places the scene at the run's first tile (or pose); without either, says why. */
  placeOrExplain(url) {
    const origin = this.layers.map((l) => l.anyOrigin()).find(Boolean) ?? this.track?.poses[0]?.p;
    if (origin) {
      this.placeScene(origin, url);
      performance.mark('raillomer:scene-placed');
      return;
    }
    const id = this.run.id;
    this.message(
      this.run.status === 'live'
        ? `Run ${id} has no tiles yet: they appear as the train streams them.`
        : `Run ${id} has no tiles: nothing was mapped.`,
      'info',
    );
  }

  async openLayer(id, runIndex) {
    const layer = new TileLayer({
      run: id,
      runIndex,
      view: this.view,
      grid: this.info.tiles,
      decoder: this.decoder,
      material: pointMaterial(this.uniforms, runIndex),
      onChange: () => this.view.requestRender(),
    });
    await layer.loadIndex();
    this.view.scene.add(layer.group);
    return layer;
  }

  async loadTrack(runId) {
    const [tum, geo] = await Promise.all([api.trajectoryTum(runId), api.trajectoryGeo(runId)]);
    this.rawTrack = new Track(parseTrajectory(tum, geo));
    this.setTrack(this.rawTrack);
  }

  setTrack(track) {
    this.track = track;
    if (this.trackGroup) this.trackGroup.removeFromParent();
    this.trackGroup = null;
    this.drawTrack();
  }

  /**
   * Later runs are drawn where change detection registered them onto their reference (whose
   * map the changes are placed in): a run alone onto its reference; of two runs, the one whose
   * reference the other is, or both when they share their reference.
   */
  loadRegistrations(ids) {
    return Promise.all(ids.map((id) => api.registration(id).catch(() => null)));
  }

  async applyRegistration(answers = null) {
    answers ??= await this.loadRegistrations(this.layers.map((l) => l.run));
    this.registration = null;
    this.layers.forEach((layer, i) => {
      const a = answers[i];
      const other = this.layers.length === 2 ? this.layers[1 - i].run : null;
      const theirs = other === null ? null : answers[1 - i];
      const sameReference = theirs?.reference_run === a?.reference_run && theirs?.stretches.length > 0;
      const use =
        a?.reference_run && a.stretches.length && (other === null || other === a.reference_run || sameReference);
      const registration = use ? new Registration(a) : null;
      layer.setRegistration(registration, this.rawTrack);
      if (layer.run === this.run.id) this.registration = registration;
    });
    const reg = this.registration;
    if (!reg) return this.setTrack(this.rawTrack);
    const poses = this.rawTrack.poses.map((p) =>
      Number.isFinite(p.chainage) ? { ...p, p: reg.apply(reg.at(p.chainage), p.p) } : p,
    );
    this.setTrack(new Track(poses));
    this.view.requestRender();
  }

  /** A point of the opened run (UTM) where the view draws it (its registration applied). */
  registered(utm) {
    const reg = this.registration;
    if (!reg) return utm;
    const located = this.rawTrack?.locate(utm);
    return located ? reg.apply(reg.at(located.chainage), utm) : utm;
  }

  placeScene(origin, url) {
    this.view.setOrigin(origin);
    this.uniforms.originZ.value = this.view.origin[2];
    if (url.cam) {
      this.view.camera.position.copy(this.view.toScene(url.cam.slice(0, 3)));
      this.view.controls.target.copy(this.view.toScene(url.cam.slice(3, 6)));
      this.view.controls.update();
    } else if (Number.isFinite(url.km) && this.jumpToKm(url.km)) {
      // placed by the km
    } else if (this.track?.hasChainage) {
      this.jumpToKm((this.track.range()[0] + 40) / 1000);
    } else if (this.track?.poses.length) {
      const first = this.track.poses[Math.min(20, this.track.poses.length - 1)];
      this.view.lookAt(this.view.toScene(first.p), 70);
    } else {
      this.view.lookAt(this.view.toScene(origin), 70);
    }
    if (url.change) this.changes.select(url.change, true);
  }

  /**
   * Compiles the point shaders while the first tiles are on their way (in software a compile
   * takes a good part of a second; the first frame with points then only draws).
   */
  warmShaders() {
    const scene = new THREE.Scene();
    const one = { positions: new Float32Array(3), intensities: new Uint8Array(1), points: 1 };
    for (const layer of this.layers) scene.add(tilePoints(one, layer.material));
    this.view.renderer.compile(scene, this.view.camera);
    for (const p of scene.children) p.geometry.dispose();
  }

  /**
   * Once the first points are on screen: the track, its labels, the change boxes, POIs and
   * eye-dome lighting (their shaders and canvases cost the first frame a second in software).
   */
  afterFirstPoints() {
    if (!this.view.plain) return;
    this.view.plain = false;
    this.extras(true);
    this.drawTrack();
    this.fitTrackToRails().catch((e) => this.fail(e));
    this.view.requestRender();
  }

  extras(visible) {
    for (const group of [this.changes.group, this.pois.group, this.tools.measureGroup]) group.visible = visible;
  }

  /**
   * The path is the body's (the IMU's) path, above the rails: the rail plane found in a
   * section near the start sets how far the drawn track and train go down.
   */
  async fitTrackToRails() {
    if (!this.track?.hasChainage || !this.layers.length) return;
    const [lo, hi] = this.track.range();
    const at = this.track.at(Math.min(lo + 40, (lo + hi) / 2));
    const section = await cutSection(this.layers.slice(-1), this.view, at, 1.0, 3);
    const drop = at.p[2] - section.railZ;
    if (!(Math.abs(drop) < 5)) return;
    this.railDrop = drop;
    if (this.trackGroup) this.trackGroup.position.z = -drop;
    this.view.requestRender();
  }

  drawTrack() {
    if (!this.track || !this.view.origin || this.trackGroup || this.view.plain) return;
    this.trackGroup = trackObjects(this.track, this.view);
    if (this.railDrop) this.trackGroup.position.z = -this.railDrop;
    this.view.scene.add(this.trackGroup);
    const range = this.track.range();
    if (range) {
      $('profile-from').value ||= (range[0] / 1000).toFixed(3);
      $('profile-to').value ||= (range[1] / 1000).toFixed(3);
    }
  }

  closeLayers() {
    for (const l of this.layers) l.dispose();
    this.layers = [];
  }

  /** Moves the camera to a kilometre, looking along the track. */
  jumpToKm(km) {
    if (!this.track?.hasChainage) {
      this.fail('this run has no chainage yet (its line has no centreline)');
      return false;
    }
    const [lo, hi] = this.track.range();
    if (km * 1000 < lo - 1 || km * 1000 > hi + 1) {
      this.fail(`${formatKm(km)} is off this run (it covers ${formatKm(lo / 1000)} to ${formatKm(hi / 1000)})`);
      return false;
    }
    const at = this.track.at(km * 1000);
    this.km = km;
    const heading = Math.atan2(-at.dir[1], -at.dir[0]) + 0.5; // behind and to the right
    this.view.lookAt(this.view.toScene(at.p), 45, heading, 0.45);
    $('km-input').value = formatKm(km);
    return true;
  }

  /** The chainage (m) under the view's centre, or null off the track. */
  currentChainage() {
    if (!this.track?.hasChainage || !this.view.origin) return null;
    return this.track.locate(this.view.toUtm(this.view.controls.target))?.chainage ?? null;
  }

  /** Moves the view `metres` along the track, keeping the camera's place relative to it. */
  moveAlong(metres) {
    const c = this.currentChainage();
    if (c === null) return false;
    const [lo, hi] = this.track.range();
    const next = Math.min(hi, Math.max(lo, c + metres));
    const at = this.track.at(next);
    const target = this.view.toScene(at.p);
    const offset = this.view.camera.position.clone().sub(this.view.controls.target);
    this.view.controls.target.copy(target);
    this.view.camera.position.copy(target).add(offset);
    this.view.controls.update();
    this.km = next / 1000;
    $('km-input').value = formatKm(this.km);
    this.view.requestRender();
    return next > lo && next < hi;
  }

  /** Ride: the view moves along the track at 15 m/s until unticked or the run ends. */
  ride(on) {
    clearInterval(this.rideTimer);
    if (!on) return;
    this.rideTimer = setInterval(() => {
      if (!this.moveAlong(3)) {
        $('drive').checked = false;
        clearInterval(this.rideTimer);
      }
    }, 200);
  }

  /** Per frame: tiles to draw, the status line, the URL. */
  frame() {
    const share = Math.floor(this.budget / Math.max(1, this.layers.length));
    for (const layer of this.layers) layer.update(share);
    if (this.view.plain && this.layers.some((l) => l.visible.size)) setTimeout(() => this.afterFirstPoints(), 0);
    this.tools.onFrame();
    if (this.uniforms.mode.value === 3) this.tools.updateChangeColours();
    this.updateStatus();
    this.scheduleUrl();
  }

  updateStatus() {
    if ($('status').classList.contains('error')) return;
    const loading = this.layers.reduce((n, l) => n + l.inFlight.size, 0);
    const points = this.layers.reduce((n, l) => n + l.stats.points, 0);
    const failed = this.layers.find((l) => l.lastError);
    const run = this.run ? `run ${this.run.id}${this.run.status === 'live' ? ' (live)' : ''}` : '';
    $('status').textContent =
      `${run} · ${(points / 1e6).toFixed(2)} M points` +
      (loading ? ` · loading ${loading} tiles…` : '') +
      (failed ? ` · ${failed.lastError}` : '');
    if (loading) setTimeout(() => this.view.requestRender(), 250);
  }

  scheduleUrl() {
    clearTimeout(this.urlTimer);
    this.urlTimer = setTimeout(() => this.writeUrlNow(), 400);
  }

  writeUrlNow() {
    if (!this.run || !this.view.origin) return;
    const cam = [...this.view.toUtm(this.view.camera.position), ...this.view.toUtm(this.view.controls.target)];
    const located = this.track?.locate(this.view.toUtm(this.view.controls.target));
    writeUrl({
      line: this.run.line,
      run: this.run.id,
      compare: this.compare?.id,
      km: located ? located.chainage / 1000 : undefined,
      cam,
      color: COLOR_MODES[this.uniforms.mode.value],
      change: this.changes.selected?.id,
    });
  }

  applyColorMode(mode = $('color-select').value) {
    this.uniforms.mode.value = Math.max(0, COLOR_MODES.indexOf(mode));
    const z = this.track?.poses.map((p) => p.p[2]) ?? [];
    if (z.length) {
      const lo = Math.min(...z) - 3;
      this.uniforms.heightRange.value.set(lo, Math.max(...z) + 8);
    }
    drawLegend($('legend'), mode, {
      runs: this.layers.map((l) => l.run),
      colors: RUN_COLORS,
      heightRange: this.uniforms.heightRange.value,
      hasReference: this.layers.length === 2,
    });
    this.view.requestRender();
  }

  onLive(m) {
    if (m.type === 'pose' && m.run === this.run?.id) this.moveTrain(m);
    else if (m.type === 'tiles') {
      const layer = this.layers.find((l) => l.run === m.run);
      if (layer) this.refreshTiles(layer, m.tiles, m.sent_ns);
    } else if (m.type === 'change' && this.layers.some((l) => l.run === m.run)) {
      if (m.run === this.run?.id) this.changes.onLive(m);
      clearTimeout(this.registrationTimer);
      this.registrationTimer = setTimeout(() => this.applyRegistration().catch((e) => this.fail(e)), 1000);
    } else if (m.type === 'run') this.onRunMessage(m);
  }

  async refreshTiles(layer, tiles, sentNs) {
    try {
      await layer.refresh(tiles, sentNs);
      if (!this.view.origin && layer.anyOrigin()) {
        this.message('');
        this.placeScene(layer.anyOrigin(), {});
      }
      this.view.requestRender();
    } catch (e) {
      this.fail(e);
    }
  }

  moveTrain(m) {
    if (!m.georeferenced || !this.view.origin) return;
    // The path grows with the run: read it again now and then (km marks, sections, km jumps).
    if (!this.trackLoading && performance.now() - (this.trackLoadedAt ?? 0) > 15_000) {
      this.trackLoading = true;
      this.loadTrack(this.run.id)
        .then(() => this.applyRegistration())
        .catch((e) => this.fail(e))
        .finally(() => {
          this.trackLoading = false;
          this.trackLoadedAt = performance.now();
        });
    }
    const p = this.view.toScene(this.registered(m.p));
    this.train.visible = true;
    this.train.position.copy(p);
    this.train.position.z += 2 - (this.railDrop ?? 0); // the box stands on the rails
    this.train.quaternion.set(m.q[0], m.q[1], m.q[2], m.q[3]);
    this.lastPose = m;
    if ($('follow').checked) {
      const offset = this.view.camera.position.clone().sub(this.view.controls.target);
      this.view.controls.target.copy(p);
      this.view.camera.position.copy(p).add(offset);
      this.view.controls.update();
    }
    this.view.requestRender();
  }

  async onRunMessage(m) {
    try {
      this.runs = await api.runs();
    } catch (e) {
      return this.fail(e);
    }
    if (m.run === this.run?.id) {
      this.run = this.runs.find((r) => r.id === m.run);
      if (this.run?.status === 'finished') {
        await this.loadTrack(this.run.id);
        await this.applyRegistration();
      }
    }
  }

  setLiveState(state) {
    this.liveState = state;
  }

  bindControls() {
    this.bindRunPickers();
    this.bindNavigation();
    this.bindDisplay();
    $('token-input').onchange = () => saveToken(this.token);
    for (const b of document.querySelectorAll('.tabs button')) {
      b.onclick = () => this.showTab(b.dataset.tab);
    }
  }

  bindRunPickers() {
    $('line-select').onchange = () => {
      const run = this.pickRun({ line: $('line-select').value });
      this.fillRuns(run.line, run.id);
      this.reopen(run.id, null);
    };
    $('run-select').onchange = () => {
      const id = Number($('run-select').value);
      this.fillRuns(this.run.line, id);
      this.reopen(id, null);
    };
    $('compare-select').onchange = () => {
      this.reopen(this.run.id, Number($('compare-select').value) || null);
    };
  }

  bindNavigation() {
    $('km-form').onsubmit = (e) => {
      e.preventDefault();
      const km = parseKm($('km-input').value);
      if (Number.isNaN(km)) return this.fail(`"${$('km-input').value}" is not a kilometre (12.345 or K12+345)`);
      $('status').classList.remove('error');
      this.jumpToKm(km);
    };
    $('km-back').onclick = () => this.moveAlong(-100);
    $('km-ahead').onclick = () => this.moveAlong(100);
    $('drive').onchange = () => this.ride($('drive').checked);
  }

  bindDisplay() {
    $('color-select').onchange = () => {
      if ($('color-select').value === 'change' && this.layers.length < 2) this.compareWithReference();
      this.applyColorMode();
    };
    $('budget').onchange = () => {
      this.budget = Math.max(100_000, Number($('budget').value) || 2_000_000);
      this.view.requestRender();
    };
    $('edl').onchange = () => {
      this.view.edlEnabled = $('edl').checked;
      this.view.requestRender();
    };
  }

  showTab(name) {
    for (const b of document.querySelectorAll('.tabs button')) b.classList.toggle('active', b.dataset.tab === name);
    for (const s of document.querySelectorAll('.tab')) s.hidden = s.id !== `tab-${name}`;
  }

  /** Colouring by change needs the reference run beside this one. */
  compareWithReference() {
    const reference = this.changes.detection?.reference_run;
    if (!reference || reference === this.run.id) {
      this.fail('colour by change needs a second run: pick one under Compare');
      return;
    }
    $('compare-select').value = String(reference);
    this.reopen(this.run.id, reference);
  }

  reopen(runId, compareId) {
    const url = { cam: this.view.origin ? [...this.view.toUtm(this.view.camera.position), ...this.view.toUtm(this.view.controls.target)] : null };
    this.open(runId, compareId, url.cam ? url : {});
  }

  /** What tests and benchmarks read. */
  snapshot() {
    return {
      run: this.run?.id,
      compare: this.compare?.id ?? null,
      origin: this.view.origin,
      target: this.view.origin ? this.view.toUtm(this.view.controls.target) : null,
      km: this.km ?? null,
      points: this.layers.reduce((n, l) => n + l.stats.points, 0),
      tilesLoaded: this.layers.reduce((n, l) => n + l.loaded.size, 0),
      inFlight: this.layers.reduce((n, l) => n + l.inFlight.size, 0),
      firstPointsMs: this.firstPointsMs ?? null,
      frames: this.view.frames,
      live: this.liveState,
      changes: this.changes.items.length,
      train: this.train.visible ? this.view.toUtm(this.train.position) : null,
      liveLatencyMs: this.layers.flatMap((l) => l.liveLatencyMs),
      liveViewLatencyMs: this.layers.flatMap((l) => l.liveViewLatencyMs),
      errors: [...this.errors],
    };
  }
}

const app = new App();
window.raillomer = app;
app.start().catch((e) => app.fail(e, true));
