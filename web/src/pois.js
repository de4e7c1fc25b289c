// Points of interest of the line: list, markers in the view, add, edit and delete (token).
import * as THREE from 'three';
import { api, send } from './api.js';
import { textSprite } from './track.js';
import { escapeHtml } from './util.js';

const $ = (id) => document.getElementById(id);

export class PoiPanel {
  constructor(app) {
    this.app = app;
    this.items = [];
    this.group = new THREE.Group();
    this.group.name = 'pois';
    app.view.scene.add(this.group);
    $('poi-form').onsubmit = (e) => {
      e.preventDefault();
      this.save();
    };
    $('poi-cancel').onclick = () => this.edit(null);
  }

  async load(line) {
    this.line = line;
    try {
      this.items = (await api.pois(line)).pois;
    } catch (e) {
      this.app.fail(e);
    }
    this.render();
  }

  render() {
    const list = $('poi-list');
    list.innerHTML = '';
    for (const p of this.items) {
      const li = document.createElement('li');
      li.dataset.poiId = p.id;
      const located = this.app.track?.locate(p.position);
      li.innerHTML =
        `<b>${escapeHtml(p.kind)}</b> ${escapeHtml(p.name || '')}` +
        (located ? ` · km ${(located.chainage / 1000).toFixed(3)}` : '') +
        ` <button class="poi-edit">edit</button> <button class="poi-delete">delete</button>`;
      li.onclick = (e) => {
        if (e.target.classList.contains('poi-edit')) return this.edit(p);
        if (e.target.classList.contains('poi-delete')) return this.remove(p);
        if (this.app.view.origin) this.app.view.lookAt(this.app.view.toScene(p.position), 30);
      };
      list.appendChild(li);
    }
    this.drawMarkers();
  }

  drawMarkers() {
    for (const child of [...this.group.children]) child.removeFromParent();
    if (!this.app.view.origin) return;
    for (const p of this.items) {
      const at = this.app.view.toScene(p.position);
      const pin = new THREE.Mesh(
        new THREE.ConeGeometry(0.4, 1.2, 8),
        new THREE.MeshBasicMaterial({ color: 0x00d1ff }),
      );
      pin.rotation.x = -Math.PI / 2;
      pin.position.copy(at).add(new THREE.Vector3(0, 0, 0.6));
      this.group.add(pin);
      const label = textSprite(`${p.kind} ${p.name || ''}`.trim(), 0.6, '#00d1ff');
      label.position.copy(at).add(new THREE.Vector3(0.5, 0, 1.8));
      this.group.add(label);
    }
    this.app.view.requestRender();
  }

  edit(p) {
    $('poi-id').value = p ? p.id : '';
    $('poi-kind').value = p ? p.kind : '';
    $('poi-name').value = p ? p.name : '';
    $('poi-save').textContent = p ? 'Save' : 'Add';
  }

  /** Where a new POI goes: the last picked point, else the view's centre. */
  position() {
    const picked = this.app.tools.lastPick;
    if (picked) return picked;
    return this.app.view.toUtm(this.app.view.controls.target);
  }

  async save() {
    const token = this.app.token;
    if (!token) return this.app.fail('adding or editing a POI needs the token');
    const id = $('poi-id').value;
    const old = this.items.find((p) => String(p.id) === id);
    const body = {
      line: this.line,
      kind: $('poi-kind').value.trim(),
      name: $('poi-name').value.trim(),
      utm_zone: old?.utm_zone ?? this.app.run.utm_zone,
      position: old ? old.position : this.position(),
      properties: old?.properties ?? {},
    };
    try {
      const saved = id
        ? await send('PUT', `/api/v1/pois/${id}`, body, token)
        : await send('POST', '/api/v1/pois', body, token);
      this.items = this.items.filter((p) => p.id !== saved.id).concat([saved]);
      this.edit(null);
      this.render();
    } catch (e) {
      this.app.fail(e);
    }
  }

  async remove(p) {
    const token = this.app.token;
    if (!token) return this.app.fail('deleting a POI needs the token');
    try {
      await send('DELETE', `/api/v1/pois/${p.id}`, undefined, token);
      this.items = this.items.filter((x) => x.id !== p.id);
      this.render();
    } catch (e) {
      this.app.fail(e);
    }
  }
}
