export function escapeHtml(s) {
  const map = { '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' };
  return String(s).replace(/[&<>"']/g, (c) => map[c]);
}

export const fmt = (v, digits = 2) => (Number.isFinite(v) ? v.toFixed(digits) : '–');
