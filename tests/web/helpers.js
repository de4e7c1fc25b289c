// What every spec shares: the fixture's state, a page that fails its test on any console error
// or unhandled rejection, waiting on the viewer's state, and screenshots kept as artefacts.
import fs from 'node:fs';
import path from 'node:path';
import { expect } from '@playwright/test';
import { decodePng, countColor } from './png.js';
import { stateFile } from './fixture.js';

export const fixture = () => JSON.parse(fs.readFileSync(stateFile, 'utf8'));
export const BACKGROUND = [16, 20, 26];

/** Collects console errors and page errors; `check()` asserts there were none. */
export function watchErrors(page) {
  const errors = [];
  page.on('console', (m) => {
    if (m.type() === 'error') errors.push(`console: ${m.text()}`);
  });
  page.on('pageerror', (e) => errors.push(`page error: ${e.message}`));
  return {
    errors,
    check: () => expect(errors, errors.join('\n')).toEqual([]),
  };
}

export async function viewerState(page) {
  return page.evaluate(() => window.raillomer?.snapshot());
}

export async function waitForPoints(page, min = 1) {
  await expect
    .poll(async () => (await viewerState(page))?.points ?? 0, { timeout: 90_000 })
    .toBeGreaterThanOrEqual(min);
  await expect.poll(async () => (await viewerState(page)).inFlight, { timeout: 90_000 }).toBe(0);
}

/** A screenshot kept under results/screenshots/, with its pixels. */
export async function shot(page, name, locator) {
  const file = path.join(path.dirname(stateFile), 'screenshots', `${name}.png`);
  const buffer = await (locator ?? page).screenshot({ path: file });
  return decodePng(buffer);
}

export { countColor };
