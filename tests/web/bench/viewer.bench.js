// The viewer's figures (issue 49) on a streamed 3 km run, server on loopback, headless Debian
// chromium with software WebGL (SwiftShader): first points after navigation, live tiles'
// delay from the server writing them to the screen (p95; also counted from when the view first
// wanted each, so that time out of view is told apart), the page's JavaScript gzipped, and
// console errors. Prints the figures as JSON and checks them against the targets.
import fs from 'node:fs';
import path from 'node:path';
import zlib from 'node:zlib';
import { test, expect } from '@playwright/test';
import { getJson, repo, startServer, streamRun, waitFor, webRoot } from '../fixture.js';
import { viewerState, watchErrors } from '../helpers.js';

const SCENARIO = process.env.BENCH_SCENARIO || 'rich_high_town_a';
const percentile = (v, q) => [...v].sort((a, b) => a - b)[Math.min(v.length - 1, Math.floor(q * v.length))];

function javascriptGzipBytes() {
  const assets = path.join(webRoot, 'assets');
  return fs
    .readdirSync(assets)
    .filter((f) => f.endsWith('.js'))
    .reduce((n, f) => n + zlib.gzipSync(fs.readFileSync(path.join(assets, f)), { level: 9 }).length, 0);
}

test('viewer figures on a streamed 3 km run', async ({ page, browser }) => {
  test.setTimeout(1_800_000);
  const server = await startServer();
  const errors = watchErrors(page);
  try {
    const stream = streamRun(server, SCENARIO, 'Bench line');
    const run = await waitFor('the run to be created', async () => (await getJson(server, '/api/v1/runs')).runs[0], 120_000, 100);
    await page.goto(`${server.base}/?run=${run.id}`);
    await stream.done;
    await page.waitForTimeout(3000);
    const { liveLatencyMs: live, liveViewLatencyMs: liveInView } = await viewerState(page);
    await page.close();

    // The final stretches' detection done, the server idle: fresh browser contexts (nothing
    // cached) open the finished run; the page tells when its first frame with points was drawn,
    // in milliseconds from the navigation's start.
    await waitFor('the run\'s detection to finish', async () => {
      const c = await getJson(server, `/api/v1/runs/${run.id}/changes`);
      return ['done', 'failed'].includes(c.detection.status) || c.detection.reason;
    }, 300_000, 1000);
    const firstPoints = [];
    const freshErrors = [];
    for (let i = 0; i < 5; i++) {
      const context = await browser.newContext({ viewport: { width: 1280, height: 800 } });
      const fresh = await context.newPage();
      freshErrors.push(watchErrors(fresh));
      await fresh.goto(`${server.base}/?run=${run.id}`);
      await expect.poll(async () => (await viewerState(fresh))?.firstPointsMs ?? null, { timeout: 60_000 }).not.toBeNull();
      firstPoints.push(Math.round((await viewerState(fresh)).firstPointsMs));
      await context.close();
    }
    const result = {
      scenario: SCENARIO,
      km: (await getJson(server, '/api/v1/lines')).lines[0]?.length_m / 1000,
      rendering: 'headless chromium, SwiftShader (software WebGL), 2 cores shared with server and estimator',
      first_points_ms: firstPoints,
      first_points_ms_median: percentile(firstPoints, 0.5),
      first_points_note: 'from navigation start to the end of the first frame with points, fresh browser context each, run finished and server idle',
      live_tiles_drawn: live.length,
      live_tile_ms_p50: live.length ? Math.round(percentile(live, 0.5)) : null,
      live_tile_ms_p95: live.length ? Math.round(percentile(live, 0.95)) : null,
      live_tile_in_view_ms_p50: liveInView.length ? Math.round(percentile(liveInView, 0.5)) : null,
      live_tile_in_view_ms_p95: liveInView.length ? Math.round(percentile(liveInView, 0.95)) : null,
      live_tile_note: 'from the server announcing a tile to the frame that draws it; in_view: from the later of that and the view first wanting it',
      javascript_gzip_kb: Math.round(javascriptGzipBytes() / 1024),
      console_errors: errors.errors.length + freshErrors.reduce((n, e) => n + e.errors.length, 0),
    };
    console.log(`VIEWER_BENCH ${JSON.stringify(result)}`);
    fs.mkdirSync(path.join(repo, 'tests/web/results'), { recursive: true });
    fs.writeFileSync(path.join(repo, 'tests/web/results/bench.json'), JSON.stringify(result, null, 2));
    expect(result.first_points_ms_median).toBeLessThanOrEqual(1500);
    expect(result.live_tiles_drawn).toBeGreaterThan(0);
    expect(result.live_tile_ms_p95).toBeLessThanOrEqual(3000);
    expect(result.javascript_gzip_kb).toBeLessThanOrEqual(400);
    errors.check();
    freshErrors.forEach((e) => e.check());
  } finally {
    await server.stop();
  }
});
