// The track profile of a km range (from the segment API): gradient, curvature and cant
// against chainage, one strip each.
import { formatKm } from './track.js';

const STRIPS = [
  { key: 'gradient_per_mille', label: 'gradient ‰', color: '#58a6ff', scale: 1 },
  { key: 'curvature_per_m', label: 'curvature 1/km', color: '#f0883e', scale: 1000 },
  { key: 'cant_mm', label: 'cant mm', color: '#3fb950', scale: 1 },
];

export function drawProfile(canvas, profile) {
  const ctx = canvas.getContext('2d');
  const W = canvas.width, H = canvas.height;
  ctx.fillStyle = '#0d1117';
  ctx.fillRect(0, 0, W, H);
  const c = profile.chainage_m;
  ctx.font = '11px sans-serif';
  if (!c || c.length < 2) {
    ctx.fillStyle = '#8b949e';
    ctx.fillText('no centreline in this range', 10, 20);
    return;
  }
  const left = 70, right = 8;
  const X = (s) => left + ((s - c[0]) / (c[c.length - 1] - c[0] || 1)) * (W - left - right);
  const stripH = (H - 20) / STRIPS.length;
  STRIPS.forEach((strip, k) => {
    const values = profile[strip.key].map((v) => v * strip.scale);
    const lo = Math.min(0, ...values), hi = Math.max(0, ...values);
    const span = hi - lo || 1;
    const top = k * stripH + 4, bottom = top + stripH - 8;
    const Y = (v) => bottom - ((v - lo) / span) * (bottom - top);
    ctx.strokeStyle = '#263040';
    ctx.beginPath();
    ctx.moveTo(left, Y(0));
    ctx.lineTo(W - right, Y(0));
    ctx.stroke();
    ctx.strokeStyle = strip.color;
    ctx.beginPath();
    values.forEach((v, i) => (i ? ctx.lineTo(X(c[i]), Y(v)) : ctx.moveTo(X(c[i]), Y(v))));
    ctx.stroke();
    ctx.fillStyle = strip.color;
    ctx.fillText(strip.label, 4, top + 12);
    ctx.fillStyle = '#8b949e';
    ctx.fillText(`${hi.toFixed(1)}`, 4, top + 26);
    ctx.fillText(`${lo.toFixed(1)}`, 4, bottom);
  });
  ctx.fillStyle = '#8b949e';
  ctx.fillText(formatKm(c[0] / 1000), left, H - 4);
  const end = formatKm(c[c.length - 1] / 1000);
  ctx.fillText(end, W - right - ctx.measureText(end).width, H - 4);
}
