// Point rendering: one shader for every tile, coloured by intensity, height, run or change
// (distance to the reference run), with fixed-pixel or attenuated point sizes.
import * as THREE from 'three';

export const COLOR_MODES = ['intensity', 'height', 'run', 'change'];

const vertexShader = /* glsl */ `
  attribute float intensity;
  attribute float change;
  uniform float pointSize;
  uniform float attenuate;
  uniform float scale;
  uniform int mode;
  uniform vec3 runColor;
  uniform vec2 heightRange;
  uniform float originZ;
  uniform float changeMax;
  varying vec3 vColor;
  #include <clipping_planes_pars_vertex>

  vec3 ramp(float t) {
    t = clamp(t, 0.0, 1.0);
    vec3 a = vec3(0.18, 0.20, 0.60), b = vec3(0.10, 0.65, 0.75), c = vec3(0.35, 0.80, 0.30),
         d = vec3(0.95, 0.85, 0.25), e = vec3(0.85, 0.25, 0.15);
    if (t < 0.25) return mix(a, b, t / 0.25);
    if (t < 0.5) return mix(b, c, (t - 0.25) / 0.25);
    if (t < 0.75) return mix(c, d, (t - 0.5) / 0.25);
    return mix(d, e, (t - 0.75) / 0.25);
  }

  void main() {
    vec4 mvPosition = modelViewMatrix * vec4(position, 1.0);
    #include <clipping_planes_vertex>
    gl_Position = projectionMatrix * mvPosition;
    float size = pointSize;
    if (attenuate > 0.5) size = clamp(pointSize * scale / -mvPosition.z, 1.0, 12.0);
    gl_PointSize = size;
    float z = (modelMatrix * vec4(position, 1.0)).z + originZ;
    if (mode == 0) {
      float g = 0.18 + 0.82 * pow(intensity, 0.5);
      vColor = vec3(g);
    } else if (mode == 1) {
      vColor = ramp((z - heightRange.x) / max(0.01, heightRange.y - heightRange.x));
    } else if (mode == 2) {
      vColor = runColor * (0.55 + 0.45 * intensity);
    } else {
      // change: grey where the runs agree, yellow to red as the distance grows, blue unknown
      if (change < 0.0) vColor = vec3(0.35, 0.45, 0.75);
      else vColor = change < 0.1 ? vec3(0.7) : ramp(0.5 + 0.5 * change / changeMax);
    }
  }
`;

const fragmentShader = /* glsl */ `
  varying vec3 vColor;
  #include <clipping_planes_pars_fragment>
  void main() {
    #include <clipping_planes_fragment>
    vec2 c = gl_PointCoord - 0.5;
    if (dot(c, c) > 0.25) discard;
    gl_FragColor = vec4(vColor, 1.0);
  }
`;

export const RUN_COLORS = [new THREE.Color(0x4fa3ff), new THREE.Color(0xff8a3d)];

/** A material for one run's tiles; settings are shared through `uniforms`. */
export function pointMaterial(shared, runIndex) {
  const material = new THREE.ShaderMaterial({
    vertexShader,
    fragmentShader,
    uniforms: {
      ...shared,
      runColor: { value: RUN_COLORS[runIndex % RUN_COLORS.length] },
    },
    clipping: true,
  });
  return material;
}

export function sharedUniforms() {
  return {
    pointSize: { value: 2.0 },
    attenuate: { value: 0.0 },
    scale: { value: 400.0 },
    mode: { value: 0 },
    heightRange: { value: new THREE.Vector2(0, 20) },
    originZ: { value: 0 },
    changeMax: { value: 1.0 },
  };
}

/** A THREE.Points for a decoded tile; its owner places it (matrix, not position). */
export function tilePoints(decoded, material) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(decoded.positions, 3));
  geometry.setAttribute('intensity', new THREE.BufferAttribute(decoded.intensities, 1, true));
  const change = new Float32Array(decoded.points).fill(-1);
  geometry.setAttribute('change', new THREE.BufferAttribute(change, 1));
  geometry.computeBoundingSphere();
  const points = new THREE.Points(geometry, material);
  points.frustumCulled = true;
  points.matrixAutoUpdate = false;
  return points;
}
