// The viewer benchmark (slow tier): one long test, no shared fixture.
import { defineConfig } from '@playwright/test';
import base from '../playwright.config.js';

export default defineConfig({
  ...base,
  testDir: '.',
  testMatch: /.*\.bench\.js/,
  globalSetup: undefined,
  outputDir: '../results/bench-artifacts',
  timeout: 1_800_000,
});
