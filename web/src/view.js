// The 3D view: renderer, camera and orbit controls in a scene frame whose origin is a UTM point
// (x east, y north, z up; UTM never goes into a float), rendered on demand (software WebGL is
// slow), with eye-dome lighting as the depth cue.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const edlVertex = /* glsl */ `
  varying vec2 vUv;
  void main() { vUv = uv; gl_Position = vec4(position.xy, 0.0, 1.0); }
`;

// Eye-dome lighting (Boucher's EDL, as Potree shades its clouds): a pixel nearer than its
// neighbours in log depth stays lit, one behind an edge darkens.
const edlFragment = /* glsl */ `
  uniform sampler2D tColor;
  uniform sampler2D tDepth;
  uniform vec2 texel;
  uniform float strength;
  uniform float radius;
  uniform float near;
  uniform float far;
  uniform vec3 background;
  varying vec2 vUv;
  float logDepth(vec2 uv) {
    float d = texture2D(tDepth, uv).x;
    if (d >= 1.0) return 0.0;
    float z = near * far / (far - d * (far - near));
    return log2(z);
  }
  void main() {
    vec4 color = texture2D(tColor, vUv);
    float d = texture2D(tDepth, vUv).x;
    if (d >= 1.0) { gl_FragColor = vec4(background, 1.0); return; }
    float own = logDepth(vUv);
    float sum = 0.0;
    for (int i = 0; i < 8; i++) {
      float a = float(i) * 0.78539816;
      vec2 uv = vUv + radius * texel * vec2(cos(a), sin(a));
      float n = logDepth(uv);
      if (n != 0.0) sum += max(0.0, own - n);
    }
    float shade = exp(-sum / 8.0 * 300.0 * strength);
    gl_FragColor = vec4(color.rgb * shade, 1.0);
  }
`;

export class View {
  constructor(container) {
    this.container = container;
    const early = window.__raillomerCanvas; // started by index.html
    this.renderer = new THREE.WebGLRenderer(
      early ? { canvas: early.canvas, context: early.gl, antialias: false } : { antialias: false },
    );
    this.renderer.setPixelRatio(1);
    this.renderer.localClippingEnabled = true;
    this.renderer.setClearColor(0x10141a);
    container.appendChild(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(55, 1, 0.2, 20000);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(-60, -60, 50);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.screenSpacePanning = false;
    this.controls.maxPolarAngle = Math.PI * 0.495;
    this.controls.addEventListener('change', () => this.requestRender());
    this.origin = null; // [E, N, h] of the scene frame
    this.edlEnabled = true;
    // Until the first points are on screen, frames are drawn plain: the extras' shaders
    // (eye-dome lighting, lines, labels) compile after them, not before.
    this.plain = true;
    this.edlStrength = 0.4;
    this.listeners = [];
    this.renderedListeners = [];
    this.pending = false;
    this.frames = 0;
    this.makeEdl();
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
  }

  makeEdl() {
    this.target = new THREE.WebGLRenderTarget(1, 1, {
      depthTexture: new THREE.DepthTexture(1, 1),
    });
    this.edlMaterial = new THREE.ShaderMaterial({
      vertexShader: edlVertex,
      fragmentShader: edlFragment,
      uniforms: {
        tColor: { value: this.target.texture },
        tDepth: { value: this.target.depthTexture },
        texel: { value: new THREE.Vector2() },
        strength: { value: this.edlStrength },
        radius: { value: 1.4 },
        near: { value: this.camera.near },
        far: { value: this.camera.far },
        background: { value: new THREE.Vector3(16 / 255, 20 / 255, 26 / 255) },
      },
      depthTest: false,
      depthWrite: false,
    });
    this.edlScene = new THREE.Scene();
    this.edlScene.add(new THREE.Mesh(new THREE.PlaneGeometry(2, 2), this.edlMaterial));
    this.edlCamera = new THREE.OrthographicCamera(-1, 1, 1, -1, 0, 1);
  }

  resize() {
    const w = Math.max(1, this.container.clientWidth);
    const h = Math.max(1, this.container.clientHeight);
    if (w === this.width && h === this.height) return;
    this.width = w;
    this.height = h;
    // Resizing the drawing buffer costs; a canvas made at this size keeps its own.
    const size = this.renderer.getSize(new THREE.Vector2());
    if (size.x !== w || size.y !== h) this.renderer.setSize(w, h);
    this.target.setSize(w, h);
    this.edlMaterial.uniforms.texel.value.set(1 / w, 1 / h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.requestRender();
  }

  /** Places the scene frame at a UTM point (once: everything is placed relative to it). */
  setOrigin(utm) {
    if (!this.origin) this.origin = [utm[0], utm[1], utm[2]];
    return this.origin;
  }

  toScene(utm) {
    const o = this.origin;
    return new THREE.Vector3(utm[0] - o[0], utm[1] - o[1], utm[2] - o[2]);
  }

  toUtm(v) {
    const o = this.origin;
    return [v.x + o[0], v.y + o[1], v.z + o[2]];
  }

  /** Called before each frame (tile selection watches the camera). */
  onFrame(fn) {
    this.listeners.push(fn);
  }

  /** Called after each frame is drawn. */
  onRendered(fn) {
    this.renderedListeners.push(fn);
  }

  requestRender() {
    if (this.pending) return;
    this.pending = true;
    requestAnimationFrame(() => {
      this.pending = false;
      this.draw();
    });
  }

  draw() {
    for (const fn of this.listeners) fn();
    // Nothing is placed before the scene has its origin: an empty frame would only cost time
    // (compiling shaders in software takes a good part of a second).
    if (!this.origin) return;
    if (this.edlEnabled && !this.plain) {
      this.edlMaterial.uniforms.strength.value = this.edlStrength;
      this.renderer.setRenderTarget(this.target);
      this.renderer.render(this.scene, this.camera);
      this.renderer.setRenderTarget(null);
      this.renderer.render(this.edlScene, this.edlCamera);
    } else {
      this.renderer.render(this.scene, this.camera);
    }
    this.frames += 1;
    for (const fn of this.renderedListeners) fn();
  }

  /** Looks at a scene point from `distance` metres, along `heading` (radians, east = 0). */
  lookAt(target, distance = 60, heading = null, pitch = 0.6) {
    const h = heading ?? Math.atan2(
      this.camera.position.y - this.controls.target.y,
      this.camera.position.x - this.controls.target.x,
    );
    const horizontal = distance * Math.cos(pitch);
    this.controls.target.copy(target);
    this.camera.position.set(
      target.x + horizontal * Math.cos(h),
      target.y + horizontal * Math.sin(h),
      target.z + distance * Math.sin(pitch),
    );
    this.controls.update();
    this.requestRender();
  }

  /** Pixels per metre at a distance (for level-of-detail choices). */
  pixelsPerMetre(distance) {
    const h = this.renderer.domElement.height;
    return h / (2 * Math.tan((this.camera.fov * Math.PI) / 360) * Math.max(distance, 0.1));
  }
}
