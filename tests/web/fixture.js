// The real system the browser tests run against: raillomer-server on loopback ports the OS
// picks, serving the built viewer, with simulated runs streamed into it by raillomer-estimator.
import { spawn } from 'node:child_process';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
export const repo = path.resolve(here, '../..');
export const binDir = process.env.RAILLOMER_BIN || path.join(repo, 'build/bin');
export const webRoot = process.env.RAILLOMER_WEB_ROOT || path.join(repo, 'web/dist');
export const stateFile = path.join(here, 'results', 'fixture.json');

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

export async function waitFor(what, fn, timeoutMs = 120_000, everyMs = 250) {
  const until = Date.now() + timeoutMs;
  for (;;) {
    const value = await fn();
    if (value) return value;
    if (Date.now() > until) throw new Error(`timed out after ${timeoutMs} ms waiting for ${what}`);
    await sleep(everyMs);
  }
}

/** raillomer-server with its own store folder; resolves once it logs the ports it serves. */
export async function startServer() {
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'raillomer_web_'));
  const data = path.join(dir, 'data');
  const log = path.join(dir, 'server.log');
  const out = fs.openSync(log, 'w');
  const proc = spawn(
    path.join(binDir, 'raillomer-server'),
    ['--data', data, '--port', '0', '--ws-port', '0', '--web-root', webRoot],
    { stdio: ['ignore', out, out] },
  );
  const started = await waitFor('raillomer-server to start', () => {
    const text = fs.readFileSync(log, 'utf8');
    const m = /serving http:\/\/127\.0\.0\.1:(\d+)\/.*ws:\/\/127\.0\.0\.1:(\d+)\/live/.exec(text);
    if (m) return { port: Number(m[1]), wsPort: Number(m[2]) };
    if (proc.exitCode !== null) throw new Error(`raillomer-server did not start:\n${text}`);
    return null;
  }, 20_000, 50);
  const token = fs.readFileSync(path.join(data, 'ingest.token'), 'utf8').trim();
  return {
    ...started,
    token,
    dir,
    log,
    pid: proc.pid,
    base: `http://127.0.0.1:${started.port}`,
    /** Stops the server and removes its folder (store and log). */
    stop() {
      return new Promise((resolve) => {
        const removed = () => {
          fs.rmSync(dir, { recursive: true, force: true });
          resolve();
        };
        if (proc.exitCode !== null || proc.signalCode !== null) return removed();
        proc.once('exit', removed);
        proc.kill('SIGTERM');
      });
    },
  };
}

/** raillomer-estimator --sim streaming a simulated run into the server; resolves when done. */
export function streamRun(server, scenario, line, { seed, out } = {}) {
  const args = [
    '--sim', scenario, '--quiet', '--no-keyframes',
    '--out', out || fs.mkdtempSync(path.join(server.dir, 'run_')),
    '--server', server.base, '--token', server.token, '--line', line,
  ];
  if (seed !== undefined) args.push('--seed', String(seed));
  const proc = spawn(path.join(binDir, 'raillomer-estimator'), args, { stdio: ['ignore', 'ignore', 'pipe'] });
  let stderr = '';
  proc.stderr.on('data', (d) => (stderr += d));
  const done = new Promise((resolve, reject) => {
    proc.on('exit', (code) =>
      code === 0 ? resolve() : reject(new Error(`raillomer-estimator ${scenario} failed (${code}):\n${stderr}`)),
    );
  });
  return { proc, done };
}

export async function getJson(server, p) {
  const res = await fetch(server.base + p);
  if (!res.ok) throw new Error(`GET ${p}: ${res.status} ${await res.text()}`);
  return res.json();
}
