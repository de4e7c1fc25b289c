// A run registered onto its reference as change detection registered it, stretch by stretch
// (GET /api/v1/runs/{run}/changes/registration): its points, path and train drawn in the
// reference run's map, where the changes lie. Where no stretch is compared yet, the nearest
// compared one stands in (the receivers' offsets vary slowly along a line).
import * as THREE from 'three';

export class Registration {
  constructor(answer) {
    this.reference = answer.reference_run;
    this.stretches = answer.stretches.map((s) => ({
      ...s,
      mid: (s.from_m + s.to_m) / 2,
      R: [s.T_reference_run.slice(0, 3), s.T_reference_run.slice(4, 7), s.T_reference_run.slice(8, 11)],
      t: [s.T_reference_run[3], s.T_reference_run[7], s.T_reference_run[11]],
    }));
  }

  get empty() {
    return this.stretches.length === 0;
  }

  /** The stretch at a chainage: the one holding it nearest its middle, else the nearest. */
  at(chainage) {
    let best = null;
    for (const s of this.stretches) {
      const d = Math.abs(s.mid - chainage);
      if (!best || d < best.d) best = { s, d };
    }
    return best?.s ?? null;
  }

  /** A UTM point of the run in the reference's map (through stretch `s`; none: as it is). */
  apply(s, p) {
    return applyStretch(s, p);
  }
}

function applyStretch(s, p) {
  if (!s) return p;
  const a = [p[0] - s.origin[0], p[1] - s.origin[1], p[2] - s.origin[2]];
  return [0, 1, 2].map((i) => s.R[i][0] * a[0] + s.R[i][1] * a[1] + s.R[i][2] * a[2] + s.t[i] + s.origin[i]);
}

/**
 * The matrix placing a tile's points (offsets from `tileOrigin`, UTM) in the scene (origin `O`),
 * through a stretch's registration (none: at the tile's origin as recorded).
 */
export function tileMatrix(s, tileOrigin, O) {
  const d = applyStretch(s, tileOrigin);
  const R = s?.R ?? [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  return new THREE.Matrix4().set(
    R[0][0], R[0][1], R[0][2], d[0] - O[0],
    R[1][0], R[1][1], R[1][2], d[1] - O[1],
    R[2][0], R[2][1], R[2][2], d[2] - O[2],
    0, 0, 0, 1,
  );
}

/** The points of a THREE.Points in its parent's frame (its matrix applied). */
export function* framePoints(obj) {
  const pos = obj.geometry.attributes.position.array;
  const e = obj.matrix.elements;
  for (let i = 0; i < pos.length; i += 3) {
    const x = pos[i], y = pos[i + 1], z = pos[i + 2];
    yield [
      e[0] * x + e[4] * y + e[8] * z + e[12],
      e[1] * x + e[5] * y + e[9] * z + e[13],
      e[2] * x + e[6] * y + e[10] * z + e[14],
      i / 3,
    ];
  }
}
