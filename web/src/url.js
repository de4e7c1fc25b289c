// The view's state in the URL (line, run, compare, km, camera, colour, change), so a link
// opens the same view.
export function readUrl() {
  const q = new URLSearchParams(location.search);
  const num = (k) => (q.has(k) && q.get(k) !== '' && Number.isFinite(Number(q.get(k))) ? Number(q.get(k)) : undefined);
  const cam = q.get('cam')?.split(',').map(Number);
  return {
    line: q.get('line') || undefined,
    run: num('run'),
    compare: num('compare'),
    km: num('km'),
    cam: cam?.length === 6 && cam.every(Number.isFinite) ? cam : undefined,
    color: q.get('color') || undefined,
    change: num('change'),
  };
}

export function writeUrl(state) {
  const q = new URLSearchParams();
  if (state.line) q.set('line', state.line);
  q.set('run', state.run);
  if (state.compare) q.set('compare', state.compare);
  if (Number.isFinite(state.km)) q.set('km', state.km.toFixed(3));
  if (state.cam) q.set('cam', state.cam.map((v) => v.toFixed(2)).join(','));
  if (state.color && state.color !== 'intensity') q.set('color', state.color);
  if (state.change) q.set('change', state.change);
  const next = `${location.pathname}?${q}`;
  if (next !== location.pathname + location.search) history.replaceState(null, '', next);
}
