// The viewer in Debian's chromium against a real server holding two streamed runs of the demo
// line: points drawn, km navigation, the cross-section's gauge, the changes, POIs, errors.
import { test, expect } from '@playwright/test';
import { getJson } from './fixture.js';
import { BACKGROUND, countColor, fixture, shot, viewerState, waitForPoints, watchErrors } from './helpers.js';

let errors;
test.beforeEach(({ page }) => {
  errors = watchErrors(page);
});
test.afterEach(() => errors.check());

test('the bare address opens the most recent run and draws its points', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/`);
  await waitForPoints(page, 10_000);
  const runs = (await getJson(f, '/api/v1/runs')).runs;
  const live = runs.filter((r) => r.status === 'live');
  const newest = (live.length ? live : runs).reduce((a, b) => (b.start_ns > a.start_ns ? b : a));
  const state = await viewerState(page);
  expect(state.run).toBe(newest.id);
  await expect.poll(() => page.url()).toContain(`run=${newest.id}`);
  const png = await shot(page, 'map', page.locator('#viewport > canvas'));
  const drawn = countColor(png, BACKGROUND, 6).other;
  expect(drawn / (png.width * png.height)).toBeGreaterThan(0.02);
});

test('a kilometre typed as K0+200 moves the camera there', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/?run=${f.reference}`);
  await waitForPoints(page);
  const before = (await viewerState(page)).target;
  await page.fill('#km-input', 'K0+200');
  await page.press('#km-input', 'Enter');
  const tum = await (await fetch(`${f.base}/api/v1/runs/${f.reference}/trajectory?format=tum`)).text();
  const geo = await getJson(f, `/api/v1/runs/${f.reference}/trajectory?format=geojson`);
  const poses = tum.split('\n').filter((l) => l && !l.startsWith('#')).map((l) => l.split(' ').map(Number));
  const chainage = geo.features?.[0]?.properties.chainage_m ?? geo.properties.chainage_m;
  let best = 0;
  chainage.forEach((c, i) => {
    if (c !== null && Math.abs(c - 200) < Math.abs(chainage[best] - 200)) best = i;
  });
  const expected = poses[best].slice(1, 4);
  const after = (await viewerState(page)).target;
  expect(Math.hypot(after[0] - expected[0], after[1] - expected[1])).toBeLessThan(2);
  expect(Math.hypot(after[0] - before[0], after[1] - before[1])).toBeGreaterThan(20);
  await expect.poll(() => page.url()).toMatch(/km=0\.(19|20)\d/);
  await waitForPoints(page);
  await shot(page, 'km-jump');
  // A link with that URL opens the same view.
  const link = page.url();
  const other = await page.context().newPage();
  await other.goto(link);
  await expect.poll(async () => (await viewerState(other))?.target ?? [0, 0]).not.toEqual([0, 0]);
  const reopened = (await viewerState(other)).target;
  expect(Math.hypot(reopened[0] - after[0], reopened[1] - after[1])).toBeLessThan(0.5);
});

test('a cross-section shows the points under the structure gauge', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/?run=${f.reference}`);
  await waitForPoints(page);
  await page.click('button[data-tab="tools"]');
  await page.fill('#section-km', '0.15');
  await page.fill('#section-thickness', '1');
  await page.click('#section-btn');
  await expect(page.locator('#section-panel')).toBeVisible();
  await expect.poll(() => page.evaluate(() => window.raillomer.tools.section?.points ?? 0)).toBeGreaterThan(200);
  const section = await page.evaluate(() => window.raillomer.tools.section);
  // Both rails lie on the rail plane the section found, the nearest point's margin is measured
  // (the platform edge at K0+150 stands inside the default four-corner gauge).
  expect(section.rails[0]).toBeGreaterThanOrEqual(4);
  expect(section.rails[1]).toBeGreaterThanOrEqual(4);
  expect(Number.isFinite(section.margin)).toBe(true);
  await expect(page.locator('#section-panel')).toBeVisible();
  const png = await shot(page, 'section', page.locator('#section-canvas'));
  expect(countColor(png, [255, 77, 79], 30).near).toBeGreaterThan(300); // the gauge's outline
  expect(countColor(png, [255, 138, 61], 30).near).toBeGreaterThan(100); // the points
});

test('the changed run lists its changes; one is opened and its status set', async ({ page }) => {
  const f = fixture();
  const api = await getJson(f, `/api/v1/runs/${f.changed}/changes`);
  expect(api.features.length).toBeGreaterThan(0);
  await page.goto(`${f.base}/?run=${f.changed}`);
  const items = page.locator('#changes-list li');
  await expect(items).toHaveCount(api.features.length);
  const first = api.features[0].properties;
  await page.click(`#changes-list li[data-change-id="${first.id}"]`);
  await expect(page.locator('#change-detail')).toBeVisible();
  await expect(page.locator('#change-title')).toContainText(first.kind);
  // The changed run is the first after the reference: nothing continues an earlier change.
  await expect(page.locator('#change-props')).toContainText('first seenthis run');
  await expect.poll(() => page.evaluate(() => document.getElementById('change-snapshot').naturalWidth)).toBeGreaterThan(100);
  // Without the token the write is refused and says so.
  await page.selectOption('#change-status', 'confirmed');
  await page.click('#change-save');
  await expect(page.locator('#status')).toContainText('token');
  await page.fill('#token-input', f.token);
  await page.click('#change-save');
  await expect(page.locator('#status')).toContainText('confirmed');
  const stored = await getJson(f, `/api/v1/changes/${first.id}`);
  expect(stored.properties.status).toBe('confirmed');
  await shot(page, 'change');
  // The report is one click away.
  const href = await page.locator('#report-link').getAttribute('href');
  expect((await fetch(f.base + href)).status).toBe(200);
});

test('a change found again by a later run says since when, in the list and its details', async ({ page }) => {
  const f = fixture();
  const api = await getJson(f, `/api/v1/runs/${f.repeat}/changes`);
  const again = api.features.map((x) => x.properties).filter((c) => c.earlier_change);
  expect(again.length).toBeGreaterThan(0);
  await page.goto(`${f.base}/?run=${f.repeat}`);
  const item = page.locator(`#changes-list li[data-change-id="${again[0].id}"]`);
  await expect(item).toContainText(`since run ${f.changed}`);
  await item.click();
  await expect(page.locator('#change-props')).toContainText(
    `first seenrun ${f.changed} (continues change ${again[0].earlier_change})`,
  );
  // A change new in this run carries no such mark.
  const fresh = api.features.map((x) => x.properties).find((c) => !c.earlier_change);
  if (fresh) await expect(page.locator(`#changes-list li[data-change-id="${fresh.id}"]`)).not.toContainText('since run');
});

test('the changes are reviewed one after another: n, p, the arrows and Save, next', async ({ page }) => {
  const f = fixture();
  const api = await getJson(f, `/api/v1/runs/${f.changed}/changes`);
  // The list's order: intrusions first, then by kilometre.
  const order = api.features
    .map((x) => x.properties)
    .sort((a, b) => b.intrudes_envelope - a.intrudes_envelope || a.chainage_m - b.chainage_m);
  expect(order.length).toBeGreaterThan(2);
  await page.goto(`${f.base}/?run=${f.changed}`);
  await expect(page.locator('#changes-list li')).toHaveCount(order.length);
  const title = page.locator('#change-title');
  const position = page.locator('#change-position');
  await page.keyboard.press('n');
  await expect(title).toContainText(`Change ${order[0].id}:`);
  await expect(position).toHaveText(`1 of ${order.length}`);
  await expect(page.locator('#change-prev')).toBeDisabled();
  await page.keyboard.press('n');
  await expect(title).toContainText(`Change ${order[1].id}:`);
  await page.keyboard.press('p');
  await expect(title).toContainText(`Change ${order[0].id}:`);
  for (let i = 1; i < order.length; ++i) await page.click('#change-next');
  await expect(title).toContainText(`Change ${order[order.length - 1].id}:`);
  await expect(position).toHaveText(`${order.length} of ${order.length}`);
  await expect(page.locator('#change-next')).toBeDisabled();
  // A key typed into the note is text, not a step.
  await page.fill('#change-note', '');
  await page.type('#change-note', 'np');
  await expect(title).toContainText(`Change ${order[order.length - 1].id}:`);
  // Save, next: the status is stored and the next change opens.
  await page.click('#change-prev');
  const reviewed = order[order.length - 2];
  await expect(title).toContainText(`Change ${reviewed.id}:`);
  await page.fill('#token-input', f.token);
  await page.selectOption('#change-status', 'dismissed');
  await page.fill('#change-note', 'a shadow');
  await page.click('#change-save-next');
  await expect(title).toContainText(`Change ${order[order.length - 1].id}:`);
  const stored = await getJson(f, `/api/v1/changes/${reviewed.id}`);
  expect(stored.properties.status).toBe('dismissed');
  expect(stored.properties.note).toBe('a shadow');
  await expect(page.locator(`#changes-list li[data-change-id="${reviewed.id}"]`)).toContainText('dismissed');
  // What is still open leaves the dismissed one out; the dismissed alone is that one.
  await page.selectOption('#change-state', 'new,confirmed');
  await expect(page.locator('#changes-list li')).toHaveCount(order.length - 1);
  await expect(page.locator(`#changes-list li[data-change-id="${reviewed.id}"]`)).toHaveCount(0);
  await page.selectOption('#change-state', 'dismissed');
  await expect(page.locator('#changes-list li')).toHaveCount(1);
  await expect(page.locator('#changes-list li')).toContainText('dismissed');
  // The report link carries the list's filters: the report holds the dismissed change alone.
  const href = await page.locator('#report-link').getAttribute('href');
  expect(href).toContain('status=dismissed');
  const report = await (await fetch(f.base + href)).text();
  expect(report).toContain('status dismissed');
  expect(report.match(/id="change-\d+"/g)).toEqual([`id="change-${reviewed.id}"`]);
});

test('a point of interest is added, renamed and deleted through the page', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/?run=${f.reference}`);
  await waitForPoints(page);
  await page.fill('#token-input', f.token);
  await page.click('button[data-tab="pois"]');
  await page.fill('#poi-kind', 'mast');
  await page.fill('#poi-name', 'M-17');
  await page.click('#poi-save');
  await expect(page.locator('#poi-list li')).toHaveCount(1);
  let pois = (await getJson(f, '/api/v1/pois?line=Demo')).pois;
  expect(pois.map((p) => p.name)).toEqual(['M-17']);
  await page.click('#poi-list li .poi-edit');
  await page.fill('#poi-name', 'M-18');
  await page.click('#poi-save');
  await expect(page.locator('#poi-list li')).toContainText('M-18');
  pois = (await getJson(f, '/api/v1/pois?line=Demo')).pois;
  expect(pois.map((p) => p.name)).toEqual(['M-18']);
  await page.click('#poi-list li .poi-delete');
  await expect(page.locator('#poi-list li')).toHaveCount(0);
  expect((await getJson(f, '/api/v1/pois?line=Demo')).pois).toEqual([]);
});

test('an unreachable server is said so, not left blank', async ({ page }) => {
  const f = fixture();
  await page.route('**/api/v1/**', (route) => route.abort('connectionrefused'));
  errors.errors.length = 0;
  await page.goto(`${f.base}/`);
  await expect(page.locator('#message')).toContainText('unreachable');
  // The browser logs the refused requests itself; those are what this test provokes.
  errors.errors.splice(0, errors.errors.length, ...errors.errors.filter((e) => !/ERR_CONNECTION_REFUSED|Failed to load resource/.test(e)));
});

test('two runs in one view: coloured by run, split by a divide, coloured by change', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/?run=${f.changed}&compare=${f.reference}&color=run`);
  await waitForPoints(page);
  expect((await viewerState(page)).compare).toBe(f.reference);
  await expect(page.locator('.split-control')).toBeVisible();
  const canvas = page.locator('#viewport > canvas');
  let png = await shot(page, 'two-runs', canvas);
  // Both runs' colours (blue: the reference, orange: the later run; shaded by intensity).
  const blueish = (p) => countHue(p, (r, g, b) => b > r + 40 && b > g);
  const orangeish = (p) => countHue(p, (r, g, b) => r > b + 40 && g > b);
  const blueBefore = blueish(png);
  expect(blueBefore).toBeGreaterThan(2000);
  expect(orangeish(png)).toBeGreaterThan(2000);
  // The divide at the start: only the later run is left in view (a change's box and the
  // legend's swatch stay blue).
  await page.locator('#split').fill('0');
  await expect.poll(async () => blueish(await shot(page, 'two-runs-split', canvas))).toBeLessThan(blueBefore / 10);
  png = await shot(page, 'two-runs-split', canvas);
  expect(orangeish(png)).toBeGreaterThan(2000);
  // Colour by change: the distance to the other run, grey where they agree.
  await page.locator('#split').fill('500');
  await page.selectOption('#color-select', 'change');
  await expect(page.locator('#legend')).toContainText('distance to the other run');
  await waitForPoints(page);
  png = await shot(page, 'change-colours', canvas);
  // Registered as the detection registered them, the runs agree almost everywhere.
  const grey = countHue(png, (r, g, b) => Math.abs(r - g) < 8 && Math.abs(g - b) < 8 && r > 60);
  const red = countHue(png, (r, g, b) => r > 150 && g < 110 && b < 80);
  expect(grey).toBeGreaterThan(2000);
  expect(grey).toBeGreaterThan(5 * red);
});

test('two later runs of one reference are both drawn where the detection registered them', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/?run=${f.changed}&compare=${f.repeat}&color=change`);
  await expect(page.locator('#legend')).toContainText('distance to the other run');
  await waitForPoints(page);
  const png = await shot(page, 'two-later-runs', page.locator('#viewport > canvas'));
  // Each in the reference's map, the runs (one line changed the same way twice) agree almost
  // everywhere: grey, not red.
  const grey = countHue(png, (r, g, b) => Math.abs(r - g) < 8 && Math.abs(g - b) < 8 && r > 60);
  const red = countHue(png, (r, g, b) => r > 150 && g < 110 && b < 80);
  expect(grey).toBeGreaterThan(2000);
  expect(grey).toBeGreaterThan(5 * red);
});

test('measuring two points and the track profile', async ({ page }) => {
  const f = fixture();
  await page.goto(`${f.base}/?run=${f.reference}`);
  await waitForPoints(page);
  await page.click('button[data-tab="tools"]');
  const box = await page.locator('#viewport > canvas').boundingBox();
  await page.mouse.move(box.x + box.width * 0.5, box.y + box.height * 0.75);
  await page.keyboard.down('Shift');
  await page.mouse.down();
  await page.mouse.up();
  await page.mouse.move(box.x + box.width * 0.6, box.y + box.height * 0.85);
  await page.mouse.down();
  await page.mouse.up();
  await page.keyboard.up('Shift');
  await expect(page.locator('#measure-out')).toContainText('distance');
  await expect(page.locator('#measure-out')).toContainText('above rail');
  const m = await page.evaluate(() => window.raillomer.tools.measurement);
  expect(m.distance).toBeGreaterThan(0.5);
  expect(m.distance).toBeLessThan(100);
  await page.click('button[data-tab="profile"]');
  await page.fill('#profile-from', '0.05');
  await page.fill('#profile-to', '0.25');
  await page.click('#profile-form button');
  await expect
    .poll(async () => countHue(await shot(page, 'profile', page.locator('#profile-canvas')), (r, g, b) => b > 200 && r < 120))
    .toBeGreaterThan(50);
});

function countHue(png, test) {
  let n = 0;
  for (let i = 0; i < png.pixels.length; i += 3) if (test(png.pixels[i], png.pixels[i + 1], png.pixels[i + 2])) n++;
  return n;
}

test('tiles seen before are revalidated by their ETag, not fetched again', async ({ page }) => {
  const f = fixture();
  const count304 = async () => {
    const text = await (await fetch(`${f.base}/metrics`)).text();
    const m = /raillomer_http_requests_total\{route="tiles\.get",status="304"\} (\d+)/.exec(text);
    return m ? Number(m[1]) : 0;
  };
  await page.goto(`${f.base}/?run=${f.reference}`);
  await waitForPoints(page);
  const before = await count304();
  await page.reload();
  await waitForPoints(page);
  expect(await count304()).toBeGreaterThan(before);
});

test('a run without tiles says so over the view', async ({ page }) => {
  const f = fixture();
  const post = (p, body) =>
    fetch(f.base + p, {
      method: 'POST',
      headers: { Authorization: `Bearer ${f.token}`, 'Content-Type': 'application/json' },
      body: JSON.stringify(body),
    }).then((r) => r.json());
  const run = await post('/api/v1/runs', { line: 'Empty line', vehicle: 'RLM-9' });
  try {
    await page.goto(`${f.base}/?run=${run.id}`);
    await expect(page.locator('#message')).toContainText(`Run ${run.id} has no tiles yet`);
  } finally {
    await post(`/api/v1/runs/${run.id}/finish`, {});
  }
});
