// A run streamed while the viewer is open: the bare address opens it (a live run first), the
// train's marker moves, tiles written during the run appear without a reload, and the changes
// found as it passes pop into the list.
import path from 'node:path';
import { test, expect } from '@playwright/test';
import { getJson, repo, streamRun, waitFor } from './fixture.js';
import { BACKGROUND, countColor, fixture, shot, viewerState, watchErrors } from './helpers.js';

test('a streaming run grows on screen without a reload', async ({ page }) => {
  const errors = watchErrors(page);
  const f = fixture();
  const before = (await getJson(f, '/api/v1/runs')).runs.length;
  const stream = streamRun(f, path.join(repo, 'tests/tools/change_scenarios/demo_changed_b.yaml'), 'Demo', { seed: 7 });
  const run = await waitFor('the streamed run to be created', async () => {
    const runs = (await getJson(f, '/api/v1/runs')).runs;
    return runs.length > before ? runs[runs.length - 1] : null;
  }, 60_000, 100);
  await page.goto(`${f.base}/`);
  await expect.poll(async () => (await viewerState(page))?.run).toBe(run.id);
  const first = await viewerState(page);
  await expect.poll(async () => (await viewerState(page)).train, { timeout: 90_000 }).not.toBeNull();
  await expect
    .poll(async () => (await viewerState(page)).liveLatencyMs.length, { timeout: 90_000 })
    .toBeGreaterThan(0);
  const grown = await viewerState(page);
  expect(grown.tilesLoaded).toBeGreaterThan(first.tilesLoaded);
  await shot(page, 'live');
  await stream.done;
  // The changes found as the train passed arrive on the hub and into the list.
  await expect
    .poll(async () => (await viewerState(page)).changes, { timeout: 120_000 })
    .toBeGreaterThan(0);
  // Once the run's report is final (stretches compared on provisional output are compared
  // again after the run ends), the list holds exactly its changes.
  const api = await waitFor('the run\'s final report', async () => {
    const answer = await getJson(f, `/api/v1/runs/${run.id}/changes`);
    return answer.detection.status === 'done' ? answer : null;
  }, 120_000, 500);
  await expect(page.locator('#changes-list li')).toHaveCount(api.features.length, { timeout: 60_000 });
  const png = await shot(page, 'live-done', page.locator('#viewport > canvas'));
  expect(countColor(png, BACKGROUND, 6).other).toBeGreaterThan(1000);
  errors.check();
});
