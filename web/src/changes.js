// A run's changes: the list (filtered by kind, status, intrusion and km), boxes in the 3D view,
// the selected change's properties, snapshot and status, and new ones as the live hub finds them.
import * as THREE from 'three';
import { api, send } from './api.js';
import { formatKm, parseKm } from './track.js';
import { escapeHtml, fmt } from './util.js';

const $ = (id) => document.getElementById(id);
const KIND_COLORS = { added: 0xff7b72, removed: 0x58a6ff, moved: 0xd2a8ff, vegetation: 0x3fb950 };

/** The change against the structure gauge, in words (a removed object no longer intrudes). */
function gaugeText(c) {
  if (c.intrudes_envelope) return `yes, ${fmt(-c.margin_m)} m inside`;
  if (c.kind === 'removed' && c.margin_m < 0) return `gone: it stood ${fmt(-c.margin_m)} m inside`;
  return `no, ${fmt(c.margin_m)} m clear`;
}

/** Where across the track a change lies: "left 2.3 m", or its extent when it lies across. */
function placeText(c, digits) {
  const side = (o) => `${fmt(Math.abs(o), digits)} m ${o >= 0 ? 'left' : 'right'}`;
  if (c.side === 'across' && c.offset_range_m) {
    return `across, ${side(c.offset_range_m[0])} to ${side(c.offset_range_m[1])}`;
  }
  return `${c.side} ${fmt(Math.abs(c.offset_m), digits)} m`;
}

export class ChangesPanel {
  constructor(app) {
    this.app = app;
    this.items = [];
    this.detection = null;
    this.selected = null;
    this.group = new THREE.Group();
    this.group.name = 'changes';
    app.view.scene.add(this.group);
    for (const id of ['change-kind', 'change-state', 'change-intrusions', 'change-from', 'change-to']) {
      $(id).addEventListener('change', () => this.render());
    }
    $('change-save').onclick = () => this.save();
    $('change-save-next').onclick = async () => {
      if (await this.save()) this.step(1);
    };
    $('change-prev').onclick = () => this.step(-1);
    $('change-next').onclick = () => this.step(1);
    document.addEventListener('keydown', (e) => this.onKey(e));
  }

  /** n and p step through the list, unless the key is typed into a field. */
  onKey(e) {
    if (e.ctrlKey || e.metaKey || e.altKey || e.target.closest?.('input, textarea, select')) return;
    if (e.key === 'n') this.step(1);
    else if (e.key === 'p') this.step(-1);
  }

  /** Opens the change `delta` places on from the selected one in the filtered list (the first or
   * last when none is selected), stopping at its ends. */
  step(delta) {
    const list = this.filtered();
    if (list.length === 0) return;
    const i = list.findIndex((c) => c.id === this.selected?.id);
    const next = i < 0 ? (delta > 0 ? 0 : list.length - 1) : Math.min(Math.max(i + delta, 0), list.length - 1);
    if (next !== i) this.select(list[next].id, true);
  }

  async load(run) {
    this.run = run;
    this.items = [];
    this.selected = null;
    $('change-detail').hidden = true;
    try {
      const answer = await api.changes(run.id);
      this.items = answer.features.map((f) => f.properties);
      this.detection = answer.detection;
    } catch (e) {
      this.app.fail(e);
    }
    this.render();
    if (this.pendingSelect) this.select(this.pendingSelect, true);
  }

  onLive(message) {
    for (const f of [...message.changes, ...message.closed]) this.upsert(f.properties);
    // Found on the estimator's provisional output and not again on its final output, or by an
    // earlier comparison of the run and not again by this one.
    const withdrawn = new Set(message.withdrawn ?? []);
    this.items = this.items.filter((c) => !withdrawn.has(c.id));
    if (this.selected && withdrawn.has(this.selected.id)) {
      this.selected = null;
      $('change-detail').hidden = true;
    }
    this.detection = message.detection;
    this.render();
  }

  upsert(change) {
    const i = this.items.findIndex((c) => c.id === change.id);
    if (i >= 0) this.items[i] = change;
    else this.items.push(change);
  }

  /** The panel's filters (absent ones null). */
  filters() {
    const from = parseKm($('change-from').value), to = parseKm($('change-to').value);
    return {
      kind: $('change-kind').value || null,
      statuses: $('change-state').value ? $('change-state').value.split(',') : null,
      intrusions: $('change-intrusions').checked,
      from: Number.isNaN(from) ? null : from,
      to: Number.isNaN(to) ? null : to,
    };
  }

  /** The report of the run with the list's filters. */
  reportUrl() {
    const f = this.filters();
    const query = new URLSearchParams();
    if (f.kind) query.set('kind', f.kind);
    if (f.statuses) query.set('status', f.statuses.join(','));
    if (f.intrusions) query.set('intrudes_envelope', 'true');
    if (f.from !== null) query.set('from_km', f.from);
    if (f.to !== null) query.set('to_km', f.to);
    const q = query.toString();
    return `/api/v1/runs/${this.run.id}/changes/report${q ? `?${q}` : ''}`;
  }

  filtered() {
    const f = this.filters();
    return this.items
      .filter((c) => !f.kind || c.kind === f.kind)
      .filter((c) => !f.statuses || f.statuses.includes(c.status))
      .filter((c) => !f.intrusions || c.intrudes_envelope)
      .filter((c) => f.from === null || c.chainage_m >= f.from * 1000)
      .filter((c) => f.to === null || c.chainage_m <= f.to * 1000)
      .sort((a, b) => b.intrudes_envelope - a.intrudes_envelope || a.chainage_m - b.chainage_m);
  }

  render() {
    const d = this.detection;
    $('detection').textContent = d
      ? `detection ${d.status}` +
        (d.reference_run ? ` against run ${d.reference_run}` : '') +
        (d.km_compared ? `, ${fmt(d.km_compared)} km compared` : '') +
        (d.reason ? ` (${d.reason})` : '') +
        ` · ${this.items.length} changes`
      : '';
    if (this.run) $('report-link').href = this.reportUrl();
    const shown = this.filtered();
    this.showPosition(shown);
    const list = $('changes-list');
    list.innerHTML = '';
    for (const c of shown) {
      const li = document.createElement('li');
      li.dataset.changeId = c.id;
      li.classList.toggle('intrudes', !!c.intrudes_envelope);
      li.classList.toggle('selected', this.selected?.id === c.id);
      li.innerHTML =
        `<span class="kind ${escapeHtml(c.kind)}">${escapeHtml(c.kind)}</span>` +
        `${formatKm(c.chainage_m / 1000)} ${escapeHtml(placeText(c, 1))}` +
        ` · ${fmt(Math.max(...c.size_m), 1)} m` +
        (c.intrudes_envelope ? ' · <b>in gauge</b>' : '') +
        ` · <i>${escapeHtml(c.status)}</i>` +
        (c.earlier_change
          ? ` · <i title="found before as change ${c.earlier_change}">since run ${c.first_seen_run}</i>`
          : '') +
        (c.provisional ? ' · <i title="found on provisional output; checked again on the final map">provisional</i>' : '');
      li.onclick = () => this.select(c.id, true);
      list.appendChild(li);
    }
    this.drawBoxes();
  }

  /** Where the selected change stands in the filtered list; ◀ and ▶ stop at its ends. */
  showPosition(shown) {
    const i = shown.findIndex((c) => c.id === this.selected?.id);
    $('change-position').textContent = i >= 0 ? `${i + 1} of ${shown.length}` : `not among the ${shown.length} listed`;
    $('change-prev').disabled = i === 0 || shown.length === 0;
    $('change-next').disabled = i === shown.length - 1 || shown.length === 0;
  }

  drawBoxes() {
    for (const child of [...this.group.children]) {
      child.geometry.dispose();
      child.removeFromParent();
    }
    if (!this.app.view.origin) return;
    for (const c of this.items) {
      const centre = this.app.view.toScene(c.utm);
      const at = this.app.track?.hasChainage ? this.app.track.at(c.chainage_m) : null;
      const [along, across, height] = c.size_m.map((v) => Math.max(v, 0.2));
      const box = new THREE.LineSegments(
        new THREE.EdgesGeometry(new THREE.BoxGeometry(along, across, height)),
        new THREE.LineBasicMaterial({
          color: this.selected?.id === c.id ? 0xffffff : KIND_COLORS[c.kind] ?? 0xffffff,
        }),
      );
      box.position.copy(centre);
      if (at) box.rotation.z = Math.atan2(at.dir[1], at.dir[0]);
      box.userData.change = c.id;
      this.group.add(box);
    }
    this.app.view.requestRender();
  }

  /** Shows a change's properties and snapshot; flies to it. */
  select(id, fly) {
    const c = this.items.find((x) => x.id === id);
    if (!c) {
      this.pendingSelect = id; // the URL named it before the list arrived
      return;
    }
    this.pendingSelect = null;
    this.selected = c;
    $('change-detail').hidden = false;
    $('change-title').textContent = `Change ${c.id}: ${c.kind} at ${formatKm(c.chainage_m / 1000)}`;
    const rows = [
      ['side, offset', placeText(c, 2)],
      ['size (along, across, height)', c.size_m.map((v) => fmt(v)).join(' × ') + ' m'],
      ['height above rail', `${fmt(c.height_above_rail_m[0])} to ${fmt(c.height_above_rail_m[1])} m`],
      ['in the gauge', gaugeText(c)],
      ['vegetation rule', c.breaks_vegetation_rule ? 'broken' : 'kept'],
      ['UTM', `${c.utm.map((v) => v.toFixed(2)).join(', ')} (${c.utm_zone})`],
      ['reference run', c.reference_run],
      ['first seen', c.earlier_change ? `run ${c.first_seen_run} (continues change ${c.earlier_change})` : 'this run'],
      ['points (reference, run)', `${c.points.reference}, ${c.points.run}`],
      ['level of detection', `${fmt(c.lod_m)} m`],
      ['confidence', fmt(c.confidence)],
    ];
    $('change-props').innerHTML = rows
      .map(([k, v]) => `<tr><td>${escapeHtml(k)}</td><td>${escapeHtml(v)}</td></tr>`)
      .join('');
    $('change-snapshot').src = `${c.snapshot}?v=${c.updated_ns}`;
    $('change-status').value = c.status;
    $('change-note').value = c.note ?? '';
    this.app.showTab('changes');
    this.render();
    if (fly && this.app.view.origin) this.app.view.lookAt(this.app.view.toScene(c.utm), 25, null, 0.5);
  }

  /** Sets the selected change's status and note on the server; whether it did. */
  async save() {
    const c = this.selected;
    if (!c) return false;
    const token = this.app.token;
    if (!token) {
      this.app.fail('setting a status needs the token (the field under the panels)');
      return false;
    }
    try {
      const answer = await send('PATCH', `/api/v1/changes/${c.id}`, {
        status: $('change-status').value,
        note: $('change-note').value,
      }, token);
      this.upsert(answer.properties ?? answer);
      this.selected = this.items.find((x) => x.id === c.id);
      $('status').classList.remove('error');
      $('status').textContent = `change ${c.id} is ${this.selected.status}`;
      this.render();
      return true;
    } catch (e) {
      this.app.fail(e);
      return false;
    }
  }
}
