// Before the browser tests: a server with three runs of the demo line (the second changed, the
// third the changed line again with other sensor noise, whose changes continue the second's;
// their detections done), the state the specs read in results/fixture.json.
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
  await streamRun(server, CHANGED, 'Demo', { seed: 7 }).done;
  const runs = (await getJson(server, '/api/v1/runs')).runs;
  const [reference, changed, repeat] = runs.map((r) => r.id);
  for (const run of [changed, repeat]) {
    await waitFor(`change detection of run ${run}`, async () => {
      const c = await getJson(server, `/api/v1/runs/${run}/changes`);
      return c.detection.status === 'done';
    }, 180_000, 500);
  }
  fs.writeFileSync(stateFile, JSON.stringify({ ...server, reference, changed, repeat }, null, 2));
  return () => server.stop();
}
