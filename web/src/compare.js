// Colour by change: for each point of a tile, the distance to the nearest point of the other
// run's tile at the same place, through a voxel hash of the other points (0.5 m cells, the
// 27 around a point searched; beyond that the distance reads as the cap, 1 m).
const CELL_M = 0.5;
const CAP_M = 1.0;
import { framePoints } from './registration.js';

const B = 65536;
const H = 32768;

const keyOf = (cx, cy, cz) => ((cx + H) * B + (cy + H)) * B + (cz + H);

function hashPoints(objects) {
  const cells = new Map();
  for (const obj of objects) {
    for (const [x, y, z] of framePoints(obj)) {
      const key = keyOf(Math.floor(x / CELL_M), Math.floor(y / CELL_M), Math.floor(z / CELL_M));
      let cell = cells.get(key);
      if (!cell) cells.set(key, (cell = []));
      cell.push(x, y, z);
    }
  }
  return cells;
}

export function changeDistances(points, others, toleranceM = 0) {
  const cells = hashPoints(others);
  const out = points.geometry.attributes.change;
  for (const [x, y, z, k] of framePoints(points)) {
    const cx = Math.floor(x / CELL_M), cy = Math.floor(y / CELL_M), cz = Math.floor(z / CELL_M);
    let best = CAP_M * CAP_M;
    for (let dx = -1; dx <= 1; dx++) {
      for (let dy = -1; dy <= 1; dy++) {
        for (let dz = -1; dz <= 1; dz++) {
          const cell = cells.get(keyOf(cx + dx, cy + dy, cz + dz));
          if (!cell) continue;
          for (let j = 0; j < cell.length; j += 3) {
            const d = (cell[j] - x) ** 2 + (cell[j + 1] - y) ** 2 + (cell[j + 2] - z) ** 2;
            if (d < best) best = d;
          }
        }
      }
    }
    out.array[k] = Math.max(0, Math.sqrt(best) - toleranceM);
  }
  out.needsUpdate = true;
}
