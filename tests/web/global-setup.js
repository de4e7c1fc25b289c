// Before the browser tests: a server with two runs of the demo line (the second changed, its
// detection done), the state the specs read in results/fixture.json.
import fs from 'node:fs';
import path from 'node:path';
import { getJson, startServer, stateFile, streamRun, waitFor, webRoot } from './fixture.js';

const CHANGED = 'demo_changed'; // the simulator's built-in changed run of the demo line

export default async function globalSetup() {
  if (!fs.existsSync(path.join(webRoot, 'index.html'))) {
    throw new Error(`no built viewer in ${webRoot}: npm --prefix web ci && npm --prefix web run build`);
  }
  fs.mkdirSync(path.dirname(stateFile), { recursive: true });
  const server = await startServer();
  await streamRun(server, 'demo', 'Demo').done;
  await streamRun(server, CHANGED, 'Demo', { seed: 5 }).done;
  const runs = (await getJson(server, '/api/v1/runs')).runs;
  const [reference, changed] = runs.map((r) => r.id);
  await waitFor('change detection of the second run', async () => {
    const c = await getJson(server, `/api/v1/runs/${changed}/changes`);
    return c.detection.status === 'done';
  }, 180_000, 500);
  fs.writeFileSync(stateFile, JSON.stringify({ ...server, reference, changed }, null, 2));
  return () => server.stop();
}
