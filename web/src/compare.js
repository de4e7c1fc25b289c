// Colour by change: for each point of a tile, the distance to the nearest point of the other
// run's tile at the same place, through a voxel hash of the other points (0.5 m cells, the
// 27 around a point searched; beyond that the distance reads as the cap, 1 m).
const CELL_M = 0.5;
const CAP_M = 1.0;
const B = 65536;
const H = 32768;

const keyOf = (cx, cy, cz) => ((cx + H) * B + (cy + H)) * B + (cz + H);

function hashPoints(objects) {
  const cells = new Map();
  for (const obj of objects) {
    const pos = obj.geometry.attributes.position.array;
    const o = obj.position;
    for (let i = 0; i < pos.length; i += 3) {
      const x = pos[i] + o.x, y = pos[i + 1] + o.y, z = pos[i + 2] + o.z;
      const key = keyOf(Math.floor(x / CELL_M), Math.floor(y / CELL_M), Math.floor(z / CELL_M));
      let cell = cells.get(key);
      if (!cell) cells.set(key, (cell = []));
      cell.push(x, y, z);
    }
  }
  return cells;
}

export function changeDistances(points, others) {
  const cells = hashPoints(others);
  const pos = points.geometry.attributes.position.array;
  const o = points.position;
  const out = points.geometry.attributes.change;
  for (let i = 0, k = 0; i < pos.length; i += 3, k++) {
    const x = pos[i] + o.x, y = pos[i + 1] + o.y, z = pos[i + 2] + o.z;
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
    out.array[k] = Math.sqrt(best);
  }
  out.needsUpdate = true;
}
