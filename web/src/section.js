// A cross-section across the track at a chainage: the points of a thin slab in the track's
// frame (offset left of the centre, height above the rail plane), the structure gauge over them
// and the nearest point's margin, drawn in 2D.
import { formatKm } from './track.js';

export const RAIL_HALF_GAUGE_M = 0.7175; // rail-head centres: 1435 mm gauge + head width

/** Signed distance of (u, h) from a polygon: negative inside. */
export function polygonMargin(poly, u, h) {
  let inside = false;
  let best = Infinity;
  for (let i = 0, j = poly.length - 1; i < poly.length; j = i++) {
    const [x1, y1] = poly[j], [x2, y2] = poly[i];
    if (y2 > h !== y1 > h && u < ((x1 - x2) * (h - y2)) / (y1 - y2) + x2) inside = !inside;
    const dx = x2 - x1, dy = y2 - y1;
    const t = Math.max(0, Math.min(1, ((u - x1) * dx + (h - y1) * dy) / (dx * dx + dy * dy || 1)));
    best = Math.min(best, Math.hypot(u - (x1 + t * dx), h - (y1 + t * dy)));
  }
  return inside ? -best : best;
}

/** The gauge outline widened on a curve (RAIL_FACTS: 40500/R mm inside, 44000/R mm outside). */
export function widenedGauge(clearance, curvature) {
  const outline = clearance.gauge_outline;
  const r = curvature ? 1 / Math.abs(curvature) : Infinity;
  if (!(r < clearance.widen_below_radius_m)) return outline.map((c) => [...c]);
  const left = curvature > 0; // turning left: the left side is the inside
  return outline.map(([u, h]) => {
    const inside = (u > 0) === left;
    const widen = (inside ? 40.5 : 44.0) / r;
    return [u + Math.sign(u) * widen, h];
  });
}

function percentile(values, q) {
  if (!values.length) return NaN;
  const s = [...values].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
}

/**
 * The section's points from the layers' loaded tiles, with the rail plane found from the rail
 * heads (the highest points at the rails' offsets).
 */
export async function cutSection(layers, view, at, thicknessM = 0.3, halfWidthM = 12) {
  const centre = view.toScene(at.p);
  const [dx, dy] = at.dir;
  const raw = [];
  const detail = await Promise.all(layers.map((layer) => layer.detailNear(centre, halfWidthM + 1)));
  layers.forEach((layer, runIndex) => {
    for (const [x, y, z] of layer.pointsNear(centre, halfWidthM + 1, detail[runIndex])) {
      const ex = x - centre.x, ey = y - centre.y;
      const along = ex * dx + ey * dy;
      if (Math.abs(along) > thicknessM / 2) continue;
      const u = -ex * dy + ey * dx;
      if (Math.abs(u) > halfWidthM) continue;
      raw.push([u, z, runIndex]);
    }
  });
  const railTop = (side) =>
    percentile(
      raw.filter(([u, z]) => Math.abs(u - side * RAIL_HALF_GAUGE_M) < 0.08 && z < centre.z + 0.5)
        .map(([, z]) => z),
      0.9,
    );
  let left = railTop(1), right = railTop(-1);
  if (!Number.isFinite(left) || !Number.isFinite(right)) {
    const ballast = percentile(raw.filter(([u]) => Math.abs(u) < 0.6).map(([, z]) => z), 0.5);
    left = right = Number.isFinite(ballast) ? ballast + 0.15 : centre.z - 2;
  }
  const rail = (left + right) / 2;
  const cant = left - right;
  const points = raw.map(([u, z, run]) => [u, z - rail - (u * cant) / (2 * RAIL_HALF_GAUGE_M), run]);
  return { points, railZ: rail + view.origin[2], cantM: cant * (1.5 / (2 * RAIL_HALF_GAUGE_M)) };
}

/** The point with the least margin against the gauge. */
export function nearestToGauge(points, gauge) {
  let best = null;
  for (const [u, h, run] of points) {
    if (h < 0.05) continue; // the rails and the ground they stand on
    const m = polygonMargin(gauge, u, h);
    if (!best || m < best.margin) best = { u, h, run, margin: m };
  }
  return best;
}

/** Draws a section into a canvas; returns the nearest point's margin. */
export function drawSection(canvas, section, gauge, { chainage, colors, halfWidthM = 8 }) {
  const ctx = canvas.getContext('2d');
  const W = canvas.width, H = canvas.height;
  const pad = 34;
  const hMin = -2, hMax = 9;
  const scale = Math.min((W - 2 * pad) / (2 * halfWidthM), (H - 2 * pad) / (hMax - hMin));
  const X = (u) => W / 2 - u * scale; // looking along increasing chainage: left is left
  const Y = (h) => H - pad - (h - hMin) * scale;
  ctx.fillStyle = '#0d1117';
  ctx.fillRect(0, 0, W, H);
  drawGrid(ctx, X, Y, halfWidthM, hMin, hMax);
  ctx.save();
  ctx.beginPath();
  ctx.rect(X(halfWidthM), Y(hMax), X(-halfWidthM) - X(halfWidthM), Y(hMin) - Y(hMax));
  ctx.clip();
  for (const [u, h, run] of section.points) {
    ctx.fillStyle = colors[run] ?? '#ccc';
    ctx.fillRect(X(u) - 1, Y(h) - 1, 2, 2);
  }
  ctx.restore();
  ctx.strokeStyle = '#ff4d4f';
  ctx.lineWidth = 2;
  ctx.setLineDash([6, 4]);
  ctx.beginPath();
  gauge.forEach(([u, h], i) => (i ? ctx.lineTo(X(u), Y(h)) : ctx.moveTo(X(u), Y(h))));
  ctx.closePath();
  ctx.stroke();
  ctx.setLineDash([]);
  const nearest = nearestToGauge(section.points, gauge);
  ctx.fillStyle = '#e6edf3';
  ctx.font = '12px sans-serif';
  ctx.fillText(`${formatKm(chainage / 1000)} looking forward; ${section.points.length} points`, 8, 16);
  if (nearest) {
    ctx.strokeStyle = nearest.margin < 0 ? '#ff4d4f' : '#3fb950';
    ctx.beginPath();
    ctx.arc(X(nearest.u), Y(nearest.h), 6, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.fillText(
      `nearest point: margin ${nearest.margin.toFixed(2)} m (offset ${nearest.u.toFixed(2)} m, ` +
        `${nearest.h.toFixed(2)} m above rail)`,
      8,
      32,
    );
  }
  return nearest;
}

function drawGrid(ctx, X, Y, halfWidthM, hMin, hMax) {
  ctx.strokeStyle = '#263040';
  ctx.fillStyle = '#8b949e';
  ctx.lineWidth = 1;
  ctx.font = '10px sans-serif';
  for (let u = -Math.floor(halfWidthM); u <= halfWidthM; u += 2) {
    ctx.beginPath();
    ctx.moveTo(X(u), Y(hMin));
    ctx.lineTo(X(u), Y(hMax));
    ctx.stroke();
    ctx.fillText(`${u}`, X(u) - 4, Y(hMin) + 12);
  }
  for (let h = hMin; h <= hMax; h += 1) {
    ctx.beginPath();
    ctx.moveTo(X(halfWidthM), Y(h));
    ctx.lineTo(X(-halfWidthM), Y(h));
    ctx.stroke();
    ctx.fillText(`${h}`, X(halfWidthM) - 16, Y(h) + 3);
  }
  ctx.strokeStyle = '#8b949e';
  ctx.beginPath();
  ctx.moveTo(X(halfWidthM), Y(0));
  ctx.lineTo(X(-halfWidthM), Y(0));
  ctx.stroke();
}
