// The legend for the colouring in use.
import { escapeHtml } from './util.js';

const RAMP = 'linear-gradient(90deg, #2e3399, #1aa6bf, #59cc4d, #f2d940, #d94026)';

export function drawLegend(el, mode, { runs, colors, heightRange, hasReference }) {
  let html = '';
  if (mode === 'intensity') {
    html = 'intensity<div class="bar" style="background: linear-gradient(90deg,#000,#fff)"></div>low · high';
  } else if (mode === 'height') {
    html = `height (m)<div class="bar" style="background:${RAMP}"></div>` +
      `${heightRange.x.toFixed(0)} · ${heightRange.y.toFixed(0)}`;
  } else if (mode === 'run') {
    html = runs
      .map((r, i) => {
        const c = colors[runs.length === 2 ? i : 1].getStyle();
        return `<div><span class="swatch" style="background:${c}"></span>run ${escapeHtml(r)}</div>`;
      })
      .join('');
  } else if (mode === 'change') {
    html = hasReference
      ? `distance to the other run (m)<div class="bar" style="background: linear-gradient(90deg,#b3b3b3 0 20%, #59cc4d 20%, #f2d940 55%, #d94026)"></div>0 · 0.1 · ≥1` +
        '<div><span class="swatch" style="background:#5973bf"></span>not compared yet</div>'
      : 'pick a second run under Compare to colour by change';
  }
  el.innerHTML = html;
}
